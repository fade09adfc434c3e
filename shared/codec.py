"""The only module that touches msgpack: message dataclasses <-> bytes.

Wire format (little-endian):

    b"CTM" | format (1 byte, = 1) | header length L (uint32) | msgpack header (L bytes)
    | zero padding to a multiple of 16 | array blobs

The header is the msgpack map {"t": type name, "v": schema version, "d": fields}. Numpy arrays
are not inside the msgpack: the header holds {"__nd__": encoding, "dt", "sh", "o", "n"} and the
bytes follow in the blob section, so a raw 1280x720 frame decodes as a read-only numpy view of
the payload (zero-copy). Boolean arrays are bit-packed; a Frame image may be sent as JPEG
(`encode(msg, jpeg_quality=90)`) for a radio link.

`decode` validates everything (type tag, schema version, field types, dtypes, shapes, finiteness)
and raises `DecodeError` — one error type for every malformed or unsupported payload. Decoding
is total: the header is bounded in size (MAX_HEADER_BYTES), nesting depth (MAX_DEPTH) and element
count (MAX_ELEMENTS) before any field is looked at, arrays in element count (MAX_ARRAY_ELEMENTS),
JPEG images in pixels (MAX_JPEG_PIXELS, read from the JPEG's header before decoding),
and any other exception raised while decoding (a bug, a library's odd error type) is turned
into a DecodeError too, so a receiver needs to catch exactly one type.
Unknown fields are ignored (a newer sender may add fields); missing fields are an error, except
fields added by a later schema version than the payload's (`since` in the field's metadata), which
take their defaults — a class reads every version from its MIN_SCHEMA_VERSION up.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import struct
import types
import typing
from typing import Any

import msgpack
import numpy as np

from cinetransfer.shared import messages as M

MAGIC = b"CTM"
FORMAT = 1
_PREFIX = struct.Struct("<3sBI")
_ALIGN = 16
_UNIONS = (typing.Union, types.UnionType)

#: Limits on what one payload may ask of a receiver. Generous for every real message (the biggest
#: header, a Measurement with dozens of people, is a few kB; arrays are not in the header), tight
#: enough that no payload can exhaust the stack (a 576-byte Command with args nested 500 lists deep
#: used to raise RecursionError) or make the receiver allocate gigabytes.
MAX_HEADER_BYTES = 16 << 20
MAX_DEPTH = 32  # the deepest real header (Instructions -> source -> ...) nests about 6
MAX_ELEMENTS = 1_000_000  # scalars, lists and maps in one header, all together
MAX_ARRAY_ELEMENTS = 1 << 28  # 4K RGB is 2.5e7
#: largest JPEG image decoded, in pixels (8K UHD is 3.3e7): its size is read from the JPEG's own
#: header and checked, with the message's declared shape, before a byte of it is decoded
MAX_JPEG_PIXELS = 40_000_000
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


class CodecError(ValueError):
    """A message could not be encoded or decoded."""


class DecodeError(CodecError):
    """A payload is malformed, of an unknown type, or of an unsupported schema version."""


class EncodeError(CodecError):
    """A message does not satisfy its own schema (wrong dtype/shape, non-finite value, ...)."""


# --------------------------------------------------------------------------- field specs
@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, vars(M))


@functools.cache
def _fields(cls: type) -> tuple[tuple[dataclasses.Field, Any], ...]:
    hints = _hints(cls)
    return tuple((f, hints[f.name]) for f in dataclasses.fields(cls))


def _nan_ok(f: dataclasses.Field) -> bool:
    return "NaN =" in f.metadata.get("doc", "")


# --------------------------------------------------------------------------- encode
class _Blobs:
    def __init__(self) -> None:
        self.parts: list[memoryview | bytes] = []
        self.size = 0

    def add(self, data: memoryview | bytes) -> tuple[int, int]:
        pad = (-self.size) % _ALIGN
        if pad:
            self.parts.append(b"\0" * pad)
            self.size += pad
        off = self.size
        n = len(data) if isinstance(data, bytes) else data.nbytes
        self.parts.append(data)
        self.size += n
        return off, n


def _check_array(value: Any, meta: dict, where: str, err: type[CodecError]) -> np.ndarray:
    if not isinstance(value, np.ndarray):
        raise err(f"{where}: expected a numpy array, got {type(value).__name__}")
    dt = np.dtype(meta["dtype"])
    if value.dtype != dt:
        if err is EncodeError and np.can_cast(value.dtype, dt, casting="same_kind"):
            value = value.astype(dt)
        else:
            raise err(f"{where}: dtype {value.dtype} where {dt} is required")
    shape = meta["shape"]
    if value.ndim != len(shape) or any(s is not None and s != v for s, v in zip(shape, value.shape)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise err(f"{where}: shape {value.shape} where {want} is required")
    if dt.kind == "f":
        if meta["allow_nan"]:
            if np.isinf(value).any():
                raise err(f"{where}: contains ±inf")
        elif not np.isfinite(value).all():
            raise err(f"{where}: contains NaN or ±inf")
    return value


def _encode_array(value: np.ndarray, meta: dict, blobs: _Blobs, jpeg_quality: int | None) -> dict:
    if meta["dtype"] == "bool":
        packed = np.packbits(value.reshape(-1))
        off, n = blobs.add(packed.tobytes())
        return {"__nd__": "bits", "dt": "bool", "sh": list(value.shape), "o": off, "n": n}
    if jpeg_quality is not None and meta["dtype"] == "uint8" and meta["shape"] == (None, None, 3):
        import cv2

        ok, buf = cv2.imencode(".jpg", value, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise EncodeError("JPEG encoding failed")
        off, n = blobs.add(buf.tobytes())
        return {"__nd__": "jpeg", "dt": "uint8", "sh": list(value.shape), "o": off, "n": n}
    value = np.ascontiguousarray(value)
    off, n = blobs.add(memoryview(value.reshape(-1).view(np.uint8)) if value.size else b"")
    return {"__nd__": "raw", "dt": value.dtype.str, "sh": list(value.shape), "o": off, "n": n}


def _encode_value(value: Any, tp: Any, where: str, f: dataclasses.Field | None, blobs: _Blobs,
                  jq: int | None) -> Any:
    origin = typing.get_origin(tp)
    if origin in _UNIONS:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _encode_value(value, args[0], where, f, blobs, jq)
    if tp is np.ndarray:
        meta = f.metadata if f is not None else {}
        if value is None:
            if meta.get("optional"):
                return None
            raise EncodeError(f"{where}: array is required")
        value = _check_array(value, meta, where, EncodeError)
        return _encode_array(value, meta, blobs, jq)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, tp):
            raise EncodeError(f"{where}: expected {tp.__name__}, got {type(value).__name__}")
        return _encode_fields(value, blobs, jq, where)
    if origin is list:
        (item_tp,) = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise EncodeError(f"{where}: expected a list")
        return [_encode_value(v, item_tp, f"{where}[{i}]", None, blobs, jq) for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise EncodeError(f"{where}: expected a dict")
        return {str(k): _plain(v, f"{where}.{k}", EncodeError) for k, v in value.items()}
    return _scalar(value, tp, where, f, EncodeError)


def _encode_fields(msg: Any, blobs: _Blobs, jq: int | None, where: str) -> dict:
    return {f.name: _encode_value(getattr(msg, f.name), tp, f"{where}.{f.name}", f, blobs, jq)
            for f, tp in _fields(type(msg))}


def encode(msg: Any, *, jpeg_quality: int | None = None) -> bytes:
    """Encode a message dataclass. `jpeg_quality` (1-100) sends images as JPEG instead of raw."""
    cls = type(msg)
    if cls.__name__ not in M.MESSAGE_TYPES:
        raise EncodeError(f"{cls.__name__} is not a top-level message type")
    blobs = _Blobs()
    body = _encode_fields(msg, blobs, jpeg_quality, cls.__name__)
    header = msgpack.packb({"t": cls.__name__, "v": cls.SCHEMA_VERSION, "d": body}, use_bin_type=True)
    head_len = _PREFIX.size + len(header)
    pad = (-head_len) % _ALIGN
    # One join = one copy of the array bytes (no zero-fill, no second copy).
    return b"".join([_PREFIX.pack(MAGIC, FORMAT, len(header)), header, b"\0" * pad, *blobs.parts])


# --------------------------------------------------------------------------- decode
def _scalar(value: Any, tp: Any, where: str, f: dataclasses.Field | None, err: type[CodecError]) -> Any:
    if tp is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise err(f"{where}: expected bool, got {type(value).__name__}")
        return bool(value)
    if tp is int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise err(f"{where}: expected int, got {type(value).__name__}")
        return int(value)
    if tp is float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise err(f"{where}: expected float, got {type(value).__name__}")
        value = float(value)
        if math.isinf(value) or (math.isnan(value) and not (f is not None and _nan_ok(f))):
            raise err(f"{where}: non-finite value {value}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise err(f"{where}: expected str, got {type(value).__name__}")
        return value
    if tp is Any:
        return _plain(value, where, err)
    raise err(f"{where}: unsupported field type {tp}")


def _plain(value: Any, where: str, err: type[CodecError]) -> Any:
    """Values allowed in free-form dict fields: scalars and lists of scalars."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, (list, tuple)):
        return [_plain(v, where, err) for v in value]
    raise err(f"{where}: unsupported value type {type(value).__name__}")


