"""The report's "Camera motion" section: the source camera's moves (from the style), the output's
(the same extraction on the output video), the truth (from the simulated camera's poses and lens)
and per shot how often the output's class matches the source's.

Output row k is instruction row k (the take is filmed frame for frame); truth rows come from the
vehicle states interpolated to the recorded frames' stamps (the camera's yaw, pitch, roll and the
vehicle's velocity, which counts as a translation from |v| / subject distance >= 0.03 /s) and each
frame's focal length. The states come at the 20 Hz control steps, the frames at 24 fps: taking the
last state before each frame repeated one state every sixth frame (a pan rate of 0 there).
"""
from __future__ import annotations

import html
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from cinetransfer.services.smoother.camera_motion import motion_style
from cinetransfer.shared import camera_motion as cm
from cinetransfer.shared import messages as M
from cinetransfer.shared.angles import wrap_angle

RATES = ("pan_rate_dps", "tilt_rate_dps", "roll_rate_dps", "zoom_rate")
FIGURE = "fig_camera_motion.png"


def style_rates(instr: M.Instructions | None) -> dict[str, np.ndarray] | None:
    """Rates (K,) and classes of a style; None when it has no camera-motion style."""
    if instr is None or instr.camera_motion_class is None:
        return None
    out: dict[str, Any] = {n: np.asarray(getattr(instr, n), dtype=float) for n in RATES}
    out["translation_dir"] = np.asarray(instr.translation_dir, dtype=float)
    out["class"] = list(instr.camera_motion_class)
    return out


def interpolate_states(stamps_ns: np.ndarray, values: np.ndarray, t_ns: int, angles: bool = False) -> np.ndarray:
    """`values` (N, D) stamped `stamps_ns` (N,, ascending) linearly interpolated at `t_ns`, held
    beyond the ends; `angles`: radians, interpolated the short way round and wrapped to (-pi, pi]."""
    v = np.asarray(values, dtype=float)
    i = int(np.searchsorted(stamps_ns, t_ns, side="right"))
    if i <= 0 or i >= len(stamps_ns):
        return v[min(max(i - 1, 0), len(v) - 1)].copy()
    a, b = v[i - 1], v[i]
    d = wrap_angle(b - a) if angles else b - a
    out = a + d * ((t_ns - int(stamps_ns[i - 1])) / (int(stamps_ns[i]) - int(stamps_ns[i - 1])))
    return wrap_angle(out) if angles else out


def truth_rates(states: Sequence[M.VehicleState], truths: Sequence[M.GroundTruth], rows: int,
                fps: float, starts: Sequence[int] = ()) -> dict[str, Any] | None:
    """Rates per instruction row from the camera's poses at the recorded frames (the vehicle states
    interpolated to each frame's stamp) and the frames' focal lengths; None without truth.
    Rows in `starts` begin a take: the camera settled between it and the row before, so no rate.
    Smoothed and classed as the smoother does the clip's motion."""
    if not truths or not states or rows <= 0:
        return None
    st = sorted(states, key=lambda s: int(s.stamp_ns))
    stamps = np.array([int(s.stamp_ns) for s in st], dtype=np.int64)
    st_ypr = np.array([np.asarray(s.camera_ypr_rad, dtype=float) for s in st])
    st_vel = np.array([np.asarray(s.velocity_mps, dtype=float) for s in st])
    ypr = np.full((rows, 3), np.nan)
    focal = np.full(rows, np.nan)
    trans = np.full((rows, 3), np.nan)
    for t in truths:
        k = int(t.frame_index)
        i = int(np.searchsorted(stamps, int(t.stamp_ns), side="right")) - 1
        if 0 <= k < rows and i >= 0:
            ypr[k] = interpolate_states(stamps, st_ypr, int(t.stamp_ns), angles=True)
            f = float(t.focal_length_mm)
            focal[k] = f if np.isfinite(f) and f > 0 else float(st[i].lens.focal_length_mm)
            vel = interpolate_states(stamps, st_vel, int(t.stamp_ns))
            trans[k] = cm.translation_from_velocity(vel, ypr[k], float(t.subject_distance_m))
    raw = cm.rates_from_poses(ypr, focal, fps)
    # per frame, as the detector measures it; then smoothed and classed as the smoother does the clip's
    motion = np.column_stack([np.radians([raw[n] for n in RATES[:3]]).T / fps, raw["zoom_rate"] / fps, trans])
    cuts = np.zeros(rows, dtype=bool)
    cuts[[k for k in starts if 0 <= k < rows]] = True
    style = motion_style(motion, fps, cuts)
    return {**{n: np.asarray(style[n], dtype=float) for n in (*RATES, "translation_dir")},
            "class": style["camera_motion_class"]}


def shot_motion(r: dict[str, Any] | None, a: int, b: int) -> dict[str, Any] | None:
    """Class and median rates of rows [a, b) of one side (None when the side is missing)."""
    if r is None or len(r["class"]) < b:
        return None
    med = {}
    for n in RATES:
        v = np.asarray(r[n][a:b], dtype=float)
        v = v[np.isfinite(v)]
        med[n] = round(float(np.median(v)), 4) if v.size else None
    t = np.asarray(r["translation_dir"][a:b], dtype=float)
    t = t[np.isfinite(t).all(axis=1)] if t.size else t
    tm = t.mean(axis=0) if len(t) else np.zeros(3)
    tdir = tm / np.linalg.norm(tm) if np.linalg.norm(tm) >= 0.5 else np.zeros(3)
    known = any(v is not None for v in med.values())
    cls = cm.classify(*(np.nan if med[n] is None else med[n] for n in RATES), tdir) if known else ""
    return {"class": cls, **med, "translation_dir": [round(float(x), 3) for x in tdir]}


