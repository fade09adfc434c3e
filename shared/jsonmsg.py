"""Our messages as JSON (for MCAP channels and the live Foxglove view), with JSON schemas generated
from shared/messages.py — the one source of truth; a test checks that they match.

Mapping (field by field, following the dataclass annotations and `array(...)` metadata):

- int, bool, str -> integer, boolean, string; float -> number, or number|null where the field's
  doc says what NaN means (JSON has no NaN: NaN travels as null);
- a nested message -> an object with its own schema (inline, so every viewer can follow it);
  `X | None` -> X or null;
- list[...] -> array; dict[str, Any] (command args, health counters) -> object;
- numeric arrays -> nested arrays (plottable: `/ct/r/vehicle/state.position_m[2]`), NaN -> null;
- image-like arrays (bool or uint8 with 2 or more dimensions: masks, focus maps) -> an object
  {"shape", "dtype", "base64"} holding the raw bytes (bool bit-packed), which keeps them small.

`Frame` is the exception: its image goes on a foxglove CompressedImage channel, so its JSON form
(`FrameInfo`) has every field but `image` (see cinetransfer/runlog.py).
"""
from __future__ import annotations

import base64
import dataclasses
import functools
import math
import types
import typing
from typing import Any

import numpy as np

from cinetransfer.shared import messages as M
from cinetransfer.shared.codec import _hints

_UNIONS = (typing.Union, types.UnionType)
#: fields left out of a type's JSON form (carried elsewhere)
OMIT: dict[type, tuple[str, ...]] = {M.Frame: ("image",)}


class JsonMessageError(ValueError):
    """A JSON message does not fit its schema (a foreign or corrupt recording)."""


def schema_name(cls: type) -> str:
    """The MCAP schema name of a message type: `cinetransfer.<Type>` (`FrameInfo` for Frame)."""
    return "cinetransfer.FrameInfo" if cls is M.Frame else f"cinetransfer.{cls.__name__}"


def _binary(meta: dict) -> bool:
    return np.dtype(meta["dtype"]).kind in "bu" and np.dtype(meta["dtype"]).itemsize == 1 and len(meta["shape"]) >= 2


def _nan_ok(f: dataclasses.Field | None) -> bool:
    return f is not None and "NaN =" in f.metadata.get("doc", "")


def _array_schema(meta: dict, doc: str) -> dict:
    if _binary(meta):
        s: dict = {"type": "object", "description": doc,
                   "properties": {"shape": {"type": "array", "items": {"type": "integer"}},
                                  "dtype": {"type": "string"},
                                  "base64": {"type": "string", "contentEncoding": "base64"}},
                   "required": ["shape", "dtype", "base64"]}
    else:
        kind = np.dtype(meta["dtype"]).kind
        leaf: dict = {"type": {"f": "number", "b": "boolean"}.get(kind, "integer")}
        if kind == "f" and meta["allow_nan"]:
            leaf = {"type": ["number", "null"]}
        s = leaf
        for n in reversed(meta["shape"]):
            s = {"type": "array", "items": s, **({"minItems": n, "maxItems": n} if n is not None else {})}
        s = {**s, "description": doc}
    if meta.get("optional"):
        s = {**s, "type": [s["type"], "null"]}
    return s


def _schema_of(tp: Any, f: dataclasses.Field | None) -> dict:
    doc = f.metadata.get("doc", "") if f is not None else ""
    if tp is np.ndarray or getattr(tp, "__name__", "") == "ndarray":
        return _array_schema(f.metadata, doc)
    origin = typing.get_origin(tp)
    if origin in _UNIONS:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        inner = _schema_of(args[0], f)
        return {**inner, "type": [inner["type"], "null"]}
    if dataclasses.is_dataclass(tp):
        return {**object_schema(tp), **({"description": doc} if doc else {})}
    if origin is list:
        (item,) = typing.get_args(tp)
        return {"type": "array", "items": _schema_of(item, None), "description": doc}
    if origin is dict or tp is dict:
        return {"type": "object", "description": doc}
    if tp is bool:
        return {"type": "boolean", "description": doc}
    if tp is int:
        return {"type": "integer", "description": doc}
    if tp is float:
        return {"type": ["number", "null"] if _nan_ok(f) else "number", "description": doc}
    if tp is str:
        return {"type": "string", "description": doc}
    raise TypeError(f"no JSON schema for {tp!r}")


def _fields(cls: type) -> list[tuple[dataclasses.Field, Any]]:
    hints = _hints(cls)
    return [(f, hints[f.name]) for f in dataclasses.fields(cls) if f.name not in OMIT.get(cls, ())]


