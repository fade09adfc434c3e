"""The report's figures (PNG, matplotlib's Agg canvas; no pyplot global state).

- fig_frames.png  sampled frames side by side: source (top) and output (bottom), with the
                  source's joint targets (hollow rings), the output extraction (dots) and the
                  truth (crosses); the source's credit line underneath
- fig_joints.png  normalised x and y of every controlled joint over time: source light,
                  output extraction dark, ground truth dashed (the paper's Fig. 6 style)
- fig_focus.png   per region: fraction of focused pixels over time (source light, output dark,
                  truth dashed) and the in-focus booleans as strips (the paper's Fig. 7 style)
- fig_error.png   joint error over time (extraction, truth) with the goal lines, and where the
                  focus booleans agree or not
"""
from __future__ import annotations

import logging
import re
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from cinetransfer.report import fidelity as F
from cinetransfer.report.workers import FIGURE_WAIT_S

log = logging.getLogger("cinetransfer.report")

DPI = 100
JOINT_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")
SOURCE_ALPHA = 0.35
TRUTH_COLOUR = "#222222"


def _figure(w_in: float, h_in: float):  # -> matplotlib.figure.Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w_in, h_in), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: Path) -> Path:
    fig.savefig(path, format="png", dpi=DPI)
    return path


def _colour(e: int) -> str:
    return JOINT_COLOURS[e % len(JOINT_COLOURS)]


def hex_rgb(colour: str) -> tuple[float, float, float]:
    """'#rrggbb' as RGB in [0, 1], the very floats matplotlib's `to_rgb` gives (each byte / 255):
    the side-by-side video takes its colours from here, so the transfer's process never imports
    matplotlib (the figures are drawn in their own process)."""
    if not re.fullmatch(r"#[0-9a-fA-F]{6}", colour):
        raise ValueError(f"not a #rrggbb colour: {colour!r}")
    r, g, b = (int(colour[i:i + 2], 16) / 255 for i in (1, 3, 5))
    return (r, g, b)


def _dark(colour: str, f: float = 0.65) -> tuple[float, float, float]:
    r, g, b = hex_rgb(colour)
    return (r * f, g * f, b * f)


# --------------------------------------------------------------------------- credit + video
def credit_for(video: str | Path | None) -> str:
    """The credit line of a bundled clip, from the MANIFEST.md beside it ('' if none)."""
    if not video:
        return ""
    p = Path(video)
    manifest = p.resolve().parent / "MANIFEST.md"
    if not manifest.is_file():
        return ""
    for line in manifest.read_text(encoding="utf-8", errors="replace").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 4 and cells[0].strip("` ") == p.name:
            return f"{p.name}: {cells[3]}"
    return ""


def read_frames(path: str | Path | None, indices: Sequence[int]) -> dict[int, np.ndarray]:
    """The requested frames of a video as RGB arrays (sequential decode: exact on any codec).
    Frames that cannot be read are missing from the result."""
    if not path or not Path(path).is_file():
        return {}
    import cv2

    want = sorted({int(i) for i in indices if i >= 0})
    out: dict[int, np.ndarray] = {}
    if not want:
        return out
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            return out
        i = 0
        for target in want:
            while i < target:
                if not cap.grab():
                    return out
                i += 1
            ok, img = cap.read()
            if not ok:
                return out
            i += 1
            out[target] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    finally:
        cap.release()
    return out


def video_info(path: str | Path | None) -> dict[str, Any]:
    """Frame count, fps and size of a video ({} when it cannot be opened)."""
    if not path or not Path(path).is_file():
        return {}
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            return {}
        return {"frames": int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), "fps": float(cap.get(cv2.CAP_PROP_FPS)),
                "width": int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), "height": int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))}
    finally:
        cap.release()


# --------------------------------------------------------------------------- figures
def _in_focus_text(tr: F.Track, i: int) -> str:
    if not tr.available[i]:
        return "no data"
    names = [r for r, p, f in zip(F.REGIONS, tr.present[i], tr.focus_in[i]) if p and f]
    return "in focus: " + (", ".join(names) if names else "none")


