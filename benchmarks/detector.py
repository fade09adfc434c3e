"""Detector throughput: frames/s of the full detector at 640x360 and 1280x720, and on TUD, on this machine.

Frames: the sam2_juggle clip (one person, full body), resized to each resolution, and the
TUD-Stadtmitte clip (640x480, about 5 people per frame), held in memory (decoding is excluded
here; in `cinetransfer detect` it runs in its own thread, ~3 ms per 720p frame). For each
resolution it times, over a fixed number of frames after a warm-up:
- the stages alone: pose (the default box_first backend; and the mediapipe backend), focus (edge
  stage + propagation), HOG fallback;
- the full detector sequentially (threads=1) and with both cores (threads=2), with the SSD on
  every frame (`bf_ssd_every=1`, as before it skipped frames), without and with the HOG fallback
  (juggle) / with the mediapipe backend (TUD).
Prints median / p95 / max latency per frame, throughput (frames/s) and CPU use (process CPU
time / wall time: 2.0 = both cores busy) and CPU time per frame (independent of other load:
on an idle 2-core machine frames/s can reach at most 2000 / CPU-ms).
          goal (detector speed): >= 30 frames/s at 1280x720 (one person), >= 10 frames/s on TUD

    python benchmarks/detector.py [--frames 100] [--warmup 10]
    python benchmarks/detector.py --quick --set bf_threads=2          # a setting tried, 1280x720 only
    python benchmarks/detector.py --stages [--set ...]                 # thread CPU per stage, streamed

`--stages` times each stage in the thread that runs it (`time.thread_time` around the stage's
function), so its ms a frame hold on a loaded machine too; the stages overlap in three threads
(caller: the tracking crop; pose worker: the SSD and the second look; tail: the focus edges and the
shot signature, then the mask refinement, the propagation, the camera motion).

Each streamed row also prints `where` a frame's CPU went: each thread's CPU, user / system time,
context switches, minor page faults and the time the host stole (docs/detector.md: why a frame's
CPU differs from run to run).

Writes benchmarks/results/detector.json.
"""
from __future__ import annotations

import argparse
import ast
import collections
import functools
import os
import resource
import threading
import time

import cv2
import numpy as np

from eval_detector_common import data_dir, stats, write_result
from cinetransfer.services.detector import box_first, camera_motion, shots, subject_mask
from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.services.detector.core import Detector
from cinetransfer.services.detector.focus import FocusEstimator
from cinetransfer.services.detector.hog_people import HogPeople
from cinetransfer.shared.frame_sources import SourceFrame, iter_frames

RESOLUTIONS = ((640, 360), (1280, 720))
STREAMED = "full, 2 threads, streamed (a file)"


def _time(fn, frames, warmup: int) -> dict:
    for i in range(warmup):
        fn(frames[i % len(frames)], i)
    lat = []
    c0, m0, t0 = time.process_time(), time.thread_time(), time.perf_counter()
    for i, f in enumerate(frames):
        t = time.perf_counter()
        fn(f, warmup + i)
        lat.append(time.perf_counter() - t)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    main = time.thread_time() - m0
    lat_ms = 1e3 * np.asarray(lat)
    # On 2 idle cores a frame takes at least the caller thread's CPU time and at least half the
    # process's: a load-independent estimate of the quiet-machine rate (upper bound, perfect overlap).
    idle_ms = 1e3 * max(main, cpu / 2) / len(frames)
    return {"fps": len(frames) / wall, "latency_ms": stats(lat_ms), "cpu_cores_used": cpu / wall,
            "cpu_ms_per_frame": 1e3 * cpu / len(frames),
            "caller_thread_cpu_ms_per_frame": 1e3 * main / len(frames), "idle_estimate_fps": 1e3 / idle_ms}


def _thread_cpu_ns() -> dict[int, int]:
    """CPU time of each of this process's threads now [ns] (the scheduler's own count, by thread id)."""
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/schedstat") as f:
                out[int(tid)] = int(f.read().split()[0])
        except (OSError, ValueError):  # the thread ended meanwhile
            continue
    return out


