"""Recording benchmark: how big is run.mcap per second of flight, what does recording
cost, and does the report's video play in a browser.

    python benchmarks/recording.py [--source CLIP] [--scene open_country] [--max-frames 240] [--run DIR]

Runs the README's `cinetransfer transfer` (or reads an existing run folder with `--run`), then:
- run.mcap: size, seconds of flight it covers (camera frame stamps, simulation time), MB per second
  of flight (goal <= 2 at 960x540, 24 fps), bytes per channel, time to read it all back;
- the recorder's per-message cost (shared.runlog.views: JSON, JPEG, transforms): warm-up, then a
  fixed number of samples of recorded frames and vehicle states; median, p95, max;
- output.mp4 and report_video.mp4: codec, faststart, frames, size;
- the report in headless Chromium, offline: the side-by-side video's readyState and duration.
Prints a summary and writes benchmarks/results/recording.json (commit, machine, load, config).
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


from cinetransfer.data import data_dir

try:
    from harness import stats, write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import stats, write_result

HERE = Path(__file__).resolve().parent
WARMUP, SAMPLES = 5, 60


def per_channel_bytes(path: Path) -> dict[str, int]:
    from mcap.reader import make_reader

    out: dict[str, int] = collections.Counter()
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages():
            out[ch.topic] += len(msg.data)
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def views_cost(path: Path) -> dict:
    """Milliseconds per message of shared.runlog.views on recorded camera frames and vehicle states."""
    from cinetransfer import runlog

    picked: dict[str, list[tuple[str, bytes]]] = {"frame": [], "vehicle_state": []}
    for _, key, payload in runlog.read_run(path):
        kind = "frame" if key.endswith("/camera/frame") else "vehicle_state" if key.endswith("/vehicle/state") else None
        if kind and len(picked[kind]) < WARMUP + SAMPLES:
            picked[kind].append((key, payload))
        if all(len(v) >= WARMUP + SAMPLES for v in picked.values()):
            break
    out = {}
    for name, kind, video in (("frame_h264_record", "frame", True), ("frame_jpeg_live", "frame", False),
                              ("vehicle_state", "vehicle_state", True)):
        streams: dict = {}
        times = []
        for i, (key, payload) in enumerate(picked[kind]):
            t = time.perf_counter()
            runlog.views(key, payload, video=streams if video else None)
            if i >= WARMUP:
                times.append((time.perf_counter() - t) * 1e3)
        out[name + "_ms"] = stats(times, digits=3) if times else None
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--source", default=None, help="source clip (default: the README's juggling clip)")
    p.add_argument("--scene", default="open_country")
    p.add_argument("--max-frames", type=int, default=240, help="instruction frames (240 = 10 s at 24 fps)")
    p.add_argument("--run", help="measure this existing run folder instead of running a transfer")
    p.add_argument("--out", default=str(HERE / "results" / "recording.json"))
    p.add_argument("--keep", help="run the transfer into this folder (kept) instead of a temporary one")
    args = p.parse_args()
    load_before = os.getloadavg()
    tmp = None
    if args.run:
        run, transfer_s = Path(args.run), None
    else:
        if args.keep:
            run = Path(args.keep)
        else:
            tmp = tempfile.TemporaryDirectory(prefix="ct-bench-rec-")
            run = Path(tmp.name) / "run"
        src = Path(args.source) if args.source else data_dir() / "sam2_juggle_1280x720.mp4"
        cmd = [sys.executable, "-m", "cinetransfer", "transfer", str(src), "--scene", args.scene, "-o", str(run),
               "--rig", "benchrec", *(["--max-frames", str(args.max_frames)] if args.max_frames else [])]
        t = time.monotonic()
        r = subprocess.run(cmd, capture_output=True, text=True)
        transfer_s = round(time.monotonic() - t, 1)
        if r.returncode != 0:
            sys.exit(f"transfer failed (exit {r.returncode}):\n{r.stderr[-3000:]}")
    from cinetransfer.report.browser_check import BrowserError, check, verdict
    from cinetransfer.runlog import RunReader, size_report
    from cinetransfer.shared.video import probe

    t = time.monotonic()
    reader = RunReader(run / "run.mcap")
    n_back = sum(1 for _ in reader.messages())
    read_s = time.monotonic() - t
    size = size_report(reader.info)
    if transfer_s is None and (run / "bench_transfer_s.txt").is_file():
        transfer_s = float((run / "bench_transfer_s.txt").read_text())
    elif transfer_s is not None:
        (run / "bench_transfer_s.txt").write_text(str(transfer_s))
    result = {
        "load_avg_before": [round(x, 2) for x in load_before],
        "config": {"scene": args.scene, "max_frames": args.max_frames, "run": str(args.run or "fresh transfer")},
        "transfer_wall_s": transfer_s,
        "meta": {k: v for k, v in json.loads((run / "meta.json").read_text()).items()
                 if k in ("recorded_frames", "instruction_frames", "preroll_frames", "fps", "logged_messages",
                          "clock_mode", "timings")},
        "mcap": {**size, "goal_mb_per_flight_s": 2.0, "goal_met": bool(size["mb_per_flight_s"] and
                                                                      size["mb_per_flight_s"] <= 2.0),
                 "read_back_s": round(read_s, 2), "messages_read_back": n_back,
                 "bytes_by_channel": per_channel_bytes(run / "run.mcap")},
        "recorder_cost": views_cost(run / "run.mcap"),
        "output_mp4": {**probe(run / "output.mp4"), "bytes": (run / "output.mp4").stat().st_size},
    }
    if (run / "report_video.mp4").is_file():
        result["report_video"] = {**probe(run / "report_video.mp4"), "bytes": (run / "report_video.mp4").stat().st_size}
    try:
        t = time.monotonic()
        br = check(run / "report.html")
        result["chromium"] = {"video": br["video"], "problems": verdict(br), "s": round(time.monotonic() - t, 2),
                              "report_html_bytes": (run / "report.html").stat().st_size}
    except BrowserError as e:
        result["chromium"] = {"error": str(e)}
    print(f"wrote {write_result(args.out, result)}")
    m = result["mcap"]
    print(f"run.mcap: {m['bytes'] / 1e6:.2f} MB for {m['flight_s']:.2f} s of flight ({m['camera_frames']} camera "
          f"frames) = {m['mb_per_flight_s']:.3f} MB/s "
          f"(goal <= 2: {'met' if m['goal_met'] else 'MISSED'}); {m['messages']} MCAP messages, read back in "
          f"{m['read_back_s']} s")
    top = list(m["bytes_by_channel"].items())[:4]
    print("largest channels: " + ", ".join(f"{k} {v / 1e6:.2f} MB" for k, v in top))
    rc = result["recorder_cost"]
    print(f"per message (ms): frame into the recording (H.264) {rc['frame_h264_record_ms']}, frame for the live "
          f"view (JPEG) {rc['frame_jpeg_live_ms']}, vehicle state {rc['vehicle_state_ms']}")
    o = result["output_mp4"]
    print(f"output.mp4: {o['codec']} {o['width']}x{o['height']} {o['frames']} frames, faststart {o['faststart']}, "
          f"{o['bytes'] / 1e6:.2f} MB")
    print(f"chromium: {result['chromium']}")
    print(f"load average before/after: {result['machine']['loadavg_before']} / {result['machine']['loadavg_after']}")
    print(f"wrote {args.out}")
    if tmp is not None:
        tmp.cleanup()
    return 0 if m["goal_met"] and not result["chromium"].get("problems") and "error" not in result["chromium"] else 1


if __name__ == "__main__":
    sys.exit(main())
