"""Style fidelity: how closely a recorded shot follows the source's instructions (pure numpy).

Two measures:

- **by extraction** — the same style extraction run on the recorded output video gives a second
  `Instructions`; its controlled-joint targets and focus booleans are compared with the source's
  (what the paper's Figs 6-7 show);
- **by ground truth** — the simulator's exact `GroundTruth` of every recorded frame (projected
  joints, per-region in-focus labels) is compared with the source's instructions.

Alignment: output frame i is shown at t = i / output_fps and follows source instruction row
k = i when both run at the same rate (the recording starts when the planner starts following
row 0); otherwise k = round(t * source_fps). Only frames that exist on both sides are compared
(the common length). Output-extraction row r is output frame `first_frame + r`; a truth is output
frame `frame_index - min(frame_index)` of the truths given (the first recorded frame is 0).

Joint error of one joint in one frame: |output - source| in normalised image units, per axis and
Euclidean; counted only where both sides see the joint (finite target, subject visible; for the
truth: `joints_visible`). Focus agreement of a region: the fraction of frames with equal in-focus
booleans, over frames where the region is present on both sides (instructions: `focus_smoothed`
finite; truth: `region_present`).

Left and right by image side: in a frame where the output's person faces the other way from the
source's (a front-view style on a subject seen from behind: the library's walker), the output's
left/right joints are compared with the source's joints on the same side of the image, as the
planner aims them (shared/facing.py; decided by which way each view faces, never by the smaller
error). The number of such frames (`frames_by_image_side`) and the error with left/right matched by
name (`euclidean_by_name`) are kept next to it, and the report states both.

Goals: by extraction, mean joint error <= 0.05 and focus agreement >= 90 % per region;
by ground truth, <= 0.03 and >= 95 %. The joint goal uses the Euclidean error pooled over the
controlled joints and frames (stricter than either axis alone).

No I/O, no plotting, no clock: `compute_fidelity` returns a JSON-ready summary and the aligned
per-frame series the figures draw.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from cinetransfer.report import focus_misses as FM
from cinetransfer.report import focus_reach as FR
from cinetransfer.report import reach_frames as RF
from cinetransfer.shared import messages as M
from cinetransfer.shared.facing import faces_opposite, mirror_permutation

REGIONS: tuple[str, ...] = M.FOCUS_REGIONS

#: goal thresholds (docs/report.md)
EXTRACTION_JOINT_ERROR_MAX = 0.05
EXTRACTION_FOCUS_AGREEMENT_MIN = 0.90
TRUTH_JOINT_ERROR_MAX = 0.03
TRUTH_FOCUS_AGREEMENT_MIN = 0.95

#: relative fps difference below which output frame i simply follows instruction row i
SAME_FPS_RTOL = 1e-3


# --------------------------------------------------------------------------- tracks
@dataclass(frozen=True, eq=False)
class Track:
    """Per-frame joints and focus of one side (source, output extraction or truth).

    N frames, E controlled joints. Arrays are aligned to whatever timeline the builder used.
    """

    xy: np.ndarray  # (N, E, 2) normalised x, y; NaN = unknown
    ok: np.ndarray  # (N, E) joint seen (finite, subject visible)
    available: np.ndarray  # (N,) this side has data for the frame at all
    frac: np.ndarray  # (N, 3) fraction of focused pixels per region; NaN = absent/unknown
    smoothed: np.ndarray  # (N, 3) smoothed B (instructions) or NaN (truth)
    focus_in: np.ndarray  # (N, 3) region in focus
    present: np.ndarray  # (N, 3) region present

    @property
    def n(self) -> int:
        return int(self.available.shape[0])

    def take(self, rows: np.ndarray) -> "Track":
        """Rows `rows` (index -1 or beyond the end = unavailable frame)."""
        rows = np.asarray(rows, dtype=int)
        good = (rows >= 0) & (rows < self.n)
        r = np.where(good, rows, 0)
        if self.n == 0:
            return empty_track(len(rows), self.xy.shape[1])

        def pick(a: np.ndarray, fill: Any) -> np.ndarray:
            out = a[r].copy()
            out[~good] = fill
            return out

        return Track(xy=pick(self.xy, np.nan), ok=pick(self.ok, False), available=pick(self.available, False),
                     frac=pick(self.frac, np.nan), smoothed=pick(self.smoothed, np.nan),
                     focus_in=pick(self.focus_in, False), present=pick(self.present, False))


def empty_track(n: int, e: int) -> Track:
    """A side with no data for n frames (e.g. the output extraction failed)."""
    return Track(xy=np.full((n, e, 2), np.nan), ok=np.zeros((n, e), bool), available=np.zeros(n, bool),
                 frac=np.full((n, 3), np.nan), smoothed=np.full((n, 3), np.nan),
                 focus_in=np.zeros((n, 3), bool), present=np.zeros((n, 3), bool))


def _rows_of(a: np.ndarray, k: int, width: int) -> np.ndarray | None:
    a = np.asarray(a)
    return a if a.ndim == 2 and a.shape == (k, width) else None


def instructions_track(instr: M.Instructions, joint_names: Sequence[str]) -> Track:
    """One row per instruction frame; joints picked by name (a missing name is never seen)."""
    tg = np.asarray(instr.image_targets, dtype=float)
    K = int(tg.shape[0]) if tg.ndim == 3 else 0
    E = len(joint_names)
    xy = np.full((K, E, 2), np.nan)
    names = list(instr.joint_names)
    for e, name in enumerate(joint_names):
        if name in names and K:
            xy[:, e] = tg[:, names.index(name), :2]
    ok = np.isfinite(xy).all(axis=2)
    vis = np.asarray(instr.subject_visible, dtype=bool)
    if vis.shape == (K,):
        ok &= vis[:, None]
    nan3 = np.full((K, 3), np.nan)
    raw = _rows_of(np.asarray(instr.focus_raw, dtype=float), K, 3)
    sm = _rows_of(np.asarray(instr.focus_smoothed, dtype=float), K, 3)
    fin = _rows_of(np.asarray(instr.focus_in, dtype=bool), K, 3)
    if sm is not None:
        present = np.isfinite(sm)
    elif raw is not None:
        present = np.isfinite(raw)
    else:
        present = np.ones((K, 3), bool)
    return Track(xy=xy, ok=ok, available=np.ones(K, bool),
                 frac=raw if raw is not None else nan3, smoothed=sm if sm is not None else nan3.copy(),
                 focus_in=fin if fin is not None else np.zeros((K, 3), bool), present=present)


def truth_frame_offset(truths: Sequence[M.GroundTruth]) -> int:
    """frame_index of the first recorded frame (output frame 0)."""
    return min((int(t.frame_index) for t in truths), default=0)


def truth_track(truths: Sequence[M.GroundTruth], joint_names: Sequence[str], n: int) -> Track:
    """Truth on the output timeline 0..n-1 (duplicates: the first one counts)."""
    E = len(joint_names)
    tr = empty_track(n, E)
    xy, ok, avail = tr.xy, tr.ok, tr.available
    frac, fin, pres = tr.frac, tr.focus_in, tr.present
    off = truth_frame_offset(truths)
    for t in truths:
        i = int(t.frame_index) - off
        if not (0 <= i < n) or avail[i]:
            continue
        avail[i] = True
        names = list(t.joint_names)
        jn = np.asarray(t.joints_norm, dtype=float)
        jv = np.asarray(t.joints_visible, dtype=bool)
        for e, name in enumerate(joint_names):
            if name in names:
                j = names.index(name)
                if j < len(jn):
                    xy[i, e] = jn[j, :2]
                    ok[i, e] = bool(j < len(jv) and jv[j]) and bool(np.isfinite(jn[j, :2]).all())
        rp = np.asarray(t.region_present, dtype=bool)
        if rp.shape == (3,):
            pres[i] = rp
        ri = np.asarray(t.region_in_focus, dtype=bool)
        if ri.shape == (3,):
            fin[i] = ri
        rf = np.asarray(t.region_focus_fraction, dtype=float)
        if rf.shape == (3,):
            frac[i] = rf
    return tr


def output_track(instr: M.Instructions, joint_names: Sequence[str], n: int) -> Track:
    """Output extraction on the output timeline 0..n-1 (row r is frame first_frame + r)."""
    tr = instructions_track(instr, joint_names)
    rows = np.arange(n) - int(instr.first_frame)
    return tr.take(rows)


def align_rows(n_out: int, out_fps: float, n_src: int, src_fps: float) -> tuple[np.ndarray, np.ndarray, str]:
    """(t_s, k) per output frame: time since recording start and the source row it follows
    (-1 beyond the source's end); plus the mode ('index' or 'time')."""
    i = np.arange(n_out)
    out_fps = out_fps if out_fps and math.isfinite(out_fps) and out_fps > 0 else src_fps
    t = i / out_fps if out_fps and out_fps > 0 else i.astype(float)
    if src_fps and out_fps and abs(out_fps - src_fps) > SAME_FPS_RTOL * src_fps:
        k, mode = np.rint(t * src_fps).astype(int), "time"
    else:
        k, mode = i.copy(), "index"
    k[k >= n_src] = -1
    return t, k, mode


# --------------------------------------------------------------------------- statistics
def _f(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def stats(values: np.ndarray) -> dict[str, Any]:
    """mean, std (population), max and count of the finite values; None when there are none."""
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": None, "std": None, "max": None, "n": 0}
    return {"mean": _f(v.mean()), "std": _f(v.std()), "max": _f(v.max()), "n": int(v.size)}


def _frame_mean(err: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Per-frame mean over joints where ok; NaN where no joint is compared (no warnings)."""
    cnt = ok.sum(axis=1)
    tot = np.where(ok, err, 0.0).sum(axis=1)
    out = np.full(err.shape[0], np.nan)
    np.divide(tot, cnt, out=out, where=cnt > 0)
    return out


def by_image_side(ref: Track, est: Track, joint_names: Sequence[str]) -> tuple[Track, np.ndarray]:
    """`est` with left/right swapped in the frames where it faces the other way from `ref`
    (module docstring); (relabelled track, which frames were swapped)."""
    perm = mirror_permutation(joint_names)
    xy, ok = est.xy.copy(), est.ok.copy()
    swapped = np.zeros(est.n, dtype=bool)
    for i in range(min(ref.n, est.n)):
        r = np.where(ref.ok[i][:, None], ref.xy[i], np.nan)
        o = np.where(est.ok[i][:, None], est.xy[i], np.nan)
        if faces_opposite(r, o, joint_names):
            xy[i], ok[i], swapped[i] = est.xy[i][perm], est.ok[i][perm], True
    return replace(est, xy=xy, ok=ok), swapped


def joint_frame_counts(ref: Track, est: Track) -> dict[str, int]:
    """What the joint error leaves out, in joint-frames (the same rule for every clip): where the
    source's subject is framed (some joint has a target) but this joint has none (out of the
    source's frame, or unseen for longer than the smoother bridges), and where the source has a
    target but the compared side does not see the joint (out of the output's frame)."""
    framed = ref.ok.any(axis=1)[:, None] & est.available[:, None]
    return {"joint_frames_compared": int((ref.ok & est.ok).sum()),
            "joint_frames_without_target": int((framed & ~ref.ok).sum()),
            "joint_frames_target_unseen": int((ref.ok & est.available[:, None] & ~est.ok).sum())}


def compare_joints(ref: Track, est: Track, joint_names: Sequence[str]) -> tuple[dict[str, Any], np.ndarray]:
    """Joint error of `est` against `ref` (same timeline), left/right by image side:
    (summary, per-frame mean Euclidean error)."""
    by_name = est
    est, swapped = by_image_side(ref, est, joint_names)
    both = ref.ok & est.ok
    d = np.abs(est.xy - ref.xy)  # (N, E, 2)
    eu = np.sqrt((d ** 2).sum(axis=2))
    per_joint = {}
    for e, name in enumerate(joint_names):
        m = both[:, e]
        per_joint[name] = {"x": stats(d[m, e, 0]), "y": stats(d[m, e, 1]), "euclidean": stats(eu[m, e])}
    overall = {"x": stats(d[..., 0][both]), "y": stats(d[..., 1][both]), "euclidean": stats(eu[both])}
    n_frames = int(both.any(axis=1).sum())
    named = ref.ok & by_name.ok
    overall["euclidean_by_name"] = stats(np.linalg.norm(by_name.xy - ref.xy, axis=2)[named])
    summary = {"per_joint": per_joint, "overall": overall, "frames_compared": n_frames,
               "frames_by_image_side": int((swapped & both.any(axis=1)).sum()),
               "frames_reference_seen": int(ref.ok.any(axis=1).sum()),
               "frames_compared_seen": int(est.ok.any(axis=1).sum()), **joint_frame_counts(ref, est)}
    return summary, _frame_mean(eu, both)


def compare_focus(ref: Track, est: Track, unreachable: np.ndarray | None = None) -> dict[str, Any]:
    """Per region: agreement of the in-focus booleans where the region is present on both sides
    (raw, and over the frames where the asked label was within the lens's reach: `unreachable`
    (N, 3) marks the others), agreement of presence where both sides have data, and error of the
    focused fraction."""
    out: dict[str, Any] = {}
    avail = ref.available & est.available
    if unreachable is None:
        unreachable = np.zeros((ref.n, 3), bool)
    for r, name in enumerate(REGIONS):
        both = avail & ref.present[:, r] & est.present[:, r]
        n = int(both.sum())
        agree = (ref.focus_in[both, r] == est.focus_in[both, r]).mean() if n else float("nan")
        reach = both & ~unreachable[:, r]
        n_reach = int(reach.sum())
        agree_reach = (ref.focus_in[reach, r] == est.focus_in[reach, r]).mean() if n_reach else float("nan")
        n_av = int(avail.sum())
        pres_agree = (ref.present[avail, r] == est.present[avail, r]).mean() if n_av else float("nan")
        fe = np.abs(est.frac[both, r] - ref.frac[both, r])
        out[name] = {"agreement": _f(agree), "n_frames": n,
                     "agreement_reachable": _f(agree_reach), "n_frames_reachable": n_reach,
                     "n_frames_unreachable": n - n_reach,
                     "present_reference": int((avail & ref.present[:, r]).sum()),
                     "present_compared": int((avail & est.present[:, r]).sum()),
                     "presence_agreement": _f(pres_agree),
                     "in_focus_reference": int((both & ref.focus_in[:, r]).sum()),
                     "in_focus_compared": int((both & est.focus_in[:, r]).sum()),
                     "fraction_error": stats(fe)}
    return out


# --------------------------------------------------------------------------- goals
@dataclass(frozen=True)
class Goal:
    id: str
    label: str
    measure: str  # 'extraction' | 'truth'
    op: str  # '<=' | '>='
    threshold: float

    def judge(self, value: float | None) -> str:
        if value is None or not math.isfinite(value):
            return "n/a"
        ok = value <= self.threshold if self.op == "<=" else value >= self.threshold
        return "met" if ok else "missed"


def goals() -> list[Goal]:
    g = [Goal("extraction_joint_error", "mean joint error (extraction)", "extraction", "<=",
              EXTRACTION_JOINT_ERROR_MAX)]
    g += [Goal(f"extraction_focus_{r}", f"focus agreement, {r} (extraction, reachable frames)", "extraction", ">=",
               EXTRACTION_FOCUS_AGREEMENT_MIN) for r in REGIONS]
    g += [Goal("truth_joint_error", "mean joint error (ground truth)", "truth", "<=", TRUTH_JOINT_ERROR_MAX)]
    g += [Goal(f"truth_focus_{r}", f"focus agreement, {r} (ground truth, reachable frames)", "truth", ">=",
               TRUTH_FOCUS_AGREEMENT_MIN) for r in REGIONS]
    return g


def judge_goals(measures: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for g in goals():
        m = measures.get(g.measure) or {}
        if g.id.endswith("joint_error"):
            value = ((m.get("joints") or {}).get("overall") or {}).get("euclidean", {}).get("mean")
        else:
            region = g.id.rsplit("_", 1)[1]
            value = ((m.get("focus") or {}).get(region) or {}).get("agreement_reachable")
        status = g.judge(value) if m.get("available") else "n/a"
        out.append({"id": g.id, "label": g.label, "measure": g.measure, "op": g.op, "threshold": g.threshold,
                    "value": value, "status": status})
    return out


# --------------------------------------------------------------------------- everything
@dataclass(frozen=True, eq=False)
class Fidelity:
    """JSON-ready numbers plus the aligned per-frame series for the figures."""

    summary: dict[str, Any]
    series: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Aligned:
    """The output timeline against the source's rows and the three sides' tracks on it: what the
    side-by-side video draws, known before any goal is judged (`align`)."""

    t: np.ndarray  # (n,) output time [s] of each compared frame
    k: np.ndarray  # (n,) source row of each compared frame
    mode: str  # how the rows were aligned (align_rows)
    n_out: int  # frames on the output timeline (compared or not)
    keep: np.ndarray  # (n_out,) the output frames compared (those with a source row)
    src_full: Track  # the source's every row
    src: Track
    out: Track
    truth: Track
    kept_truths: list  # the GroundTruth (or None) of each compared frame
    src_fps: float
    output_fps: float
    joint_names: list[str]
    first_frame: int  # the source's first frame

    def series(self) -> dict[str, Any]:
        """The series the side-by-side video and the frame picks read (`compute_fidelity`'s series
        begins with the same objects)."""
        return {"t_s": self.t, "k": self.k, "joint_names": self.joint_names, "source_first_frame": self.first_frame,
                "source": self.src, "extraction": self.out, "truth": self.truth}


def align(source: M.Instructions, output: M.Instructions | None, truths: Sequence[M.GroundTruth] = (), *,
          output_fps: float | None = None, output_frames: int | None = None) -> Aligned:
    """The output timeline and the source, extraction and truth tracks on it (`compute_fidelity`'s
    first half: no goal, no focus reach)."""
    joint_names = list(source.joint_names)
    E = len(joint_names)
    src_full = instructions_track(source, joint_names)
    src_fps = float(source.fps) if source.fps and source.fps > 0 else float("nan")
    if output_fps is None or not (output_fps > 0):
        output_fps = float(output.fps) if output is not None and output.fps > 0 else src_fps
    truths = list(truths)
    n_candidates = [0]
    if output is not None:
        n_candidates.append(int(output.first_frame) + int(np.asarray(output.image_targets).shape[0]))
    if truths:
        off = truth_frame_offset(truths)
        n_candidates.append(max(int(t.frame_index) for t in truths) - off + 1)
    if output_frames is not None and output_frames > 0:
        n_candidates.append(int(output_frames))
    n_out = max(n_candidates)
    t, k, mode = align_rows(n_out, output_fps, src_full.n, src_fps)
    keep = k >= 0  # compare over the common length only
    t, k = t[keep], k[keep]
    n = int(keep.sum())
    src = src_full.take(k)
    out_tr = output_track(output, joint_names, n_out).take(np.flatnonzero(keep)) if output is not None \
        else empty_track(n, E)
    tru_tr = truth_track(truths, joint_names, n_out).take(np.flatnonzero(keep)) if truths else empty_track(n, E)
    by_frame = RF.truths_by_frame(truths, n_out, truth_frame_offset(truths)) if truths else [None] * n_out
    kept_truths = [by_frame[i] for i in np.flatnonzero(keep)]
    return Aligned(t=t, k=k, mode=mode, n_out=n_out, keep=keep, src_full=src_full, src=src, out=out_tr,
                   truth=tru_tr, kept_truths=kept_truths, src_fps=src_fps, output_fps=output_fps,
                   joint_names=joint_names, first_frame=int(source.first_frame))


def compute_fidelity(source: M.Instructions, output: M.Instructions | None,
                     truths: Sequence[M.GroundTruth] = (), *, output_fps: float | None = None,
                     output_frames: int | None = None, output_missing_reason: str = "",
                     reach_memo: RF.Memo | None = None,
                     lens_rates: FR.LensRates | None = None, aligned: Aligned | None = None) -> Fidelity:
    """Compare the output (extraction and/or truth) with the source instructions.

    `output_fps` defaults to the output extraction's fps, else the source's. The output timeline
    is as long as the longest of `output_frames` (e.g. the recorded video's frame count), the
    output extraction and the truths. `reach_memo`: the focus-reach verdicts of frames judged
    before (reach_frames.reach), shared by the calls of one report. `lens_rates`: the vehicle's lens
    rates, to excuse the misses they force round a switch of the focus labels (reach_frames).
    `aligned`: `align` of the same arguments, when the caller has it already.
    """
    joint_names = list(source.joint_names)
    truths = list(truths)
    a = aligned if aligned is not None else align(source, output, truths, output_fps=output_fps,
                                                  output_frames=output_frames)
    t, mode, n_out, n = a.t, a.mode, a.n_out, int(a.keep.sum())
    src_full, src, out_tr, tru_tr, kept_truths = a.src_full, a.src, a.out, a.truth, a.kept_truths
    src_fps, output_fps = a.src_fps, a.output_fps
    # the extraction's regions are judged where the truth has none but kept the band's depths (focus_misses)
    reach = RF.reach(src.focus_in, src.present & tru_tr.present, kept_truths, reach_memo, rates=lens_rates,
                     also=src.present & out_tr.present & tru_tr.available[:, None])

    measures: dict[str, Any] = {}
    errs: dict[str, np.ndarray] = {}
    for name, tr, have, why in (
            ("extraction", out_tr, output is not None,
             output_missing_reason or "no output style (extraction on the output video failed or was skipped)"),
            ("truth", tru_tr, bool(truths), "no ground truth recorded")):
        if have and not tr.available.any():
            have, why = False, f"{name} data do not overlap the source instructions in time"
        if have:
            js, err = compare_joints(src, tr, joint_names)
            measures[name] = {"available": True, "reason": None, "frames": int(tr.available.sum()),
                              "joints": js, "focus": compare_focus(src, tr, reach.unreachable)}
        else:
            err = np.full(n, np.nan)
            measures[name] = {"available": False, "reason": why, "frames": 0, "joints": None, "focus": None}
        errs[name] = err

    misses = {name: FM.explain(src, tr, tru_tr, reach, kept_truths, name)
              for name, tr in (("truth", tru_tr), ("extraction", out_tr)) if measures[name]["available"]}
    goal_list = judge_goals(measures)
    n_met = sum(g["status"] == "met" for g in goal_list)
    n_judged = sum(g["status"] != "n/a" for g in goal_list)
    alignment = {"mode": mode, "source_fps": _f(src_fps), "output_fps": _f(output_fps),
                 "source_frames": src_full.n, "output_frames": n_out, "compared_frames": n,
                 "compared_duration_s": _f(n / output_fps) if output_fps and output_fps > 0 else None,
                 "output_extraction_frames": (int(np.asarray(output.image_targets).shape[0])
                                              if output is not None else 0),
                 "truth_frames": len(truths)}

    def _headline(name: str) -> dict[str, Any]:
        m = measures[name]
        if not m["available"]:
            return {"available": False, "reason": m["reason"]}
        return {"available": True, "joint_error_mean": m["joints"]["overall"]["euclidean"]["mean"],
                "joint_error_std": m["joints"]["overall"]["euclidean"]["std"],
                "frames_by_image_side": m["joints"]["frames_by_image_side"],
                "joint_error_by_name": m["joints"]["overall"]["euclidean_by_name"]["mean"],
                "focus_agreement": {r: m["focus"][r]["agreement"] for r in REGIONS},
                "focus_agreement_reachable": {r: m["focus"][r]["agreement_reachable"] for r in REGIONS}}

    headline = {"goals_met": f"{n_met}/{n_judged}", "extraction": _headline("extraction"),
                "truth": _headline("truth"), "goals": {g["id"]: g["status"] for g in goal_list}}
    summary = {"joint_names": joint_names, "regions": list(REGIONS), "alignment": alignment,
               "focus_reach": {"frames_judged": int(reach.judged.sum()),
                               "unreachable_frames": {r: int(reach.unreachable[:, i].sum())
                                                      for i, r in enumerate(REGIONS)},
                               "rate_windows": RF.window_rows(reach, t)},
               "focus_misses": {name: FM.counts(m) for name, m in misses.items()},
               "extraction": measures["extraction"], "truth": measures["truth"], "goals": goal_list,
               "headline": headline}
    series = {**a.series(),
              "source_full": src_full, "source_t_full": np.arange(src_full.n) / src_fps if src_fps > 0
              else np.arange(src_full.n, dtype=float),
              "error_extraction": errs["extraction"], "error_truth": errs["truth"],
              "have_extraction": measures["extraction"]["available"], "have_truth": measures["truth"]["available"],
              "reach": reach, "misses": misses}
    return Fidelity(summary, series)
