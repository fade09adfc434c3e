"""The style file: recording instructions as versioned JSON (DESIGN §1.2), and window slicing.

A style file holds exactly the content of one `Instructions` message (shared/messages.py) plus
an optional "diagnostics" section (raw per-frame measures for plots and evaluation):

    {
      "format": "cinetransfer-style",
      "version": 1,
      "instructions": { every Instructions field; arrays as nested lists, NaN written as null },
      "diagnostics": { "raw_box": [[...]], "raw_joints": ..., ... }      (optional)
    }

The JSON Schema is `json_schema()` (docs/instructions.schema.json is generated from it by
`python -m cinetransfer.shared.instructions --write-schema docs/instructions.schema.json`).
`load_style` checks the format name and version first (a wrong version is refused with the
version this build reads), then the schema, then the shapes and values through the message codec.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cinetransfer.shared import codec
from cinetransfer.shared import messages as M
from cinetransfer.shared.atomic import atomic_write
from cinetransfer.shared.plausible import unusable_targets

FORMAT_NAME = "cinetransfer-style"
FORMAT_VERSION = 1

_ARRAY_FIELDS = {f.name: f.metadata for f in dataclasses.fields(M.Instructions) if "dtype" in f.metadata}


class StyleFileError(ValueError):
    """A style file is unreadable, of another format or version, or inconsistent."""


@dataclass(frozen=True, eq=False)
class StyleFile:
    instructions: M.Instructions
    diagnostics: dict[str, Any] = field(default_factory=dict)
    version: int = FORMAT_VERSION
    warnings: tuple[str, ...] = ()  #: e.g. the source was truncated (see `save_style`)


# --------------------------------------------------------------------------- JSON helpers
def _to_json(v: Any) -> Any:
    """numpy arrays / scalars -> nested lists with NaN as null (JSON has no NaN)."""
    if isinstance(v, np.ndarray):
        if v.dtype.kind == "f":
            obj = v.astype(float).tolist()
            return _nan_to_none(obj)
        return v.tolist()
    if isinstance(v, (np.floating, float)):
        return None if not math.isfinite(float(v)) else float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if isinstance(v, dict):
        return {str(k): _to_json(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_to_json(x) for x in v]
    return v


def _nan_to_none(obj: Any) -> Any:
    if isinstance(obj, list):
        return [_nan_to_none(x) for x in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _none_to_nan(obj: Any) -> Any:
    if isinstance(obj, list):
        return [_none_to_nan(x) for x in obj]
    return float("nan") if obj is None else obj


def instructions_to_dict(instr: M.Instructions) -> dict[str, Any]:
    """Every field of the message, JSON-ready."""
    d: dict[str, Any] = {"schema_version": M.Instructions.SCHEMA_VERSION}
    for f in dataclasses.fields(M.Instructions):
        v = getattr(instr, f.name)
        if f.name == "source":
            v = dataclasses.asdict(v)
        d[f.name] = _to_json(v)
    return d


def _absent_ok(f: dataclasses.Field) -> bool:
    """A field added after the first version that may be None: a file written before it lacks it."""
    return f.metadata.get("since", 1) > 1 and (bool(f.metadata.get("optional")) or f.default is None)


def instructions_from_dict(d: dict[str, Any]) -> M.Instructions:
    """Inverse of `instructions_to_dict` (shapes and values checked by the codec)."""
    kw: dict[str, Any] = {}
    for f in dataclasses.fields(M.Instructions):
        if f.name not in d:
            if _absent_ok(f):
                continue  # written before the field existed: its default (e.g. one shot)
            raise StyleFileError(f"instructions.{f.name} is missing")
        v = d[f.name]
        if v is None and f.metadata.get("optional"):
            kw[f.name] = None
            continue
        if f.name == "source":
            v = M.SourceInfo(**v)
        elif f.name in _ARRAY_FIELDS:
            meta = _ARRAY_FIELDS[f.name]
            dt = np.dtype(meta["dtype"])
            arr = np.array(_none_to_nan(v) if dt.kind == "f" else v, dtype=dt)
            if arr.size == 0:
                arr = arr.reshape([0 if s is None else s for s in meta["shape"]])
            v = arr
        kw[f.name] = v
    instr = M.Instructions(**kw)
    try:  # the codec enforces dtypes, shapes and finiteness of every field
        codec.decode(codec.encode(instr), M.Instructions)
    except codec.CodecError as e:
        raise StyleFileError(f"instructions do not satisfy the message schema: {e}") from None
    check_consistent(instr)
    return instr


#: the highest style frame rate: the simulated camera's (and the bridge's 'reset') range is (0, 240] fps
MAX_STYLE_FPS = 240.0


def check_consistent(instr: M.Instructions) -> None:
    """Row counts agree, E = len(joint_names), joints are COCO-17 names."""
    K = instr.image_targets.shape[0]
    E = len(instr.joint_names)
    if instr.image_targets.shape[1:] != (E, 2):
        raise StyleFileError(f"image_targets has shape {instr.image_targets.shape}, expected ({K}, {E}, 2)")
    for name in ("subject_visible", "subject_box", "focus_raw", "focus_smoothed", "focus_in"):
        n = getattr(instr, name).shape[0]
        if n != K:
            raise StyleFileError(f"{name} has {n} rows where image_targets has {K}")
    if instr.shot_start is not None and instr.shot_start.shape[0] != K:
        raise StyleFileError(f"shot_start has {instr.shot_start.shape[0]} rows where image_targets has {K}")
    _check_motion(instr, K)
    for j in instr.joint_names:
        if j not in M.COCO17_NAMES:
            raise StyleFileError(f"joint {j!r} is not a COCO-17 name")
    if not 0 < instr.fps <= MAX_STYLE_FPS:
        raise StyleFileError(f"fps {instr.fps:g} is outside the camera's range (0, {MAX_STYLE_FPS:g}]: "
                             "the vehicle's camera films at the style's frame rate")
    if not (instr.fps > 0 and abs(instr.frame_duration_s * instr.fps - 1.0) < 1e-6):
        raise StyleFileError(f"fps {instr.fps} and frame_duration_s {instr.frame_duration_s} disagree")


#: the camera-motion fields of Instructions (all present, or all None: no motion style)
MOTION_FIELDS = ("camera_motion_class", "pan_rate_dps", "tilt_rate_dps", "roll_rate_dps", "zoom_rate",
                 "translation_dir")


def _check_motion(instr: M.Instructions, rows: int) -> None:
    """The camera-motion fields: all or none, one row each, classes from the vocabulary."""
    from cinetransfer.shared.camera_motion import CLASSES

    have = [n for n in MOTION_FIELDS if getattr(instr, n) is not None]
    if not have:
        return
    if len(have) != len(MOTION_FIELDS):
        raise StyleFileError(f"camera motion: {', '.join(sorted(set(MOTION_FIELDS) - set(have)))} missing "
                             f"where {', '.join(have)} are given")
    for n in MOTION_FIELDS:
        if len(getattr(instr, n)) != rows:
            raise StyleFileError(f"{n} has {len(getattr(instr, n))} rows where image_targets has {rows}")
    bad = {c for c in instr.camera_motion_class if c and not set(c.split("+")) <= set(CLASSES)}
    if bad:
        raise StyleFileError(f"camera_motion_class: {sorted(bad)[0]!r} is not made of {', '.join(CLASSES)}")


# --------------------------------------------------------------------------- schema
def _num_or_null() -> dict:
    return {"type": ["number", "null"]}


def _rows(item: dict, width: int | None = None) -> dict:
    row: dict[str, Any] = {"type": "array", "items": item}
    if width is not None:
        row.update(minItems=width, maxItems=width)
    return {"type": "array", "items": row}


def json_schema() -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of a style file."""
    pair = {"type": "array", "items": _num_or_null(), "minItems": 2, "maxItems": 2}
    source = {
        "type": "object",
        "required": ["path", "width", "height", "fps", "n_frames", "sha256"],
        "properties": {"path": {"type": "string"}, "width": {"type": "integer", "minimum": 0},
                       "height": {"type": "integer", "minimum": 0}, "fps": {"type": "number", "minimum": 0},
                       "n_frames": {"type": "integer", "minimum": 0}, "sha256": {"type": "string"}},
    }
    instr = {
        "type": "object",
        "description": "Same content as the Instructions message (shared/messages.py); NaN is null.",
        "required": ["schema_version"] + [f.name for f in dataclasses.fields(M.Instructions) if not _absent_ok(f)],
        "properties": {
            "schema_version": {"enum": list(range(M.Instructions.MIN_SCHEMA_VERSION,
                                                  M.Instructions.SCHEMA_VERSION + 1))},
            "stamp_ns": {"type": "integer"},
            "seq": {"type": "integer", "minimum": 0},
            "valid": {"type": "boolean"},
            "source": source,
            "fps": {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_STYLE_FPS,
                    "description": "instruction (and camera) frame rate; the camera flies at this rate"},
            "frame_duration_s": {"type": "number", "exclusiveMinimum": 0},
            "first_frame": {"type": "integer", "minimum": 0},
            "final": {"type": "boolean"},
            "joint_names": {"type": "array", "minItems": 1, "uniqueItems": True,
                            "items": {"enum": list(M.COCO17_NAMES)}},
            "image_targets": {"type": "array", "description": "(K, E, 2) normalised x, y; null = not controlled",
                              "items": {"type": "array", "items": pair}},
            "subject_visible": {"type": "array", "items": {"type": "boolean"}},
            "subject_box": {**_rows(_num_or_null(), 4), "description": "(K, 4) normalised x0 y0 x1 y1"},
            "focus_raw": {**_rows(_num_or_null(), 3), "description": "(K, 3) b: foreground, subject, background"},
            "focus_smoothed": {**_rows(_num_or_null(), 3), "description": "(K, 3) B in [0, 1]"},
            "focus_in": {**_rows({"type": "boolean"}, 3), "description": "(K, 3) B > theta"},
            "theta": {"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 1},
            "mu_m": {"type": "number", "exclusiveMinimum": 0},
            "shot_start": {"type": ["array", "null"], "items": {"type": "boolean"},
                           "description": "(K,) row starts a new shot of the source; null or absent = one shot"},
            "camera_motion_class": {"type": ["array", "null"], "items": {"type": "string"},
                                    "description": "(K,) the camera's move per row ('static', 'pan+tilt', ...; "
                                                   "'' = unknown); null or absent = no camera-motion style"},
            **{n: {"type": ["array", "null"], "items": _num_or_null(), "description": d}
               for n, d in (("pan_rate_dps", "(K,) pan rate, positive to the camera's left [deg/s]"),
                            ("tilt_rate_dps", "(K,) tilt rate, positive up [deg/s]"),
                            ("roll_rate_dps", "(K,) roll rate, positive clockwise as the camera sees it [deg/s]"),
                            ("zoom_rate", "(K,) d ln(focal length)/dt [1/s]"))},
            "translation_dir": {"type": ["array", "null"], "items": {"type": "array", "items": _num_or_null(),
                                                                       "minItems": 3, "maxItems": 3},
                                "description": "(K, 3) unit translation direction, camera frame (x right, y down, "
                                               "z forward); zeros = none seen"},
        },
        "additionalProperties": True,
    }
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://cinetransfer.example/schemas/style-v1.json",
        "title": "cinetransfer style file (recording instructions)",
        "type": "object",
        "required": ["format", "version", "instructions"],
        "properties": {
            "format": {"const": FORMAT_NAME},
            "version": {"const": FORMAT_VERSION},
            "instructions": instr,
            "diagnostics": {"type": "object", "description": "raw per-frame measures for plots (free form)"},
            "warnings": {"type": "array", "items": {"type": "string"},
                         "description": "how the file was made that a reader should know (e.g. truncated source)"},
        },
    }


