"""Keep-out obstacles in the MPC: the camera's position kept out of each nearby cylinder.

The planner holds a fixed number of obstacle slots (N_OBSTACLE_SLOTS, structural: each is one
soft-constraint row and one slack per stage, so the NLP is built once). Before every solve the
nearest obstacles to the measured position fill them (`obstacle_params`): those whose clearance
the camera's height is within and whose keep-out circle lies within the horizon's reach (the speed
limit times the horizon); an empty slot asks nothing (radius 0). Each row is

    sqrt((x - x_o)^2 + (y - y_o)^2 + eps) + slack >= R_o,   R_o = r_o + sqrt(c^2 - h^2)

with the exact (L1 + L2) penalty of the other soft constraints (constraints.py): held exactly
whenever it can be, smooth in the position (eps keeps the root differentiable on the axis), and a
camera that starts inside is brought out instead of making the problem infeasible. The clearance is
the vehicle profile's `min_obstacle_distance_m` (Bounds), c; h is the measured height's vertical
gap to the obstacle's band (shared/obstacles.keep_out_radius_m), taken once per solve. The obstacles
themselves are a runtime parameter (`PlannerConfig.obstacles_m`; shared/obstacles.py).
"""
from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from cinetransfer.services.planner.model import NORM_EPS2
from cinetransfer.shared.obstacles import Obstacle, nearest_keep_outs

#: obstacles the NLP can hold at once: the nearest ones are enough within a 1.5 s horizon at 2 m/s
N_OBSTACLE_SLOTS = 2
#: numbers per slot in the parameter vector: x, y, radius incl. the clearance
SLOT_SIZE = 3


def obstacle_rows(cam_xy, slack, params):  # noqa: ANN001, ANN201 - casadi or float
    """The soft-constraint rows (each required >= 0) of the obstacle slots for a camera at `cam_xy`:
    horizontal distance to the axis + slack - (radius + clearance)."""
    rows = []
    for i in range(N_OBSTACLE_SLOTS):
        x, y, r = params[SLOT_SIZE * i], params[SLOT_SIZE * i + 1], params[SLOT_SIZE * i + 2]
        dx, dy = cam_xy[0] - x, cam_xy[1] - y
        rows.append(ca.sqrt(dx * dx + dy * dy + NORM_EPS2) + slack[i] - r)
    return ca.vertcat(*rows)


def obstacle_params(obstacles: Sequence[Obstacle], position: Sequence[float], *, clearance_m: float,
                    reach_m: float) -> np.ndarray:
    """(N_OBSTACLE_SLOTS * SLOT_SIZE,) slot values for a camera at `position` (x, y, z): the nearest
    obstacles within `reach_m` of it (shared/obstacles.nearest_keep_outs), each as its axis and its
    keep-out radius at the camera's height (the radius grown by the round clearance); empty slots are
    zeros (radius 0: every distance keeps it)."""
    out = np.zeros(N_OBSTACLE_SLOTS * SLOT_SIZE)
    near = nearest_keep_outs(obstacles, position, clearance_m=clearance_m, reach_m=reach_m, count=N_OBSTACLE_SLOTS)
    for i, (k, r) in enumerate(near):
        out[SLOT_SIZE * i:SLOT_SIZE * (i + 1)] = (k.x_m, k.y_m, r)
    return out
