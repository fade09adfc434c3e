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
the vehicle profile's `min_obstacle_distance_m` (Bounds), c; h is the smallest vertical gap to the
obstacle's band from the heights the horizon can reach (`reachable_heights_m`: the measured height
plus or minus the climb rate times the horizon, within the altitude band; shared/obstacles.
keep_out_radius_over_m), taken once per solve: the radius at the measured height alone let a plan
climb into a tree's crown it was passing under. Where that would widen a slot, the solve takes the
slots over the heights up to a ceiling instead, and the ceiling as its altitude band's top
(`slots_and_ceiling`). The obstacles themselves are a runtime parameter (`PlannerConfig.obstacles_m`;
shared/obstacles.py).
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
                    reach_m: float, heights_m: Sequence[float] | None = None) -> np.ndarray:
    """(N_OBSTACLE_SLOTS * SLOT_SIZE,) slot values for a camera at `position` (x, y, z): the nearest
    obstacles within `reach_m` of it (shared/obstacles.nearest_keep_outs), each as its axis and its
    widest keep-out radius over `heights_m` (lo, hi; the camera's height alone when not given: the
    radius grown by the round clearance); empty slots are zeros (radius 0: every distance keeps it)."""
    out = np.zeros(N_OBSTACLE_SLOTS * SLOT_SIZE)
    near = nearest_keep_outs(obstacles, position, clearance_m=clearance_m, reach_m=reach_m, count=N_OBSTACLE_SLOTS,
                             heights_m=heights_m)
    for i, (k, r) in enumerate(near):
        out[SLOT_SIZE * i:SLOT_SIZE * (i + 1)] = (k.x_m, k.y_m, r)
    return out


def reachable_heights_m(z_m: float, *, climb_mps: float, horizon_s: float,
                        band_m: Sequence[float]) -> tuple[float, float]:
    """(lo, hi) the heights [m] a camera at `z_m` can reach within `horizon_s` at `climb_mps`, within the
    altitude band `band_m` (lo, hi; the bridge clamps every setpoint into it); a camera outside the band
    is taken where it is as well."""
    lo, hi = z_m - climb_mps * horizon_s, z_m + climb_mps * horizon_s
    return min(max(lo, float(band_m[0])), z_m), max(min(hi, float(band_m[1])), z_m)


def slots_and_ceiling(obstacles: Sequence[Obstacle], position: Sequence[float], *, clearance_m: float,
                      reach_m: float, heights_m: Sequence[float], planned_top_m: float,
                      allowance_m: float) -> tuple[np.ndarray, float]:
    """The obstacle slots of a solve (obstacle_params) and the height its stages may climb to (inf: the
    altitude band's own top), so that every stage that keeps both keeps every clearance. Over all the
    heights the horizon can reach (`heights_m`, lo..hi) a slot is as wide as a crown the plan could climb
    into; where that is wider than over the heights up to `planned_top_m` (the last plan's highest stage,
    or the camera's height if higher) plus `allowance_m`, the solve takes the narrower slots and that
    height as its ceiling instead: a camera flying under a crown's edge keeps the clearance its height
    needs and may not climb into the crown, rather than being pushed out from under it. With the
    allowance the climb rate times the time to the next solve, the ceiling, re-centred every solve,
    never holds the camera itself back."""
    lo, hi = float(heights_m[0]), float(heights_m[1])
    wide = obstacle_params(obstacles, position, clearance_m=clearance_m, reach_m=reach_m, heights_m=(lo, hi))
    cap = max(float(planned_top_m), float(position[2])) + allowance_m
    if cap >= hi:
        return wide, math.inf
    narrow = obstacle_params(obstacles, position, clearance_m=clearance_m, reach_m=reach_m, heights_m=(lo, cap))
    if np.array_equal(narrow, wide):
        return wide, math.inf
    return narrow, cap