def _show(ax: Any, img: np.ndarray | None, text: str) -> None:
    ax.set_xticks([])
    ax.set_yticks([])
    if img is None:
        ax.set_facecolor("#dddddd")
        ax.set_xlim(0, 1)
        ax.set_ylim(1, 0)
        ax.text(0.5, 0.5, text, ha="center", va="center", fontsize=9, color="#555555", transform=ax.transAxes)
        return
    h, w = img.shape[:2]
    ax.imshow(img, extent=(0, 1, 1, 0), interpolation="bilinear")
    ax.set_xlim(0, 1)
    ax.set_ylim(1, 0)
    ax.set_aspect(h / w)


def frame_picks(series: dict[str, Any], n_samples: int = 6) -> tuple[np.ndarray, list[int], list[int]]:
    """The rows fig_frames shows, and the source and output frame indices they show."""
    n = len(series["t_s"])
    picks = np.unique(np.linspace(0, n - 1, min(n_samples, n)).round().astype(int)) if n else np.zeros(0, int)
    first = int(series.get("source_first_frame", 0))
    return picks, [first + int(series["k"][i]) for i in picks], [int(i) for i in picks]


def fig_frames(path: Path, series: dict[str, Any], *, source_video: str | Path | None,
               output_video: str | Path | None, credit: str = "", n_samples: int = 6,
               decoded: tuple[dict[int, np.ndarray], dict[int, np.ndarray]] | None = None) -> Path:
    """`decoded`: the (source, output) frames of `frame_picks` as RGB, when the caller decoded the
    videos already (the side-by-side video does); else they are read here."""
    t, k = series["t_s"], series["k"]
    src: F.Track = series["source"]
    ext: F.Track = series["extraction"]
    tru: F.Track = series["truth"]
    E = len(series["joint_names"])
    first = int(series.get("source_first_frame", 0))
    picks, src_idx, out_idx = frame_picks(series, n_samples)
    src_imgs, out_imgs = decoded if decoded is not None else ({}, {})
    missing = ([i for i in src_idx if i not in src_imgs], [i for i in out_idx if i not in out_imgs])
    src_imgs = {**src_imgs, **(read_frames(source_video, missing[0]) if missing[0] else {})}
    out_imgs = {**out_imgs, **(read_frames(output_video, missing[1]) if missing[1] else {})}
    cols = max(len(picks), 1)
    shapes = [im.shape[:2] for im in (*src_imgs.values(), *out_imgs.values())]
    aspect = float(np.clip(np.mean([h / w for h, w in shapes]), 0.3, 1.5)) if shapes else 9 / 16
    # Sizes in inches: the image rows fit their aspect, so the figure has no dead space.
    left_in, right_in, cell_w, gap_w = 0.45, 0.05, 2.3, 0.06
    top_in, label_in, title_in, bottom_in = 0.4, 0.2, 0.22, 0.3 if credit else 0.1
    width = left_in + right_in + cols * cell_w + (cols - 1) * gap_w
    img_h = cell_w * aspect
    height = top_in + 2 * (title_in + img_h + label_in) + bottom_in
    fig = _figure(width, height)
    gs = fig.add_gridspec(2, cols, left=left_in / width, right=1 - right_in / width,
                          top=1 - (top_in + title_in) / height,
                          bottom=(bottom_in + label_in) / height, wspace=gap_w / cell_w,
                          hspace=(label_in + title_in) / img_h)
    if not len(picks):
        ax = fig.add_subplot(gs[:, :])
        _show(ax, None, "no frames to compare")
    for c, i in enumerate(picks):
        a_src = fig.add_subplot(gs[0, c])
        a_out = fig.add_subplot(gs[1, c])
        _show(a_src, src_imgs.get(first + int(k[i])), "source frame\nnot readable")
        _show(a_out, out_imgs.get(int(i)), "no output video" if not output_video else "output frame\nnot readable")
        a_src.set_title(f"t = {t[i]:.2f} s  (k = {int(k[i])})", fontsize=8)
        a_src.set_xlabel(_in_focus_text(src, i), fontsize=7, labelpad=2)
        # Two lines: one line per caption overflows into the next panel at six panels a row.
        a_out.set_xlabel(_in_focus_text(tru if tru.available[i] else ext, i)
                         + ("\n(simulator truth)" if tru.available[i] else "\n(extraction)"), fontsize=7, labelpad=2)
        for e in range(E):
            col = _colour(e)
            if src.ok[i, e]:
                for ax in (a_src, a_out):
                    ax.plot(*src.xy[i, e], "o", ms=7, mfc="none", mec=col, mew=1.5)
            if ext.ok[i, e]:
                a_out.plot(*ext.xy[i, e], "o", ms=3.5, color=_dark(col))
            if tru.ok[i, e]:
                a_out.plot(*tru.xy[i, e], "x", ms=5, mew=1.2, color="white")
        if c == 0:
            a_src.set_ylabel("source", fontsize=9)
            a_out.set_ylabel("output", fontsize=9)
    fig.suptitle("Sampled frames: source (top) and recorded output (bottom). Rings: source targets; "
                 "dots: extraction on the output; crosses: truth", fontsize=9, y=1 - 0.12 / height, va="top")
    if credit:
        fig.text(0.5, 0.08 / height, credit, ha="center", va="bottom", fontsize=7, color="#444444", wrap=True)
    return _save(fig, path)


