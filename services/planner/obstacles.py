"""Keep-out obstacles in the MPC: the camera's position kept out of each nearby cylinder.

The planner holds a fixed number of obstacle slots per stage (N_OBSTACLE_SLOTS, structural: each is
one soft-constraint row and one slack per stage, so the NLP is built once). Before every solve the
nearest obstacles fill each stage's slots (`stage_obstacle_params`): those whose clearance that
stage's planned height is within and whose keep-out circle lies within the horizon's reach of the
measured position (the speed limit times the horizon); an empty slot asks nothing (radius 0). Each
row is

    sqrt((x - x_o)^2 + (y - y_o)^2 + eps) + slack >= R_o,   R_o = r_o + sqrt(c^2 - h_k^2)

with the exact (L1 + L2) penalty of the other soft constraints (constraints.py): held exactly
whenever it can be, smooth in the position (eps keeps the root differentiable on the axis), and a
camera that starts inside is brought out instead of making the problem infeasible. The clearance is
the vehicle profile's `min_obstacle_distance_m` (Bounds), c; h_k is the vertical gap from stage k's
planned height to the obstacle's band (shared/obstacles.keep_out_radius_m). The planned height is
the last plan's at the stage's time (`stage_heights`; the measured one without a plan): a parameter,
so the rows stay as smooth as before, and a plan that climbs under a tree's crown meets the crown's
wider keep-out at the stages where it is high, not only at the measured height. The obstacles
themselves are a runtime parameter (`PlannerConfig.obstacles_m`; shared/obstacles.py).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import casadi as ca
import numpy as np

from cinetransfer.services.planner.model import NORM_EPS2
from cinetransfer.shared.obstacles import Obstacle, nearest_keep_outs

#: obstacles the NLP can hold at once: the nearest ones are enough within a 1.5 s horizon at 2 m/s
N_OBSTACLE_SLOTS = 2
#: numbers per slot in the parameter vector: x, y, radius incl. the clearance
SLOT_SIZE = 3
#: numbers per stage in the parameter vector: every slot of the stage
STAGE_SIZE = N_OBSTACLE_SLOTS * SLOT_SIZE


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


def stage_obstacle_params(obstacles: Sequence[Obstacle], position: Sequence[float], heights_m: Sequence[float], *,
                          clearance_m: float, reach_m: float) -> np.ndarray:
    """(len(heights_m), STAGE_SIZE) slot values, row k those of a camera at `position`'s (x, y) and the
    height `heights_m[k]` (obstacle_params): each stage's keep-outs at its own planned height."""
    x, y = float(position[0]), float(position[1])
    # no height widens a keep-out past r + c: the others are out of reach at every stage (beside tree_3 the
    # courtyard's 15 stages took 0.27 ms CPU so, 0.51 ms over all 81 cylinders; a warm solve is ~4 ms)
    near = [k for k in obstacles if math.hypot(x - k.x_m, y - k.y_m) - k.radius_m - clearance_m <= reach_m]
    return np.array([obstacle_params(near, (x, y, float(z)), clearance_m=clearance_m, reach_m=reach_m)
                     for z in heights_m]).reshape(len(heights_m), STAGE_SIZE)


def stage_heights(plan_z, dt_s: float, shift_s: float, n: int, z_now: float) -> np.ndarray:  # noqa: ANN001
    """(n,) the planned height [m] of stages 1..n of a solve `shift_s` after the last plan was computed:
    that plan's heights `plan_z` ((M+1,), stages `dt_s` apart) at shift + k dt, linearly interpolated and
    held at its last stage beyond it; `z_now` at every stage without a plan (None) or when `shift_s` lies
    outside it (a clock jump: the solve forgets that plan)."""
    z = None if plan_z is None else np.asarray(plan_z, dtype=float)
    if z is None or not 0.0 <= shift_s <= dt_s * (len(z) - 1):
        return np.full(n, float(z_now))
    return np.interp(shift_s + dt_s * np.arange(1, n + 1), dt_s * np.arange(len(z)), z)
