"""Where the source cuts from one shot to the next, from the detector's shot-change scores.

Smoothing across a cut would invent a camera move that no shot had (the box, the joints and
the focus would glide from one shot's framing to the next over several frames). A frame
starts a new shot when its score is both high in absolute terms and an outlier against its
neighbours, which keeps fast pans and focus pulls (scores up to ~0.2 on the bundled clips)
inside their shot while a cut between similar palettes (0.37 in tos_clip01) still counts.
"""
from __future__ import annotations

import numpy as np


def find_cuts(scores: np.ndarray, *, threshold: float = 0.25, ratio: float = 3.0, window: int = 5) -> np.ndarray:
    """cut[f] = True where frame f starts a new shot (never frame 0). NaN scores are never cuts."""
    s = np.asarray(scores, dtype=float)
    F = s.size
    cut = np.zeros(F, dtype=bool)
    for f in np.flatnonzero(np.nan_to_num(s, nan=0.0) >= threshold):
        if f == 0:
            continue
        lo, hi = max(0, f - window), min(F, f + window + 1)
        nb = np.concatenate([s[lo:f], s[f + 1:hi]])
        nb = nb[np.isfinite(nb)]
        local = float(np.median(nb)) if nb.size else 0.0
        cut[f] = s[f] >= ratio * local
    return cut


def shot_index(cut: np.ndarray | None, n: int) -> np.ndarray:
    """(n,) the shot each frame belongs to (0 for the first); all 0 without cuts or when `cut`
    does not have one entry per frame."""
    if cut is None or len(cut) != n:
        return np.zeros(n, dtype=int)
    return np.cumsum(np.asarray(cut, dtype=int))


def segments(cut: np.ndarray) -> list[slice]:
    """The shots as slices of frames [start, stop)."""
    starts = [0, *np.flatnonzero(cut).tolist(), len(cut)]
    return [slice(a, b) for a, b in zip(starts[:-1], starts[1:]) if b > a]