# --------------------------------------------------------------------------- files
def style_to_dict(instr: M.Instructions, diagnostics: dict[str, Any] | None = None) -> dict[str, Any]:
    d: dict[str, Any] = {"format": FORMAT_NAME, "version": FORMAT_VERSION,
                         "instructions": instructions_to_dict(instr)}
    if diagnostics:
        d["diagnostics"] = _to_json(diagnostics)
    return d


def save_style(path: str | os.PathLike, instr: M.Instructions, diagnostics: dict[str, Any] | None = None,
               warnings: list[str] | tuple[str, ...] = ()) -> None:
    """Write a style file (atomically: a unique temporary file renamed into place).

    `warnings`: what a reader should know about how it was made (e.g. a truncated source);
    stored at the top level, so they survive --no-diagnostics."""
    check_consistent(instr)
    d = style_to_dict(instr, diagnostics)
    if warnings:
        d["warnings"] = [str(w) for w in warnings]
    with atomic_write(path) as fh:
        json.dump(d, fh, separators=(",", ":"), allow_nan=False)
        fh.write("\n")


#: sha256 of the style-file texts that matched the schema in this process: the same text read
#: again (a transfer reads its style.json up to four times) is not validated again (jsonschema
#: takes ~0.3 CPU s for a 250-frame style)
_MATCHED_SCHEMA: set[str] = set()


