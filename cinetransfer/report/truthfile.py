"""The truth file of a run: the simulator's GroundTruth messages, one per recorded frame.

Format (`RUN_DIR/truth.msgpack`): a plain concatenation of records, each

    length L (uint32, little-endian) | codec.encode(GroundTruth) (L bytes)

so it can be appended to while recording and read back after a crash or Ctrl-C: a truncated
last record is dropped (and counted), never fatal. Every record is decoded and validated by
the message codec (`cinetransfer.shared.codec`), so a wrong schema version is refused with the
codec's message.
"""
from __future__ import annotations

import logging
import os
import struct
from pathlib import Path
from typing import BinaryIO, Iterable, Iterator

from cinetransfer.shared import codec
from cinetransfer.shared import messages as M

log = logging.getLogger("cinetransfer.report")

_LEN = struct.Struct("<I")
#: a record longer than this is taken as corruption (a GroundTruth is a few hundred bytes)
MAX_RECORD_BYTES = 16 * 1024 * 1024


class TruthFileError(ValueError):
    """A truth file is unreadable or holds a record that is not a valid GroundTruth."""


class TruthWriter:
    """Appends GroundTruth records to a truth file (use as a context manager)."""

    def __init__(self, path: str | os.PathLike, *, append: bool = False) -> None:
        self.path = Path(path)
        self._fh: BinaryIO = open(self.path, "ab" if append else "wb")
        self.count = 0

    def write(self, truth: M.GroundTruth) -> None:
        if not isinstance(truth, M.GroundTruth):
            raise TypeError(f"expected a GroundTruth, got {type(truth).__name__}")
        payload = codec.encode(truth)
        self._fh.write(_LEN.pack(len(payload)))
        self._fh.write(payload)
        self.count += 1

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()

    def __enter__(self) -> "TruthWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_truths(path: str | os.PathLike, truths: Iterable[M.GroundTruth]) -> int:
    """Write every truth to `path` (replacing it); returns the number written."""
    with TruthWriter(path) as w:
        for t in truths:
            w.write(t)
        return w.count


def iter_truths(path: str | os.PathLike) -> Iterator[M.GroundTruth]:
    """Yield the records of a truth file in order; a truncated tail ends the iteration quietly
    (logged). A record that does not decode raises TruthFileError naming its position."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise TruthFileError(f"{p}: no such truth file") from None
    pos, n = 0, 0
    while pos < len(data):
        if pos + _LEN.size > len(data):
            log.warning("%s: truncated record header at byte %d after %d records (ignored)", p, pos, n)
            return
        (size,) = _LEN.unpack_from(data, pos)
        if size > MAX_RECORD_BYTES:
            raise TruthFileError(f"{p}: record {n} at byte {pos} claims {size} bytes: not a truth file")
        start, end = pos + _LEN.size, pos + _LEN.size + size
        if end > len(data):
            log.warning("%s: truncated record %d at byte %d (ignored)", p, n, pos)
            return
        try:
            msg = codec.decode(data[start:end], M.GroundTruth)
        except codec.DecodeError as e:
            raise TruthFileError(f"{p}: record {n} at byte {pos}: {e}") from None
        yield msg
        n += 1
        pos = end


def read_truths(path: str | os.PathLike) -> list[M.GroundTruth]:
    """Every complete record of a truth file (see `iter_truths`)."""
    return list(iter_truths(path))
