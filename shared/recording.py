"""Run logs: every message of a run, as received, so that it can be replayed and re-plotted.

File layout (`*.ctlog`):

    b"CTLOG1\\n" | one JSON line of metadata | records...
    record = uint64 t_ns (receive time, ns since epoch) | uint16 key length | uint32 payload length
             | key (utf-8) | payload (the codec bytes exactly as they travelled)

Payloads are stored undecoded: a log keeps even messages the recorder could not decode, and
replay republishes the very bytes that were sent.
"""
from __future__ import annotations

import json
import struct
import threading
import time
from pathlib import Path
from typing import Any, BinaryIO, Iterator

MAGIC = b"CTLOG1\n"
_REC = struct.Struct("<QHI")


class LogFormatError(ValueError):
    """Not a cinetransfer run log, or a corrupt one."""


class LogWriter:
    """Append records to a log; thread-safe; flushes on close."""

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f: BinaryIO = open(self.path, "wb")
        self._f.write(MAGIC + json.dumps(meta or {}, default=str).encode() + b"\n")
        self._lock = threading.Lock()
        self.count = 0

    def write(self, key: str, payload: bytes, t_ns: int | None = None) -> None:
        k = key.encode()
        with self._lock:
            self._f.write(_REC.pack(time.time_ns() if t_ns is None else t_ns, len(k), len(payload)))
            self._f.write(k)
            self._f.write(payload)
            self.count += 1

    def flush(self) -> None:
        with self._lock:
            self._f.flush()

    def close(self) -> None:
        with self._lock:
            if not self._f.closed:
                self._f.close()

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_meta(path: str | Path) -> dict[str, Any]:
    with open(path, "rb") as f:
        return _read_header(f)


def _read_header(f: BinaryIO) -> dict[str, Any]:
    if f.read(len(MAGIC)) != MAGIC:
        raise LogFormatError(f"{getattr(f, 'name', 'log')}: not a cinetransfer run log (bad magic)")
    line = f.readline()
    try:
        return json.loads(line)
    except json.JSONDecodeError as e:
        raise LogFormatError(f"corrupt log metadata: {e}") from None


def read_log(path: str | Path, keyexpr_prefix: str = "") -> Iterator[tuple[int, str, bytes]]:
    """(t_ns, key, payload) for every record; a record cut short at the end (crash) is skipped."""
    with open(path, "rb") as f:
        _read_header(f)
        while True:
            head = f.read(_REC.size)
            if len(head) < _REC.size:
                return
            t_ns, klen, plen = _REC.unpack(head)
            key = f.read(klen)
            payload = f.read(plen)
            if len(key) < klen or len(payload) < plen:
                return  # truncated tail: keep what was complete
            k = key.decode(errors="replace")
            if k.startswith(keyexpr_prefix):
                yield t_ns, k, payload