def _decode_array(obj: Any, meta: dict, where: str, blob: memoryview) -> np.ndarray:
    kind, dt, shape, count, data = _array_ref(obj, where, blob)
    decode = _ARRAY_DECODERS.get(kind) if isinstance(kind, str) else None
    if decode is None:
        raise DecodeError(f"{where}: unknown array encoding {kind!r}")
    return _check_array(decode(data, dt, shape, count, where), meta, where, DecodeError)


def _array_ref(obj: Any, where: str, blob: memoryview) -> tuple[Any, Any, list[int], int, memoryview]:
    """An array reference checked against the blob: (encoding, dtype, shape, element count, bytes)."""
    if not isinstance(obj, dict) or "__nd__" not in obj:
        raise DecodeError(f"{where}: expected an array reference")
    try:
        kind, dt, shape, off, n = obj["__nd__"], obj["dt"], [int(s) for s in obj["sh"]], int(obj["o"]), int(obj["n"])
    except (KeyError, TypeError, ValueError) as e:
        raise DecodeError(f"{where}: malformed array reference ({e})") from None
    if len(shape) > 8:  # before math.prod: a long shape list would make it slow
        raise DecodeError(f"{where}: array of {len(shape)} dimensions")
    if off < 0 or n < 0 or off + n > len(blob) or any(s < 0 for s in shape):
        raise DecodeError(f"{where}: array bytes out of range")
    count = math.prod(shape)
    if count > MAX_ARRAY_ELEMENTS:
        raise DecodeError(f"{where}: shape {shape} exceeds the limit of {MAX_ARRAY_ELEMENTS} elements")
    return kind, dt, shape, count, blob[off:off + n]


