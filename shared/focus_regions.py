"""The three focus regions of a frame, one definition for the style and the simulator's truth.

Image-space, because the style is read from a video that has no depths: the subject is the
subject's pixels; the foreground is the band of rows below the subject's lowest pixel (its feet),
the subject excluded, when that band is at least `min_rows` rows high; the background is the rest.
With no subject in the frame there is no foreground and the background is the whole frame.

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


def region_masks(subject: np.ndarray | None, feet: int | None, min_rows: int,
                 shape: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(foreground, subject, background) boolean masks; `subject` None (or `shape` given with no
    subject) = no subject in the frame; `feet`: the first row below the subject (feet_row)."""
    if subject is None:
        empty = np.zeros(shape, bool)
        return empty, empty.copy(), np.ones(shape, bool)
    subj = np.asarray(subject, bool)
    fg = np.zeros_like(subj)
    h = subj.shape[0]
    if feet is not None and h - feet >= max(min_rows, 1):
        fg[feet:, :] = True
        fg &= ~subj
    return fg, subj, ~(subj | fg)
