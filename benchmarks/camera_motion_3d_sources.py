"""Camera-motion test sources rendered in the simulator's 3-D world, with the truth from the poses.

A camera in the courtyard (pillars near, a brick wall far, the paving between: real parallax) pans,
tilts, zooms, dollies, trucks, orbits a point ahead and dolly-zooms while the walker crosses the
yard; each frame is drawn by the 3-D renderer (services/autopilot_bridge/sim/renderer3d.py) at the
field of view the extraction assumes for an unknown lens (shared/camera_motion.ASSUMED_HFOV_DEG),
so rotation rates are judged at face value. The truth comes from the camera's poses and focal
lengths the same way the report's truth does (camera_motion.rates_from_poses,
translation_from_velocity against the distance of the point the camera looks at).

Each source is the pair NAME.mp4 + NAME.truth.json of benchmarks/camera_motion_sources.py, so
benchmarks/eval_camera_motion.py judges both kinds:

    .venv/bin/python benchmarks/camera_motion_3d_sources.py -o /tmp/cm3d
    .venv/bin/python benchmarks/eval_camera_motion.py /tmp/cm3d
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cinetransfer.shared import camera_motion as cm

SCENE = "courtyard"
#: the camera's start: south-west of the yard looking north-east past the right colonnade
START_POS_M = (-10.0, -8.0, 1.6)
START_YPR_DEG = (30.0, -4.0, 0.0)
#: the point the orbit goes round and the dolly-zoom holds the size of [m ahead of the start]
CENTRE_AHEAD_M = 9.0
START_TIME_S = 1.0
F_NUMBER = 11.0  # deep focus: the moves, not the blur, are under test


@dataclass(frozen=True)
class Move3D:
    """A constant-rate move of the camera from the start pose (the class is what the extraction must say)."""

    name: str
    cls: str
    pan_dps: float = 0.0
    tilt_dps: float = 0.0
    zoom_rate: float = 0.0  #: d ln f / dt [1/s]
    velocity_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: forward, left, up in the start camera's axes
    orbit_dps: float = 0.0  #: round the centre ahead, turning to the left when positive (the camera moves right)
    dolly_zoom_mps: float = 0.0  #: towards the centre, the focal length following its distance


MOVES = (
    Move3D("static", "static"),
    Move3D("pan_left", "pan", pan_dps=6.0),
    Move3D("pan_right", "pan", pan_dps=-4.0),
    Move3D("tilt_up", "tilt", tilt_dps=4.0),
    Move3D("zoom_in", "zoom_in", zoom_rate=0.15),
    Move3D("zoom_out", "zoom_out", zoom_rate=-0.12),
    Move3D("dolly_in", "dolly_in", velocity_mps=(1.5, 0.0, 0.0)),
    Move3D("dolly_in_slow", "dolly_in", velocity_mps=(0.6, 0.0, 0.0)),
    Move3D("dolly_out", "dolly_out", velocity_mps=(-1.2, 0.0, 0.0)),
    Move3D("truck_right", "truck", velocity_mps=(0.0, -1.0, 0.0)),
    Move3D("pedestal_up", "pedestal", velocity_mps=(0.0, 0.0, 0.6)),
    Move3D("orbit_left", "orbit", orbit_dps=8.0),
    Move3D("orbit_right", "orbit", orbit_dps=-6.0),
    Move3D("dolly_zoom_in", "dolly_zoom", dolly_zoom_mps=1.2),
    Move3D("dolly_zoom_out", "dolly_zoom", dolly_zoom_mps=-1.0),
    Move3D("pan_tilt", "pan+tilt", pan_dps=5.0, tilt_dps=3.0),
)


def start_focal_mm(sensor_width_mm: float) -> float:
    """The focal length whose horizontal view is the extraction's assumed one."""
    return 0.5 * sensor_width_mm / math.tan(math.radians(cm.ASSUMED_HFOV_DEG) / 2.0)


def _heading(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw), math.sin(yaw), 0.0])