def _raw_array(data: memoryview, dt: Any, shape: list[int], count: int, where: str) -> np.ndarray:
    try:
        dtype = np.dtype(dt)
    except TypeError:
        raise DecodeError(f"{where}: unknown dtype {dt!r}") from None
    if dtype.hasobject or count * dtype.itemsize != len(data):
        raise DecodeError(f"{where}: {len(data)} bytes do not hold shape {shape} of {dtype}")
    return np.frombuffer(data, dtype=dtype, count=count).reshape(shape)


def _bits_array(data: memoryview, _dt: Any, shape: list[int], count: int, where: str) -> np.ndarray:
    if (count + 7) // 8 != len(data):
        raise DecodeError(f"{where}: {len(data)} packed bytes do not hold shape {shape}")
    return np.unpackbits(np.frombuffer(data, dtype=np.uint8), count=count).astype(bool).reshape(shape)


def jpeg_size(data: bytes | memoryview) -> tuple[int, int] | None:
    """(height, width) from a JPEG's frame header, without decoding it; None if there is none."""
    b = bytes(data[:1 << 20])  # the frame header comes before the image data, near the start
    if b[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 4 <= len(b):
        if b[i] != 0xFF:
            return None
        m = b[i + 1]
        if m == 0xFF:  # fill byte
            i += 1
            continue
        if m in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            i += 2
            continue
        if m in _SOF:
            return (int.from_bytes(b[i + 5:i + 7], "big"), int.from_bytes(b[i + 7:i + 9], "big")) \
                if i + 9 <= len(b) else None
        if m == 0xDA:  # image data began without a frame header
            return None
        i += 2 + int.from_bytes(b[i + 2:i + 4], "big")
    return None


def _jpeg_array(data: memoryview, _dt: Any, shape: list[int], _count: int, where: str) -> np.ndarray:
    import cv2

    size = jpeg_size(data)
    if size is None or len(shape) != 3 or shape[2] != 3 or list(size) != shape[:2]:
        raise DecodeError(f"{where}: JPEG header size {size} does not match the declared shape {shape}")
    if size[0] * size[1] > MAX_JPEG_PIXELS:
        raise DecodeError(f"{where}: JPEG image of {size[1]}x{size[0]} exceeds the limit of {MAX_JPEG_PIXELS} pixels")
    arr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if arr is None or list(arr.shape) != shape:
        raise DecodeError(f"{where}: corrupt JPEG image")
    return arr


#: the array encodings of the wire format, by their tag
_ARRAY_DECODERS = {"raw": _raw_array, "bits": _bits_array, "jpeg": _jpeg_array}


def _decode_value(obj: Any, tp: Any, where: str, f: dataclasses.Field | None, blob: memoryview) -> Any:
    origin = typing.get_origin(tp)
    if origin in _UNIONS:
        if obj is None:
            return None
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _decode_value(obj, args[0], where, f, blob)
    if tp is np.ndarray:
        meta = f.metadata if f is not None else {}
        if obj is None and meta.get("optional"):
            return None
        return _decode_array(obj, meta, where, blob)
    if dataclasses.is_dataclass(tp):
        if not isinstance(obj, dict):
            raise DecodeError(f"{where}: expected a map for {tp.__name__}")
        return _decode_fields(tp, obj, blob, where)
    if origin is list:
        (item_tp,) = typing.get_args(tp)
        if not isinstance(obj, list):
            raise DecodeError(f"{where}: expected a list")
        return [_decode_value(v, item_tp, f"{where}[{i}]", None, blob) for i, v in enumerate(obj)]
    if origin is dict:
        if not isinstance(obj, dict) or not all(isinstance(k, str) for k in obj):
            raise DecodeError(f"{where}: expected a map with string keys")
        return {k: _plain(v, f"{where}.{k}", DecodeError) for k, v in obj.items()}
    return _scalar(obj, tp, where, f, DecodeError)


def _decode_fields(cls: type, body: dict, blob: memoryview, where: str, version: int | None = None) -> Any:
    kwargs = {}
    for f, tp in _fields(cls):
        if f.name not in body:
            if version is not None and f.metadata.get("since", 1) > version:
                continue  # added after the payload's version: the dataclass default stands
            raise DecodeError(f"{where}.{f.name}: missing field")
        kwargs[f.name] = _decode_value(body[f.name], tp, f"{where}.{f.name}", f, blob)
    return cls(**kwargs)


def check_bounds(obj: Any, *, max_depth: int = MAX_DEPTH, max_elements: int = MAX_ELEMENTS) -> None:
    """Raise DecodeError if `obj` (an unpacked header) nests deeper than `max_depth` or holds more
    than `max_elements` values. Iterative, so that the check itself cannot overflow the stack."""
    stack = [(obj, 1)]
    seen = 0
    while stack:
        value, depth = stack.pop()
        seen += 1
        if seen > max_elements:
            raise DecodeError(f"header holds more than {max_elements} values")
        if isinstance(value, (list, tuple, dict)):
            if depth > max_depth:
                raise DecodeError(f"header nests deeper than {max_depth} levels")
            items = value.values() if isinstance(value, dict) else value
            stack.extend((v, depth + 1) for v in items)


def peek_type(payload: bytes | bytearray | memoryview) -> tuple[str, int]:
    """(type name, schema version) of a payload without decoding its body."""
    _, header, _ = _split(payload)
    return header["t"], header["v"]


def _split(payload: bytes | bytearray | memoryview) -> tuple[int, dict, memoryview]:
    view = memoryview(payload).cast("B") if not isinstance(payload, memoryview) else payload.cast("B")
    if len(view) < _PREFIX.size:
        raise DecodeError(f"payload of {len(view)} bytes is too short to be a cinetransfer message")
    magic, fmt, hlen = _PREFIX.unpack_from(view, 0)
    if magic != MAGIC:
        raise DecodeError("not a cinetransfer message (bad magic bytes)")
    if fmt != FORMAT:
        raise DecodeError(f"wire format {fmt} is not supported (this build reads format {FORMAT})")
    end = _PREFIX.size + hlen
    if hlen > MAX_HEADER_BYTES:
        raise DecodeError(f"header of {hlen} bytes exceeds the limit of {MAX_HEADER_BYTES}")
    if end > len(view):
        raise DecodeError("truncated payload (header runs past the end)")
    try:
        header = msgpack.unpackb(view[_PREFIX.size:end], raw=False, strict_map_key=True)
    except Exception as e:  # msgpack raises several unrelated types for garbage
        raise DecodeError(f"corrupt message header ({type(e).__name__}: {e})") from None
    check_bounds(header)
    if not isinstance(header, dict) or not {"t", "v", "d"} <= header.keys():
        raise DecodeError("message header lacks type/version/data")
    start = end + ((-end) % _ALIGN)
    return start, header, view[start:] if start <= len(view) else view[len(view):]


def decode(payload: bytes | bytearray | memoryview, expected: type | None = None) -> Any:
    """Decode and validate a payload; raise DecodeError on anything wrong — and nothing else.

    `expected` (a message class) additionally requires that type.
    """
    try:
        return _decode(payload, expected)
    except DecodeError:
        raise
    except Exception as e:  # totality: whatever a payload trips over is that payload's fault
        raise DecodeError(f"undecodable payload ({type(e).__name__}: {str(e)[:200]})") from None


def _decode(payload: bytes | bytearray | memoryview, expected: type | None) -> Any:
    _, header, blob = _split(payload)
    name, version, body = header["t"], header["v"], header["d"]
    cls = M.MESSAGE_TYPES.get(name) if isinstance(name, str) else None
    if cls is None:
        raise DecodeError(f"unknown message type {name!r}")
    if expected is not None and cls is not expected:
        raise DecodeError(f"expected a {expected.__name__} message, got {name}")
    oldest = getattr(cls, "MIN_SCHEMA_VERSION", cls.SCHEMA_VERSION)
    if isinstance(version, bool) or not isinstance(version, int) or not oldest <= version <= cls.SCHEMA_VERSION:
        reads = (f"version {cls.SCHEMA_VERSION}" if oldest == cls.SCHEMA_VERSION
                 else f"versions {oldest} to {cls.SCHEMA_VERSION}")
        raise DecodeError(f"{name} schema version {version!r} is not supported (this build reads {reads})")
    if not isinstance(body, dict):
        raise DecodeError(f"{name}: body is not a map")
    return _decode_fields(cls, body, blob, name, version)


def summary(msg: Any) -> str:
    """A one-line human summary of a decoded message (for the monitor and logs)."""
    name = type(msg).__name__
    if isinstance(msg, M.Frame):
        h, w = msg.image.shape[:2]
        return f"Frame #{msg.index} {w}x{h} from {msg.source or '?'}"
    if isinstance(msg, M.Measurement):
        fm = "focus" if msg.focus_map is not None else "no focus"
        return f"Measurement #{msg.frame_index} {len(msg.people)} people, {len(msg.skeletons)} skeletons, {fm}"
    if isinstance(msg, M.Instructions):
        k = msg.image_targets.shape[0]
        return (f"Instructions frames {msg.first_frame}..{msg.first_frame + k - 1} "
                f"({'final' if msg.final else 'window'}), joints {','.join(msg.joint_names)}")
    if isinstance(msg, M.Setpoint):
        p = msg.position_m
        return (f"Setpoint {msg.mode} p=({p[0]:.2f},{p[1]:.2f},{p[2]:.2f}) f={msg.lens.focal_length_mm:.0f}mm "
                f"s={msg.lens.focus_distance_m:.1f}m A={msg.lens.f_number:.1f} k={msg.instruction_frame} "
                f"{msg.solver_status}")
    if isinstance(msg, M.VehicleState):
        p = msg.position_m
        return (f"VehicleState {msg.backend}/{msg.mode} p=({p[0]:.2f},{p[1]:.2f},{p[2]:.2f})"
                f"{' HOLD' if msg.holding else ''}{' armed' if msg.armed else ''}")
    if isinstance(msg, M.SubjectState):
        c = np.nanmean(msg.joints_m, axis=0) if len(msg.joints_m) else np.full(3, np.nan)
        return f"SubjectState {msg.subject_id} centre=({c[0]:.2f},{c[1]:.2f},{c[2]:.2f})"
    if isinstance(msg, M.Command):
        return f"Command {msg.action} {msg.args or ''}".strip()
    if isinstance(msg, M.Health):
        return (f"Health {msg.node} rx={msg.received} rej={msg.rejected} drop={msg.dropped} "
                f"tx={msg.published} p50={msg.latency_ms_p50:.2f}ms"
                f"{' ERR ' + msg.last_error if msg.last_error else ''}")
    return name
