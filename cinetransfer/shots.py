"""Shots and takes of a transfer: how long each take's settle phase really took (pure).

A multi-shot source is flown one take per shot (cinetransfer/transfer.py `shot_schedule`);
before each take the planner frames the shot's first instruction frame. Here the simulator's
truth of the settle frames says when the framing got there: the first frame from which the
controlled joints stay within `tolerance` (normalised image units) of the shot's first targets
until the take begins. A take whose first frame is still off is reported unsettled, with the
best framing error reached (the next shot's framing may be unreachable in the scene).
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from cinetransfer.shared import messages as M

#: a framing within this mean joint error of the target counts as settled [normalised]
SETTLE_TOLERANCE = 0.05


def framing_error(truth: M.GroundTruth, style: M.Instructions, row: int) -> float:
    """Mean image distance of the controlled joints from the style's targets of `row` (NaN if none)."""
    names = list(truth.joint_names)
    errs = []
    for e, j in enumerate(style.joint_names):
        tgt = np.asarray(style.image_targets[row, e], dtype=float)
        if j not in names or not np.all(np.isfinite(tgt)):
            continue
        i = names.index(j)
        if truth.joints_visible[i]:
            errs.append(float(np.linalg.norm(np.asarray(truth.joints_norm[i], dtype=float) - tgt)))
    return float(np.mean(errs)) if errs else math.nan


def settle_report(style: M.Instructions, takes: Sequence[dict], truths: Mapping[int, M.GroundTruth], *,
                  tolerance: float = SETTLE_TOLERANCE) -> list[dict]:
    """Per take: settle limit, settle time (None = not settled within the limit), the framing
    error at the take's first frame and the best error reached while settling."""
    fps = float(style.fps)
    out = []
    for tk in takes:
        first, start, row = int(tk["first_index"]), int(tk["settle_start_index"]), int(tk["first_row"])
        errs = [framing_error(truths[i], style, row) if i in truths else math.nan for i in range(start, first + 1)]
        settled_at = _settled_from(errs, tolerance)
        finite = [e for e in errs if math.isfinite(e)]
        framed = bool(np.isfinite(np.asarray(style.image_targets[row], dtype=float)).all(axis=1).any())
        out.append({"shot": tk["shot"], "first_row": row, "end_row": tk["end_row"],
                    "settle_limit_s": tk["settle_limit_s"],
                    "settle_s": None if settled_at is None else round(settled_at / fps, 3),
                    # None: the shot's first frame shows no subject, so there is no framing to settle on
                    "settled": (settled_at is not None) if framed else None,
                    "error_at_take_start": errs[-1] if errs and math.isfinite(errs[-1]) else None,
                    "best_error_while_settling": min(finite) if finite else None})
    return out


def _settled_from(errs: list[float], tolerance: float) -> int | None:
    """First index from which every error is finite and within tolerance (None if the last isn't)."""
    k = len(errs)
    while k > 0 and math.isfinite(errs[k - 1]) and errs[k - 1] <= tolerance:
        k -= 1
    return None if k == len(errs) else k
