"""Lens axes the camera cannot be commanded on (VehicleState.lens_unsupported): held fixed.

The bridge marks an axis unsupported when the camera never acknowledges its command (or answers
UNSUPPORTED). The planner then plans with that axis where it is: the axis's state bounds shrink to
a band of +-0.1 % around its value (runtime bounds, no solver rebuild), so framing and depth of
field are reached with what can still move (position, gimbal, the other lens axes).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from cinetransfer.services.planner.config import Bounds

#: VehicleState lens axis -> (index in the lens vector (f, s, A), Bounds min field, Bounds max field)
AXES = {"focal_length_mm": (0, "focal_length_min_mm", "focal_length_max_mm"),
        "focus_distance_m": (1, "focus_distance_min_m", "focus_distance_max_m"),
        "f_number": (2, "f_number_min", "f_number_max")}
BAND = 1e-3


def pinned_bounds(free: Bounds, axes: tuple[str, ...], lens: np.ndarray) -> Bounds:
    """`free` with each of `axes` (unknown names ignored) narrowed to its value in `lens`."""
    changes = {}
    for axis in axes:
        if axis not in AXES:
            continue
        i, lo_name, hi_name = AXES[axis]
        lo, hi = getattr(free, lo_name), getattr(free, hi_name)
        v = float(np.clip(lens[i], lo, hi))
        half = BAND * v
        changes[lo_name], changes[hi_name] = max(lo, v - half), min(hi, v + half)
        if changes[hi_name] - changes[lo_name] < half:  # at an end of the range: keep a band inside it
            changes[lo_name], changes[hi_name] = (lo, lo + 2 * half) if v - lo < hi - v else (hi - 2 * half, hi)
    return dataclasses.replace(free, **changes).validate() if changes else free
