"""Where a finished transfer's CPU goes, part by part, measured again in this process on its run folder.

    python benchmarks/transfer_cpu.py RUN_DIR [--frames 96] [--views 24]

`cinetransfer transfer` books the CPU seconds of each process per stage (meta.json `stage_cpu_s`);
this splits the largest of them by what they do, each part timed with this thread's or this
process's CPU clock (a loaded machine inflates the wall, much less the CPU):
- the output's measuring (the transfer process, during the flight and after it): the detector with
  `cinetransfer extract`'s settings on output.mp4's first `--frames` frames, and the camera motion's
  share of it (`CameraMotionTracker.update`, on the tail's thread);
- the recorder's H.264 encode of those frames (output.mp4's settings: one encode for output.mp4
  and run.mcap);
- the bridge's renderer on `--views` of the take's flown views (run.mcap's vehicle states): a
  frame with its picture, and a frame drawn for its truth alone (pre-roll, settle), whose depths
  and surface ids must be the picture's to the bit;
- the report (`build_report` into a scratch folder, its figures drawn in this process), by part.
Writes benchmarks/results/transfer_cpu.json.
"""
from __future__ import annotations

import argparse
import collections
import json
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

try:
    from harness import write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import write_result


def timed(acc: collections.Counter, label: str, fn: Callable, clock: Callable[[], float] = time.thread_time):
    """`fn` that adds its CPU seconds (by `clock`) to acc[label]."""
    def wrapper(*a: Any, **k: Any) -> Any:
        t = clock()
        try:
            return fn(*a, **k)
        finally:
            acc[label] += clock() - t
    return wrapper


def video_frames(path: Path, n: int) -> list[np.ndarray]:
    import cv2

    cap = cv2.VideoCapture(str(path))
    out = []
    while len(out) < n:
        ok, img = cap.read()
        if not ok:
            break
        out.append(img)
    cap.release()
    return out


def output_measuring(frames: list[np.ndarray], fps: float) -> dict[str, float]:
    """ms CPU a frame of the output's measuring (live_output.py's detector and stream), and its camera motion."""
    from cinetransfer.services.detector import camera_motion as CMD
    from cinetransfer.services.detector.config import DetectorConfig
    from cinetransfer.services.detector.core import Detector, FrameStream

    acc: collections.Counter = collections.Counter()
    update = CMD.CameraMotionTracker.update
    CMD.CameraMotionTracker.update = timed(acc, "camera_motion", update)
    try:
        det = Detector(DetectorConfig())
        t = time.process_time()
        with FrameStream(det) as stream:
            for i, img in enumerate(frames):
                stream.push(np.ascontiguousarray(img), i, int(round(i * 1e9 / fps)), source="output.mp4", fps=fps)
            stream.flush()
        cpu = time.process_time() - t
        det.close()
    finally:
        CMD.CameraMotionTracker.update = update
    n = max(len(frames), 1)
    return {"frames": len(frames), "ms_per_frame": round(1e3 * cpu / n, 1),
            "camera_motion_ms_per_frame": round(1e3 * acc["camera_motion"] / n, 1),
            "camera_motion_share": round(acc["camera_motion"] / cpu, 3) if cpu else None}


def recorder_encode(frames: list[np.ndarray], fps: float, scratch: Path) -> dict[str, float]:
    from cinetransfer.runlog import KEYFRAME_S, VIDEO_X264_PARAMS
    from cinetransfer.shared.video import H264Writer

    t = time.process_time()
    with H264Writer(scratch / "encode.mp4", fps, stream_keyframe_s=KEYFRAME_S, x264_params=VIDEO_X264_PARAMS) as w:
        for img in frames:
            w.write(img)
    return {"ms_per_frame": round(1e3 * (time.process_time() - t) / max(len(frames), 1), 1)}


def flown_views(run: Path, meta: dict, renderer: Any, n: int) -> list[tuple[Any, float]]:
    """(view, simulation time) of n vehicle states of the take, evenly spread."""
    from cinetransfer.report.build import read_vehicle_states
    from cinetransfer.runlog import RunReader
    from cinetransfer.services.autopilot_bridge.sim.renderer import View

    epoch = int(meta["epoch_ns"])
    states = [s for s in read_vehicle_states(RunReader(run / "run.mcap")) if s.stamp_ns >= epoch]
    picked = [states[int(i)] for i in np.linspace(0, len(states) - 1, min(n, len(states)))]
    return [(View(np.asarray(s.position_m, float), np.asarray(s.camera_ypr_rad, float), s.lens.focal_length_mm,
                  s.lens.focus_distance_m, s.lens.f_number, renderer.width, renderer.height, renderer.sensor),
             (s.stamp_ns - epoch) * 1e-9) for s in picked]