def object_schema(cls: type) -> dict:
    props = {f.name: _schema_of(tp, f) for f, tp in _fields(cls)}
    return {"type": "object", "title": cls.__name__, "description": (cls.__doc__ or "").strip().splitlines()[0],
            "properties": props, "required": list(props)}


@functools.cache
def message_schema(cls: type) -> dict:
    """The JSON schema of a top-level message type (a draft 2020-12 document)."""
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": schema_name(cls), **object_schema(cls)}


# --------------------------------------------------------------------------- values
def _array_to_json(a: np.ndarray, meta: dict) -> Any:
    if _binary(meta):
        raw = np.packbits(a, axis=None).tobytes() if a.dtype == bool else np.ascontiguousarray(a).tobytes()
        return {"shape": list(a.shape), "dtype": a.dtype.name, "base64": base64.b64encode(raw).decode()}
    if a.dtype.kind == "f":
        return np.where(np.isfinite(a), a, None).tolist() if a.size else a.tolist()
    return a.tolist()


def _to_json(v: Any, tp: Any, f: dataclasses.Field | None) -> Any:
    if v is None:
        return None
    if isinstance(v, np.ndarray):
        return _array_to_json(v, f.metadata)
    if dataclasses.is_dataclass(v):
        return to_json(v)
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, (list, tuple)):
        if typing.get_origin(tp) in _UNIONS:  # an optional list: the list arm says the items
            tp = next(a for a in typing.get_args(tp) if a is not type(None))
        (item,) = typing.get_args(tp) or (Any,)
        return [_to_json(x, item, None) for x in v]
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    return v


def _plain(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def to_json(msg: Any) -> dict:
    """A message (or nested message) as a JSON-ready dict matching its schema."""
    return {f.name: _to_json(getattr(msg, f.name), tp, f) for f, tp in _fields(type(msg))}


def _array_from_json(obj: Any, meta: dict, where: str) -> np.ndarray:
    dt = np.dtype(meta["dtype"])
    if _binary(meta):
        if not isinstance(obj, dict) or not {"shape", "base64"} <= set(obj):
            raise JsonMessageError(f"{where}: expected {{shape, dtype, base64}}")
        shape = [int(s) for s in obj["shape"]]
        raw = base64.b64decode(obj["base64"])
        n = math.prod(shape)
        if dt.kind == "b":
            return np.unpackbits(np.frombuffer(raw, np.uint8), count=n).astype(bool).reshape(shape)
        return np.frombuffer(raw, dt, count=n).reshape(shape).copy()
    try:
        a = np.array(obj, dtype=object)
        if dt.kind == "f":
            a = np.where(a == None, np.nan, a)  # noqa: E711 - element-wise
        a = a.astype(dt)
    except (TypeError, ValueError) as e:
        raise JsonMessageError(f"{where}: {e}") from None
    if a.size == 0:
        a = a.reshape([0 if s is None else s for s in meta["shape"]])
    return a


def _from_json(obj: Any, tp: Any, f: dataclasses.Field | None, where: str) -> Any:
    if tp is np.ndarray or getattr(tp, "__name__", "") == "ndarray":
        if obj is None and f.metadata.get("optional"):
            return None
        return _array_from_json(obj, f.metadata, where)
    origin = typing.get_origin(tp)
    if origin in _UNIONS:
        if obj is None:
            return None
        tp = [a for a in typing.get_args(tp) if a is not type(None)][0]
        origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        return from_json(tp, obj, where)
    if origin is list:
        (item,) = typing.get_args(tp)
        if not isinstance(obj, list):
            raise JsonMessageError(f"{where}: expected a list")
        return [_from_json(x, item, None, f"{where}[{i}]") for i, x in enumerate(obj)]
    if tp is float:
        return float("nan") if obj is None else float(obj)
    return obj


def from_json(cls: type, obj: Any, where: str = "") -> Any:
    """The message of type `cls` from its JSON form; fields missing from `obj` (an older
    recording) take their defaults. Extra keyword `image` etc. come from elsewhere."""
    where = where or cls.__name__
    if not isinstance(obj, dict):
        raise JsonMessageError(f"{where}: expected an object")
    kw = {}
    for f, tp in _fields(cls):
        if f.name in obj:
            kw[f.name] = _from_json(obj[f.name], tp, f, f"{where}.{f.name}")
    try:
        return cls(**kw)
    except TypeError as e:
        raise JsonMessageError(f"{where}: {e}") from None
