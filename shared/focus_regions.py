"""The three focus regions of a frame, one definition for the style and the simulator's truth.

Image-space, because the style is read from a video that has no depths: the subject is the
subject's pixels; the foreground is the band of rows below the subject's lowest pixel (its feet),
the subject excluded, when that band is at least FOREGROUND_MIN_ROWS of the frame's height; the
background is the rest. With no subject in the frame there is no foreground and the background is
the whole frame.

Whether the band is a foreground is judged once, by `foreground_present`, on the band's height in
the frame's own pixels (from the subject's lowest pixel at full resolution), not in the rows of
whatever grid a side samples its regions on: the truth reads its regions from every 4th rendered
row and the extraction from a focus map of 1/6 the frame's rows, and a threshold rounded up to
whole rows of each grid (5 of 135 rows: 3.7 % of the frame; 3 of 90: 3.3 %) made the two disagree
about the same band of 16-19 px of 540 (parkour, "only the subject sharp", docs/report.md).

The style extraction (services/smoother/features.py) applies it to the detector's mask and focus
map; the simulator's truth (services/autopilot_bridge/sim/backend.py) to the exact subject mask of
its label pass, whose depths then tell which pixels lie inside the depth of field. A band below the
feet on open ground starts at the subject's own depth: docs/report.md says when that makes a label
out of any lens's reach.
"""
from __future__ import annotations

import numpy as np

#: the foreground band exists when it is at least this fraction of the frame's height
FOREGROUND_MIN_ROWS = 0.03


def feet_row(subject: np.ndarray) -> int | None:
    """The first row below the subject's lowest pixel; None when the mask is empty."""
    rows = np.flatnonzero(np.asarray(subject, bool).any(axis=1))
    return int(rows[-1]) + 1 if rows.size else None


def foreground_present(feet_px: float | None, height_px: float, min_share: float = FOREGROUND_MIN_ROWS) -> bool:
    """Whether the band below the feet is a foreground: `feet_px`, the first row below the subject's
    lowest pixel at the frame's full resolution (feet_row of the full-resolution mask), leaves at least
    `min_share` of the frame's `height_px` rows below it."""
    return feet_px is not None and height_px > 0 and height_px - feet_px >= min_share * height_px


def region_masks(subject: np.ndarray | None, feet: int | None, foreground: bool,
                 shape: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(foreground, subject, background) boolean masks on the subject mask's grid; `subject` None (or
    `shape` given with no subject) = no subject in the frame; `feet`: the first row of that grid below the
    subject (feet_row); `foreground`: whether the band is one (foreground_present, judged at full resolution)."""
    if subject is None:
        empty = np.zeros(shape, bool)
        return empty, empty.copy(), np.ones(shape, bool)
    subj = np.asarray(subject, bool)
    fg = np.zeros_like(subj)
    if foreground and feet is not None:
        fg[feet:, :] = True
        fg &= ~subj
    return fg, subj, ~(subj | fg)