def _where(before: tuple, after: tuple, names: dict[int, str], n: int) -> dict:
    """Where the streamed frames' CPU went, a frame: each thread (by its name's prefix: MainThread,
    focus, box_first, tail; threads that Python did not start, i.e. native pools, as `native`),
    user / system time, context switches, minor page faults, and the time the hypervisor stole from
    the machine's CPUs meanwhile (both CPUs, whoever ran). Explains a frame's CPU that the stages' own
    times do not: a pool spinning, the kernel, faults, a busy host."""
    (cpu0, ru0, st0), (cpu1, ru1, st1) = before, after
    threads: dict[str, float] = collections.defaultdict(float)
    for tid, ns in cpu1.items():
        name = names.get(tid, "native").rsplit("_", 1)[0]
        threads[name] += (ns - cpu0.get(tid, 0)) / 1e6 / n
    return {"thread_cpu_ms_per_frame": dict(threads), "user_ms_per_frame": 1e3 * (ru1.ru_utime - ru0.ru_utime) / n,
            "system_ms_per_frame": 1e3 * (ru1.ru_stime - ru0.ru_stime) / n,
            "voluntary_switches_per_frame": (ru1.ru_nvcsw - ru0.ru_nvcsw) / n,
            "involuntary_switches_per_frame": (ru1.ru_nivcsw - ru0.ru_nivcsw) / n,
            "minor_faults_per_frame": (ru1.ru_minflt - ru0.ru_minflt) / n,
            "stolen_ms_per_frame": 1e3 * (st1 - st0) / n}