def fig_joints(path: Path, series: dict[str, Any]) -> Path:
    names = series["joint_names"]
    E = max(len(names), 1)
    fig = _figure(12, 1.9 * E + 0.9)
    axes = fig.subplots(E, 2, sharex=True, squeeze=False)
    srcf: F.Track = series["source_full"]
    ts = series["source_t_full"]
    t = series["t_s"]
    ext: F.Track = series["extraction"]
    tru: F.Track = series["truth"]
    for e, name in enumerate(names):
        col = _colour(e)
        for a, ax in enumerate(axes[e]):
            y = np.where(srcf.ok[:, e], srcf.xy[:, e, a], np.nan)
            ax.plot(ts, y, color=col, alpha=SOURCE_ALPHA, lw=3.5, label="source")
            shown = [y]
            if series["have_extraction"]:
                shown.append(np.where(ext.ok[:, e], ext.xy[:, e, a], np.nan))
                ax.plot(t, shown[-1], color=_dark(col), lw=1.3, label="output (extraction)")
            if series["have_truth"]:
                shown.append(np.where(tru.ok[:, e], tru.xy[:, e, a], np.nan))
                ax.plot(t, shown[-1], "--", color=TRUTH_COLOUR, lw=1.0, label="output (truth)")
            ax.set_ylabel(f"{name}\n{'x' if a == 0 else 'y (down)'}", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            _mark_repeats(ax, series)
            vals = np.concatenate(shown)
            vals = vals[np.isfinite(vals)]
            if vals.size:
                lo, hi = float(vals.min()), float(vals.max())
                pad = max(0.08, 0.5 * (hi - lo))
                ax.set_ylim(max(-0.05, lo - pad), min(1.05, hi + pad))
    axes[0, 0].set_title("normalised x", fontsize=9)
    axes[0, 1].set_title("normalised y", fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel("time since recording start [s]", fontsize=8)
    top = 1 - 0.62 / (1.9 * E + 0.9)
    fig.suptitle("Controlled joints over time: source light, output dark, truth dashed", fontsize=10,
                 y=1 - 0.08 / (1.9 * E + 0.9), va="top")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, top), ncol=3, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, top + 0.2 / (1.9 * E + 0.9)))
    return _save(fig, path)


_STRIP_ABSENT, _STRIP_OUT, _STRIP_IN = 0, 1, 2


