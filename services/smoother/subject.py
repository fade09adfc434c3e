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
                         track_switch_cost                  between detections of two different
                                                            detector tracks (track_id >= 0); x LEAVE_FACTOR
                                                            if the track left is still in the later frame

   where d = |r_j - r_i| / s is the change of the box 4-vector relative to the mean diagonal s
   of the two boxes (scale-free), or 1 - IoU with continuity='iou'; along one detector track d is
   scaled by same_track_move (the tracker's word that it is one person outweighs box jitter).
   Moving a distance d in g frames at constant speed costs g (d/g)^2 = d^2/g, so a dropout is
   judged by the implied speed. The path with the fewest invisible frames and the smoothest identity is the person
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
from cinetransfer.services.smoother.shots import shot_index

# Detector track ids (the box-first backend's tracker follows each person by motion): a step along
# one track counts its box change at SAME_TRACK_MOVE x, a step from one track to another costs
# TRACK_SWITCH_COST more, LEAVE_FACTOR x that when the track left is still there in the frame
# stepped to (a deliberate change of person, not a track that ended). Measured on TUD-Stadtmitte
# (eval_smoother_box.py): purity 1.0 with no switch for switch costs 2-10 with same-track factors
# 0.1-0.5; without the track terms the path crossed from one walker to another through a box that
# merged both (purity 0.65), and so it did with a same-track factor of 1 or without LEAVE_FACTOR
# at some of these settings.
TRACK_SWITCH_COST = 5.0
SAME_TRACK_MOVE = 0.25
LEAVE_FACTOR = 4.0


@dataclass(frozen=True, eq=False)
class Selection:
    """Result of the selection step (per frame)."""

    person: np.ndarray  # (F,) index into that frame's people, -1 = none (invisible or bridged)
    visible: np.ndarray  # (F,) bool: subject visible (detected or bridged dropout)
    bridged: np.ndarray  # (F,) bool: visible but not detected (a bridged dropout)
    cost: float  # optimal path cost


@dataclass(frozen=True, eq=False)
class _Candidates:
    """Every frame's detections, flattened: detection i is person i - start[f] of frame frame_of[i]."""

    start: np.ndarray  # (F+1,) first flat index of each frame's detections
    frame_of: np.ndarray  # (N,) frame of each detection
    boxes: np.ndarray  # (N, 4)
    emit: np.ndarray  # (N,) confidence cost of choosing the detection
    track: np.ndarray  # (N,) detector track id, -1 = none


def _candidates(feats: list[FrameFeatures], confidence_cost: float) -> _Candidates:
    counts = np.array([f.n_people for f in feats], dtype=int)
    start = np.concatenate([[0], np.cumsum(counts)])
    with_people = [f for f in feats if f.n_people]
    boxes = np.concatenate([f.boxes for f in with_people]).astype(float) if with_people else np.zeros((0, 4))
    conf = np.concatenate([f.conf for f in with_people]).astype(float) if with_people else np.zeros(0)
    track = np.concatenate([_tracks(f) for f in with_people]) if with_people else np.zeros(0, dtype=np.int64)
    ok = track >= 0
    if ok.any():  # ids 0..n-1 in order (any id a detector sends: keys frame * n + id stay small)
        track = track.copy()
        track[ok] = np.unique(track[ok], return_inverse=True)[1]
    return _Candidates(start, np.repeat(np.arange(len(feats)), counts), boxes,
                       confidence_cost * (1.0 - np.clip(conf, 0.0, 1.0)), track)


def _tracks(f: FrameFeatures) -> np.ndarray:
    t = np.asarray(f.track, dtype=np.int64)
    return t if t.shape == (f.n_people,) else np.full(f.n_people, -1, dtype=np.int64)


def _step_pairs(start: np.ndarray, G: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every step between detections g = 1..G frames apart, grouped by the later frame f as one
    (P_f, M_f) block (P_f = detections in frames f-G..f-1, M_f = detections in frame f):
    (src, dst, pa_f = first flat index of frame f-G, off = block offsets)."""
    F = start.size - 1
    fr = np.arange(F)
    pa_f = start[np.maximum(0, fr - G)]
    a_f, b_f = start[:-1], start[1:]
    n_f = (a_f - pa_f) * (b_f - a_f)
    off = np.concatenate([[0], np.cumsum(n_f)])
    rep = np.repeat(fr, n_f)
    local = np.arange(int(off[-1])) - off[rep]
    msafe = np.maximum(b_f - a_f, 1)[rep]
    return pa_f[rep] + local // msafe, a_f[rep] + local % msafe, pa_f, off


def _box_change(bs: np.ndarray, bd: np.ndarray, continuity: str) -> np.ndarray:
    """d of the cost: |box change| / mean box diagonal, or 1 - IoU."""
    if continuity == "iou":
        iw = np.clip(np.minimum(bs[:, 2], bd[:, 2]) - np.maximum(bs[:, 0], bd[:, 0]), 0, None)
        ih = np.clip(np.minimum(bs[:, 3], bd[:, 3]) - np.maximum(bs[:, 1], bd[:, 1]), 0, None)
        inter = iw * ih
        area_s = (bs[:, 2] - bs[:, 0]) * (bs[:, 3] - bs[:, 1])
        area_d = (bd[:, 2] - bd[:, 0]) * (bd[:, 3] - bd[:, 1])
        return 1.0 - inter / np.maximum(area_s + area_d - inter, 1e-9)
    diag = lambda b: np.hypot(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])  # noqa: E731
    s = 0.5 * (diag(bs) + diag(bd))
    return np.linalg.norm(bs - bd, axis=1) / np.maximum(s, 1e-9)


def _step_costs(c: _Candidates, src: np.ndarray, dst: np.ndarray, *, move_cost: float, miss_cost: float,
                free_move: float, continuity: str, track_switch_cost: float, same_track_move: float,
                cuts: np.ndarray | None) -> np.ndarray:
    """Cost of every step src -> dst: the frames skipped, the box change beyond free motion and,
    between two different detector tracks, `track_switch_cost`."""
    g = (c.frame_of[dst] - c.frame_of[src]).astype(float)
    excess = np.maximum(_box_change(c.boxes[src], c.boxes[dst], continuity) - free_move * g, 0.0)
    tracked = (c.track[src] >= 0) & (c.track[dst] >= 0)
    switch = tracked & (c.track[src] != c.track[dst])
    excess = np.where(tracked & ~switch, same_track_move * excess, excess)
    if cuts is not None and np.any(cuts):
        # Across a cut the subject may appear anywhere in the new shot: no continuity cost.
        shot = shot_index(cuts, len(cuts))
        across = shot[c.frame_of[dst]] != shot[c.frame_of[src]]
        excess = np.where(across, 0.0, excess)
        switch &= ~across
    # Leaving a person whose track is still there in the destination frame is a deliberate change of
    # person (costlier than taking up a track that has ended): track_switch_cost x LEAVE_FACTOR.
    sw = np.flatnonzero(switch)
    n_ids = int(c.track.max()) + 1
    present = c.frame_of[c.track >= 0] * n_ids + c.track[c.track >= 0]
    alive = np.isin(c.frame_of[dst[sw]] * n_ids + c.track[src[sw]], present)
    extra = np.zeros(src.size)
    extra[sw] = track_switch_cost * np.where(alive, LEAVE_FACTOR, 1.0)
    return (g - 1.0) * miss_cost + move_cost * excess ** 2 / g + extra


def select_subject(feats: list[FrameFeatures], *, fps: float, move_cost: float = 100.0, miss_cost: float = 1.0,
                   confidence_cost: float = 0.2, max_bridge_s: float = 0.5, free_move: float = 0.0,
                   continuity: str = "box", reentry_cost: float = 2.0, cuts: np.ndarray | None = None,
                   track_switch_cost: float = TRACK_SWITCH_COST, same_track_move: float = SAME_TRACK_MOVE) -> Selection:
    """Viterbi over each frame's candidates plus 'not visible' (exact minimiser of the cost above)."""
    F = len(feats)
    c = _candidates(feats, confidence_cost)
    if c.frame_of.size == 0:
        return Selection(np.full(F, -1), np.zeros(F, bool), np.zeros(F, bool), F * miss_cost)
    G = 1 + max(0, int(round(max_bridge_s * fps)))  # longest step between detections (frames)
    src, dst, pa_f, off = _step_pairs(c.start, G)
    step_cost = _step_costs(c, src, dst, move_cost=move_cost, miss_cost=miss_cost, free_move=free_move,
                            continuity=continuity, track_switch_cost=track_switch_cost,
                            same_track_move=same_track_move, cuts=cuts)
    D, back, r_back = _forward(c, step_cost, pa_f, off, G=G, miss_cost=miss_cost, reentry_cost=reentry_cost)
    return _backtrack(c, D, back, r_back, miss_cost)


def _forward(c: _Candidates, step_cost: np.ndarray, pa_f: np.ndarray, off: np.ndarray, *, G: int,
             miss_cost: float, reentry_cost: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Viterbi recursion. D[i]: best cost of a path ending at detection i (frames up to and
    including its frame); back[i]: its predecessor detection, -1 = fresh start, -2 = re-entry;
    r_back[f]: the detection an absence that may end at frame f started from (-1 = continued)."""
    F = c.start.size - 1
    D = np.full(c.frame_of.size, np.inf)
    back = np.full(c.frame_of.size, -1, dtype=np.int64)
    # R: best cost of a path that was visible and has been invisible for at least G frames up to
    # frame f-1 (longer than any bridge), so that it may re-appear at f without a continuity check.
    R = math.inf
    r_back = np.full(F + 1, -1, dtype=np.int64)
    a_l, pa_l, off_l = c.start[:-1].tolist(), pa_f.tolist(), off.tolist()
    for f in range(F):
        R += miss_cost
        R = _absence_from(D, c.start, f - G - 1, R, G * miss_cost, r_back, f)
        a, b = a_l[f], c.start[f + 1]
        if b == a:
            continue
        # Fresh start (all earlier frames invisible) or re-entry after an absence ...
        fresh = f * miss_cost
        base, arg0 = (R + reentry_cost, -2) if R + reentry_cost < fresh else (fresh, -1)
        D[a:b], back[a:b] = base, arg0
        pa = pa_l[f]
        if a > pa:  # ... or a step from a detection at most G frames back
            tot = D[pa:a, None] + step_cost[off_l[f]:off_l[f + 1]].reshape(a - pa, b - a)
            k = tot.argmin(axis=0)
            v = tot[k, np.arange(b - a)]
            better = v < base
            D[a:b] = np.where(better, v, base)
            back[a:b] = np.where(better, pa + k, arg0)
        D[a:b] += c.emit[a:b]
    return D, back, r_back


def _absence_from(D: np.ndarray, start: np.ndarray, f0: int, R: float, cost: float, r_back: np.ndarray,
                  f: int) -> float:
    """R for frame f: the absence continues, or began after the best detection of frame f0 = f-G-1."""
    if f0 < 0 or start[f0 + 1] == start[f0]:
        return R
    i0 = int(start[f0]) + int(np.argmin(D[start[f0]:start[f0 + 1]]))
    if float(D[i0]) + cost < R:
        r_back[f] = i0
        return float(D[i0]) + cost
    return R


def _backtrack(c: _Candidates, D: np.ndarray, back: np.ndarray, r_back: np.ndarray, miss_cost: float) -> Selection:
    """The best path's detections, bridged and visible frames. It ends never visible, or at a
    detection with the remaining frames invisible."""
    F = c.start.size - 1
    ends = D + (F - 1 - c.frame_of) * miss_cost
    i = int(np.argmin(ends))
    person = np.full(F, -1)
    visible = np.zeros(F, dtype=bool)
    bridged = np.zeros(F, dtype=bool)
    if F * miss_cost <= float(ends[i]):
        return Selection(person, visible, bridged, F * miss_cost)
    total = float(ends[i])
    while i >= 0:
        f = int(c.frame_of[i])
        person[f] = i - c.start[f]
        visible[f] = True
        j = int(back[i])
        if j >= 0:
            fj = int(c.frame_of[j])
            visible[fj + 1:f] = True
            bridged[fj + 1:f] = True
        elif j == -2:
            g = f
            while r_back[g] == -1:
                g -= 1
            j = int(r_back[g])
        i = j
    return Selection(person, visible, bridged, total)


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of boxes b (M, 4) with box a (4,)."""
    iw = np.clip(np.minimum(a[2], b[:, 2]) - np.maximum(a[0], b[:, 0]), 0, None)
    ih = np.clip(np.minimum(a[3], b[:, 3]) - np.maximum(a[1], b[:, 1]), 0, None)
    inter = iw * ih
    ua = (a[2] - a[0]) * (a[3] - a[1]) + (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]) - inter
    return inter / np.maximum(ua, 1e-9)


def extend_runs(feats: list[FrameFeatures], sel: Selection, *, min_iou: float = 0.5,
                cuts: np.ndarray | None = None) -> Selection:
    """Give frames the path left out (fast motion or a shape change made them costlier than a
    miss) the detection that overlaps the neighbouring chosen box by at least `min_iou`, when
    it is the only such detection: forwards, then backwards. Identity is kept: a detection of
    another person rarely overlaps the subject's previous box that much, and never uniquely in
    a crowd. Never across a cut (`cuts[f]`: frame f starts a shot): there the same place in the
    image says nothing about who the subject is."""
    person = sel.person.copy()
    F = len(feats)
    shot = shot_index(cuts, F)

    def grow(order: range, prev_of: int) -> None:
        for f in order:
            p = f + prev_of
            if person[f] >= 0 or not 0 <= p < F or person[p] < 0 or feats[f].n_people == 0 or shot[p] != shot[f]:
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
