"""The measurements file: every Measurement of one video, as written by `cinetransfer detect`.

Layout (all integers little-endian)::

    magic    8 bytes   b"CTMEAS\\r\\n"  (the CR/LF catches text-mode mangling)
    record*  u32 length N, then N bytes

Record 0 is the header: a msgpack map (see `MeasurementsHeader`) with
``{"format": "cinetransfer-measurements", "version": 1, "source": {SourceInfo fields},
"detector": str, "config": {...}, "created_ns": int, "focus_map_scale": float}``.
Every following record is one `Measurement` encoded with `cinetransfer.shared.codec.encode`
(the same bytes that travel on `ct/{rig}/detector/measurement`), in frame order.

A file cut short (a crash, a full disk) is still readable: `read_measurements` keeps every
complete record and, unless `strict=True`, ignores a partial last one (it reports it in
`MeasurementsFile.truncated`). A record that is complete but does not decode is an error
(`MeasurementsFileError`), because that means corruption, not truncation.

Usage::

    from cinetransfer.shared.measurements_file import read_measurements, write_measurements

    mf = read_measurements("measurements.msgpack")
    mf.header.source.fps, mf.header.source.width
    for m in mf:                 # Measurement objects, frame order
        ...

    write_measurements("out.msgpack", measurements, source=SourceInfo(path="clip.mp4", ...))

    with MeasurementsWriter("out.msgpack", source=info, detector="mediapipe") as w:   # streaming
        w.write(measurement)
"""
from __future__ import annotations

import dataclasses
import os
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Iterable, Iterator

import msgpack

from cinetransfer.shared import codec
from cinetransfer.shared.atomic import AtomicFile
from cinetransfer.shared.messages import Measurement, SourceInfo

MAGIC = b"CTMEAS\r\n"
FORMAT_NAME = "cinetransfer-measurements"
FORMAT_VERSION = 1
_LEN = struct.Struct("<I")
_MAX_RECORD = 1 << 30  # 1 GiB: anything larger is corruption


class MeasurementsFileError(ValueError):
    """The file is not a measurements file, is of an unsupported version, or is corrupt."""


@dataclass(frozen=True)
class MeasurementsHeader:
    """Record 0 of a measurements file."""

    version: int = FORMAT_VERSION
    source: SourceInfo = field(default_factory=SourceInfo)
    detector: str = ""  # backend name ('mediapipe', 'torchvision', ...)
    config: dict[str, Any] = field(default_factory=dict)  # detector config used (plain values)
    created_ns: int = 0  # when the file was started [ns since epoch]
    focus_map_scale: float = float("nan")  # focus-map width / frame width; NaN = unknown / none

    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT_NAME, "version": self.version, "source": dataclasses.asdict(self.source),
                "detector": self.detector, "config": _plain(self.config), "created_ns": int(self.created_ns),
                "focus_map_scale": float(self.focus_map_scale)}

    @classmethod
    def from_dict(cls, d: Any) -> "MeasurementsHeader":
        if not isinstance(d, dict) or d.get("format") != FORMAT_NAME:
            raise MeasurementsFileError("header record is not a cinetransfer measurements header")
        version = d.get("version")
        if version != FORMAT_VERSION:
            raise MeasurementsFileError(f"measurements file version {version!r} is not supported "
                                        f"(this build reads version {FORMAT_VERSION})")
        src = d.get("source") or {}
        if not isinstance(src, dict):
            raise MeasurementsFileError("header 'source' is not a map")
        known = {f.name for f in dataclasses.fields(SourceInfo)}
        try:
            source = SourceInfo(**{k: v for k, v in src.items() if k in known})
        except TypeError as e:
            raise MeasurementsFileError(f"bad source info in header: {e}") from None
        return cls(version=version, source=source, detector=str(d.get("detector", "")),
                   config=dict(d.get("config") or {}), created_ns=int(d.get("created_ns", 0)),
                   focus_map_scale=float(d.get("focus_map_scale", float("nan"))))


@dataclass
class MeasurementsFile:
    """What `read_measurements` returns: the header and the measurements (iterable, indexable)."""

    header: MeasurementsHeader
    measurements: list[Measurement]
    truncated: bool = False  # a partial last record was ignored

    def __iter__(self) -> Iterator[Measurement]:
        return iter(self.measurements)

    def __len__(self) -> int:
        return len(self.measurements)

    def __getitem__(self, i: int) -> Measurement:
        return self.measurements[i]

    @property
    def source(self) -> SourceInfo:
        return self.header.source


