"""Left and right by image side when two views of a person face opposite ways.

A style measured on a person seen from the front puts their left shoulder on the image's right.
Another person seen from behind (the subject library's walker: the TUD footage shows his back)
has it on the image's left. Matched by name, every left/right pair of targets is then mirrored
on him, and no framing of a back view can undo that (a camera cannot turn the person round, and
the simulator has no picture of his front). The framing the style asks for, where the body sits
in the image, is then reproduced by image side: the target of the style's left shoulder is met
by the shoulder on the same side of the image. The planner maps targets this way and the report
compares this way, and says in how many frames it did (docs/planner.md, "Back views").

Which way a view faces is read from the joints alone: the sum over the left/right pairs of
x(left) - x(right) (image x to the right) is > 0 for a front view, < 0 for a back view. The swap
is decided by that sign, never by which labelling gives the smaller error.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def mirror_permutation(names: Sequence[str]) -> np.ndarray:
    """Index permutation of `names` that swaps every left_X with its right_X (both present)."""
    names = list(names)
    perm = np.arange(len(names))
    for i, n in enumerate(names):
        for a, b in (("left_", "right_"), ("right_", "left_")):
            if n.startswith(a) and b + n[len(a):] in names:
                perm[i] = names.index(b + n[len(a):])
    return perm


def lateral_sign(xy: np.ndarray, names: Sequence[str]) -> float:
    """Sum of x(left_X) - x(right_X) over the pairs whose both joints are finite: > 0 front view,
    < 0 back view, 0 unknown (no pair, or side-on). `xy` (E, >=1): x first."""
    xy = np.asarray(xy, dtype=float)
    perm = mirror_permutation(names)
    total = 0.0
    for i, n in enumerate(names):
        j = int(perm[i])
        if n.startswith("left_") and j != i and np.isfinite(xy[i, 0]) and np.isfinite(xy[j, 0]):
            total += float(xy[i, 0] - xy[j, 0])
    return total


def faces_opposite(reference_xy: np.ndarray, other_xy: np.ndarray, names: Sequence[str]) -> bool:
    """True when one view is from the front and the other from behind (signs strictly opposite)."""
    return lateral_sign(reference_xy, names) * lateral_sign(other_xy, names) < 0.0


def by_image_side(reference_xy: np.ndarray, other_xy: np.ndarray, names: Sequence[str]) -> tuple[np.ndarray, bool]:
    """`other_xy` relabelled left/right by image side when it faces the other way from
    `reference_xy` (both (E, 2) in the order of `names`); (relabelled, whether it was swapped)."""
    other_xy = np.asarray(other_xy, dtype=float)
    if faces_opposite(reference_xy, other_xy, names):
        return other_xy[mirror_permutation(names)], True
    return other_xy, False


#: The left/right joint pairs whose axis says which way a body faces, most reliable first.
HEADING_PAIRS: tuple[tuple[str, str], ...] = (("left_shoulder", "right_shoulder"), ("left_hip", "right_hip"))


def heading_from_joints(names: Sequence[str], joints_m: np.ndarray, min_width_m: float = 0.05) -> float:
    """Yaw [rad, world, z up] of the way a body faces, from its 3-D joints: the body's left-right
    axis (the sum of left - right over the shoulder and hip pairs) crossed with up points forward.
    NaN when no pair is known or the axis is too short horizontally (`min_width_m`: a body seen
    lying along its own axis, or joints all on one point)."""
    names = list(names)
    joints = np.asarray(joints_m, dtype=float)
    axis = np.zeros(3)
    for left, right in HEADING_PAIRS:
        if left in names and right in names:
            d = joints[names.index(left)] - joints[names.index(right)]
            if np.all(np.isfinite(d)):
                axis += d
    # (left - right) x z = (L_y, -L_x, 0): forward in the ground plane
    fwd_x, fwd_y = float(axis[1]), 0.0 - float(axis[0])  # (0.0 - 0.0 is +0: heading pi, not -pi)
    if np.hypot(fwd_x, fwd_y) < min_width_m:
        return float("nan")
    return float(np.arctan2(fwd_y, fwd_x))


def subject_heading(heading_rad: float | None, names: Sequence[str], joints_m: np.ndarray) -> float:
    """The heading to publish: the one given when finite (a body's own yaw), else the one its 3-D
    joints show (heading_from_joints), else NaN."""
    if heading_rad is not None and np.isfinite(heading_rad):
        return float(np.arctan2(np.sin(heading_rad), np.cos(heading_rad)))
    return heading_from_joints(names, joints_m)
