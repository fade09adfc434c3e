"""How much of the zoom's hold along the optical axis applies, by how well the subject is framed now.

A camera that zooms in place and moves along its axis reads as a dolly-zoom, so a zoom row holds the
velocity along the axis (`weights.zoom_still`). From a start where the first frame's framing is met
(the subject waiting on his mark) the hold costs nothing; from a start off the source's pose the
framing needs the travel along the axis to catch up, and held there the joint error grew from 0.011
to 0.026 (docs/planner.md, "Zoom held along the axis"). So the hold applies in full while the framing
is settled and gives way linearly as the framing error grows.
"""

from __future__ import annotations

import numpy as np

#: mean image error per joint (normalised units) up to which the hold applies in full
HOLD_FULL_ERROR = 0.010
#: ... and from which it is off: the framing goal is 0.03, the hold must not push the error towards it
HOLD_OFF_ERROR = 0.020


def framing_error_now(seen_xy: np.ndarray, targets_xy: np.ndarray, weights: np.ndarray) -> float:
    """Weighted mean image distance of the joints seen now (E, 2) from their targets (E, 2); NaN where
    no weighted joint is seen (behind the camera or no target)."""
    seen_xy, targets_xy, weights = (np.asarray(a, dtype=float) for a in (seen_xy, targets_xy, weights))
    ok = (weights > 0) & np.all(np.isfinite(seen_xy), axis=1) & np.all(np.isfinite(targets_xy), axis=1)
    if not ok.any():
        return float("nan")
    dist = np.linalg.norm(seen_xy[ok] - targets_xy[ok], axis=1)
    return float(np.sum(weights[ok] * dist) / np.sum(weights[ok]))


def settled_hold_share(error: float, full: float = HOLD_FULL_ERROR, off: float = HOLD_OFF_ERROR) -> float:
    """1 at a framing error up to `full`, 0 from `off` on, linear between; 0 for an unknown error."""
    if not np.isfinite(error):
        return 0.0
    return float(np.clip((off - error) / (off - full), 0.0, 1.0))
