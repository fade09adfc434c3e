"""build_report: numbers (report.json), figures (fig_*.png), the side-by-side video
(report_video.mp4, H.264) and the page (report.html) of one run."""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from concurrent.futures import BrokenExecutor, Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from cinetransfer.report import fidelity as F
from cinetransfer.report.workers import FIGURE_WAIT_S
from cinetransfer.report import figures as figs
from cinetransfer.report import focus_misses as FM
from cinetransfer.report import focus_reach as FR
from cinetransfer.report import reach_frames as RF
from cinetransfer.report.html import write_html
from cinetransfer.report.style import StyleLike, StyleLoadError, load_style_any
from cinetransfer.shared.instructions import shot_segments, slice_instructions
from cinetransfer.shared import messages as M
from cinetransfer.shared.vehicle import load_vehicle

log = logging.getLogger("cinetransfer.report")

REPORT_FORMAT = "cinetransfer-report"
REPORT_VERSION = 1
VIDEO = "report_video.mp4"


def _recording(run: Any) -> dict[str, Any]:
    """Size and content of a run.mcap (a shared.runlog.RunReader)."""
    from cinetransfer.runlog import size_report

    topics = {t: c["schema"] or c["encoding"] for t, c in sorted(run.info.channels.items())}
    return {"path": str(run.path), **size_report(run.info), "topics": topics}


def jsonable(v: Any) -> Any:
    """numpy and paths -> JSON values; NaN/inf -> None (report.json is strict JSON)."""
    if isinstance(v, dict):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return jsonable(v.tolist())
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(float(v)) else None
    if v is None or isinstance(v, str):
        return v
    if isinstance(v, os.PathLike):
        return os.fspath(v)
    return str(v)


def _round_list(a: np.ndarray, digits: int = 5) -> list[float | None]:
    return [None if not math.isfinite(float(x)) else round(float(x), digits) for x in np.asarray(a, float)]


#: camera roll [deg] from which the report says the horizon was tilted (the style does not
#: measure the source camera's roll, so a rolled output departs from it: docs/planner.md)
ROLL_NOTE_DEG = 1.0


def camera_roll_deg(states: Sequence[M.VehicleState], frame_stamps_ns: Sequence[int]) -> dict[str, float] | None:
    """|camera roll| [deg] at the recorded frames (each frame: the last vehicle state stamped at
    or before it): median, 95th percentile and maximum; None when no frame has a state."""
    st = sorted((int(s.stamp_ns), float(s.camera_ypr_rad[2])) for s in states)
    stamps = np.array([t for t, _ in st], dtype=np.int64)
    rolls = np.array([r for _, r in st])
    idx = np.searchsorted(stamps, np.asarray(frame_stamps_ns, dtype=np.int64), side="right") - 1
    r = np.degrees(np.abs(rolls[idx[idx >= 0]])) if stamps.size else np.zeros(0)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return None
    p50, p95 = np.percentile(r, [50, 95])
    return {"p50": round(float(p50), 2), "p95": round(float(p95), 2), "max": round(float(r.max()), 2)}


def read_vehicle_states(run: Any) -> list[M.VehicleState]:
    """Every vehicle state of a run.mcap (by topic: the camera frames are not decoded)."""
    from cinetransfer.shared import codec

    return [codec.decode(p, M.VehicleState) for topic in run.info.channels if topic.endswith("/vehicle/state")
            for _, _, p in run.messages(topic)]


def camera_motion_facts(outdir: Path, source: M.Instructions, output: M.Instructions | None,
                        states: Sequence[M.VehicleState], truths: Sequence[M.GroundTruth],
                        segments: Sequence[tuple[int, int]], figure_worker: Any = None
                        ) -> tuple[dict[str, Any], Callable[[], dict[str, Path]]]:
    """report.json's camera_motion, and its figure as it is drawn (in `figure_worker` when given):
    call the second for {file name: path}. A failed figure is reported in the summary, never fatal."""
    from cinetransfer.report import camera_motion as CM

    summary, series = CM.camera_motion_summary(source, output, states, truths, segments)
    path = outdir / CM.FIGURE
    job = figure_worker.submit(CM.fig_camera_motion, path, series) if series and figure_worker is not None else None

    def drawn() -> dict[str, Path]:
        if not series:
            return {}
        try:
            if job is not None:
                try:
                    return {CM.FIGURE: job.result(timeout=FIGURE_WAIT_S)}
                except (BrokenExecutor, TimeoutError) as e:  # the figure process died or hangs: drawn here
                    log.warning("figure %s: the figure process failed (%s); drawn here instead", CM.FIGURE, e)
            return {CM.FIGURE: CM.fig_camera_motion(path, series)}
        except Exception as e:  # noqa: BLE001 - a plotting bug must not lose the numbers
            log.exception("figure %s failed", CM.FIGURE)
            summary["figure_error"] = f"{type(e).__name__}: {e}"[:300]
            return {}

    return summary, drawn


