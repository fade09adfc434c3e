"""The subject heading the simulator publishes (SubjectState.heading_rad), from whatever subject it films.

A subject with a heading of its own says so with `heading_at(t_s)` (the yaw it faces, world, rad;
NaN = none at that time); without one, the heading its 3-D joints show stands in
(shared/facing.py). A subject that turns to face the camera (`faces_camera`: the 2.5-D cut-out)
has none: its joints lie on a plane turned to the camera, so a heading read from them would follow
the camera round, and the planner, which flies round to the side a style shows, would chase it.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cinetransfer.shared.facing import subject_heading


def subject_heading_rad(subject: object, t_s: float, names: Sequence[str], joints_m: np.ndarray) -> float:
    """The heading to publish for `subject` at `t_s` with these world joints [rad]; NaN = none."""
    if getattr(subject, "faces_camera", False):
        return math.nan
    heading_at = getattr(subject, "heading_at", None)
    own = float(heading_at(t_s)) if callable(heading_at) else None
    return subject_heading(own, names, joints_m)
