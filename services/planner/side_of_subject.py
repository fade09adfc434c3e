"""Which side of the subject to film from: the side the style shows (pure numpy).

A style row whose person is seen from the front (their left shoulder on the image's right,
shared/facing.py) is filmed from in front of the subject: the camera's bearing round the subject
(the horizontal direction from the subject to the camera) should be the subject's heading; a back
view from behind (heading + pi); a side-on row (no clear sign) asks nothing. The cost term is
max(0, cos FREE_ANGLE_RAD - cos(bearing - wanted))^2 (cost.bearing_shortfall): free within 45 deg
of the wanted bearing (that close, the same side shows; the framing and camera-motion terms place
the camera there), and its slope vanishes at the antipode, so the wanted bearing handed to the
solver is a carrot at most `MAX_STEP_RAD` round from where the camera is now, on the shorter way:
the camera is drawn round steadily, and from straight behind too.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cinetransfer.shared.facing import lateral_sign

#: a row faces the camera (or away) only when its left/right pairs are this far apart in x, summed
#: (normalised image units; a side-on view has them on top of each other)
MIN_LATERAL = 0.02
MAX_STEP_RAD = math.radians(90.0)
FREE_ANGLE_RAD = math.radians(45.0)


def style_view(targets_xy: np.ndarray, names: Sequence[str], min_lateral: float = MIN_LATERAL) -> int:
    """+1 the row's person is seen from the front, -1 from behind, 0 side-on or unknown."""
    s = lateral_sign(np.asarray(targets_xy, dtype=float), list(names))
    return 0 if abs(s) < min_lateral else (1 if s > 0 else -1)


def wanted_bearing(heading_rad: float, view: int) -> float:
    """Bearing of the camera round the subject that shows `view` (+1 front: along the heading;
    -1 back: opposite); NaN when either is unknown."""
    if view == 0 or not math.isfinite(heading_rad):
        return float("nan")
    return heading_rad if view > 0 else heading_rad + math.pi


def camera_bearing(camera_xy: np.ndarray, subject_xy: np.ndarray) -> float:
    """Horizontal direction from the subject to the camera [rad]; NaN when they coincide."""
    d = np.asarray(camera_xy, dtype=float)[:2] - np.asarray(subject_xy, dtype=float)[:2]
    return float(math.atan2(d[1], d[0])) if float(np.hypot(*d)) > 1e-6 else float("nan")


def carrot(bearing_now: float, wanted: float, max_step: float = MAX_STEP_RAD) -> float:
    """The bearing to aim at now: `wanted`, or `max_step` from `bearing_now` towards it the shorter
    way round (straight behind: the way of increasing bearing)."""
    err = math.remainder(wanted - bearing_now, 2 * math.pi)
    if abs(abs(err) - math.pi) < 1e-9:
        err = math.pi
    return bearing_now + max(-max_step, min(max_step, err))


def side_targets(target_rows: np.ndarray, rows: Sequence[int], names: Sequence[str], heading_rad: float,
                 bearing_now: float) -> np.ndarray:
    """(N, 3) per stage: the unit bearing vector to aim at (cos, sin) and its mask (1 where the
    row shows a front or back view and heading and bearing are known)."""
    out = np.zeros((len(rows), 3))
    if not (math.isfinite(heading_rad) and math.isfinite(bearing_now)):
        return out
    for k, r in enumerate(rows):
        want = wanted_bearing(heading_rad, style_view(target_rows[r], names))
        if math.isfinite(want):
            b = carrot(bearing_now, want)
            out[k] = (math.cos(b), math.sin(b), 1.0)
    return out