def recording_facts(meta: dict[str, Any], roll: dict[str, float] | None = None) -> dict[str, Any]:
    """How the output was recorded, including whatever makes its numbers look better than a
    user's case would (repeated frames, a short take, a rolled camera): stated, never hidden."""
    k = meta.get("instruction_frames")
    rep = int(meta.get("repeated_frames") or 0)
    facts = {"clock": meta.get("clock_mode", "unknown"), "instruction_frames": k,
             "recorded_frames": meta.get("recorded_frames"), "repeated_frames": rep,
             "repeated_share": round(rep / k, 4) if k else None, "missing_frames": meta.get("missing_frames", 0)}
    notes = []
    if rep:
        notes.append(f"{rep} of {k} output frames ({rep / k:.1%}) repeat the previous frame (real-time "
                     "recording: the simulator could not render them in time); the scores include them, "
                     "shaded on the time plots")
    if k and (meta.get("recorded_frames") or 0) < k:
        notes.append(f"the take is short: {meta.get('recorded_frames')} of {k} instruction frames recorded")
    facts["camera_roll_deg"] = roll
    if roll and roll["max"] >= ROLL_NOTE_DEG:
        notes.append(f"the camera rolled to match the joints (|roll| median {roll['p50']:.1f} deg, 95th percentile "
                     f"{roll['p95']:.1f}, max {roll['max']:.1f}): the source's horizon is not measured, so a "
                     "tilted horizon is not part of its style; the joint errors include what the roll bought")
    facts["notes"] = notes
    return facts


def floor_facts(source: M.Instructions, truths: Sequence[M.GroundTruth], meta: dict[str, Any],
                fid: Any, ahead: Any = None) -> tuple[dict[str, Any], Any]:
    """The truth joint error's floor (floor.py) for report.json, and the Floor (None if not computed).
    `ahead`: a Future of `floor.run_floor` on the same source, truths and meta with the frames
    aligned by index, started before the output's style was known (used when they are)."""
    from cinetransfer.report import floor as FL

    by_index = (fid.summary.get("alignment") or {}).get("mode") == "index"
    if ahead is not None and by_index:
        fl, why = ahead.result()
    else:
        fl, why = FL.run_floor(source, list(truths), meta, aligned_by_index=by_index)
    if fl is None:
        return {"joint_error": None, "reason": why}, None
    return {"joint_error": fl.mean(), "joint_frames": int(fl.counts.sum()), "model": fl.model}, fl


def per_shot(source: M.Instructions, output: M.Instructions | None, truths: list, output_fps: float | None,
             takes: list[dict] | None = None, floor: Any = None, reach_memo: RF.Memo | None = None,
             lens_rates: FR.LensRates | None = None) -> list[dict[str, Any]]:
    """Goals per shot of a multi-shot source (output frame k follows instruction row k), with the
    take's settle figures when the recording was made one take per shot, and each shot's share of
    the truth joint error's floor (`floor`: floor.Floor on the instruction rows, or None).
    `reach_memo`: the whole run's focus-reach verdicts (a shot's frames are not judged again)."""
    # the takes as flown (very short shots are filmed on in the take before), else the source's shots
    segs = [(int(t["first_row"]), int(t["end_row"])) for t in takes] if takes else shot_segments(source)
    if len(segs) < 2:
        return []
    by_row = {t.get("first_row"): t for t in (takes or [])}
    out = []
    for i, (a, b) in enumerate(segs):
        src = slice_instructions(source, a, b, final=True)
        outp = None
        if output is not None and output.image_targets.shape[0] >= b:
            outp = dataclasses.replace(slice_instructions(output, a, b, final=True), first_frame=0)
        tr = [dataclasses.replace(t, frame_index=int(t.frame_index) - a) for t in truths if a <= int(t.frame_index) < b]
        fid = F.compute_fidelity(dataclasses.replace(src, first_frame=0), outp, tr, output_fps=output_fps,
                                 output_frames=b - a, reach_memo=reach_memo, lens_rates=lens_rates)
        h = fid.summary["headline"]
        take = by_row.get(a, {})
        out.append({"shot": i, "rows": [a, b], "goals_met": h["goals_met"], "goals": h["goals"],
                    "joint_error_extraction": h["extraction"].get("joint_error_mean"),
                    "joint_error_truth": h["truth"].get("joint_error_mean"),
                    "focus_unreachable_frames": fid.summary["focus_reach"]["unreachable_frames"],
                    "joint_error_floor_truth": floor.mean(slice(a, b)) if floor is not None else None,
                    "settle_limit_s": take.get("settle_limit_s"), "settle_s": take.get("settle_s"),
                    "settled": take.get("settled"), "error_at_take_start": take.get("error_at_take_start")})
    return out