def _mark_repeats(ax: Any, series: dict[str, Any]) -> None:
    """Shade the output frames that repeat the previous one (real-time recordings only), and
    draw the source's cuts (where one take ends and the next begins)."""
    t = series["t_s"]
    rows = list(series["k"])
    for r in series.get("shot_rows", ()):
        if r in rows:
            ax.axvline(t[rows.index(r)], color="#7b3294", lw=0.9, ls="--", alpha=0.8)
    half = 0.5 * float(t[1] - t[0]) if len(t) > 1 else 0.02
    for j in series.get("repeated_slots", ()):
        if 0 <= j < len(t):
            ax.axvspan(t[j] - half, t[j] + half, color="#f0a000", alpha=0.25, lw=0)


def _strip_values(tr: F.Track, r: int) -> np.ndarray:
    v = np.full(tr.n, _STRIP_ABSENT, dtype=float)
    pres = tr.available & tr.present[:, r]
    v[pres] = np.where(tr.focus_in[pres, r], _STRIP_IN, _STRIP_OUT)
    return v


def _strips(ax: Any, rows: list[tuple[str, np.ndarray]], t: np.ndarray, colours: Sequence[str]) -> None:
    from matplotlib.colors import ListedColormap

    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    img = np.vstack([r for _, r in rows]) if rows else np.zeros((1, 1))
    t0 = float(t[0]) if len(t) else 0.0
    t1 = float(t[-1]) + dt if len(t) else 1.0
    ax.imshow(img, aspect="auto", interpolation="nearest", cmap=ListedColormap(list(colours)), vmin=-0.5,
              vmax=len(colours) - 0.5, extent=(t0 - dt / 2, t1 - dt / 2, len(rows) - 0.5, -0.5))
    for y in range(len(rows) - 1):
        ax.axhline(y + 0.5, color="white", lw=1.5)
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels([name for name, _ in rows], fontsize=7)
    ax.tick_params(axis="x", labelsize=7)


def fig_focus(path: Path, series: dict[str, Any]) -> Path:
    t = series["t_s"]
    src: F.Track = series["source"]
    ext: F.Track = series["extraction"]
    tru: F.Track = series["truth"]
    fig = _figure(12, 8.2)
    gs = fig.add_gridspec(6, 1, height_ratios=[3, 1.1] * 3, hspace=0.55, left=0.11, right=0.98, top=0.905,
                          bottom=0.07)
    col_src, col_out = "#1f77b4", "#0b2e59"
    for r, region in enumerate(F.REGIONS):
        ax = fig.add_subplot(gs[2 * r])
        ax.plot(t, src.frac[:, r], ".", color=col_src, alpha=SOURCE_ALPHA, ms=3, label="source b (raw)")
        ax.plot(t, src.smoothed[:, r], color=col_src, alpha=SOURCE_ALPHA + 0.1, lw=3.5, label="source B (smoothed)")
        if series["have_extraction"]:
            ax.plot(t, ext.frac[:, r], ".", color=col_out, ms=2.5, label="output b (raw)")
            ax.plot(t, ext.smoothed[:, r], color=col_out, lw=1.3, label="output B (smoothed)")
        if series["have_truth"]:
            ax.plot(t, tru.frac[:, r], "--", color=TRUTH_COLOUR, lw=1.0, label="truth fraction")
        ax.axhline(0.5, color="#999999", lw=0.8, ls=":")
        ax.set_ylim(-0.05, 1.05)
        ax.set_ylabel(f"{region}\nfocused fraction", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        _mark_repeats(ax, series)
        if r == 0:
            handles, labels = ax.get_legend_handles_labels()
            fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, 0.915), ncol=5, fontsize=8,
                       frameon=False)
        sx = fig.add_subplot(gs[2 * r + 1], sharex=ax)
        rows = [("source", _strip_values(src, r))]
        if series["have_extraction"]:
            rows.append(("output (extr.)", _strip_values(ext, r)))
        if series["have_truth"]:
            rows.append(("output (truth)", _strip_values(tru, r)))
        _strips(sx, rows, t, ("#ffffff", "#c9c9c9", "#2ca02c"))
    sx.set_xlabel("time since recording start [s]   (strips: green = in focus, grey = out of focus, "
                  "white = region absent)", fontsize=8)
    fig.suptitle("Focus per region: source light, output dark, truth dashed", fontsize=10, y=0.99, va="top")
    return _save(fig, path)


