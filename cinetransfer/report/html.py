"""The report as one self-contained HTML file (inline CSS, figures embedded as base64 PNG).

It opens offline in any browser, and still works when copied alone; the PNGs beside it are
linked too ("full size") for when the folder travels together.
"""
from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from typing import Any

from cinetransfer.report import fidelity as F

CSS = """
* { box-sizing: border-box; }
body { font-family: -apple-system, "Segoe UI", Roboto, "DejaVu Sans", Arial, sans-serif; margin: 0;
       background: #f4f5f7; color: #1d2430; font-size: 14px; line-height: 1.45; }
main { max-width: 1240px; margin: 0 auto; padding: 20px 24px 40px; }
h1 { font-size: 22px; margin: 4px 0 2px; }
h2 { font-size: 17px; margin: 28px 0 8px; border-bottom: 1px solid #d5d9e0; padding-bottom: 4px; }
.sub { color: #5a6475; margin: 0 0 14px; }
.card { background: #fff; border: 1px solid #dde1e7; border-radius: 6px; padding: 12px 14px; margin: 10px 0;
        overflow-x: auto; }
.warn { background: #fff6e0; border-color: #f0c36d; }
table { border-collapse: collapse; width: 100%; font-size: 13px; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid #e1e4ea; padding: 4px 8px; text-align: right; white-space: nowrap; }
th { background: #eef1f5; font-weight: 600; }
td.l, th.l { text-align: left; }
td.met { background: #d9f2dd; color: #135a1e; font-weight: 600; }
td.missed { background: #fadcdc; color: #8a1616; font-weight: 600; }
td.na { background: #eeeeee; color: #666; }
tr.group td { background: #e4e9f1; font-weight: 600; color: #2a3a55; }
tr.total td { font-weight: 600; }
.badge { display: inline-block; padding: 2px 10px; border-radius: 12px; font-weight: 600; margin-right: 8px; }
.badge.met { background: #d9f2dd; color: #135a1e; }
.badge.missed { background: #fadcdc; color: #8a1616; }
.badge.na { background: #eeeeee; color: #555; }
figure { margin: 0; }
figure img { width: 100%; height: auto; display: block; border: 1px solid #e1e4ea; background: #fff; }
figcaption { color: #5a6475; font-size: 12.5px; margin-top: 6px; }
.credit { font-size: 12px; color: #444; margin-top: 4px; font-style: italic; }
pre { margin: 0; font-size: 12px; white-space: pre-wrap; word-break: break-word; text-align: left; }
.meta td { text-align: left; white-space: normal; vertical-align: top; }
.meta td:first-child { white-space: nowrap; font-weight: 600; width: 1%; }
.small { font-size: 12px; color: #5a6475; }
summary { cursor: pointer; color: #2a3a55; }
"""

CAPTIONS = {
    "fig_frames.png": "Source frames (top) and recorded output frames (bottom) at evenly spaced times. "
                      "Rings: the source's joint targets (also drawn on the output, where they should land); "
                      "dots: the joints the extraction found on the output; white crosses: the simulator's "
                      "exact joints.",
    "fig_joints.png": "Normalised image position of each controlled joint over time; source light, output "
                      "(extraction on the recorded video) dark, ground truth dashed.",
    "fig_focus.png": "Per region, the fraction of focused pixels (b raw, B smoothed) over time, and the "
                     "in-focus booleans of the source, the output extraction and the truth as strips.",
    "fig_error.png": "Mean error of the controlled joints per frame, with the goal lines, and per region "
                     "where the focus label agrees with the source.",
}


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _num(x: Any, digits: int = 4) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, float):
        return f"{x:.{digits}f}"
    return _e(x)


def _pct(x: Any) -> str:
    return "–" if x is None else f"{100.0 * float(x):.1f} %"


def _ms(s: dict[str, Any] | None) -> str:
    if not s or s.get("mean") is None:
        return "–"
    return f"{s['mean']:.4f} ± {s['std']:.4f}"


def _status_cls(status: str) -> str:
    return {"met": "met", "missed": "missed"}.get(status, "na")


