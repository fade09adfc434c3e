"""The frames of a simulated run where the source's focus label was out of any lens's reach.

Per compared output frame and region: the label the source asks (its `focus_in`), the region's
depths and the filmed focal length from the simulator's truth (`GroundTruth.region_inverse_depth`,
`focal_length_mm`, `lens_limits`), judged by focus_reach.unreachable_labels. Frames whose truth
predates those fields (an older recording) are never called unreachable.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from cinetransfer.report import focus_reach as FR
from cinetransfer.shared import messages as M


@dataclass(frozen=True, eq=False)
class Reach:
    """Per frame of the compared timeline and region: unreachable, and why ('' when reachable)."""

    unreachable: np.ndarray  # (N, 3) bool
    reasons: np.ndarray  # (N, 3) object (str)
    judged: np.ndarray  # (N,) the frame had what the judgement needs (truth with depths and lens)

    @classmethod
    def none(cls, n: int) -> "Reach":
        return cls(np.zeros((n, 3), bool), np.full((n, 3), "", dtype=object), np.zeros(n, bool))


def _lens_of(t: M.GroundTruth) -> FR.Lens | None:
    lim = np.asarray(t.lens_limits, dtype=float)
    inv = np.asarray(t.region_inverse_depth)
    if lim.shape != (4,) or not np.isfinite(lim).all() or not np.isfinite(t.focal_length_mm) \
            or inv.ndim != 2 or inv.shape[1] == 0:
        return None
    return FR.Lens(float(t.focal_length_mm), (float(lim[0]), float(lim[1])), (float(lim[2]), float(lim[3])))


def truths_by_frame(truths: Sequence[M.GroundTruth], n: int, offset: int) -> list[M.GroundTruth | None]:
    """The truth of each output frame 0..n-1 (the first one of duplicates), as fidelity.truth_track."""
    out: list[M.GroundTruth | None] = [None] * n
    for t in truths:
        i = int(t.frame_index) - offset
        if 0 <= i < n and out[i] is None:
            out[i] = t
    return out


#: a frame's verdicts by what they are computed from (`frame_key`): see `reach`'s `memo`
Memo = dict[tuple, list[FR.Unreachable]]


def frame_key(lens: FR.Lens, asked: np.ndarray, present: np.ndarray, inv_depth: np.ndarray) -> tuple:
    """Everything `unreachable_labels` reads of one frame, as a dictionary key (exact values)."""
    return (lens, np.asarray(asked, bool).tobytes(), np.asarray(present, bool).tobytes(), inv_depth.shape,
            inv_depth.tobytes())


def reach(asked: np.ndarray, present: np.ndarray, truths: Sequence[M.GroundTruth | None],
          memo: Memo | None = None) -> Reach:
    """Reach of the asked labels `asked` (N, 3) where `present` (N, 3) (the region present on both
    sides), one truth (or None) per frame. `memo`: verdicts of frames judged before (filled here),
    so that one report judges each frame once (its shots compare the same frames again)."""
    n = len(truths)
    out = Reach.none(n)
    for i, t in enumerate(truths):
        lens = _lens_of(t) if t is not None else None
        if lens is None:
            continue
        out.judged[i] = True
        if not present[i].any():
            continue
        inv = np.asarray(t.region_inverse_depth, float)
        key = frame_key(lens, asked[i], present[i], inv) if memo is not None else None
        found = memo.get(key) if key is not None else None
        if found is None:
            found = FR.unreachable_labels(lens, asked[i], present[i], inv)
            if key is not None:
                memo[key] = found
        for u in found:
            out.unreachable[i, u.region] = True
            out.reasons[i, u.region] = u.reason
    return out


def runs(rch: Reach, t_s: np.ndarray, rows: np.ndarray, shot_rows: Sequence[int] = ()) -> list[dict[str, Any]]:
    """Consecutive unreachable frames per region (and shot) as report rows: region, shot (by the
    source row `rows` each frame follows; `shot_rows`: the first row of every shot after the first),
    first and last output frame, frames, time span, and the reason at its first and last frame."""
    bounds = [0, *sorted(int(r) for r in shot_rows)]
    out = []
    for r, name in enumerate(FR.REGIONS):
        idx = np.flatnonzero(rch.unreachable[:, r])
        if idx.size == 0:
            continue
        shot = np.searchsorted(bounds, np.asarray(rows)[idx], side="right") - 1
        cut = np.flatnonzero((np.diff(idx) > 1) | (np.diff(shot) != 0)) + 1
        for seg in np.split(np.arange(idx.size), cut):
            a, b = int(idx[seg[0]]), int(idx[seg[-1]])
            first, last = str(rch.reasons[a, r]), str(rch.reasons[b, r])
            out.append({"region": name, "shot": int(shot[seg[0]]), "first_frame": a, "last_frame": b,
                        "frames": int(seg.size), "t_s": [float(t_s[a]), float(t_s[b])],
                        "reason": first, "reason_last": last if last != first else None})
    return out
