"""Camera-motion test sources with known truth, cut from real static footage.

A static clip is taken as the view of a pinhole camera with a wide field of view (SOURCE_HFOV_DEG);
a virtual camera inside it with a narrower view (the extraction's assumed one) pans, tilts, rolls
and zooms: each output frame is the source frame warped by the homography K_out R^T K_src^-1 of
the virtual camera's attitude R and focal length at that instant. For small moves this is a
sliding (pan, tilt), rotating (roll) or shrinking (zoom in) crop; the homography makes the truth
exact for any move. The people of the clip keep moving as they did.

Every source is a pair NAME.mp4 + NAME.truth.json:

    {"name": ..., "class": "pan+tilt", "fps": 24.0, "frames": K, "origin": "crop of CLIP",
     "pan_rate_dps": [K], "tilt_rate_dps": [K], "roll_rate_dps": [K], "zoom_rate": [K],
     "translation_dir": [[3] x K]}

with the sign conventions of the style file (docs/instructions.md). Any other generator (a render
of the simulator's 3-D world with its camera poses) that writes the same pair plugs into
benchmarks/eval_camera_motion.py unchanged.

    .venv/bin/python benchmarks/camera_motion_sources.py -o /tmp/cm_sources
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

#: the field of view a static source clip is taken to have [deg]; the virtual camera's (the
#: extraction's assumed one) is narrower, which leaves room to move inside the frame
SOURCE_HFOV_DEG = 62.0
DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


@dataclass(frozen=True)
class Move:
    """A constant-rate move of the virtual camera (the class is what the extraction must say)."""

    name: str
    cls: str
    pan_dps: float = 0.0
    tilt_dps: float = 0.0
    roll_dps: float = 0.0
    zoom_rate: float = 0.0  # d ln f / dt [1/s]


MOVES = (
    Move("static", "static"),
    Move("pan_left", "pan", pan_dps=6.0),
    Move("pan_right", "pan", pan_dps=-5.0),
    Move("pan_slow", "pan", pan_dps=3.0),
    Move("tilt_up", "tilt", tilt_dps=4.0),
    Move("tilt_down", "tilt", tilt_dps=-4.0),
    Move("roll_cw", "roll", roll_dps=8.0),
    Move("roll_ccw", "roll", roll_dps=-8.0),
    Move("zoom_in", "zoom_in", zoom_rate=0.15),
    Move("zoom_out", "zoom_out", zoom_rate=-0.12),
    Move("pan_tilt", "pan+tilt", pan_dps=5.0, tilt_dps=3.0),
    Move("pan_zoom_in", "pan+zoom_in", pan_dps=-4.0, zoom_rate=0.12),
)


def _rot(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    """Rotation matrix about a unit axis by angle [rad] (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def attitude(move: Move, t_s: float) -> np.ndarray:
    """The virtual camera's attitude at time t (OpenCV camera axes: x right, y down, z forward):
    pan about the up axis (-y), tilt about x, roll about z, each at its constant rate. Composed
    in the camera's own axes, so the rates are the camera's angular rates."""
    pan, tilt, roll = (math.radians(r) * t_s for r in (move.pan_dps, move.tilt_dps, move.roll_dps))
    w = np.array([tilt, -pan, roll])  # one rotation vector: constant body rates compose exactly
    ang = float(np.linalg.norm(w))
    return np.eye(3) if ang == 0.0 else _rot(tuple(w / ang), ang)


def homography(move: Move, t_s: float, t0_s: float, src_size: tuple[int, int], out_size: tuple[int, int]) -> np.ndarray:
    """Source pixel -> output pixel at time t (the move centred on t0: it starts as far one way as
    it ends the other)."""
    (sw, sh), (ow, oh) = src_size, out_size
    f_src = cm.focal_px(sw, SOURCE_HFOV_DEG)
    f_out = cm.focal_px(ow, cm.ASSUMED_HFOV_DEG) * math.exp(move.zoom_rate * (t_s - t0_s))
    k_src = np.array([[f_src, 0, (sw - 1) / 2], [0, f_src, (sh - 1) / 2], [0, 0, 1]])
    k_out = np.array([[f_out, 0, (ow - 1) / 2], [0, f_out, (oh - 1) / 2], [0, 0, 1]])
    r = attitude(move, t_s - t0_s)
    return k_out @ r.T @ np.linalg.inv(k_src)


def truth(move: Move, frames: int, fps: float, origin: str) -> dict:
    """The truth file of a constant-rate move (first row NaN: no previous frame)."""
    def rows(v: float) -> list:
        return [None] + [v] * (frames - 1)

    return {"name": move.name, "class": move.cls, "fps": fps, "frames": frames, "origin": origin,
            "pan_rate_dps": rows(move.pan_dps), "tilt_rate_dps": rows(move.tilt_dps),
            "roll_rate_dps": rows(move.roll_dps), "zoom_rate": rows(move.zoom_rate),
            "translation_dir": [[0.0, 0.0, 0.0]] * frames}


def read_frames(clip: Path, start: int, count: int) -> tuple[list[np.ndarray], float]:
    cap = cv2.VideoCapture(str(clip))
    try:
        fps = cap.get(cv2.CAP_PROP_FPS) or 24.0
        cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        frames = []
        while len(frames) < count:
            ok, img = cap.read()
            if not ok:
                break
            frames.append(img)
    finally:
        cap.release()
    return frames, float(fps)


def make_source(clip: Path, move: Move, out_dir: Path, *, start: int, frames: int,
                out_size: tuple[int, int]) -> Path:
    """Write out_dir/NAME.mp4 and NAME.truth.json for one move cut from `clip`."""
    imgs, fps = read_frames(clip, start, frames)
    if len(imgs) < frames:
        raise ValueError(f"{clip}: only {len(imgs)} frames from {start}")
    name = f"{clip.stem.split('_')[0]}_{move.name}"
    path = out_dir / f"{name}.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, out_size)
    t0 = (frames - 1) / 2 / fps
    try:
        for k, img in enumerate(imgs):
            h = homography(move, k / fps, t0, (img.shape[1], img.shape[0]), out_size)
            writer.write(cv2.warpPerspective(img, h, out_size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT))
    finally:
        writer.release()
    tr = truth(move, frames, fps, f"crop of {clip.name} from frame {start}")
    (out_dir / f"{name}.truth.json").write_text(json.dumps(tr) + "\n", encoding="utf-8")
    return path


#: static clips of /work/shared/data and the output size cut from each
CLIPS = (("sam2_juggle_1280x720.mp4", (640, 360)), ("tud_stadtmitte_640x480.mp4", (384, 288)))


def make_all(out_dir: Path, *, frames: int = 48, moves: tuple[Move, ...] = MOVES, data: Path = DATA) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    made = []
    for c, (clip, size) in enumerate(CLIPS):
        for i, mv in enumerate(moves):
            start = (i * 11 + c * 5) % 120  # different stretches of the clip: different people's motion
            made.append(make_source(data / clip, mv, out_dir, start=start, frames=frames, out_size=size))
    return made


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--out", type=Path, required=True, help="folder for the NAME.mp4 + NAME.truth.json pairs")
    ap.add_argument("--frames", type=int, default=48, help="frames per source (default %(default)s)")
    ap.add_argument("--data", type=Path, default=DATA, help="folder of the static clips")
    args = ap.parse_args(argv)
    made = make_all(args.out, frames=args.frames, data=args.data)
    print(f"wrote {len(made)} sources to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