def agreement(src: Sequence[str], out: Sequence[str] | None, a: int, b: int) -> float | None:
    """Share of rows [a, b) whose output class equals the source's, over rows both know."""
    if out is None or len(out) < b:
        return None
    pairs = [(s, o) for s, o in zip(src[a:b], out[a:b]) if s and o]
    return round(sum(s == o for s, o in pairs) / len(pairs), 4) if pairs else None


def camera_motion_summary(source: M.Instructions, output: M.Instructions | None,
                          states: Sequence[M.VehicleState], truths: Sequence[M.GroundTruth],
                          segments: Sequence[tuple[int, int]]) -> tuple[dict[str, Any], dict[str, Any]]:
    """report.json's camera_motion (shots[] with rows, source, output, truth, agreement) and the
    per-row series for the figure."""
    src = style_rates(source)
    if src is None:
        return {"available": False, "reason": "the source style has no camera-motion fields (an older style file)",
                "shots": []}, {}
    rows = len(src["class"])
    out = style_rates(output)
    tru = truth_rates(states, truths, rows, float(source.fps), [a for a, _ in segments if 0 <= a < rows])
    shots = []
    for i, (a, b) in enumerate(segments):
        shots.append({"shot": i, "rows": [int(a), int(b)], "source": shot_motion(src, a, b),
                      "output": shot_motion(out, a, b), "truth": shot_motion(tru, a, b),
                      "agreement": agreement(src["class"], out and out["class"], a, b),
                      "truth_agreement": agreement(src["class"], tru and tru["class"], a, b)})
    summary = {"available": True, "assumed_hfov_deg": cm.ASSUMED_HFOV_DEG,
               "output_reason": "" if out is not None else "no camera-motion fields in the output's style",
               "truth_reason": "" if tru is not None else "no simulator truth or vehicle states recorded",
               "shots": shots}
    return summary, {"fps": float(source.fps), "source": src, "output": out, "truth": tru}


def fig_camera_motion(path: Path, series: dict[str, Any]) -> Path:
    """Pan, tilt, roll and zoom rates over time: source light, output dark, truth dashed."""
    from cinetransfer.report.figures import SOURCE_ALPHA, TRUTH_COLOUR, _figure, _save

    fig = _figure(10, 6.4)
    axes = fig.subplots(4, 1, sharex=True)
    labels = ("pan [deg/s]", "tilt [deg/s]", "roll [deg/s]", "zoom [1/s]")
    for ax, n, lab in zip(axes, RATES, labels):
        for side, style in (("source", dict(color="#1f77b4", alpha=SOURCE_ALPHA, lw=3)),
                            ("output", dict(color="#0b3c66", lw=1.2)),
                            ("truth", dict(color=TRUTH_COLOUR, ls="--", lw=1.0))):
            r = series.get(side)
            if r is not None:
                v = np.asarray(r[n], dtype=float)
                ax.plot(np.arange(len(v)) / series["fps"], v, label=side, **style)
        ax.set_ylabel(lab, fontsize=8)
        ax.axhline(0.0, color="#999999", lw=0.5)
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time [s] (instruction rows)")
    fig.tight_layout()
    return _save(fig, path)


def _rates_text(p: dict[str, Any] | None) -> str:
    if not p:
        return "<td>-</td><td>-</td>"
    vals = ", ".join(f"{n.split('_')[0]} {p[n]:+.2f}" for n in RATES if p.get(n) is not None)
    return f"<td><b>{html.escape(p['class'] or '?')}</b></td><td class='small'>{html.escape(vals)}</td>"


def _share(x: float | None) -> str:
    return "-" if x is None else f"{x:.0%}"


def camera_motion_card(cmo: dict[str, Any] | None, figure_html: str) -> str:
    """The report page's "Camera motion" section."""
    if not cmo:
        return ""
    if not cmo.get("available"):
        return f"<h2>Camera motion</h2><div class='card'><span class='small'>{html.escape(cmo.get('reason', ''))}" \
               "</span></div>"
    rows = "".join(
        f"<tr><td>{s['shot']}</td><td>{s['rows'][0]}-{s['rows'][1]}</td>{_rates_text(s['source'])}"
        f"{_rates_text(s['output'])}{_rates_text(s['truth'])}"
        f"<td>{_share(s['agreement'])}</td></tr>"
        for s in cmo["shots"])
    first = (cmo["shots"][0]["source"] or {}).get("class") if cmo["shots"] else ""
    said = "The source camera was static." if first == "static" and len(cmo["shots"]) == 1 else ""
    return (f"<h2>Camera motion</h2><div class='card'><p>{html.escape(said)}</p><table><tr><th>shot</th>"
            "<th>rows</th><th colspan=2>source</th><th colspan=2>output</th><th colspan=2>truth (poses)</th>"
            f"<th>agreement</th></tr>{rows}</table>"
            "<p class='small'>Rates are the shot's medians: pan positive to the camera's left, tilt up, roll "
            "clockwise as the camera sees it [deg/s], zoom = d ln(focal length)/dt [1/s]. Measured on the "
            "background's image motion with the people masked out, assuming a horizontal field of view of "
            f"{cmo.get('assumed_hfov_deg')} deg where the lens is unknown (rotation rates scale with it). "
            "Agreement = share of rows whose output class equals the source's.</p>"
            f"{figure_html}</div>")
