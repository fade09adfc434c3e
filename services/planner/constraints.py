"""Constraints of the MPC: dynamics (hard), input/state boxes (hard), and the soft ones.

Hard: the dynamics equalities, every input bound, and the state bounds on velocity (each axis;
the vertical one at the profile's climb rate), pitch, roll and the lens (`model.state_bounds`).
They are applied from stage 1 on; stage 0 is the measured state, fixed through its bounds.

Soft, with one non-negative slack each per stage and an exact penalty (L1 + L2) in the cost:
- floor:    z + s_floor >= altitude_min
- ceiling:  z - s_ceil  <= altitude_max
- distance: horizontal distance to the predicted subject centre + s_dist >= min_distance
- speed:    |v| - s_speed <= speed_max   (the norm, as the safety layer bounds it)
- obstacles: horizontal distance to each nearby keep-out cylinder's axis + s_obst >= its radius +
            the clearance at the stage's planned height (obstacles.py: N_OBSTACLE_SLOTS rows, an empty
            slot asks nothing)
The acceleration stays a box per axis: as a norm constraint it is active in every fast move, and
the SQP's Gauss-Newton Hessian, which has no constraint curvature, then converges only linearly
(a cold solve took > 300 iterations instead of < 30).
A vehicle that starts below the floor or too close is brought back rather than making the
problem infeasible; whenever the band can be kept, the exact penalty keeps it exactly.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from cinetransfer.services.planner.config import Bounds
from cinetransfer.services.planner.model import NORM_EPS2, Layout, input_bounds, state_bounds
from cinetransfer.services.planner.obstacles import N_OBSTACLE_SLOTS, obstacle_rows

N_LIMITS = 4  # floor, ceiling, distance, speed: the limits of soft_limits
N_SOFT = N_LIMITS + N_OBSTACLE_SLOTS  # ... and one row per obstacle slot


def soft_constraints(x_next, slack, centre_w, lim, obstacles):  # noqa: ANN001, ANN201
    """The soft-constraint expressions of one stage, each required to be >= 0; `lim` =
    (z_min, z_max, d_min, v_max); `obstacles` the stage's obstacle slots (obstacles.obstacle_params)."""
    z_min, z_max, d_min, v_max = (lim[i] for i in range(N_LIMITS))
    z = x_next[2]
    dx = x_next[0] - centre_w[0]
    dy = x_next[1] - centre_w[1]
    dist = ca.sqrt(dx * dx + dy * dy + NORM_EPS2)
    speed = ca.sqrt(ca.sumsqr(x_next[Layout.V]) + NORM_EPS2)
    return ca.vertcat(z + slack[0] - z_min, z_max - z + slack[1], dist + slack[2] - d_min,
                      v_max - speed + slack[3], obstacle_rows(x_next[0:2], slack[N_LIMITS:], obstacles))


def soft_limits(bounds: Bounds, min_distance_m: float = 0.0) -> list[float]:
    """The `lim` parameter of soft_constraints for these bounds; `min_distance_m` raises the
    minimum subject distance for one solve (a standoff the focus choice needs: separation.py)."""
    d_min = max(bounds.min_subject_distance_m, min_distance_m)
    return [bounds.altitude_min_m, bounds.altitude_max_m, d_min, bounds.speed_max_mps]


def decision_bounds(layout: Layout, bounds: Bounds, n: int, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the decision vector [x_0, (u_k, x_{k+1}, slack_k) for k < n]."""
    xlo, xhi = state_bounds(layout, bounds)
    ulo, uhi = input_bounds(layout, bounds)
    slo, shi = np.zeros(N_SOFT), np.full(N_SOFT, np.inf)
    lo = [np.asarray(x0, dtype=float)]
    hi = [np.asarray(x0, dtype=float)]
    for _ in range(n):
        lo += [ulo, xlo, slo]
        hi += [uhi, xhi, shi]
    return np.concatenate(lo), np.concatenate(hi)


def constraint_bounds(layout: Layout, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of g = [(dynamics_k (= 0), soft_k (>= 0)) for k < n]."""
    lo = np.tile(np.concatenate([np.zeros(layout.nx), np.zeros(N_SOFT)]), n)
    hi = np.tile(np.concatenate([np.zeros(layout.nx), np.full(N_SOFT, np.inf)]), n)
    return lo, hi


def clamp_state(layout: Layout, bounds: Bounds, x: np.ndarray, tolerance: float) -> tuple[np.ndarray, bool]:
    """Clamp a measured state into its hard bounds where it is out by <= tolerance x range.

    Returns (state, ok): ok is False when some state is further out (the problem would then be
    infeasible on purpose: the vehicle is not where the configuration says it can be).
    """
    lo, hi = state_bounds(layout, bounds)
    x = np.asarray(x, dtype=float).copy()
    ok = True
    span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    for i in range(layout.nx):
        if x[i] < lo[i]:
            if lo[i] - x[i] <= tolerance * span[i]:
                x[i] = lo[i]
            else:
                ok = False
        elif x[i] > hi[i]:
            if x[i] - hi[i] <= tolerance * span[i]:
                x[i] = hi[i]
            else:
                ok = False
    return x, ok
