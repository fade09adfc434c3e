"""Transfer benchmark: wall time of the README's main command, whole, against the clip's duration,
its stages, and whether the same take twice gives the same frames and the same report.

    python benchmarks/transfer.py [--source CLIP] [--scene open_country] [--busy 1] [--max-frames 0]

Runs `cinetransfer transfer` twice with one fresh style cache: first with an empty cache (the
README command as a new user runs it: the source's style is extracted), then the very same
command again while `--busy` processes spin on the CPU (the style comes from the cache, as when a
user iterates). Prints per run: total wall time and its ratio to the clip's duration, its
stages (node start, source extraction, flight, output style, report, and the rest), the flight's
wall time per simulated second, render and solve time per step (from the nodes' Health), the
planner's over-budget solves; then compares the two runs: ground truth, video frames and the
report's figures. Goal: the whole first command <= 3 x the clip on 2 cores, identical results.
The verdict judges the whole command (extraction, flight, evaluation, start and stop included).
Writes benchmarks/results/transfer.json.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cinetransfer.report.repeatable import report_figures
from cinetransfer.report.truthfile import read_truths
from cinetransfer.data import data_dir

try:
    from harness import write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import write_result

HERE = Path(__file__).resolve().parent


#: the stages of meta.json's timings, in order, as printed
STAGES = (("cache_lookup_s", "style cache key"), ("start_nodes_s", "start"), ("extract_source_s", "source style"),
          ("flight_s", "flight"), ("save_take_s", "save take"), ("extract_output_s", "output style"),
          ("report_s", "report"), ("wind_down_s", "stop nodes"))
#: where the bridge's and the planner's simulation steps spend their wall time (Health counters)
BRIDGE_WAITS = ("publish_s", "wait_render_s", "wait_setpoint_s", "advance_s", "pace_s")
PLANNER_WAITS = ("wait_tick_s", "wait_state_s", "step_s")


def run(source: Path, scene: str, out: Path, max_frames: int, cache: Path) -> dict:
    cmd = [sys.executable, "-m", "cinetransfer", "transfer", str(source), "--scene", scene, "-o", str(out),
           "--rig", out.name, *(["--max-frames", str(max_frames)] if max_frames else [])]
    load = os.getloadavg()[0]
    t = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "CT_CACHE_DIR": str(cache)})
    wall = time.monotonic() - t
    if r.returncode != 0:
        sys.exit(f"transfer failed (exit {r.returncode}):\n{r.stderr[-3000:]}")
    meta = json.loads((out / "meta.json").read_text())
    h = meta.get("health", {})
    pl, br = h.get("planner", {}).get("counters", {}), h.get("autopilot_bridge", {}).get("counters", {})
    flown_s = meta["preroll_frames"] / meta["fps"] + meta["instruction_frames"] / meta["fps"]
    return {"wall_s": round(wall, 2), "timings": meta.get("timings", {}), "style_origin": meta.get("style_origin"),
            "output_measured": meta.get("output_measured"), "recorded": meta["recorded_frames"],
            "instruction_frames": meta["instruction_frames"], "repeated": meta["repeated_frames"],
            "flight_wall_per_sim_s": round(meta["timings"]["flight_s"] / flown_s, 2) if "timings" in meta else None,
            "render_ms_p50": br.get("render_ms_p50"), "step_wall_ms_p50": br.get("step_wall_ms_p50"),
            "solve_ms_p50": pl.get("solve_ms_p50"), "solve_ms_p95": pl.get("solve_ms_p95"),
            "over_budget_solves": pl.get("over_budget"), "solves": pl.get("solves"),
            "stage_cpu_s": meta.get("stage_cpu_s", {}), "sim_steps": br.get("waits_steps"),
            "bridge_waits_s": {k: br[k] for k in BRIDGE_WAITS if k in br},
            "planner_waits_s": {k: pl[k] for k in PLANNER_WAITS if k in pl},
            "load_before": load, "report": meta.get("headline")}


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
    ra, rb = report_figures(a), report_figures(b)
    return {"truth_frames": [len(ta), len(tb)], "joint_max_diff": jd, "focus_labels_identical": focus_same,
            "video_frames": [len(fa), len(fb)], "video_max_pixel_diff": px, "report_identical": ra == rb,
            "report_keys_differing": sorted(k for k in set(ra) | set(rb) if ra.get(k) != rb.get(k))}


def stage_table(r: dict) -> list[str]:
    """One row per stage: wall seconds, CPU seconds of all processes, and the processes that
    spent the most CPU in it."""
    rows = [f"{'stage':>16} {'wall s':>7} {'CPU s':>7}  CPU by process"]
    for key, name in STAGES:
        if key not in r["timings"]:
            continue
        cpu = r["stage_cpu_s"].get(key, {})
        top = ", ".join(f"{p} {c:.1f}" for p, c in sorted(cpu.items(), key=lambda x: -x[1]) if c >= 0.05)
        rows.append(f"{name:>16} {r['timings'][key]:7.1f} {sum(cpu.values()):7.1f}  {top}")
    return rows


def waits_line(r: dict) -> str:
    """What each simulation step waits on, in ms per step (the take's steps, from the nodes' Health)."""
    n = r.get("sim_steps") or 0
    if not n:
        return "no simulation steps counted"
    br = ", ".join(f"{k[:-2]} {v / n * 1e3:.1f}" for k, v in r["bridge_waits_s"].items())
    pl = ", ".join(f"{k[:-2]} {v / n * 1e3:.1f}" for k, v in r["planner_waits_s"].items())
    return f"per step ({n} steps), ms: bridge {br}; planner {pl}"


def stage_line(r: dict, clip_s: float) -> str:
    """The whole command's wall time, its ratio to the clip and its stages (the rest: starting the
    command, saving the take, stopping the nodes)."""
    t = r["timings"]
    parts = [f"{name} {t[k]:.1f}" for k, name in STAGES if k in t]
    rest = r["wall_s"] - sum(t.get(k, 0.0) for k, _ in STAGES)
    return (f"{r['wall_s']:6.1f} s in all = {r['wall_s'] / clip_s:4.2f} x the clip ({clip_s:.1f} s): "
            f"{' + '.join(parts)} + rest {rest:.1f} s (style: {r['style_origin']}; output measured "
            f"{r['output_measured']})")


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
        cache = Path(tmp) / "cache"  # empty: the first run extracts the style as a new user's does
        first = run(source, args.scene, Path(tmp) / "first", args.max_frames, cache)
        busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
        try:
            again = run(source, args.scene, Path(tmp) / "again", args.max_frames, cache)
        finally:
            for p in busy:
                p.kill()
        same = compare(Path(tmp) / "first", Path(tmp) / "again")
    for name, r in (("first (empty cache)", first), (f"again, {args.busy} busy process(es)", again)):
        fl = r["timings"].get("flight_s", float("nan"))
        print(f"{name:>30}: {stage_line(r, clip_s)} [load average {r['load_before']:.1f} before it]")
        for row in stage_table(r):
            print(f"{'':>30}  {row}")
        print(f"{'':>30}  {waits_line(r)}")
        print(f"{'':>30}  flight {fl / clip_s:.2f} x the clip, {r['flight_wall_per_sim_s']} wall s per simulated s; "
              f"render p50 {r['render_ms_p50']} ms, step p50 {r['step_wall_ms_p50']} ms, solve p50/p95 "
              f"{r['solve_ms_p50']}/{r['solve_ms_p95']} ms, over real-time budget {r['over_budget_solves']}/"
              f"{r['solves']}; frames {r['recorded']}/{r['instruction_frames']}, repeats {r['repeated']}")
    identical = same["joint_max_diff"] == 0.0 and same["focus_labels_identical"] and \
        same["truth_frames"][0] == same["truth_frames"][1] and same["video_max_pixel_diff"] == 0 and \
        same["report_identical"]
    print(f"agreement: truth joints max diff {same['joint_max_diff']:.2e}, focus labels identical "
          f"{same['focus_labels_identical']}, video max pixel diff {same['video_max_pixel_diff']:.0f}, report "
          f"figures identical {same['report_identical']} {same['report_keys_differing'] or ''}")
    ratio = first["wall_s"] / clip_s
    ok = ratio <= 3.0 and identical and first["repeated"] == 0 and again["repeated"] == 0
    print(f"verdict: the whole command {ratio:.2f} x the clip (goal <= 3; again with the cached style "
          f"{again['wall_s'] / clip_s:.2f} x under load), identical results {identical} -> "
          f"{'goal met' if ok else 'goal NOT met'}; machine load average {os.getloadavg()[0]:.1f}")
    res = {"source": source.name, "scene": args.scene, "max_frames": args.max_frames,
           "clip_s": clip_s, "first": first, "again": again, "busy_processes": args.busy, "agreement": same,
           "goal_met": ok, "ratio_total": ratio, "ratio_again": again["wall_s"] / clip_s}
    print(f"wrote {write_result('transfer', res)}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