def _stolen_s() -> float:
    """CPU time the hypervisor took from this virtual machine's CPUs so far [s] (/proc/stat, all CPUs)."""
    try:
        with open("/proc/stat") as f:
            return int(f.readline().split()[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


def _snapshot() -> tuple:
    return _thread_cpu_ns(), resource.getrusage(resource.RUSAGE_SELF), _stolen_s()


def _time_stream(det: Detector, frames, warmup: int, period_ns: int, on_measure=lambda: None) -> dict:
    """`_time` for `Detector.process_frames` (the path of `process_source` and `cinetransfer detect`):
    frame k's tail overlaps frame k + 1's pose, so a frame's latency is not defined here; the latency
    columns give the time between consecutive measurements handed out. `where`: see `_where` (taken
    at the last measurement, before the stream's tail thread ends)."""
    def seq(first: int, n: int):
        return (SourceFrame(first + i, (first + i) * period_ns, frames[(first + i) % len(frames)], 24.0, "bench")
                for i in range(n))

    for _ in det.process_frames(seq(0, warmup)):
        pass
    on_measure()  # the warm-up is over (its tails too)
    lat, names = [], {}
    before = _snapshot()
    c0, m0, t0 = time.process_time(), time.thread_time(), time.perf_counter()
    t = t0
    for _ in det.process_frames(seq(warmup, len(frames))):
        now = time.perf_counter()
        lat.append(now - t)
        t = now
        names.update((th.native_id, th.name) for th in threading.enumerate())
        if len(lat) == len(frames):
            wall, cpu, main = now - t0, time.process_time() - c0, time.thread_time() - m0
            after = _snapshot()
    idle_ms = 1e3 * max(main, cpu / 2) / len(frames)
    return {"fps": len(frames) / wall, "latency_ms": stats(1e3 * np.asarray(lat)), "cpu_cores_used": cpu / wall,
            "cpu_ms_per_frame": 1e3 * cpu / len(frames),
            "caller_thread_cpu_ms_per_frame": 1e3 * main / len(frames), "idle_estimate_fps": 1e3 / idle_ms,
            "where": _where(before, after, names, len(frames))}


def _line(name: str, r: dict) -> str:
    lat = r["latency_ms"]
    return (f"  {name:<34} {r['fps']:6.1f} frames/s   median {lat['median']:6.1f} ms   p95 {lat['p95']:6.1f} ms   "
            f"max {lat['max']:6.1f} ms   cores {r['cpu_cores_used']:.2f}   CPU {r['cpu_ms_per_frame']:5.1f} ms/frame "
            f"(caller {r['caller_thread_cpu_ms_per_frame']:5.1f})   idle est. {r['idle_estimate_fps']:5.1f} frames/s")


def _where_line(w: dict) -> str:
    threads = ", ".join(f"{k} {v:.1f}" for k, v in sorted(w["thread_cpu_ms_per_frame"].items(), key=lambda kv: -kv[1]))
    return (f"    where (ms CPU a frame): {threads}; user {w['user_ms_per_frame']:.1f}, system "
            f"{w['system_ms_per_frame']:.1f}; a frame: {w['voluntary_switches_per_frame']:.0f} voluntary / "
            f"{w['involuntary_switches_per_frame']:.0f} involuntary switches, "
            f"{w['minor_faults_per_frame']:.0f} minor faults; stolen by the host {w['stolen_ms_per_frame']:.1f}")


def _print_rows(res: dict) -> None:
    for k, r in res.items():
        print(_line(k, r))
        if "where" in r:
            print(_where_line(r["where"]))


#: (owner, function, stage name) timed by `--stages`
STAGES = ((box_first.BoxFirstPose, "landmarks", "landmark crops"), (box_first.BoxFirstPose, "boxes", "SSD"),
          (box_first.BoxFirstPose, "_candidate", "candidates"), (FocusEstimator, "measure_edges", "focus edges"),
          (FocusEstimator, "propagate", "focus propagation"), (subject_mask, "refine_people", "mask refinement"),
          (camera_motion.CameraMotionTracker, "update", "camera motion"), (shots, "colour_signature", "shot signature"))


def _stages(frames: list, warmup: int, cfg: DetectorConfig) -> dict:
    """Thread CPU per stage a frame and calls a frame, streamed (each stage timed in its own thread)."""
    cpu: dict = collections.defaultdict(float)
    calls: dict = collections.defaultdict(int)
    saved = [(owner, name, getattr(owner, name)) for owner, name, _ in STAGES]

    def timed(fn, label):
        @functools.wraps(fn)
        def run(*a, **k):
            t0 = time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                cpu[label] += time.thread_time() - t0
                calls[label] += 1
        return run

    try:
        for (owner, name, label), (_, _, fn) in zip(STAGES, saved):
            setattr(owner, name, timed(fn, label))
        with Detector(cfg) as det:
            whole = _time_stream(det, frames, warmup, 41_666_667, on_measure=lambda: (cpu.clear(), calls.clear()))
    finally:
        for owner, name, fn in saved:
            setattr(owner, name, fn)
    n = len(frames)
    out = {label: {"cpu_ms_per_frame": 1e3 * cpu[label] / n, "calls_per_frame": calls[label] / n}
           for _, _, label in STAGES}
    for label, r in sorted(out.items(), key=lambda kv: -kv[1]["cpu_ms_per_frame"]):
        print(f"  {label:<20} {r['cpu_ms_per_frame']:6.1f} ms CPU a frame   {r['calls_per_frame']:.2f} calls a frame")
    print(f"  {'process':<20} {whole['cpu_ms_per_frame']:6.1f} ms CPU a frame   (caller thread "
          f"{whole['caller_thread_cpu_ms_per_frame']:.1f})")
    print(_where_line(whole["where"]))
    return out


def _resolution(frames: list, warmup: int, quick: bool, base: DetectorConfig) -> dict:
    """Every row at one resolution (`quick`: the detector only, per frame and streamed)."""
    res: dict = {}
    if not quick:
        for be in ("box_first", "mediapipe"):
            with Detector(base.replace(backend=be, focus=False, threads=1)) as det:
                res[f"pose only ({det.name})"] = _time(lambda f, i: det.backend.detect(f, i * 41_666_667), frames,
                                                       warmup)
        est = FocusEstimator(base)
        res["focus only"] = _time(lambda f, i: est.estimate(f), frames, warmup)
        hog = HogPeople(base)
        res["HOG fallback only"] = _time(lambda f, i: hog.detect(f), frames, warmup)
    with Detector(base) as det:
        res[STREAMED] = _time_stream(det, frames, warmup, 41_666_667)
    label = "full, 2 threads (default)" if base == DetectorConfig() else "full, 2 threads (--set)"
    rows = ((label, base),) if quick else (
        ("full, 1 thread", base.replace(threads=1)), ("full, 2 threads (default)", base.replace(threads=2)),
        ("full, 2 threads, SSD every frame", base.replace(threads=2, bf_ssd_every=1)),
        ("full + HOG fallback, 2 threads", base.replace(threads=2, person_fallback="hog")))
    for name, cfg in rows:
        with Detector(cfg) as det:
            res[name] = _time(lambda f, i: det.process(f, i, i * 41_666_667), frames, warmup)
    _print_rows(res)
    return res


def _tud(frames: list, warmup: int) -> dict:
    res = {}
    with Detector(DetectorConfig(focus=False, threads=1)) as det:
        res["pose only (box_first)"] = _time(lambda f, i: det.backend.detect(f, i * 40_000_000), frames, warmup)
    with Detector(DetectorConfig()) as det:
        res[STREAMED] = _time_stream(det, frames, warmup, 40_000_000)
    for name, cfg in (("full, 2 threads (default)", DetectorConfig()),
                      ("full, 2 threads, mediapipe backend", DetectorConfig(backend="mediapipe"))):
        with Detector(cfg) as det:
            res[name] = _time(lambda f, i: det.process(f, i, i * 40_000_000), frames, warmup)
    _print_rows(res)
    return res


def _verdict(label: str, r: dict, goal: float) -> None:
    print(f"goal: >= {goal:.0f} frames/s on {label}, streamed -> {r['fps']:.1f} frames/s measured "
          f"({'met' if r['fps'] >= goal else 'NOT met'}); CPU cost {r['cpu_ms_per_frame']:.1f} ms/frame, caller "
          f"thread {r['caller_thread_cpu_ms_per_frame']:.1f} -> about {r['idle_estimate_fps']:.1f} frames/s on 2 idle "
          f"cores ({'met' if r['idle_estimate_fps'] >= goal else 'NOT met'} there)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--quick", action="store_true",
                    help="1280x720 only, the detector per frame and streamed; writes no result file")
    ap.add_argument("--stages", action="store_true",
                    help="1280x720 streamed: thread CPU per stage a frame; writes no result file")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="DetectorConfig overrides for the 1280x720 rows (--quick or --stages only)")
    a = ap.parse_args()
    if a.set and not (a.quick or a.stages):
        ap.error("--set needs --quick or --stages (the result file holds the default settings)")
    base = DetectorConfig(**{kv.split("=", 1)[0]: ast.literal_eval(kv.split("=", 1)[1]) for kv in a.set})
    src = [f.image for f in iter_frames(data_dir() / "sam2_juggle_1280x720.mp4", stop=a.frames)]
    load = os.getloadavg()[0]
    print(f"load average before: {load:.2f} on {os.cpu_count()} CPUs "
          f"({'quiet' if load < 0.5 else 'UNDER LOAD: numbers are pessimistic'})")
    if a.stages:
        print(f"1280x720, {len(src)} frames, streamed, thread CPU per stage:")
        _stages([cv2.resize(img, (1280, 720), interpolation=cv2.INTER_AREA) for img in src], a.warmup, base)
        print(f"load average after: {os.getloadavg()[0]:.2f}")
        return
    results: dict = {}
    for w, h in RESOLUTIONS[-1:] if a.quick else RESOLUTIONS:
        frames = [cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA) for img in src]
        print(f"{w}x{h}, {len(frames)} frames:")
        results[f"{w}x{h}"] = _resolution(frames, a.warmup, a.quick, base)
    if not a.quick:
        tud = [f.image for f in iter_frames(data_dir() / "tud_stadtmitte_640x480.mp4", stop=a.frames)]
        print(f"TUD-Stadtmitte 640x480, {len(tud)} frames:")
        results["tud_640x480"] = _tud(tud, a.warmup)
    _verdict("1280x720 (one person)", results["1280x720"][STREAMED], 30.0)
    if not a.quick:
        _verdict("TUD (about 5 people)", results["tud_640x480"][STREAMED], 10.0)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    if not a.quick:
        results["load_avg_before"] = load
        print(f"wrote {write_result('detector', results)}")


if __name__ == "__main__":
    main()