def style_from_dict(d: Any, where: str = "style file", *, schema_checked: bool = False) -> StyleFile:
    """The style file `d` (parsed JSON); `schema_checked`: this very content matched the schema before."""
    import jsonschema

    if not isinstance(d, dict) or d.get("format") != FORMAT_NAME:
        raise StyleFileError(f"{where}: not a cinetransfer style file (format must be {FORMAT_NAME!r})")
    version = d.get("version")
    if version != FORMAT_VERSION:
        raise StyleFileError(f"{where}: style file version {version!r} is not supported; this build needs "
                             f"version {FORMAT_VERSION} (re-create it with 'cinetransfer smooth' or "
                             f"'cinetransfer extract')")
    try:
        if not schema_checked:
            jsonschema.validate(d, json_schema())
    except jsonschema.ValidationError as e:
        loc = "/".join(str(x) for x in e.absolute_path) or "(top)"
        raise StyleFileError(f"{where}: does not match the style-file schema at {loc}: {e.message}") from None
    instr = instructions_from_dict(d["instructions"])
    diag = d.get("diagnostics") or {}
    return StyleFile(instr, diag, int(version), tuple(d.get("warnings") or ()))


def load_style_file(path: str | os.PathLike) -> StyleFile:
    """Instructions and diagnostics (diagnostics: plain JSON values, NaN as None)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
        d = json.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise StyleFileError(f"{p}: no such style file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise StyleFileError(f"{p}: not valid JSON ({e})") from None
    digest = hashlib.sha256(raw).hexdigest()
    style = style_from_dict(d, str(p), schema_checked=digest in _MATCHED_SCHEMA)
    _MATCHED_SCHEMA.add(digest)  # (only reached when it matched)
    return style


def load_style(path: str | os.PathLike) -> M.Instructions:
    """The Instructions of a style file, to be flown: refuses other formats and versions, and
    targets nothing can fly (`unusable_targets`; `load_style_file` still reads those, to plot)."""
    instr = load_style_file(path).instructions
    why = unusable_targets(instr)
    if why:
        raise StyleFileError(f"{path}: {why}")
    return instr


def diag_array(diag: dict[str, Any], name: str) -> np.ndarray | None:
    """A diagnostics entry as a float array (None -> NaN), or None when absent."""
    v = diag.get(name)
    if v is None:
        return None
    return np.array(_none_to_nan(v), dtype=float)


# --------------------------------------------------------------------------- windows
def slice_instructions(instr: M.Instructions, start: int, stop: int, *, final: bool = False) -> M.Instructions:
    """Rows [start, stop) of an instruction set, as a streaming window (first_frame shifted)."""
    K = instr.image_targets.shape[0]
    start, stop = max(0, start), min(K, stop)
    return dataclasses.replace(
        instr, first_frame=instr.first_frame + start, final=final,
        image_targets=instr.image_targets[start:stop].copy(), subject_visible=instr.subject_visible[start:stop].copy(),
        subject_box=instr.subject_box[start:stop].copy(), focus_raw=instr.focus_raw[start:stop].copy(),
        focus_smoothed=instr.focus_smoothed[start:stop].copy(), focus_in=instr.focus_in[start:stop].copy(),
        shot_start=None if instr.shot_start is None else _shot_starts(instr.shot_start[start:stop]),
        **{n: None if getattr(instr, n) is None else _rows_of(getattr(instr, n), start, stop) for n in MOTION_FIELDS})


def _rows_of(v, start: int, stop: int):
    """Rows [start, stop) of a per-row field (an array or a list)."""
    return v[start:stop].copy() if isinstance(v, np.ndarray) else list(v[start:stop])


def _shot_starts(starts: np.ndarray) -> np.ndarray:
    out = np.asarray(starts, dtype=bool).copy()
    if out.size:
        out[0] = True  # a window or take always begins a shot
    return out


def shot_segments(instr: M.Instructions) -> list[tuple[int, int]]:
    """[(first row, end row)) of each shot of the instructions (one segment when unmarked)."""
    K = instr.image_targets.shape[0]
    if instr.shot_start is None or K == 0:
        return [(0, K)] if K else []
    starts = [0] + [k for k in range(1, K) if instr.shot_start[k]]
    return list(zip(starts, starts[1:] + [K]))


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description="style-file schema tools")
    ap.add_argument("--write-schema", metavar="PATH", help="write the JSON Schema to PATH")
    args = ap.parse_args(argv)
    if args.write_schema:
        Path(args.write_schema).write_text(json.dumps(json_schema(), indent=2) + "\n", encoding="utf-8")
    else:
        json.dump(json_schema(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