def _drawn(*drawings: Any) -> tuple[dict[str, Any], dict[str, str]]:
    """The figures of the drawings, and their errors, in the page's order."""
    figures: dict[str, Any] = {}
    errors: dict[str, str] = {}
    for d in drawings:
        done, failed = d.result()
        figures.update(done)
        errors.update(failed)
    order = [n for n, _ in figs.FIGURES]
    return figures, {n: errors[n] for n in sorted(errors, key=order.index)}


def _judge_by_faults(summary: dict[str, Any], faults: dict[str, Any] | None) -> None:
    """The headline states what happened in the takes (holds, planner restarts, over-budget solves,
    watchdog holds); in a degraded take no goal is reported as met (cinetransfer/take_faults.py)."""
    if not faults:
        return
    head = summary["headline"]
    head["take"] = {k: faults.get(k) for k in ("degraded", "reasons", "hold_s", "planner_restarts",
                                               "over_budget_solves", "watchdog_holds", "max_hold_share")}
    head["take"]["per_take"] = faults.get("takes", [])
    if not faults.get("degraded"):
        return
    for g in summary.get("goals", []):
        if g["status"] == "met":
            g["status"] = "void (degraded take)"
    head["goals"] = {g["id"]: g["status"] for g in summary.get("goals", [])}
    judged = sum(g["status"] != "n/a" for g in summary.get("goals", []))
    head["goals_met"] = f"0/{judged} (degraded take)"
    for shot, tf in zip(summary.get("shots", []), faults.get("takes", [])):
        shot["faults"] = tf
        if tf.get("degraded"):
            shot["goals_met"] = f"0/{shot['goals_met'].split('/')[-1]} (degraded)"


def _state_detectors(summary: dict[str, Any], meta: dict[str, Any]) -> None:
    """report.json's "detectors" (report/detectors.py); the headline names what it states."""
    from cinetransfer.report.detectors import detector_facts

    summary["detectors"] = facts = detector_facts(meta)
    if facts["notes"]:
        summary["headline"]["detectors"] = facts["notes"]


def lens_rates(meta: dict[str, Any]) -> FR.LensRates | None:
    """The lens rates of the run's vehicle profile (meta's "vehicle", else the default one), or None
    when it cannot be read (the misses the rates force are then not excused)."""
    try:
        lens = load_vehicle(meta.get("vehicle") or None).lens
    except (OSError, ValueError) as e:
        log.warning("lens rates not known (%s): no frame is excused by them", e)
        return None
    return FR.LensRates(lens.focus_rate_mps, lens.f_number_rate_ps)


def _video_beside(path: Path, series: dict[str, Any], **kwargs: Any) -> Future:
    """video.side_by_side(path, series, **kwargs) on a thread of its own: a Future of (its summary,
    '') or (None, why it was not made); never raises (the numbers are still worth a report)."""
    def make() -> tuple[dict[str, Any] | None, str]:
        try:
            from cinetransfer.report.video import side_by_side

            return side_by_side(path, series, **kwargs), ""
        except Exception as e:  # noqa: BLE001 - the numbers are still worth a report
            log.warning("side-by-side video not made: %s: %s", type(e).__name__, e)
            return None, f"{type(e).__name__}: {e}"

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="report-video")
    try:
        return pool.submit(make)
    finally:
        pool.shutdown(wait=False)


