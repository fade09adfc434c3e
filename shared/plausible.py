"""Checks of message content beyond what the codec's schema can say: values that decode fine
(finite where required, NaN where allowed) but that nothing sensible can be done with.

Pure functions, shared by the node that produces a message and the nodes that act on it.
"""
from __future__ import annotations

import numpy as np

from cinetransfer.shared import messages as M

#: a normalised image target beyond this (|x| or |y|, image = [0, 1]) is not a place in any image
TARGET_ABS_MAX = 10.0


def unusable_targets(instr: M.Instructions) -> str:
    """Why an instruction set cannot be flown ('' if it can): no finite image target at all, or
    one far outside the image (|x| or |y| > TARGET_ABS_MAX; a forged or corrupt file: ±1e6).
    Pure; the planner refuses such instructions and the smoother's `load_style` reports them."""
    t = np.asarray(instr.image_targets, dtype=float)
    finite = np.isfinite(t)
    if t.size == 0 or not finite.any():
        return "no image target is set (all NaN): nothing to frame"
    worst = float(np.abs(t[finite]).max())
    if worst > TARGET_ABS_MAX:
        return (f"an image target lies at {worst:g} image widths/heights (limit {TARGET_ABS_MAX:g}): "
                f"not a point in any image")
    return ""