def _plain(v: Any) -> Any:
    """Config values reduced to msgpack-able plain types."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        v = dataclasses.asdict(v)
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if hasattr(v, "item"):  # numpy scalar
        return v.item()
    return str(v)


class MeasurementsWriter:
    """Streams measurements to a file; use as a context manager. Each record is written whole;
    the file appears at `path` on close (temp-then-rename) unless `atomic=False`."""

    def __init__(self, path: str | os.PathLike, *, source: SourceInfo | None = None, detector: str = "",
                 config: Any = None, focus_map_scale: float = float("nan"), atomic: bool = True) -> None:
        self.path = Path(path)
        self.header = MeasurementsHeader(source=source or SourceInfo(), detector=detector,
                                         config=_plain(config) if config is not None else {},
                                         created_ns=time.time_ns(), focus_map_scale=focus_map_scale)
        # Written under a temporary name and renamed into place on close (STYLE §11): a reader of
        # `path` never sees a file still being written; the complete records of a run that
        # ended early (Ctrl-C, an exception) are still renamed into place.
        # `atomic=False` writes `path` in place, for a reader that follows the file as it grows.
        self._atomic = AtomicFile(self.path, binary=True) if atomic else None
        self._f: BinaryIO | None = self._atomic.file if self._atomic is not None else open(self.path, "wb")
        self._f.write(MAGIC)
        self._record(msgpack.packb(self.header.to_dict(), use_bin_type=True))
        self.count = 0

    def _record(self, payload: bytes) -> None:
        assert self._f is not None
        self._f.write(_LEN.pack(len(payload)) + payload)

    def write(self, m: Measurement) -> None:
        if self._f is None:
            raise ValueError("writer is closed")
        if not isinstance(m, Measurement):
            raise TypeError(f"expected a Measurement, got {type(m).__name__}")
        self._record(codec.encode(m))
        self.count += 1

    def close(self) -> None:
        if self._f is not None:
            if self._atomic is not None:
                self._atomic.commit()
            else:
                self._f.close()
            self._f = None

    def __enter__(self) -> "MeasurementsWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_measurements(path: str | os.PathLike, measurements: Iterable[Measurement], *,
                       source: SourceInfo | None = None, detector: str = "", config: Any = None,
                       focus_map_scale: float = float("nan")) -> int:
    """Write a whole measurements file; returns the number of measurements written."""
    with MeasurementsWriter(path, source=source, detector=detector, config=config,
                            focus_map_scale=focus_map_scale) as w:
        for m in measurements:
            w.write(m)
        return w.count


def _records(f: BinaryIO, strict: bool) -> Iterator[bytes | None]:
    """Yields record payloads; yields None once for a partial last record (if not strict)."""
    while True:
        head = f.read(_LEN.size)
        if not head:
            return
        if len(head) < _LEN.size:
            if strict:
                raise MeasurementsFileError("file ends inside a record length")
            yield None
            return
        (n,) = _LEN.unpack(head)
        if n > _MAX_RECORD:
            raise MeasurementsFileError(f"record length {n} is implausible: the file is corrupt")
        payload = f.read(n)
        if len(payload) < n:
            if strict:
                raise MeasurementsFileError(f"file ends inside a record ({len(payload)} of {n} bytes)")
            yield None
            return
        yield payload


def _open_checked(path: str | os.PathLike) -> BinaryIO:
    p = Path(path)
    if not p.is_file():
        raise MeasurementsFileError(f"{p}: no such measurements file")
    f = open(p, "rb")
    magic = f.read(len(MAGIC))
    if magic != MAGIC:
        f.close()
        raise MeasurementsFileError(f"{p}: not a cinetransfer measurements file (bad magic bytes)")
    return f


def _read_header(f: BinaryIO, path: str | os.PathLike) -> MeasurementsHeader:
    recs = _records(f, strict=True)
    try:
        payload = next(recs)
    except StopIteration:
        raise MeasurementsFileError(f"{path}: file has no header record") from None
    try:
        d = msgpack.unpackb(payload, raw=False)
    except Exception as e:  # msgpack raises several unrelated types for garbage
        raise MeasurementsFileError(f"{path}: corrupt header ({type(e).__name__}: {e})") from None
    return MeasurementsHeader.from_dict(d)


def read_header(path: str | os.PathLike) -> MeasurementsHeader:
    """Only the header record (cheap)."""
    with _open_checked(path) as f:
        return _read_header(f, path)


def iter_measurements(path: str | os.PathLike, *, strict: bool = False) -> Iterator[Measurement]:
    """Measurements one at a time (constant memory). A partial last record ends the iteration."""
    with _open_checked(path) as f:
        _read_header(f, path)
        for i, payload in enumerate(_records(f, strict)):
            if payload is None:
                return
            try:
                yield codec.decode(payload, Measurement)
            except codec.DecodeError as e:
                raise MeasurementsFileError(f"{path}: record {i + 1} is corrupt: {e}") from None


def read_measurements(path: str | os.PathLike, *, strict: bool = False) -> MeasurementsFile:
    """Read a whole measurements file (header + every complete measurement)."""
    with _open_checked(path) as f:
        header = _read_header(f, path)
        out: list[Measurement] = []
        truncated = False
        for i, payload in enumerate(_records(f, strict)):
            if payload is None:
                truncated = True
                break
            try:
                out.append(codec.decode(payload, Measurement))
            except codec.DecodeError as e:
                raise MeasurementsFileError(f"{path}: record {i + 1} is corrupt: {e}") from None
    return MeasurementsFile(header=header, measurements=out, truncated=truncated)
