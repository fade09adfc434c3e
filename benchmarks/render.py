"""Simulator render benchmark: frames rendered per second at 960x540 and 1280x720.

    python benchmarks/render.py [--samples 72] [--warmup 6] [--scenes lawn_juggler open_country focus_hedge]

For each scene and resolution the camera flies a slow sideways arc while zooming and pulling
focus (so that nothing can be cached between frames) and SimBackend.step renders every frame
at 24 fps of simulated time, ground truth included (label pass) and without it. Reports the
median, p95 and max time per frame and the resulting frames/s. Goal: >= 30 fps at
960x540. Wall time is what counts; CPU time (both OpenCV threads) is printed too, because on a
shared machine it is less disturbed by other load. Writes benchmarks/results/render.json (commit, machine,
config, figures).
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
    return {"scene": scene, "width": width, "height": height, "truth": truth, "samples": samples,
            "ms": ms, "fps_median": round(1000.0 / ms["median"], 1), "cpu_ms": stats(cpu, digits=2)}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=int, default=72)
    p.add_argument("--warmup", type=int, default=6)
    p.add_argument("--scenes", nargs="+", default=["lawn_juggler", "open_country", "focus_hedge"])
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
    goal = [r for r in rows if r["width"] == 960 and r["truth"]]
    worst = min(r["fps_median"] for r in goal)
    print(f"goal >= 30 fps at 960x540 (with ground truth): worst scene {worst:.1f} fps -> "
          f"{'MET' if worst >= 30 else 'NOT MET'}")
    out = {"config": {"samples": args.samples, "warmup": args.warmup, "fps_sim": 24,
                      "opencv_threads": cv2.getNumThreads()}, "results": rows,
           "goal_fps_960x540": 30, "worst_fps_960x540": worst}
    print(f"wrote {write_result(args.out, out)}  (load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