def pose(move: Move3D, t_s: float, f0_mm: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(position [m], yaw/pitch/roll [rad], focal length [mm], distance to the centre [m]) t_s into the move."""
    from cinetransfer.shared.camera import rotation_ypr

    p0 = np.array(START_POS_M, dtype=float)
    ypr0 = np.radians(START_YPR_DEG)
    centre = p0 + CENTRE_AHEAD_M * _heading(ypr0[0])
    ypr = ypr0 + np.radians([move.pan_dps * t_s + move.orbit_dps * t_s, move.tilt_dps * t_s, 0.0])
    pos = p0 + rotation_ypr(*ypr0) @ (np.asarray(move.velocity_mps) * t_s)
    if move.orbit_dps:
        pos = centre - CENTRE_AHEAD_M * _heading(ypr[0])
        pos[2] = p0[2]
    dist = CENTRE_AHEAD_M - move.dolly_zoom_mps * t_s
    if move.dolly_zoom_mps:
        pos = centre - dist * _heading(ypr0[0])
        pos[2] = p0[2]
    focal = f0_mm * math.exp(move.zoom_rate * t_s) * dist / CENTRE_AHEAD_M
    return pos, ypr, focal, float(np.linalg.norm(centre - pos))


def truth(move: Move3D, frames: int, fps: float, f0_mm: float, origin: str) -> dict:
    """The truth file: per-frame rates from the poses (first row NaN -> null) and translation direction."""
    poses = [pose(move, k / fps, f0_mm) for k in range(frames)]
    ypr = np.array([p[1] for p in poses])
    focal = np.array([p[2] for p in poses])
    rates = cm.rates_from_poses(ypr, focal, fps)
    trans = [[0.0, 0.0, 0.0]]
    for k in range(1, frames):
        v = (poses[k][0] - poses[k - 1][0]) * fps
        trans.append([round(float(x), 5) for x in cm.translation_from_velocity(v, ypr[k], poses[k][3])])

    def col(n: str) -> list:
        return [None if not math.isfinite(x) else round(float(x), 6) for x in rates[n]]

    return {"name": move.name, "class": move.cls, "fps": fps, "frames": frames, "origin": origin,
            "pan_rate_dps": col("pan_rate_dps"), "tilt_rate_dps": col("tilt_rate_dps"),
            "roll_rate_dps": col("roll_rate_dps"), "zoom_rate": col("zoom_rate"), "translation_dir": trans}


def make_source(renderer, move: Move3D, out_dir: Path, *, frames: int, fps: float) -> Path:
    """Write out_dir/NAME.mp4 and NAME.truth.json for one move rendered by `renderer` (a WorldRenderer)."""
    from cinetransfer.services.autopilot_bridge.sim.renderer import View

    f0 = start_focal_mm(renderer.sensor.width_mm)
    name = f"world3d_{move.name}"
    path = out_dir / f"{name}.mp4"
    size = (renderer.width, renderer.height)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    try:
        for k in range(frames):
            pos, ypr, focal, dist = pose(move, k / fps, f0)
            view = View(position_m=pos, ypr_rad=ypr, focal_mm=focal, focus_m=dist, f_number=F_NUMBER,
                        width=size[0], height=size[1], sensor=renderer.sensor)
            img, _ = renderer.render(view, START_TIME_S + k / fps, truth=False)
            writer.write(img)
    finally:
        writer.release()
    tr = truth(move, frames, fps, f0, f"3-D render of {renderer.scene.name}")
    (out_dir / f"{name}.truth.json").write_text(json.dumps(tr) + "\n", encoding="utf-8")
    return path


def make_all(out_dir: Path, *, frames: int = 48, size: tuple[int, int] = (640, 360),
             moves: tuple[Move3D, ...] = MOVES) -> list[Path]:
    from cinetransfer.services.autopilot_bridge.sim.renderer3d import WorldRenderer
    from cinetransfer.services.autopilot_bridge.sim.scene import load_scene

    out_dir.mkdir(parents=True, exist_ok=True)
    scene = load_scene(SCENE)
    renderer = WorldRenderer(scene, *size)
    try:
        return [make_source(renderer, mv, out_dir, frames=frames, fps=float(scene.camera.fps)) for mv in moves]
    finally:
        renderer.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--out", type=Path, required=True, help="folder for the NAME.mp4 + NAME.truth.json pairs")
    ap.add_argument("--frames", type=int, default=48, help="frames per source (default %(default)s)")
    ap.add_argument("--only", nargs="*", default=None, help="names of the moves to render (default: all)")
    args = ap.parse_args(argv)
    moves = tuple(m for m in MOVES if not args.only or m.name in args.only)
    if not moves:
        print(f"camera_motion_3d_sources: no move named {args.only}; known: {[m.name for m in MOVES]}",
              file=sys.stderr)
        return 2
    made = make_all(args.out, frames=args.frames, moves=moves)
    print(f"wrote {len(made)} sources to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