def fig_error(path: Path, series: dict[str, Any]) -> Path:
    t = series["t_s"]
    src: F.Track = series["source"]
    fig = _figure(12, 5.0)
    gs = fig.add_gridspec(2, 1, height_ratios=[2.4, 1.3], hspace=0.35, left=0.16, right=0.98, top=0.9, bottom=0.12)
    ax = fig.add_subplot(gs[0])
    if series["have_extraction"]:
        ax.plot(t, series["error_extraction"], color="#0b2e59", lw=1.2, label="by extraction")
    if series["have_truth"]:
        ax.plot(t, series["error_truth"], "--", color=TRUTH_COLOUR, lw=1.0, label="by ground truth")
    ax.axhline(F.EXTRACTION_JOINT_ERROR_MAX, color="#0b2e59", lw=0.8, ls=":",
               label=f"goal (extraction) {F.EXTRACTION_JOINT_ERROR_MAX}")
    ax.axhline(F.TRUTH_JOINT_ERROR_MAX, color=TRUTH_COLOUR, lw=0.8, ls="-.",
               label=f"goal (truth) {F.TRUTH_JOINT_ERROR_MAX}")
    ax.set_ylabel("mean joint error\n(normalised)", fontsize=8)
    errs = np.concatenate([series["error_extraction"], series["error_truth"]])
    errs = errs[np.isfinite(errs)]
    ax.set_ylim(0, max(1.15 * F.EXTRACTION_JOINT_ERROR_MAX, 1.1 * float(errs.max()) if errs.size else 0.0))
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    _mark_repeats(ax, series)
    ax.legend(fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=4, frameon=False)
    sx = fig.add_subplot(gs[1], sharex=ax)
    rows = []
    reach = series.get("reach")
    for name, key in (("extr.", "extraction"), ("truth", "truth")):
        if not series[f"have_{key}"]:
            continue
        tr: F.Track = series[key]
        for r, region in enumerate(F.REGIONS):
            both = src.available & tr.available & src.present[:, r] & tr.present[:, r]
            v = np.zeros(len(t))
            v[both] = np.where(src.focus_in[both, r] == tr.focus_in[both, r], 1, 2)
            if reach is not None:
                v[both & reach.unreachable[:, r]] += 2  # out of the lens's reach: paler, not judged
            rows.append((f"{region} ({name})", v))
    if rows:
        _strips(sx, rows, t, ("#ffffff", "#2ca02c", "#d62728", "#a9d8a9", "#eaa9a9"))
    else:
        sx.text(0.5, 0.5, "no output data", ha="center", va="center", transform=sx.transAxes)
    sx.set_xlabel("time since recording start [s]   (strips: green = focus label agrees with the source, "
                  "red = disagrees, pale = out of the lens's reach (not judged), white = undefined)", fontsize=8)
    fig.suptitle("Error over time", fontsize=10, x=0.16, ha="left", y=0.975, va="top")
    return _save(fig, path)


FIGURES = (("fig_frames.png", "Sampled frames"), ("fig_joints.png", "Controlled joints over time"),
           ("fig_focus.png", "Focus per region"), ("fig_error.png", "Error over time"))


#: the figure that shows sampled frames (it needs the decoded videos; the others only the series)
FRAMES_FIGURE = "fig_frames.png"


