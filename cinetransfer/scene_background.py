"""How far behind the subject a simulated scene's background stands, for the planner's focus standoff.

The planner cannot see depth: told how far behind the subject the background is, it backs off far
enough for a subject sharp before a soft background (services/planner/separation.py). For a bundled
scene that distance is known: the nearest background layer or solid object beyond the subject's start,
measured along the camera's first line of sight and within 45 degrees of it.
"""
from __future__ import annotations

import math

import numpy as np


def background_behind_m(scene) -> float:  # noqa: ANN001 - a sim.scene.Scene (imported lazily by the caller)
    """The depth [m] behind the subject's start of the nearest background layer or object in view; inf
    when there is none (a plain ground, a sky)."""
    subject = np.asarray(scene.subject.start_m, dtype=float)
    view = subject - np.asarray(scene.vehicle.position_m[:2], dtype=float)
    norm = float(np.hypot(*view))
    if norm < 1e-6:
        return math.inf
    ahead = view / norm
    side = np.array([-ahead[1], ahead[0]])
    places = [layer.position_m for layer in scene.layers if layer.region == "background" and layer.facing == "fixed"]
    places += [obj.position_m for obj in scene.objects]
    best = math.inf
    for p in places:
        rel = np.asarray(p, dtype=float) - subject
        depth, lateral = float(rel @ ahead), float(rel @ side)
        if depth > 0 and abs(lateral) <= depth:
            best = min(best, depth)
    return best
