"""Simulator render benchmark: frames rendered per second at 960x540 and 1280x720.

    python benchmarks/render.py [--samples 72] [--warmup 6] [--scenes open_country courtyard open_country_25d ...]

For each scene and resolution the camera flies a slow sideways arc while zooming and pulling
focus (so that nothing can be cached between frames) and SimBackend.step renders every frame
at 24 fps of simulated time, ground truth included and without it, depth of field always on.
Reports the median, p95 and max time per frame and the resulting frames/s. Goals at 960x540 with
truth: >= 30 fps for the 2.5-D compositor, >= 15 fps for the 3-D world (OpenGL on llvmpipe, depth
of field from the depth buffer). Wall time is what counts; CPU time (every thread: OpenCV's and
llvmpipe's) is printed too, because on a shared machine it is less disturbed by other load.
Writes benchmarks/results/render.json (commit, machine, config, figures); by default every 3-D
scene (the bundled scenes) and the 2.5-D fast mode's (`*_25d`).
"""
from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend
from cinetransfer.shared import messages as M

try:
    from harness import stats, write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import stats, write_result

RESOLUTIONS = ((960, 540), (1280, 720))
#: frames/s goal at 960x540 with truth, per world
GOALS = {"2.5d": 30.0, "3d": 15.0}


def measure(scene: str, width: int, height: int, samples: int, warmup: int, truth: bool) -> dict:
    sim = SimBackend(scene, width=width, height=height, epoch_ns=0, truth=truth)
    sim.start()
    v = sim.scene.vehicle
    p0 = np.array(v.position_m)
    times, cpu = [], []
    for k in range(warmup + samples):
        t = k / 24.0
        sim.apply(M.Setpoint(
            position_m=p0 + [0.3 * math.sin(0.7 * t), 2.0 * math.sin(0.5 * t), 0.2 * math.sin(0.3 * t)],
            camera_ypr_rad=np.array(v.camera_ypr_rad) + [0.1 * math.sin(0.5 * t), 0.0, 0.0],
            lens=M.LensState(focal_length_mm=v.focal_length_mm * (1 + 0.2 * math.sin(t)),
                             focus_distance_m=v.focus_distance_m * (1 + 0.3 * math.sin(0.8 * t)),
                             f_number=v.f_number)))
        t0 = time.perf_counter()
        c0 = time.process_time()
        sim.step(t)
        frames = sim.frames()
        sim.truths()
        dt = time.perf_counter() - t0
        dc = time.process_time() - c0
        assert len(frames) == 1
        if k >= warmup:
            times.append(dt * 1e3)
            cpu.append(dc * 1e3)
    ms = stats(times, digits=2)
    sim.close()
    return {"scene": scene, "world": sim.scene.world, "width": width, "height": height, "truth": truth,
            "samples": samples,
            "ms": ms, "fps_median": round(1000.0 / ms["median"], 1), "cpu_ms": stats(cpu, digits=2)}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=int, default=72)
    p.add_argument("--warmup", type=int, default=6)
    p.add_argument("--scenes", nargs="+", default=["open_country", "focus_hedge", "lawn_juggler", "courtyard",
                                                   "open_country_25d", "focus_hedge_25d", "lawn_juggler_25d"])
    p.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "render.json")
    args = p.parse_args()
    rows = []
    for scene in args.scenes:
        for w, h in RESOLUTIONS:
            for truth in (True, False):
                r = measure(scene, w, h, args.samples, args.warmup, truth)
                rows.append(r)
                print(f"{scene:14s} {w}x{h} truth={'yes' if truth else 'no ':3s}  median {r['ms']['median']:6.1f} ms "
                      f"p95 {r['ms']['p95']:6.1f} max {r['ms']['max']:6.1f}  -> {r['fps_median']:5.1f} fps "
                      f"(CPU {r['cpu_ms']['median']:5.1f} ms/frame, both threads)")
    worst = {}
    for world, goal in GOALS.items():
        got = [r["fps_median"] for r in rows if r["width"] == 960 and r["truth"] and r["world"] == world]
        if got:
            worst[world] = min(got)
            verdict = "MET" if worst[world] >= goal else "NOT MET"
            print(f"{world}: goal >= {goal:g} fps at 960x540 (with ground truth): worst scene {worst[world]:.1f} fps "
                  f"-> {verdict}")
    # per world and resolution, with truth: the slowest scene's frames/s and CPU ms per frame
    summary: dict = {}
    for r in rows:
        if r["truth"]:
            cell = summary.setdefault(r["world"], {}).setdefault(f"{r['width']}x{r['height']}", {})
            if not cell or r["fps_median"] < cell["fps"]:
                cell.update(scene=r["scene"], fps=r["fps_median"], cpu_ms=r["cpu_ms"]["median"])
    out = {"config": {"samples": args.samples, "warmup": args.warmup, "fps_sim": 24,
                      "opencv_threads": cv2.getNumThreads()}, "slowest_scene_with_truth": summary,
           "goal_fps_960x540": GOALS, "worst_fps_960x540": worst, "results": rows}
    print(f"wrote {write_result(args.out, out)}  (load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