def draw_figure(name: str, outdir: Path, series: dict[str, Any], **frames_kw: Any) -> tuple[Path | None, str]:
    """One figure of FIGURES into outdir: (its path, ""), or (None, the error) when plotting failed:
    logged, never raised (a plotting bug must not lose the numbers). `frames_kw` are fig_frames'
    keywords. Module-level with picklable arguments: a second process can draw it (report/workers.py)."""
    makers = {FRAMES_FIGURE: lambda p: fig_frames(p, series, **frames_kw),
              "fig_joints.png": lambda p: fig_joints(p, series),
              "fig_focus.png": lambda p: fig_focus(p, series),
              "fig_error.png": lambda p: fig_error(p, series)}
    # Cosmetic plotting warnings (layout, empty data) are logged, not raised: a caller that
    # runs with warnings as errors must still get its report.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return makers[name](outdir / name), ""
        except Exception as e:  # a plotting bug must not lose the numbers
            log.exception("figure %s failed", name)
            return None, re.sub(r"\s+", " ", f"{type(e).__name__}: {e}")[:300]
        finally:
            for w in caught:
                log.debug("figure %s: %s: %s", name, w.category.__name__, w.message)


class Drawing:
    """Figures being drawn: in `pool` (a report.workers.FigureWorker) when given, else here and now.
    `result()` gives ({file name: path}, {file name: error}); a figure the pool could not draw (its
    process died) is drawn here instead."""

    def __init__(self, outdir: Path, series: dict[str, Any], names: Sequence[str], pool: Any = None,
                 **frames_kw: Any) -> None:
        self.outdir, self.series, self.frames_kw = outdir, series, frames_kw
        self.jobs: dict[str, Any] = {}
        for name in names:
            job = pool.submit(draw_figure, name, outdir, series, **self._kw(name)) if pool is not None else None
            self.jobs[name] = job if job is not None else draw_figure(name, outdir, series, **self._kw(name))

    def _kw(self, name: str) -> dict[str, Any]:
        return self.frames_kw if name == FRAMES_FIGURE else {}

    def result(self) -> tuple[dict[str, Path], dict[str, str]]:
        done: dict[str, Path] = {}
        errors: dict[str, str] = {}
        for name, job in self.jobs.items():
            if not isinstance(job, tuple):
                try:
                    job = job.result(timeout=FIGURE_WAIT_S)
                except Exception as e:  # noqa: BLE001 - the worker process failed, not the figure: draw it here
                    why = f"no result in {FIGURE_WAIT_S:.0f} s" if isinstance(e, TimeoutError) else str(e)
                    log.warning("figure %s: the figure process failed (%s); drawn here instead", name, why)
                    job = draw_figure(name, self.outdir, self.series, **self._kw(name))
            path, error = job
            if path is not None:
                done[name] = path
            else:
                errors[name] = error
        return done, errors


def figure_series(series: dict[str, Any], repeated_slots: Sequence[int] = (),
                  shot_rows: Sequence[int] = ()) -> dict[str, Any]:
    """The fidelity series with what the time plots mark: repeated output frames and the cuts."""
    return {**series, "repeated_slots": list(repeated_slots), "shot_rows": list(shot_rows)}


def make_figures(outdir: Path, series: dict[str, Any], *, source_video: str | Path | None,
                 output_video: str | Path | None, credit: str = "",
                 repeated_slots: Sequence[int] = (),
                 shot_rows: Sequence[int] = (),
                 decoded: tuple[dict[int, np.ndarray], dict[int, np.ndarray]] | None = None
                 ) -> tuple[dict[str, Path], dict[str, str]]:
    """Every figure into outdir; returns ({file name: path}, {file name: error}). One failing
    figure is logged and reported, never fatal for the others or the report. Output frames in
    `repeated_slots` (repeats of the previous frame) are shaded on the time plots."""
    return Drawing(outdir, figure_series(series, repeated_slots, shot_rows), [n for n, _ in FIGURES],
                   source_video=source_video, output_video=output_video, credit=credit, decoded=decoded).result()