def build_report(outdir: Path, *, source_style: StyleLike, output_style: StyleLike | None,
                 truths: Sequence[M.GroundTruth], source_video: Path | str | None,
                 output_video: Path | str | None, meta: dict[str, Any] | None = None,
                 embed_images: bool = True, recording: Path | str | None = None,
                 figure_worker: Any = None, floor_ahead: Any = None,
                 vehicle_states: Sequence[M.VehicleState] | None = None) -> dict[str, Any]:
    """Compare a recorded run with its source style; write outdir/report.html, report.json and
    fig_*.png. Returns the summary (the content of report.json; its "headline" is a short digest).

    source_style / output_style: a style.json path or an `Instructions` message. output_style
    None (or unreadable) means the extraction on the output failed: the report says so and
    the ground-truth half is still computed. figure_worker: a report.workers.FigureWorker that draws
    the figures beside the rest (None: drawn in this process; the same files either way); floor_ahead:
    the truth floor computed ahead (`floor_facts`); vehicle_states: the recording's vehicle states
    when the caller read them already (None: read from `recording`). truths: the simulator's GroundTruth, one per
    recorded frame (may be empty). recording: the run's run.mcap, summarised in the report (size
    per second of flight, channels). Raises ValueError when the source style cannot be loaded or
    the recording is not a readable cinetransfer MCAP (shared.runlog.RunFormatError).
    """
    t0 = time.monotonic()
    from cinetransfer.runlog import RunReader

    run = RunReader(recording) if recording else None  # RunFormatError (a ValueError) if unreadable
    rec_info = _recording(run) if run else None
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    meta = dict(meta or {})
    source, _ = load_style_any(source_style)

    output: M.Instructions | None = None
    reason = ""
    if output_style is None:
        reason = "no output style: extraction on the output video failed or was not run"
    else:
        try:
            output, _ = load_style_any(output_style)
        except (StyleLoadError, OSError) as e:
            reason = f"output style could not be read: {e}"
            log.warning("%s", reason)

    vinfo = figs.video_info(output_video)
    output_fps = meta.get("output_fps")
    if not (isinstance(output_fps, (int, float)) and output_fps > 0):
        output_fps = vinfo.get("fps") if vinfo.get("fps", 0) > 0 else None
    output_frames = vinfo.get("frames") if vinfo.get("frames", 0) > 0 else None

    rates = lens_rates(meta)
    # the side-by-side video needs the tracks only, not the goals: it is made on a thread from here,
    # beside the focus reach and the rest of the numbers (OpenCV and x264 release the GIL), keeping
    # the frames the frames figure and the people picture show (a seek would decode again)
    aligned = F.align(source, output, truths, output_fps=output_fps, output_frames=output_frames)
    _, src_idx, out_idx = figs.frame_picks(aligned.series())
    from cinetransfer.report.people import make_people, middle_frame_index

    mid = middle_frame_index(source_video) if meta.get("subject") and source_video else None
    keep: tuple[dict, dict] = ({i: None for i in [*src_idx, *([mid] if mid is not None else [])]},
                               {i: None for i in out_idx})
    video_job = _video_beside(outdir / VIDEO, aligned.series(), source_video=source_video, output_video=output_video,
                              fps=float(output_fps or source.fps or 24.0), keep=keep)
    reach_memo: RF.Memo = {}  # each frame's focus reach judged once: the shots compare the same frames
    fid = F.compute_fidelity(source, output, truths, output_fps=output_fps, output_frames=output_frames,
                             output_missing_reason=reason, reach_memo=reach_memo, lens_rates=rates, aligned=aligned)
    credit = str(meta.get("credit") or figs.credit_for(source_video))
    shot_rows = ([int(t["first_row"]) for t in meta["takes"]] if meta.get("takes") else
                 [a for a, _ in shot_segments(source)])[1:]
    # the time plots are drawn (in `figure_worker` when given) while the side-by-side video decodes
    # both videos once, keeping the frames the frames figure shows
    s = fid.series
    fig_series = figs.figure_series(s, meta.get("repeated_slots") or (), shot_rows)
    plots = figs.Drawing(outdir, fig_series, [n for n, _ in figs.FIGURES if n != figs.FRAMES_FIGURE],
                         pool=figure_worker)
    floor_summary, floor = floor_facts(source, truths, meta, fid, floor_ahead)
    # camera motion before the video: its figure is drawn beside the video, not after it
    segs = ([(int(t["first_row"]), int(t["end_row"])) for t in meta["takes"]] if meta.get("takes")
            else shot_segments(source))
    states = (list(vehicle_states) if vehicle_states is not None else read_vehicle_states(run)) \
        if run and truths else []
    motion, motion_fig = camera_motion_facts(outdir, source, output, states, truths, segs, figure_worker)

    video, video_error = video_job.result()
    decoded = tuple({i: im for i, im in d.items() if im is not None and i in picks}
                    for d, picks in zip(keep, (set(src_idx), set(out_idx)))) if video else None
    middle = keep[0].get(mid) if video and mid is not None else None  # RGB, as the figures keep them
    frames = figs.Drawing(outdir, fig_series, [figs.FRAMES_FIGURE], pool=figure_worker, source_video=source_video,
                          output_video=output_video, credit=credit, decoded=decoded)

    try:
        people = make_people(outdir, meta, source_video,
                             middle=None if middle is None else cv2.cvtColor(middle, cv2.COLOR_RGB2BGR))
    except (OSError, ValueError, KeyError, cv2.error) as e:  # the report never fails on this picture
        people = {"error": str(e)}
    shots = per_shot(source, output, list(truths), output_fps, meta.get("takes"), floor, reach_memo, rates)
    figures, fig_errors = _drawn(plots, frames)
    figures.update(motion_fig())
    summary: dict[str, Any] = {
        "people": people,
        "format": REPORT_FORMAT, "version": REPORT_VERSION,
        "generated": time.strftime("%Y-%m-%d %H:%M:%S"),
        **fid.summary,
        "inputs": {"source_style": source_style if isinstance(source_style, (str, os.PathLike)) else "<Instructions>",
                   "output_style": (output_style if isinstance(output_style, (str, os.PathLike))
                                    else None if output_style is None else "<Instructions>"),
                   "source_video": source_video, "output_video": output_video,
                   "output_video_info": vinfo, "source": {"path": source.source.path, "fps": source.fps,
                                                          "frames": int(source.image_targets.shape[0])}},
        "credit": credit,
        "recording": recording_facts(meta, camera_roll_deg(states, [t.stamp_ns for t in truths]) if states else None),
        "truth_floor": floor_summary,
        "shots": shots,
        "camera_motion": motion,
        "figures": sorted(figures),
        "figure_errors": fig_errors,
        "video": video, "video_error": video_error,
        "recording_file": rec_info,
        "per_frame": {"t_s": _round_list(s["t_s"], 4), "source_row": [int(x) for x in s["k"]],
                      "focus_unreachable": {r: [x or None for x in s["reach"].reasons[:, i]]
                                            for i, r in enumerate(F.REGIONS)},
                      "focus_miss_kind": {side: {r: [x or None for x in m.kind[:, i]] for i, r in enumerate(F.REGIONS)}
                                          for side, m in s["misses"].items()},
                      "focus_miss_why": {side: {r: [x or None for x in m.why[:, i]] for i, r in enumerate(F.REGIONS)}
                                         for side, m in s["misses"].items()},
                      "joint_error_extraction": _round_list(s["error_extraction"]),
                      "joint_error_truth": _round_list(s["error_truth"])},
        "meta": meta,
    }
    summary["focus_reach"]["runs"] = RF.runs(s["reach"], s["t_s"], s["k"], shot_rows)
    summary["focus_misses"]["runs"] = [row for side, m in s["misses"].items() for row in FM.runs(m, s["t_s"], side)]
    _state_detectors(summary, meta)
    _judge_by_faults(summary, meta.get("faults"))
    summary = jsonable(summary)
    write_html(outdir / "report.html", summary, figures, meta=summary["meta"], figure_errors=fig_errors,
               credit=credit, embed=embed_images, video=(outdir / VIDEO) if video else None,
               video_error=video_error)
    summary["report_s"] = round(time.monotonic() - t0, 3)
    tmp = outdir / "report.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    tmp.replace(outdir / "report.json")
    log.info("report written to %s (%s goals met, %.1f s)", outdir / "report.html",
             summary["headline"]["goals_met"], summary["report_s"])
    return summary
