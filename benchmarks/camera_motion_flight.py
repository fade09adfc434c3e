"""Fly a style's camera motion in-process (no Zenoh, no rendering): the quick look at a transfer.

The planner flies the bridge's simulator (render off) on the transfer's schedule: a pre-roll on
the first instruction row, then one row per camera frame. At each frame the camera's pose, lens
and velocity give the output's camera motion exactly as the report's truth reads it (smoothed and
classed as the smoother does the clip's), and the subject's joints projected through that camera
give the framing error against the style's targets. So the share of rows whose class matches the
source's (the report's truth agreement) and the framing are known in seconds rather than minutes;
the real transfer (benchmarks/eval_camera_motion_transfer.py) remains the judge.

    .venv/bin/python benchmarks/camera_motion_flight.py RUN/style.json [...] [--scene courtyard]

`--mark` lets the courtyard's walker wait on his mark (where the rendered sources film him first)
for the pre-roll, as an actor does before a take (camera_motion_mark.py); `--preroll` sets how long.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from cinetransfer.services.planner.core import Planner
from cinetransfer.services.smoother.camera_motion import motion_style
from cinetransfer.shared import camera as cam
from cinetransfer.shared import camera_motion as cm
from cinetransfer.shared import messages as M

try:
    from camera_motion_mark import write_mark_scene
except ImportError:  # imported as a package
    from benchmarks.camera_motion_mark import write_mark_scene

PREROLL_S = 5.0  #: cinetransfer transfer's default pre-roll
T0_NS = 1_700_000_000_000_000_000


def _frame_sample(sim: Any, names: list[str], targets: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, float]:
    """(camera yaw/pitch/roll, focal length, translation direction, mean joint error) at one frame."""
    vs, ss = sim.vehicle_state(0), sim.subject_state(0)
    jn = list(ss.joint_names)
    joints = np.array([ss.joints_m[jn.index(n)] if n in jn else [np.nan] * 3 for n in names], dtype=float)
    ypr = np.asarray(vs.camera_ypr_rad, dtype=float)
    f = float(vs.lens.focal_length_mm)
    pts = cam.project_world(joints, vs.position_m, ypr, f)
    ok = np.isfinite(targets).all(axis=1) & np.isfinite(pts).all(axis=1)
    err = float(np.linalg.norm(pts[ok] - targets[ok], axis=1).mean()) if ok.any() else float("nan")
    centre = np.nanmean(joints, axis=0)
    dist = float(np.linalg.norm(centre - np.asarray(vs.position_m)))
    trans = cm.translation_from_velocity(np.asarray(vs.velocity_mps, dtype=float), ypr, dist)
    return ypr, f, np.asarray(trans, dtype=float), err


def fly(ins: M.Instructions, planner: Planner, sim: Any, *, preroll_s: float = PREROLL_S) -> dict[str, Any]:
    """Fly the style's rows after a pre-roll; the output's classes and rates per row and the framing."""
    fps = float(ins.fps)
    k = int(ins.image_targets.shape[0])
    names = list(ins.joint_names)
    planner.command(M.Command(action="start", args={"start_frame": int(ins.first_frame),
                                                    "preroll_s": float(preroll_s)}), T0_NS)
    period = 1.0 / planner.cfg.rate_hz
    frame_times = [preroll_s + r / fps for r in range(k)]
    ypr, focal, trans, err = np.full((k, 3), np.nan), np.full(k, np.nan), np.full((k, 3), np.nan), np.full(k, np.nan)
    t, next_plan, row, failed = 0.0, 0.0, 0, 0
    while row < k:
        t_next = min(next_plan, frame_times[row])
        if t_next > t:
            sim.step(t_next - t)
            t = t_next
        if abs(t - frame_times[row]) < 1e-9:
            ypr[row], focal[row], trans[row], err[row] = _frame_sample(
                sim, names, np.asarray(ins.image_targets[row], dtype=float))
            row += 1
        if t >= next_plan - 1e-9:
            now = T0_NS + int(round(t * 1e9))
            sp = planner.step(now, ins, sim.vehicle_state(now), sim.subject_state(now))
            failed += int(sp.mode != "track" or "failed" in sp.solver_status)
            sim.apply(sp)
            next_plan += period
    raw = cm.rates_from_poses(ypr, focal, fps)
    rates = np.column_stack([np.radians([raw[n] for n in ("pan_rate_dps", "tilt_rate_dps", "roll_rate_dps")]).T / fps,
                             raw["zoom_rate"] / fps, trans])
    out = motion_style(rates, fps, np.zeros(k, dtype=bool))
    src = list(ins.camera_motion_class or [""] * k)
    pairs = [(s, o) for s, o in zip(src, out["camera_motion_class"]) if s and o]
    return {"agreement": sum(s == o for s, o in pairs) / len(pairs) if pairs else float("nan"),
            "joint_error": float(np.nanmean(err)), "failed_steps": failed, "source": src,
            "output": out["camera_motion_class"],
            "pan_dps": np.asarray(out["pan_rate_dps"], float), "zoom_rate": np.asarray(out["zoom_rate"], float)}


def class_counts(classes: list[str]) -> str:
    """The classes of a run of rows with their counts ("pan x30, static x17")."""
    names, counts = np.unique([c or "-" for c in classes], return_counts=True)
    order = np.argsort(-counts)
    return ", ".join(f"{names[i]} x{counts[i]}" for i in order[:3])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("styles", nargs="+", type=Path, help="style files (a transfer run's style.json)")
    ap.add_argument("--scene", default="courtyard")
    ap.add_argument("--preroll", type=float, default=PREROLL_S)
    ap.add_argument("--weight", nargs="*", default=[], metavar="NAME=VALUE", help="planner cost weights to change")
    ap.add_argument("--mark", action="store_true",
                    help="the courtyard's walker waits on his mark for the pre-roll (camera_motion_mark.py)")
    args = ap.parse_args(argv)
    from cinetransfer.plan import make_sim
    from cinetransfer.services.planner.config import PlannerConfig
    from cinetransfer.services.planner.scenarios import planner_maker
    from cinetransfer.shared.instructions import load_style

    cfg = PlannerConfig()
    changed = dict(w.split("=", 1) for w in args.weight)
    weights = dataclasses.replace(cfg.weights, **{k: float(v) for k, v in changed.items()})
    cfg = dataclasses.replace(cfg, weights=weights)
    cfg = dataclasses.replace(cfg, max_solve_time_s=max(cfg.max_solve_time_s, 10.0 / cfg.rate_hz))
    make = planner_maker(cfg)
    scene = args.scene
    if args.mark:
        scene = str(write_mark_scene(Path(tempfile.mkdtemp(prefix="ct_mark_")) / "scene.yaml", wait_s=args.preroll,
                                     scene=args.scene))
    for path in args.styles:
        ins = load_style(str(path))
        sim, _ = make_sim(scene)
        try:
            r = fly(ins, make(), sim, preroll_s=args.preroll)
        finally:
            sim.close()
        print(f"{path.stem:26s} source {class_counts(r['source']):28s} output {class_counts(r['output']):44s}"
              f" agreement {r['agreement']:.2f} joint error {r['joint_error']:.4f}"
              f" failed steps {r['failed_steps']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
