"""`cinetransfer rerun RUN.mcap [-o RUN.rrd]`: the recording's plottable values as Rerun scalars.

Rerun opens run.mcap itself (video, transforms and calibration come through), but our JSON
channels arrive there as raw bytes. This export writes a Rerun recording (.rrd) with one scalar
series per value, each on the timelines Rerun's own MCAP import uses, `message_log_time` (when
the recorder got it) and `message_publish_time` (the message's own stamp, simulation time in
lockstep), so that they line up with the video, the transforms and the calibration, which the
same .rrd carries under ct/RIG/... as Rerun imports them from the MCAP (`--scalars-only` leaves
them out):

- RIG/vehicle/position/{x,y,z}, RIG/vehicle/velocity/{x,y,z}, RIG/vehicle/camera/{yaw,pitch,roll}
- RIG/lens/{focal_length_mm,focus_distance_m,f_number} (the lens as measured)
- RIG/setpoint/position/{x,y,z}, RIG/setpoint/camera/{yaw,pitch,roll},
  RIG/setpoint/lens/{focal_length_mm,focus_distance_m,f_number}, RIG/setpoint/instruction_frame
- RIG/joint_error/{mean,<joint>} per simulated camera frame (also on the timeline `frame`): the
  distance, in normalised image units, between a controlled joint's true image position and its
  target in the instruction frame the planner was following (the newest tracking setpoint at or
  before the frame's stamp); needs the run's style.json (beside RUN.mcap, or --style). Joints
  are matched by name (the report also matches them by image side).

Open the result with `rerun RUN.rrd`. Needs rerun-sdk, an optional dependency (about 500 MB
installed): `pip install 'cinetransfer[rerun]'`.
"""
from __future__ import annotations

import argparse
import bisect
import json
import math
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cinetransfer.runlog import RunFormatError, RunReader

AXES = ("x", "y", "z")
ANGLES = ("yaw", "pitch", "roll")
LENS = ("focal_length_mm", "focus_distance_m", "f_number")


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None


def _vector(prefix: str, values: Any, names: tuple[str, ...]) -> dict[str, float | None]:
    values = values if isinstance(values, list) else []
    return {f"{prefix}/{n}": _num(values[i]) if i < len(values) else None for i, n in enumerate(names)}


def _lens(prefix: str, lens: Any) -> dict[str, float | None]:
    lens = lens if isinstance(lens, dict) else {}
    return {f"{prefix}/{n}": _num(lens.get(n)) for n in LENS}


def vehicle_values(msg: dict) -> dict[str, float | None]:
    """A VehicleState (JSON form) as named scalars."""
    return {**_vector("vehicle/position", msg.get("position_m"), AXES),
            **_vector("vehicle/velocity", msg.get("velocity_mps"), AXES),
            **_vector("vehicle/camera", msg.get("camera_ypr_rad"), ANGLES), **_lens("lens", msg.get("lens"))}


def setpoint_values(msg: dict) -> dict[str, float | None]:
    """A Setpoint (JSON form) as named scalars."""
    frame = msg.get("instruction_frame")
    return {**_vector("setpoint/position", msg.get("position_m"), AXES),
            **_vector("setpoint/camera", msg.get("camera_ypr_rad"), ANGLES), **_lens("setpoint/lens", msg.get("lens")),
            "setpoint/instruction_frame": float(frame) if isinstance(frame, int) and frame >= 0 else None}


def joint_errors(truth: dict, targets: np.ndarray, target_names: list[str]) -> dict[str, float]:
    """Per controlled joint, |true image position - target| (normalised units), for the joints
    that are visible in the frame and have a target; 'mean' over them. Empty when none."""
    names = list(truth.get("joint_names") or [])
    xy = truth.get("joints_norm") or []
    visible = truth.get("joints_visible") or []
    out: dict[str, float] = {}
    for e, name in enumerate(target_names):
        if name not in names:
            continue
        j = names.index(name)
        if j >= len(xy) or j >= len(visible) or not visible[j]:
            continue
        p, t = xy[j], targets[e]
        if p is None or None in p or not np.isfinite(t).all():
            continue
        out[name] = float(math.hypot(p[0] - t[0], p[1] - t[1]))
    if out:
        out["mean"] = float(np.mean(list(out.values())))
    return out


@dataclass
class Followed:
    """Which instruction frame the planner was following, by setpoint stamp."""

    stamps: list[int] = field(default_factory=list)
    frames: list[int] = field(default_factory=list)
    _sorted: bool = True

    def add(self, msg: dict) -> None:
        if msg.get("mode") == "track" and isinstance(msg.get("instruction_frame"), int):
            self.stamps.append(int(msg.get("stamp_ns", 0)))
            self.frames.append(int(msg["instruction_frame"]))
            self._sorted = False

    def at(self, stamp_ns: int) -> int | None:
        """The frame of the newest tracking setpoint stamped at or before `stamp_ns`."""
        if not self._sorted:
            pairs = sorted(zip(self.stamps, self.frames), key=lambda p: p[0])
            self.stamps, self.frames = [p[0] for p in pairs], [p[1] for p in pairs]
            self._sorted = True
        i = bisect.bisect_right(self.stamps, stamp_ns) - 1
        return self.frames[i] if i >= 0 else None


@dataclass
class Series:
    """One scalar series: values at (log time, stamp, frame) points."""

    log_ns: list[int] = field(default_factory=list)
    stamp_ns: list[int] = field(default_factory=list)
    frame: list[int] = field(default_factory=list)
    values: list[float] = field(default_factory=list)

    def add(self, log_ns: int, stamp_ns: int, value: float | None, frame: int = -1) -> None:
        if value is not None:
            self.log_ns.append(log_ns)
            self.stamp_ns.append(stamp_ns)
            self.frame.append(frame)
            self.values.append(value)


