"""What a solve of the planner's NLP takes (StageData) and gives (SolveResult)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

OK_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
BUDGET_STATUSES = ("Maximum_Iterations_Exceeded", "Maximum_WallTime_Exceeded", "Maximum_CpuTime_Exceeded")


@dataclass
class StageData:
    """The runtime data of one solve (everything but weights and bounds)."""

    x0: np.ndarray  # measured state (nx,)
    u_prev: np.ndarray  # input applied before (nu,) (for the input-change cost)
    joints_w: np.ndarray  # (E_max, 3) world positions of the controlled joints now (0 where unused)
    subject_centre_w: np.ndarray  # (3,) subject centre now (for distance, look and DoF depth)
    subject_velocity: np.ndarray  # (3,) [m/s], joints predicted at constant velocity
    targets: np.ndarray  # (N, E_max, 2) normalised image targets at stages 1..N (0 where unused)
    mask: np.ndarray  # (N, E_max) 1 = controlled joint at that stage, else 0
    dof: np.ndarray  # (N, N_DOF) see cost.reciprocal_targets and cost.defocus_ratio
    distance_ref: np.ndarray  # (N,) subject distance used to scale the DoF errors [m]
    motion: np.ndarray | None = None  # (N, camera_motion.N_MOTION) side of the subject, camera motion; None = none
    min_distance_m: float = 0.0  # a minimum subject distance above the bounds' (separation.py) [m]; 0 = the bounds'
    obstacles: np.ndarray | None = None  # obstacle slots: (N, STAGE_SIZE) per stage, or one set for all; None = none


@dataclass
class SolveResult:
    ok: bool
    status: str
    x: np.ndarray  # (N+1, nx) planned states, x[0] = measured (possibly clamped) state
    u: np.ndarray  # (N, nu) planned inputs
    slack: np.ndarray  # (N, C.N_SOFT) soft-constraint violations (floor, ceiling, distance, speed, obstacles)
    cost: float
    iterations: int
    wall_s: float
    violation: float  # max constraint violation of the returned iterate
    cpu_s: float = float("nan")  # CPU time of this thread in the solve (robust to a loaded machine)
    over_budget: bool = False  # wall_s exceeded the time budget (never, when the budget is lifted)
    extras: dict = field(default_factory=dict)