def renderer_frames(run: Path, meta: dict, n: int) -> dict[str, Any]:
    """ms CPU (process: llvmpipe's threads included) of a pictured frame and of a truth-only one."""
    from cinetransfer.services.autopilot_bridge.sim.renderer3d import WorldRenderer
    from cinetransfer.services.autopilot_bridge.sim.scene import load_scene

    sc = load_scene(meta["scene"], subject=meta.get("subject"))
    if sc.world != "3d":
        return {"skipped": f"scene {meta['scene']} is not a 3-D world"}
    r = WorldRenderer(sc)
    views = flown_views(run, meta, r, n)
    r.render(*views[0])  # the context, programs and textures: not a frame's cost
    cpu = {"picture": 0.0, "truth_only": 0.0}
    same = True
    for view, t_s in views:
        c = time.process_time()
        _, geo = r.render(view, t_s)
        cpu["picture"] += time.process_time() - c
        c = time.process_time()
        alone = r.truth_only(view, t_s)
        cpu["truth_only"] += time.process_time() - c
        same &= all(np.array_equal(v, alone[k], equal_nan=v.dtype.kind == "f")
                    for k, v in geo.items() if isinstance(v, np.ndarray))
    r.close()
    return {"views": len(views), **{f"{k}_ms": round(1e3 * v / len(views), 1) for k, v in cpu.items()},
            "truth_only_identical": bool(same)}


#: the report's parts timed (module, function)
REPORT_PARTS = (("video", "side_by_side"), ("figures", "draw_figure"), ("build", "floor_facts"),
                ("fidelity", "compute_fidelity"), ("people", "make_people"), ("build", "read_vehicle_states"),
                ("camera_motion", "fig_camera_motion"), ("build", "load_style_any"), ("build", "write_html"))


def report_parts(run: Path, meta: dict, scratch: Path) -> dict[str, float]:
    """CPU seconds of build_report on the run (figures drawn here), in all and by part."""
    import importlib

    import cvxpy  # noqa: F401 - imported during the flight by the transfer: not the report's cost
    import matplotlib.backends.backend_agg  # noqa: F401

    from cinetransfer.report import build as B
    from cinetransfer.report.truthfile import read_truths

    acc: collections.Counter = collections.Counter()
    saved = []
    for mod_name, fn in REPORT_PARTS:
        mod = importlib.import_module(f"cinetransfer.report.{mod_name}")
        saved.append((mod, fn, getattr(mod, fn)))
        setattr(mod, fn, timed(acc, fn, getattr(mod, fn), time.process_time))
    truths = read_truths(run / "truth.msgpack")
    try:
        t = time.process_time()
        B.build_report(scratch / "report", source_style=run / "style.json", output_style=run / "output_style.json",
                       truths=truths, source_video=meta["source"], output_video=run / "output.mp4", meta=meta,
                       recording=run / "run.mcap")
        total = time.process_time() - t
    finally:
        for mod, fn, orig in saved:
            setattr(mod, fn, orig)
    return {"cpu_s": round(total, 2), **{k: round(v, 2) for k, v in acc.most_common()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a transfer's output folder")
    ap.add_argument("--frames", type=int, default=96, help="output frames measured and encoded (default 96)")
    ap.add_argument("--views", type=int, default=24, help="flown views rendered (default 24)")
    args = ap.parse_args()
    meta = json.loads((args.run / "meta.json").read_text())
    fps = float(meta.get("output_fps") or meta.get("fps") or 24.0)
    frames = video_frames(args.run / "output.mp4", args.frames)
    with tempfile.TemporaryDirectory() as tmp:
        res = {"run": str(args.run), "stage_cpu_s": meta.get("stage_cpu_s"),
               "output_measuring": output_measuring(frames, fps),
               "recorder_encode": recorder_encode(frames, fps, Path(tmp)),
               "renderer": renderer_frames(args.run, meta, args.views),
               "report": report_parts(args.run, meta, Path(tmp))}
    print(json.dumps({k: v for k, v in res.items() if k != "stage_cpu_s"}, indent=1))
    print(f"wrote {write_result('transfer_cpu', res)}")


if __name__ == "__main__":
    main()