def _goal_index(summary: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {g["id"]: g for g in summary.get("goals", [])}


def _goals_table(summary: dict[str, Any]) -> str:
    rows = []
    for g in summary.get("goals", []):
        v = g["value"]
        val = _pct(v) if "focus" in g["id"] else _num(v)
        thr = _pct(g["threshold"]) if "focus" in g["id"] else _num(g["threshold"], 3)
        op = {"<=": "≤", ">=": "≥"}.get(g["op"], g["op"])
        rows.append(f"<tr><td class='l'>{_e(g['label'])}</td><td>{val}</td><td>{_e(op)} {thr}</td>"
                    f"<td class='{_status_cls(g['status'])}'>{_e(g['status'])}</td></tr>")
    return ("<table><tr><th class='l'>goal</th><th>reached</th><th>target</th><th>status</th></tr>"
            + "".join(rows) + "</table>")


_MEASURES = (("extraction", "by extraction on the output video"), ("truth", "by the simulator's ground truth"))


def _shots_table(summary: dict[str, Any]) -> str:
    """Goals per shot, and each take's settle phase (limit, time taken, framing error at its start)."""
    shots = summary.get("shots") or []
    if not shots:
        return ""
    rows = []
    for s in shots:
        settle = ("—" if s.get("settle_limit_s") is None else
                  f"{_num(s['settle_s'], 2)} s of {_num(s['settle_limit_s'], 2)} s" if s.get("settled") else
                  "no subject in its first frame" if s.get("settled") is None else
                  f"not within {_num(s['settle_limit_s'], 2)} s")
        rows.append(f"<tr><td>{s['shot'] + 1}</td><td>{s['rows'][0]}–{s['rows'][1] - 1}</td>"
                    f"<td>{_e(s['goals_met'])}</td><td>{_num(s.get('joint_error_extraction'))}</td>"
                    f"<td>{_num(s.get('joint_error_truth'))}</td><td>{_num(s.get('joint_error_floor_truth'))}</td>"
                    f"<td>{_e(settle)}</td>"
                    f"<td>{_num(s.get('error_at_take_start'))}</td></tr>")
    return ("<h2>Shots</h2><div class='card'><table><tr><th>shot</th><th>instruction frames</th><th>goals met</th>"
            "<th>joint error (extr.)</th><th>joint error (truth)</th><th>floor (truth)</th><th>settle</th>"
            "<th>framing error at take start"
            "</th></tr>" + "".join(rows) + "</table><p class='small'>Each shot of the source is flown as its own "
            "take after a settle phase in which the drone re-frames the shot's first frame; the edit joins the "
            "takes at the source's cuts (dashed lines on the plots).</p></div>")


def _group_row(label: str, ncols: int) -> str:
    return f"<tr class='group'><td class='l' colspan='{ncols}'>{_e(label)}</td></tr>"


def _by_measure(summary: dict[str, Any], part: str, header: str, rows_of) -> str:
    """A table of one part of the fidelity summary ('joints', 'focus'): a group per measure
    (extraction, truth), each with its rows (`rows_of(measure, data)`) or 'not available'."""
    rows = [header]
    for measure, heading in _MEASURES:
        rows.append(_group_row(heading, 6))
        data = (summary.get(measure) or {}).get(part)
        if not data:
            rows.append("<tr><td class='l'></td><td colspan='5' class='na'>not available</td></tr>")
            continue
        rows += rows_of(measure, data)
    return "<table>" + "".join(rows) + "</table>"


def _image_side_note(summary: dict[str, Any]) -> str:
    """Says so when left/right were compared by image side (a subject seen from behind)."""
    parts = []
    for measure, heading in _MEASURES:
        js = (summary.get(measure) or {}).get("joints") or {}
        n = js.get("frames_by_image_side", 0)
        if n:
            by_name = ((js.get("overall") or {}).get("euclidean_by_name") or {}).get("mean")
            parts.append(f"{heading[0].upper() + heading[1:]}: in {n} of {js.get('frames_compared', 0)} frames; "
                         f"with left and right matched by name the mean joint error is {_num(by_name)}")
    if not parts:
        return ""
    return ("<div class='warn'>Left and right compared <b>by image side</b>: the filmed person faces the other way "
            "from the source's (one seen from the front, the other from behind), so the style's left-shoulder "
            "target is met by the shoulder on the same side of the image (docs/planner.md, \"Back views\"). "
            + _e(". ".join(parts)) + ".</div>")


def _joint_counts_note(summary: dict[str, Any]) -> str:
    """Which joint-frames the error leaves out, with counts (fidelity.joint_frame_counts)."""
    parts = []
    for measure, heading in _MEASURES:
        js = (summary.get(measure) or {}).get("joints") or {}
        if "joint_frames_compared" in js:
            head = heading[0].upper() + heading[1:]
            parts.append(f"{head}: {js['joint_frames_compared']} joint-frames compared; left out "
                         f"{js['joint_frames_without_target']} where the source has no target (the joint out of "
                         f"the source's frame, or unseen longer than the smoother bridges) and "
                         f"{js['joint_frames_target_unseen']} where the output does not show a joint the source "
                         "controls")
    return "<p class='small'>" + _e(". ".join(parts)) + ".</p>" if parts else ""


def _floor_note(summary: dict[str, Any]) -> str:
    """The truth joint error next to its floor (floor.py): how much of it the flight could have saved."""
    fl = summary.get("truth_floor") or {}
    if fl.get("joint_error") is None:
        return (f"<p class='small'>Floor of the truth joint error: not computed ({_e(fl['reason'])}).</p>"
                if fl.get("reason") else "")
    flown = ((summary.get("truth") or {}).get("joints") or {}).get("overall", {}).get("euclidean", {}).get("mean")
    return (f"<p class='small'><b>Floor of the truth joint error: {_num(fl['joint_error'])}</b> (flown: "
            f"{_num(flown)}) — {_e(fl['model'])}, over the same {fl['joint_frames']} joint-frames. No "
            "flight of this subject without roll gets below it; what is above it is the flight's.</p>")


def _joint_table(summary: dict[str, Any]) -> str:
    names = summary.get("joint_names", [])
    goals = _goal_index(summary)

    def rows_of(measure: str, js: dict) -> list[str]:
        rows = []
        for label, key in [(n, n) for n in names] + [("all controlled joints", None)]:
            st = js["overall"] if key is None else js["per_joint"].get(key, {})
            eu = st.get("euclidean") or {}
            cls, style = "", ""
            if key is None:
                cls = f" class='{_status_cls(goals.get(f'{measure}_joint_error', {}).get('status', 'n/a'))}'"
                style = " class='total'"
            rows.append(f"<tr{style}><td class='l'>{_e(label)}</td>"
                        f"<td>{_ms(st.get('x'))}</td><td>{_ms(st.get('y'))}</td>"
                        f"<td{cls}>{_ms(eu)}</td><td>{_num(eu.get('max'))}</td><td>{eu.get('n', 0)}</td></tr>")
        return rows

    return _by_measure(summary, "joints", "<tr><th class='l'>joint</th><th>|dx| mean ± std</th><th>|dy| mean ± std</th>"
                       "<th>euclidean mean ± std</th><th>max</th><th>joint-frames</th></tr>", rows_of)


def _frames_present(fo: dict) -> str:
    """Frames compared, and the frames left out because the region exists on one side only."""
    n = fo.get("n_frames", 0)
    src_only = fo.get("present_reference", n) - n
    out_only = fo.get("present_compared", n) - n
    return f"{n} <span class='small'>(left out: {src_only} source only, {out_only} output only)</span>"


def _focus_table(summary: dict[str, Any]) -> str:
    goals = _goal_index(summary)

    def rows_of(measure: str, focus: dict) -> list[str]:
        rows = []
        for region in F.REGIONS:
            fo = focus.get(region) or {}
            st = goals.get(f"{measure}_focus_{region}", {}).get("status", "n/a")
            fe = (fo.get("fraction_error") or {}).get("mean")
            rows.append(f"<tr><td class='l'>{_e(region)}</td><td>{_pct(fo.get('agreement'))}</td>"
                        f"<td class='{_status_cls(st)}'>{_pct(fo.get('agreement_reachable'))}</td>"
                        f"<td>{_frames_present(fo)}</td><td>{fo.get('n_frames_unreachable', 0)}</td>"
                        f"<td>{fo.get('in_focus_reference', 0)} / {fo.get('in_focus_compared', 0)}</td>"
                        f"<td>{_pct(fo.get('presence_agreement'))}</td><td>{_num(fe)}</td></tr>")
        return rows

    return _by_measure(summary, "focus", "<tr><th class='l'>region</th><th>label agreement, all frames</th>"
                       "<th>label agreement, reachable frames (judged)</th>"
                       "<th>frames (present on both sides)</th><th>of which out of the lens's reach</th>"
                       "<th>frames in focus: source / output</th>"
                       "<th>presence agreement</th><th>|b| error mean</th></tr>", rows_of)


def _run_reason(r: dict[str, Any]) -> str:
    """A run's reason at its first frame, and at its last when that differs."""
    return r["reason"] + (f" … {r['reason_last']}" if r.get("reason_last") else "")


def _unreachable_table(summary: dict[str, Any]) -> str:
    """The frames where no focus distance and f-number of the lens gives the source's label, and why."""
    reach = summary.get("focus_reach") or {}
    runs = reach.get("runs") or []
    if not reach.get("frames_judged"):
        return ("<p class='small'>Out of the lens's reach: not judged (no simulator truth with region depths "
                "and lens range; every frame counts).</p>")
    if not runs:
        return (f"<p class='small'>Out of the lens's reach: none of the {reach['frames_judged']} frames judged; "
                "every asked label was within the lens's range.</p>")
    rows = []
    for r in runs:
        why = _run_reason(r)
        rows.append(f"<tr><td class='l'>{_e(r['region'])}</td><td>{r['shot'] + 1}</td>"
                    f"<td>{r['first_frame']}–{r['last_frame']}</td><td>{r['frames']}</td>"
                    f"<td class='l'>{_e(why)}</td></tr>")
    return ("<h3>Frames out of the lens's reach</h3><table><tr><th class='l'>region</th><th>shot</th>"
            "<th>output frames</th><th>frames</th><th class='l'>why no lens setting gives the source's label</th></tr>"
            + "".join(rows) + "</table>")


_KIND_WORDS = {"out_of_reach": "out of the lens's reach", "controller": "missed by the flight (within reach)",
               "extraction": "read otherwise by the extraction (the truth has the source's label)",
               "absent": "no such region on this side", "unjudged": "the truth has no label of its own there",
               "no_data": "no data for the frame"}


def _misses_table(summary: dict[str, Any], per_frame: dict[str, Any]) -> str:
    """Every frame whose label is not the source's, per side and region: how many of each kind, the runs
    of one kind, and (folded) each frame with its reason."""
    misses = summary.get("focus_misses") or {}
    sides = [s for s in ("truth", "extraction") if s in misses]
    if not sides:
        return ""
    head = ("<h3>Why a label is not the source's, per frame</h3><table><tr><th class='l'>side</th>"
            "<th class='l'>region</th>" + "".join(f"<th>{_e(_KIND_WORDS[k])}</th>" for k in _KIND_WORDS) + "</tr>")
    rows = [f"<tr><td class='l'>{side}</td><td class='l'>{_e(reg)}</td>"
            + "".join(f"<td>{misses[side].get(reg, {}).get(k, 0)}</td>" for k in _KIND_WORDS) + "</tr>"
            for side in sides for reg in F.REGIONS]
    runs = misses.get("runs") or []
    run_rows = [f"<tr><td class='l'>{_e(r['side'])}</td><td class='l'>{_e(r['region'])}</td>"
                f"<td class='l'>{_e(_KIND_WORDS.get(r['kind'], r['kind']))}</td>"
                f"<td>{r['first_frame']}–{r['last_frame']}</td><td>{r['frames']}</td>"
                f"<td class='l'>{_e(_run_reason(r))}</td></tr>"
                for r in runs]
    runs_html = ("<table><tr><th class='l'>side</th><th class='l'>region</th><th class='l'>why</th>"
                 "<th>output frames</th><th>frames</th><th class='l'>reason (first … last frame)</th></tr>"
                 + "".join(run_rows) + "</table>") if run_rows else "<p class='small'>Every label is the source's.</p>"
    kinds, whys = per_frame.get("focus_miss_kind") or {}, per_frame.get("focus_miss_why") or {}
    frame_rows = [f"<tr><td>{i}</td><td class='l'>{side}</td><td class='l'>{_e(reg)}</td><td class='l'>{_e(k)}</td>"
                  f"<td class='l'>{_e(whys[side][reg][i] or '')}</td></tr>"
                  for side in sides for reg in F.REGIONS
                  for i, k in enumerate((kinds.get(side) or {}).get(reg) or []) if k]
    frames_html = (f"<details><summary>each of the {len(frame_rows)} frame-regions with its reason</summary>"
                   "<table><tr><th>output frame</th><th class='l'>side</th><th class='l'>region</th>"
                   "<th class='l'>kind</th><th class='l'>reason</th></tr>" + "".join(frame_rows) + "</table></details>"
                   ) if frame_rows else ""
    return head + "".join(rows) + "</table>" + runs_html + frames_html


def _kv_table(d: dict[str, Any]) -> str:
    rows = []
    for k, v in d.items():
        if isinstance(v, (dict, list)):
            text = json.dumps(v, indent=1, default=str)
            val = f"<pre>{_e(text)}</pre>"
            if text.count("\n") > 12:  # long: folded, one click away
                what = f"{len(v)} {'entries' if isinstance(v, dict) else 'items'}"
                val = f"<details><summary>{what}</summary>{val}</details>"
        elif isinstance(v, float):
            val = _num(v, 3)
        else:
            val = _e(v)
        rows.append(f"<tr><td>{_e(k)}</td><td>{val}</td></tr>")
    return "<table class='meta'>" + "".join(rows) + "</table>"


def _img(path: Path, embed: bool) -> str:
    if embed:
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        return f"<img alt='{_e(path.name)}' src='data:image/png;base64,{data}'>"
    return f"<img alt='{_e(path.name)}' src='{_e(path.name)}'>"


def _people_card(p: dict[str, Any], embed: bool) -> str:
    """Source person and target person, named, side by side."""
    if not p.get("target_person"):
        return ""
    fig = ""
    if p.get("figure") and Path(p["figure"]).is_file():
        fig = ("<figure>" + _img(Path(p["figure"]), embed) + "<figcaption>left: the source clip (middle frame); "
               "right: the target subject (a cut-out of its own footage)</figcaption></figure>")
    return (f"<h2>People</h2><div class='card'><table class='meta'>"
            f"<tr><td>source (style from)</td><td>{_e(p.get('source_person'))}</td></tr>"
            f"<tr><td>target (filmed)</td><td>{_e(p.get('target_person'))} [subject '{_e(p.get('subject'))}']"
            f"</td></tr></table>{fig}</div>")
VIDEO_EMBED_MAX_BYTES = 24 << 20  #: a larger side-by-side video is linked, not embedded


def _video(path: Path | None, info: dict[str, Any] | None, error: str, embed: bool) -> str:
    """The side-by-side video: embedded (data URI) when small enough, else linked beside the page."""
    if path is None or not Path(path).is_file():
        return f"<div class='warn'>video not made: {_e(error or 'unknown error')}</div>"
    size = Path(path).stat().st_size
    if embed and size <= VIDEO_EMBED_MAX_BYTES:
        src = "data:video/mp4;base64," + base64.b64encode(Path(path).read_bytes()).decode()
    else:
        src = _e(Path(path).name)
    info = info or {}
    return (f"<figure><video id='side-by-side' controls autoplay muted loop playsinline preload='auto' "
            f"data-duration='{_e(info.get('duration_s'))}' data-frames='{_e(info.get('frames'))}' "
            f"style='max-width:100%' src='{src}'></video>"
            f"<figcaption>Source (left) and recorded output (right), frame by frame "
            f"({_e(info.get('frames'))} frames at {_e(info.get('fps'))} fps). Rings: the source's targets for the "
            f"controlled joints; dots: extraction on the output; crosses: simulator truth; the labels name the "
            f"regions in focus. <a href='{_e(Path(path).name)}'>download</a></figcaption></figure>")


def _recording_card(rec: dict[str, Any] | None) -> str:
    if not rec:
        return ""
    rows = {"file": Path(str(rec.get("path", ""))).name, "size [MB]": round(rec.get("bytes", 0) / 1e6, 3),
            "flight covered [s]": rec.get("flight_s"), "MB per second of flight": rec.get("mb_per_flight_s"),
            "messages": rec.get("messages"), "channels": rec.get("channels"),
            "complete": "yes" if rec.get("complete") else "no: the run was interrupted (no summary)"}
    topics = "".join(f"<tr><td><code>{_e(t)}</code></td><td>{_e(s)}</td></tr>"
                     for t, s in rec.get("topics", {}).items())
    return (f"<h2>Recording</h2><div class='card'>{_kv_table(rows)}<details><summary>channels</summary>"
            f"<table><tr><th>topic</th><th>schema</th></tr>{topics}</table></details>"
            f"<p class='small'>Open it in Foxglove or Rerun (docs/recording.md).</p></div>")


def _camera_motion(summary: dict[str, Any], figures: dict[str, Path], embed: bool) -> str:
    from cinetransfer.report.camera_motion import FIGURE, camera_motion_card

    fig = figures.get(FIGURE)
    body = f"<figure>{_img(Path(fig), embed)}</figure>" if fig and Path(fig).is_file() else ""
    return camera_motion_card(summary.get("camera_motion"), body)


def render_html(summary: dict[str, Any], figures: dict[str, Path], *, meta: dict[str, Any],
                figure_errors: dict[str, str] | None = None, credit: str = "", embed: bool = True,
                video: Path | None = None, video_error: str = "") -> str:
    """The whole report page as a string."""
    from cinetransfer.report.figures import FIGURES

    figure_errors = figure_errors or {}
    goals = summary.get("goals", [])
    n_met = sum(g["status"] == "met" for g in goals)
    n_missed = sum(g["status"] == "missed" for g in goals)
    n_na = sum(g["status"] == "n/a" for g in goals)
    title = "Style fidelity report"
    sub = " · ".join(_e(x) for x in (
        f"scene {meta['scene']}" if meta.get("scene") else "",
        f"source {Path(str(meta['source'])).name}" if meta.get("source") else "",
        meta.get("started", "")) if x)
    warn = []
    for measure, what in (("extraction", "Extraction on the output"), ("truth", "Ground truth")):
        m = summary.get(measure) or {}
        if not m.get("available"):
            warn.append(f"<div class='card warn'><b>{what}: not available.</b> {_e(m.get('reason') or '')}</div>")
    faults = (summary.get("headline") or {}).get("take") or {}
    if faults.get("degraded"):
        warn.append("<div class='card warn'><b>Degraded take: no goal counts as met.</b> "
                    f"{_e('; '.join(faults.get('reasons', [])))}</div>")
    for note in (summary.get("detectors") or {}).get("notes", []):
        warn.append(f"<div class='card warn'><b>Detector:</b> {_e(note)}</div>")
    rec = summary.get("recording") or {}
    for note in rec.get("notes", []):
        warn.append(f"<div class='card warn'><b>Recording:</b> {_e(note)}</div>")
    al = summary.get("alignment", {})
    al_rows = {"source frames (instructions)": al.get("source_frames"),
               "output frames": al.get("output_frames"),
               "compared frames (common length)": al.get("compared_frames"),
               "compared duration [s]": al.get("compared_duration_s"),
               "source fps": al.get("source_fps"), "output fps": al.get("output_fps"),
               "alignment": ("output frame i follows instruction row i" if al.get("mode") == "index"
                             else "by time: row k = round(t · source fps)"),
               "output extraction rows": al.get("output_extraction_frames"),
               "truth records": al.get("truth_frames"),
               "recording clock": {"lockstep": "simulation time (lockstep): every frame its own render",
                                   "realtime": "wall clock (real time): late frames repeated"}.get(
                                       rec.get("clock"), rec.get("clock")),
               "repeated output frames": (f"{rec.get('repeated_frames')} ({_pct(rec.get('repeated_share'))})"
                                          if rec else None)}
    figs = []
    for name, heading in FIGURES:
        if name in figures and Path(figures[name]).is_file():
            body = (f"<figure>{_img(Path(figures[name]), embed)}<figcaption>{_e(CAPTIONS.get(name, ''))} "
                    f"<a href='{_e(name)}'>full size</a></figcaption>")
            if name == "fig_frames.png" and credit:
                body += f"<div class='credit'>Source footage: {_e(credit)}</div>"
            body += "</figure>"
        else:
            body = f"<div class='warn'>figure not made: {_e(figure_errors.get(name, 'unknown error'))}</div>"
        figs.append(f"<h2>{_e(heading)}</h2><div class='card'>{body}</div>")
    version = ""
    try:
        from cinetransfer import __version__ as version
    except ImportError:  # pragma: no cover
        pass
    joints = ", ".join(summary.get("joint_names", []))
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{_e(title)}{' — ' + _e(meta.get('scene')) if meta.get('scene') else ''}</title>
<style>{CSS}</style></head>
<body><main>
<h1>{_e(title)}</h1>
<p class="sub">{sub}</p>
<div class="card">
<span class="badge met">{n_met} met</span><span class="badge missed">{n_missed} missed</span>
<span class="badge na">{n_na} not measurable</span>
<span class="small">Fidelity goals: by extraction on the output, mean joint error ≤ {F.EXTRACTION_JOINT_ERROR_MAX}
and focus agreement ≥ {F.EXTRACTION_FOCUS_AGREEMENT_MIN:.0%} per region; by ground truth ≤ {F.TRUTH_JOINT_ERROR_MAX}
and ≥ {F.TRUTH_FOCUS_AGREEMENT_MIN:.0%}.</span>
</div>
{''.join(warn)}
{_image_side_note(summary)}
{_people_card(summary.get("people") or {}, embed)}
<h2>Goals</h2>
<div class="card">{_goals_table(summary)}</div>
{_shots_table(summary)}
<h2>Controlled-joint error (normalised image units)</h2>
<div class="card">{_joint_table(summary)}
<p class="small">Controlled joints: {_e(joints)}. Error = |output − source target| per axis and Euclidean,
over frames where both sides see the joint; std is the population standard deviation.</p>
{_joint_counts_note(summary)}
{_floor_note(summary)}</div>
<h2>Focus-label agreement per region</h2>
<div class="card">{_focus_table(summary)}
<p class="small">Agreement = fraction of frames whose in-focus boolean equals the source's, over frames where
the region is present on both sides (the frames where it exists on one side only are left out and counted in
brackets). Presence agreement = fraction of frames where both sides agree the region
exists. |b| error = mean absolute difference of the fraction of focused pixels. A frame is out of the lens's
reach for a region when no focus distance and f-number in the vehicle's lens range, at the focal length and
distances filmed, gives the region the source's label (together with the labels granted before it: subject,
then background, then foreground); the goals judge the agreement over the other frames, and both are shown.</p>
{_unreachable_table(summary)}
{_misses_table(summary, summary.get("per_frame") or {})}
<p class="small">Each frame-region whose label is not the source's has one reason: out of the lens's reach
(which limit), missed by the flight where a lens setting gives it (the truth's depth of field named), read
otherwise by the extraction on the output where the truth has the source's label, no such region on that
side (left out of the agreement), or no label of the truth's own to tell the flight from the extraction by
(the truth sees no such region there).</p></div>
{_camera_motion(summary, figures, embed)}
<h2>Side by side</h2>
<div class="card">{_video(video, summary.get("video"), video_error, embed)}</div>
<h2>Alignment</h2>
<div class="card">{_kv_table(al_rows)}</div>
{''.join(figs)}
{_recording_card(summary.get("recording_file"))}
<h2>Run</h2>
<div class="card">{_kv_table(meta) if meta else '<span class="small">no metadata</span>'}</div>
<p class="small">Numbers for scripts: <a href="report.json">report.json</a>. Generated by cinetransfer
{_e(version)}.</p>
</main></body></html>
"""


def write_html(path: Path, summary: dict[str, Any], figures: dict[str, Path], *, meta: dict[str, Any],
               figure_errors: dict[str, str] | None = None, credit: str = "", embed: bool = True,
               video: Path | None = None, video_error: str = "") -> Path:
    text = render_html(summary, figures, meta=meta, figure_errors=figure_errors, credit=credit, embed=embed,
                       video=video, video_error=video_error)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path
