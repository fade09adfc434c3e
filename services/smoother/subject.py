"""Main subject: exact selection by dynamic programming, then the box-constrained box QP.

The paper's step 1 (DESIGN §1.1) mixes a discrete choice (which detection is the subject in
each frame, the alphas) with a continuous fit (the box R_f), which makes it bilinear and
non-convex. We split it:

1. Selection. A path picks, in every frame, one detection or "not visible". Its cost is

       sum over frames:  confidence_cost * (1 - c)          at a detection
                         miss_cost                          where the subject is not visible
       sum over steps:   move_cost * max(0, d - free_move g)^2 / g
                                                            between detections g <= G frames apart
                                                            (g > 1: a bridged dropout)
                         reentry_cost                       re-appearing after an absence of more
                                                            than G - 1 frames (identity not checked)

   where d = |r_j - r_i| / s is the change of the box 4-vector relative to the mean diagonal s
   of the two boxes (scale-free), or 1 - IoU with continuity='iou'. Moving a distance d in g
   frames at constant speed costs g (d/g)^2 = d^2/g, so a dropout is judged by the implied
   speed. The path with the fewest invisible frames and the smoothest identity is the person
   present in most frames, continuously. Minimised exactly by dynamic programming over frames
   (Viterbi with skip transitions for dropouts of up to `max_bridge_s`, G = 1 + that in frames,
   and an 'absent' chain for longer absences); tests/unit/test_smoother_core.py checks it against
   brute-force enumeration.

2. Box. Per box coordinate, min sum c_f (R_f - r_f)^2 + lam (R_f - R_{f-1})^2
   + lam2 (R_{f+1} - 2 R_f + R_{f-1})^2 over the visible runs, with R_f inside the image: the QP
   of `qp.smooth` (bridged frames have weight 0; lam2 = 0 is the paper's form).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cinetransfer.services.smoother import qp
from cinetransfer.services.smoother.features import FrameFeatures



@dataclass(frozen=True, eq=False)
class Selection:
    """Result of the selection step (per frame)."""

    person: np.ndarray  # (F,) index into that frame's people, -1 = none (invisible or bridged)
    visible: np.ndarray  # (F,) bool: subject visible (detected or bridged dropout)
    bridged: np.ndarray  # (F,) bool: visible but not detected (a bridged dropout)
    cost: float  # optimal path cost


def select_subject(feats: list[FrameFeatures], *, fps: float, move_cost: float = 100.0, miss_cost: float = 1.0,
                   confidence_cost: float = 0.2, max_bridge_s: float = 0.5, free_move: float = 0.0,
                   continuity: str = "box", reentry_cost: float = 2.0, cuts: np.ndarray | None = None) -> Selection:
    """Viterbi over each frame's candidates plus 'not visible' (exact minimiser of the cost above)."""
    F = len(feats)
    G = 1 + max(0, int(round(max_bridge_s * fps)))  # longest step between detections (frames)
    counts = np.array([f.n_people for f in feats], dtype=int)
    start = np.concatenate([[0], np.cumsum(counts)])
    N = int(start[-1])
    if N == 0:
        return Selection(np.full(F, -1), np.zeros(F, bool), np.zeros(F, bool), F * miss_cost)
    boxes = np.concatenate([f.boxes for f in feats if f.n_people]).astype(float)
    conf = np.concatenate([f.conf for f in feats if f.n_people]).astype(float)
    frame_of = np.repeat(np.arange(F), counts)
    diag = np.hypot(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1])
    emit = confidence_cost * (1.0 - np.clip(conf, 0.0, 1.0))

    # Every step between detections g = 1..G frames apart, as one (P_f, M_f) cost matrix per
    # frame f (P_f = detections in frames f-G..f-1, M_f = detections in frame f), built at once.
    fr = np.arange(F)
    pa_f = start[np.maximum(0, fr - G)]
    a_f, b_f = start[:-1], start[1:]
    P_f, M_f = a_f - pa_f, b_f - a_f
    n_f = P_f * M_f
    off = np.concatenate([[0], np.cumsum(n_f)])
    rep = np.repeat(fr, n_f)
    local = np.arange(int(off[-1])) - off[rep]
    msafe = np.maximum(M_f, 1)[rep]
    src = pa_f[rep] + local // msafe
    dst = a_f[rep] + local % msafe
    g = (frame_of[dst] - frame_of[src]).astype(float)
    d2 = np.zeros(src.size)
    for k in range(4):
        d2 += (boxes[src, k] - boxes[dst, k]) ** 2
    s = 0.5 * (diag[src] + diag[dst])
    if continuity == "iou":
        bs, bd = boxes[src], boxes[dst]
        iw = np.clip(np.minimum(bs[:, 2], bd[:, 2]) - np.maximum(bs[:, 0], bd[:, 0]), 0, None)
        ih = np.clip(np.minimum(bs[:, 3], bd[:, 3]) - np.maximum(bs[:, 1], bd[:, 1]), 0, None)
        inter = iw * ih
        area = lambda b: (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])  # noqa: E731
        d = 1.0 - inter / np.maximum(area(bs) + area(bd) - inter, 1e-9)
    else:
        d = np.sqrt(d2) / np.maximum(s, 1e-9)  # box change relative to the box size
    excess = np.maximum(d - free_move * g, 0.0)  # ordinary motion and jitter are free
    if cuts is not None and np.any(cuts):
        # Across a cut the subject may appear anywhere in the new shot: no continuity cost.
        shot = np.cumsum(np.asarray(cuts, dtype=int))
        excess = np.where(shot[frame_of[dst]] != shot[frame_of[src]], 0.0, excess)
    step_cost = (g - 1.0) * miss_cost + move_cost * excess ** 2 / g

    D = np.full(N, np.inf)  # best cost of a path ending at detection i (frames up to and incl. its frame)
    back = np.full(N, -1, dtype=np.int64)  # predecessor detection, or -1 = fresh start, -2 = re-entry
    # R: best cost of a path that was visible and has been invisible for at least G frames up to
    # frame f-1 (longer than any bridge), so that it may re-appear at f without a continuity check.
    R = math.inf
    r_back = np.full(F + 1, -1, dtype=np.int64)  # detection the absence at frame f started from; -1 = continued
    a_l, b_l, pa_l, off_l = a_f.tolist(), b_f.tolist(), pa_f.tolist(), off.tolist()
    emit_l = emit.tolist()
    for f in range(F):
        # Update R for frame f: the absence continues, or began after a detection of frame f-G-1.
        R += miss_cost
        f0 = f - G - 1
        if f0 >= 0 and b_l[f0] > a_l[f0]:
            p0, p1 = a_l[f0], b_l[f0]
            i0 = p0 if p1 - p0 == 1 else p0 + int(np.argmin(D[p0:p1]))
            cand = float(D[i0]) + G * miss_cost
            if cand < R:
                R, r_back[f] = cand, i0
        a, b = a_l[f], b_l[f]
        m = b - a
        if not m:
            continue
        # Fresh start (all earlier frames invisible), re-entry after an absence, or a step.
        fresh = f * miss_cost
        base, arg0 = (R + reentry_cost, -2) if R + reentry_cost < fresh else (fresh, -1)
        pa = pa_l[f]
        if a > pa and m == 1:
            tot = D[pa:a] + step_cost[off_l[f]:off_l[f + 1]]
            k = int(tot.argmin())
            v = float(tot[k])
            if v < base:
                D[a], back[a] = v + emit_l[a], pa + k
            else:
                D[a], back[a] = base + emit_l[a], arg0
        elif a > pa:
            tot = D[pa:a, None] + step_cost[off_l[f]:off_l[f + 1]].reshape(a - pa, m)
            k = tot.argmin(axis=0)
            v = tot[k, np.arange(m)]
            better = v < base
            D[a:b] = np.where(better, v, base) + emit[a:b]
            back[a:b] = np.where(better, pa + k, arg0)
        else:
            D[a:b] = base + emit[a:b]
            back[a:b] = arg0
    # End: never visible, or at a detection with the remaining frames invisible.
    ends = D + (F - 1 - frame_of) * miss_cost
    i_end = int(np.argmin(ends))
    total = min(F * miss_cost, float(ends[i_end]))
    person = np.full(F, -1)
    visible = np.zeros(F, dtype=bool)
    bridged = np.zeros(F, dtype=bool)
    if F * miss_cost <= float(ends[i_end]):
        return Selection(person, visible, bridged, total)
    i = i_end
    while i >= 0:
        f = int(frame_of[i])
        person[f] = i - start[f]
        visible[f] = True
        j = int(back[i])
        if j >= 0:
            fj = int(frame_of[j])
            visible[fj + 1:f] = True
            bridged[fj + 1:f] = True
            i = j
        elif j == -2:
            g = f
            while r_back[g] == -1:
                g -= 1
            i = int(r_back[g])
        else:
            break
    return Selection(person, visible, bridged, float(total))


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of boxes b (M, 4) with box a (4,)."""
    iw = np.clip(np.minimum(a[2], b[:, 2]) - np.maximum(a[0], b[:, 0]), 0, None)
    ih = np.clip(np.minimum(a[3], b[:, 3]) - np.maximum(a[1], b[:, 1]), 0, None)
    inter = iw * ih
    ua = (a[2] - a[0]) * (a[3] - a[1]) + (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]) - inter
    return inter / np.maximum(ua, 1e-9)


def extend_runs(feats: list[FrameFeatures], sel: Selection, *, min_iou: float = 0.5) -> Selection:
    """Give frames the path left out (fast motion or a shape change made them costlier than a
    miss) the detection that overlaps the neighbouring chosen box by at least `min_iou`, when
    it is the only such detection: forwards, then backwards. Identity is kept: a detection of
    another person rarely overlaps the subject's previous box that much, and never uniquely in
    a crowd."""
    person = sel.person.copy()
    F = len(feats)

    def grow(order: range, prev_of: int) -> None:
        for f in order:
            p = f + prev_of
            if person[f] >= 0 or not 0 <= p < F or person[p] < 0 or feats[f].n_people == 0:
                continue
            ov = _iou(feats[p].boxes[person[p]], feats[f].boxes)
            ok = np.flatnonzero(ov >= min_iou)
            if ok.size == 1:
                person[f] = int(ok[0])

    grow(range(1, F), -1)
    grow(range(F - 2, -1, -1), +1)
    if np.array_equal(person, sel.person):
        return sel
    det = person >= 0
    visible = sel.visible | det
    # Re-bridge: short gaps between detections stay visible, as in the selection.
    return Selection(person, visible, visible & ~det, sel.cost)


def smooth_box(feats: list[FrameFeatures], sel: Selection, *, lam: float, width: int,
               height: int, lam2: float = 0.0, cuts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Raw and smoothed main-subject boxes, (F, 4) px each; NaN where not visible / not detected."""
    F = len(feats)
    raw = np.full((F, 4), np.nan)
    w = np.zeros((F, 4))
    for f, k in enumerate(sel.person):
        if k >= 0:
            raw[f] = feats[f].boxes[k]
            w[f] = max(float(feats[f].conf[k]), 1e-3)
    if F == 0:
        return raw, raw.copy()
    link = sel.visible[:-1] & sel.visible[1:]
    if cuts is not None:
        link &= ~np.asarray(cuts, dtype=bool)[1:]  # never smooth from one shot into the next
    hi = np.array([width, height, width, height], dtype=float)
    res = qp.smooth(raw, w, lam, lo=0.0, hi=hi, link=link, lam2=lam2)
    out = np.where(sel.visible[:, None], res.x, np.nan)
    return raw, out
