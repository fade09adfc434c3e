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
