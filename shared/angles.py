"""Angle helpers shared by the planner, the safety layer and the simulators."""
from __future__ import annotations

import math

import numpy as np


def wrap_angle(a):
    """Angle(s) wrapped to (-pi, pi]; works on floats and numpy arrays."""
    if isinstance(a, np.ndarray):
        w = np.remainder(a + math.pi, 2.0 * math.pi) - math.pi
        return np.where(w <= -math.pi, math.pi, w)
    w = math.remainder(float(a), 2.0 * math.pi)
    return math.pi if w <= -math.pi else w