def _rig(topic: str) -> str:
    parts = topic.split("/")
    return parts[1] if len(parts) > 2 else "rig"


def collect(run: RunReader, instructions: Any | None) -> dict[str, Series]:
    """Every series of the recording (see the module doc), by entity path."""
    series: dict[str, Series] = defaultdict(Series)
    followed: dict[str, Followed] = defaultdict(Followed)
    truths: list[tuple[int, str, dict]] = []
    for rec, ch, schema in run.records():
        name = schema.name if schema is not None else ""
        if name not in ("cinetransfer.VehicleState", "cinetransfer.Setpoint", "cinetransfer.GroundTruth"):
            continue
        try:
            msg = json.loads(rec.data)
        except (json.JSONDecodeError, UnicodeDecodeError):
            continue
        rig, stamp = _rig(ch.topic), int(msg.get("stamp_ns") or rec.publish_time)
        if name == "cinetransfer.GroundTruth":
            truths.append((rec.log_time, rig, msg))
            continue
        if name == "cinetransfer.Setpoint":
            followed[rig].add(msg)
        values = vehicle_values(msg) if name == "cinetransfer.VehicleState" else setpoint_values(msg)
        for key, v in values.items():
            series[f"{rig}/{key}"].add(rec.log_time, stamp, v)
    if instructions is not None:
        _add_joint_errors(series, truths, followed, instructions)
    return dict(series)


def _add_joint_errors(series: dict[str, Series], truths: list, followed: dict[str, Followed], instr: Any) -> None:
    targets = np.asarray(instr.image_targets, dtype=float)
    names = list(instr.joint_names)
    for log_ns, rig, truth in truths:
        stamp = int(truth.get("stamp_ns") or 0)
        k = followed[rig].at(stamp)
        if k is None or not 0 <= k < len(targets):
            continue
        for joint, err in joint_errors(truth, targets[k], names).items():
            series[f"{rig}/joint_error/{joint}"].add(log_ns, stamp, err, int(truth.get("frame_index", -1)))


#: Rerun's MCAP decoders that turn our Foxglove channels into video, transforms and a pinhole
MCAP_DECODERS = ("foxglove", "protobuf")
LOG_TIME, PUBLISH_TIME = "message_log_time", "message_publish_time"  # the timelines of Rerun's MCAP import


def write_rrd(series: dict[str, Series], path: Path, recording_name: str, mcap: RunReader | None = None) -> None:
    """Write the series (and, given `mcap`, its video, transforms and calibration) to `path`."""
    import rerun as rr

    rec = rr.RecordingStream("cinetransfer", send_properties=True)
    rec.save(path)
    rec.send_recording_name(recording_name)
    if mcap is not None:
        from rerun.chunk import McapReader

        rec.send_chunks(McapReader(mcap.path, decoders=list(MCAP_DECODERS), recover=not mcap.info.complete).stream())
    for entity, s in sorted(series.items()):
        indexes = [rr.TimeColumn(LOG_TIME, timestamp=np.asarray(s.log_ns, "datetime64[ns]")),
                   rr.TimeColumn(PUBLISH_TIME, timestamp=np.asarray(s.stamp_ns, "datetime64[ns]"))]
        if "/joint_error/" in entity:
            indexes.append(rr.TimeColumn("frame", sequence=s.frame))
        rec.send_columns(entity, indexes=indexes, columns=rr.Scalars.columns(scalars=np.asarray(s.values)))
    rec.flush()
    rec.disconnect()


def _instructions(run_path: Path, style: str | None) -> Any | None:
    from cinetransfer.shared.instructions import StyleFileError, load_style_file

    path = Path(style) if style else run_path.parent / "style.json"
    if not style and not path.is_file():
        return None
    try:
        return load_style_file(path).instructions
    except StyleFileError as e:
        raise ValueError(str(e)) from None


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer rerun", description=__doc__.splitlines()[0])
    p.add_argument("log", help="a recording (run.mcap)")
    p.add_argument("-o", "--output", default=None, metavar="RUN.rrd", help="where to write (default: beside the log)")
    p.add_argument("--scalars-only", action="store_true",
                   help="leave out the video, transforms and calibration (Rerun's import of the MCAP)")
    p.add_argument("--style", default=None, metavar="style.json",
                   help="the instructions flown, for the joint errors (default: style.json beside the log, if there)")
    args = p.parse_args(argv)
    try:
        import rerun  # noqa: F401 - an optional dependency: say so before reading anything
    except ImportError:
        print("cinetransfer rerun: needs rerun-sdk (optional, about 500 MB): pip install 'cinetransfer[rerun]'",
              file=sys.stderr)
        return 2
    log = Path(args.log)
    out = Path(args.output) if args.output else log.with_suffix(".rrd")
    try:
        run = RunReader(log)
        instr = _instructions(log, args.style)
        series = collect(run, instr)
        write_rrd(series, out, str(log), mcap=None if args.scalars_only else run)
    except (OSError, RunFormatError, ValueError) as e:
        print(f"cinetransfer rerun: {e}", file=sys.stderr)
        return 2
    errors = sum(1 for k in series if "/joint_error/" in k)
    points = sum(len(s.values) for s in series.values())
    print(f"wrote {out}: {len(series)} scalar series, {points} points"
          + (f" ({errors} joint-error series)" if instr is not None else " (no style.json: no joint errors)")
          + ("" if args.scalars_only else "; with the video, transforms and calibration"))
    return 0
