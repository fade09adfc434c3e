"""Transfer benchmark: wall time of the README's main command against the clip's duration, on a
quiet machine and with a busy second process, and whether the two flights are identical.

    python benchmarks/transfer.py [--source CLIP] [--scene open_country] [--busy 1] [--max-frames 0]

Runs `cinetransfer transfer` twice (the second time with the first run's style.json, while
`--busy` processes spin on the CPU), prints per run: total wall time and its ratio to the clip's
duration, the flight's wall time per simulated second, the render and solve time per step (from
the nodes' Health), the planner's over-budget solves; then compares the two recordings (ground
truth and video) frame by frame. Goal: ratio <= 3 on 2 cores, identical results. The
verdict judges the flight (pre-roll included), the part simulation time governs, and prints the
whole command's ratio (two style extractions and the report included) beside it, met or not.
Writes benchmarks/results/transfer.json.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cinetransfer.report.truthfile import read_truths
from cinetransfer.data import data_dir

try:
    from harness import write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import write_result

HERE = Path(__file__).resolve().parent


def run(source: Path, scene: str, out: Path, max_frames: int, extra: list[str]) -> dict:
    cmd = [sys.executable, "-m", "cinetransfer", "transfer", str(source), "--scene", scene, "-o", str(out),
           "--rig", out.name, *(["--max-frames", str(max_frames)] if max_frames else []), *extra]
    t = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.monotonic() - t
    if r.returncode != 0:
        sys.exit(f"transfer failed (exit {r.returncode}):\n{r.stderr[-3000:]}")
    meta = json.loads((out / "meta.json").read_text())
    h = meta.get("health", {})
    pl, br = h.get("planner", {}).get("counters", {}), h.get("autopilot_bridge", {}).get("counters", {})
    flown_s = meta["preroll_frames"] / meta["fps"] + meta["instruction_frames"] / meta["fps"]
    return {"wall_s": round(wall, 2), "timings": meta.get("timings", {}), "recorded": meta["recorded_frames"],
            "instruction_frames": meta["instruction_frames"], "repeated": meta["repeated_frames"],
            "flight_wall_per_sim_s": round(meta["timings"]["flight_s"] / flown_s, 2) if "timings" in meta else None,
            "render_ms_p50": br.get("render_ms_p50"), "step_wall_ms_p50": br.get("step_wall_ms_p50"),
            "solve_ms_p50": pl.get("solve_ms_p50"), "solve_ms_p95": pl.get("solve_ms_p95"),
            "over_budget_solves": pl.get("over_budget"), "solves": pl.get("solves"),
            "report": meta.get("headline")}


def frames(path: Path) -> list[np.ndarray]:
    import cv2

    cap, out = cv2.VideoCapture(str(path)), []
    while True:
        ok, img = cap.read()
        if not ok:
            return out
        out.append(img)


def compare(a: Path, b: Path) -> dict:
    ta, tb = read_truths(a / "truth.msgpack"), read_truths(b / "truth.msgpack")
    jd = max(float(np.nanmax(np.abs(x.joints_norm - y.joints_norm))) for x, y in zip(ta, tb))
    focus_same = all(np.array_equal(x.region_in_focus, y.region_in_focus) for x, y in zip(ta, tb))
    fa, fb = frames(a / "output.mp4"), frames(b / "output.mp4")
    px = max(float(np.abs(x.astype(int) - y.astype(int)).max()) for x, y in zip(fa, fb))
    return {"truth_frames": [len(ta), len(tb)], "joint_max_diff": jd, "focus_labels_identical": focus_same,
            "video_frames": [len(fa), len(fb)], "video_max_pixel_diff": px}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default=None, help="source clip (default: the README's juggling clip)")
    ap.add_argument("--scene", default="open_country")
    ap.add_argument("--busy", type=int, default=1, help="busy processes during the second run (default 1)")
    ap.add_argument("--max-frames", type=int, default=0)
    args = ap.parse_args()
    source = Path(args.source) if args.source else data_dir() / "sam2_juggle_1280x720.mp4"
    import cv2

    cap = cv2.VideoCapture(str(source))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    clip_s = (min(n, args.max_frames) if args.max_frames else n) / cap.get(cv2.CAP_PROP_FPS)
    with tempfile.TemporaryDirectory() as tmp:
        quiet = run(source, args.scene, Path(tmp) / "quiet", args.max_frames, [])
        busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
        try:
            loaded = run(source, args.scene, Path(tmp) / "busy", args.max_frames,
                         ["--style", str(Path(tmp) / "quiet" / "style.json")])
        finally:
            for p in busy:
                p.kill()
        same = compare(Path(tmp) / "quiet", Path(tmp) / "busy")
    for name, r in (("quiet", quiet), (f"{args.busy} busy process(es)", loaded)):
        fl = r["timings"].get("flight_s", float("nan"))
        print(f"{name:>22}: {r['wall_s']:6.1f} s in all = {r['wall_s'] / clip_s:4.2f} x the clip ({clip_s:.1f} s), "
              f"of it extraction {r['timings'].get('extract_source_s', 0):.1f} s + flight {fl:.1f} s "
              f"({fl / clip_s:.2f} x the clip) + output extraction {r['timings'].get('extract_output_s', 0):.1f} s; "
              f"flight {r['flight_wall_per_sim_s']} wall s per simulated s; render p50 {r['render_ms_p50']} ms, "
              f"step p50 {r['step_wall_ms_p50']} ms, solve p50/p95 {r['solve_ms_p50']}/{r['solve_ms_p95']} ms, "
              f"over real-time budget {r['over_budget_solves']}/{r['solves']}; "
              f"frames {r['recorded']}/{r['instruction_frames']}, repeats {r['repeated']}")
    print(f"{'':>22}  (the busy run reuses the quiet run's style: no source extraction in its total)")
    identical = same["joint_max_diff"] <= 1e-3 and same["focus_labels_identical"] and \
        same["truth_frames"][0] == same["truth_frames"][1]
    print(f"agreement: truth joints max diff {same['joint_max_diff']:.2e}, focus labels identical "
          f"{same['focus_labels_identical']}, video max pixel diff {same['video_max_pixel_diff']:.0f}")
    ratio = quiet["wall_s"] / clip_s
    flight_ratio = quiet["timings"]["flight_s"] / clip_s
    ok = flight_ratio <= 3.0 and identical and quiet["repeated"] == 0 and loaded["repeated"] == 0
    print(f"verdict: flight (pre-roll included) {flight_ratio:.2f} x the clip (goal <= 3), whole command "
          f"{ratio:.2f} x (source and output extraction included: {'<= 3' if ratio <= 3 else 'NOT <= 3'}), "
          f"identical results {identical} -> {'goal met' if ok else 'goal NOT met'} for the flight")
    res = {"clip_s": clip_s,
           "quiet": quiet, "busy": loaded, "busy_processes": args.busy, "agreement": same, "goal_met": ok,
           "ratio_total": ratio, "ratio_flight": flight_ratio}
    print(f"wrote {write_result('transfer', res)}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
