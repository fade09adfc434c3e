"""Dynamics of the camera drone for the MPC (DESIGN §4), usable with numpy and casadi alike.

State x (11, or 12 with roll):
    position p [m] (3), velocity v [m/s] (3), camera yaw, pitch[, roll] [rad],
    focal length f [mm], focus distance s [m], f-number A.
Input u (8, or 9 with roll):
    acceleration a [m/s^2] (3), yaw rate, pitch rate[, roll rate] [rad/s],
    focal-length rate [mm/s], focus rate [m/s], f-number rate [1/s].

Discretisation over a step dt with piecewise-constant inputs, exact for this model:
    p+ = p + v dt + a dt^2 / 2,  v+ = v + a dt,  angle+ = angle + rate dt,  lens+ = lens + rate dt.
CineMPC uses forward Euler (p+ = p + v dt); the exact form is as cheap and makes the plan and the
kinematic simulator agree. Like CineMPC there is no thrust/attitude model: the autopilot flies
the planned path, and the gimbal stabilises the camera, so camera angles are world angles.

The model is linear: x+ = A x + B u (the nonlinearity is all in the cost).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cinetransfer.shared.angles import wrap_angle  # noqa: F401 (the planner's callers import it from here)

from cinetransfer.services.planner.config import Bounds

#: added under the square root of the planner's norms (distances, speed) so their gradient stays smooth at 0;
#: adds < 3e-5 at 2 m/s
NORM_EPS2 = 1e-4


@dataclass(frozen=True)
class Layout:
    """Indices of the state and input vectors for a model with or without roll."""

    control_roll: bool = False

    # state indices
    P = slice(0, 3)
    V = slice(3, 6)
    YAW = 6
    PITCH = 7

    @property
    def ROLL(self) -> int | None:  # noqa: N802 - index constant
        return 8 if self.control_roll else None

    @property
    def F(self) -> int:  # noqa: N802
        return 9 if self.control_roll else 8

    @property
    def S(self) -> int:  # noqa: N802
        return self.F + 1

    @property
    def A(self) -> int:  # noqa: N802
        return self.F + 2

    @property
    def nx(self) -> int:
        return self.F + 3

    # input indices
    ACC = slice(0, 3)
    YAW_RATE = 3
    PITCH_RATE = 4

    @property
    def ROLL_RATE(self) -> int | None:  # noqa: N802
        return 5 if self.control_roll else None

    @property
    def F_RATE(self) -> int:  # noqa: N802
        return 6 if self.control_roll else 5

    @property
    def S_RATE(self) -> int:  # noqa: N802
        return self.F_RATE + 1

    @property
    def A_RATE(self) -> int:  # noqa: N802
        return self.F_RATE + 2

    @property
    def nu(self) -> int:
        return self.F_RATE + 3

    @property
    def state_names(self) -> tuple[str, ...]:
        ang = ("yaw", "pitch", "roll") if self.control_roll else ("yaw", "pitch")
        return ("px", "py", "pz", "vx", "vy", "vz", *ang, "focal_mm", "focus_m", "fnumber")

    @property
    def input_names(self) -> tuple[str, ...]:
        ang = ("yaw_rate", "pitch_rate", "roll_rate") if self.control_roll else ("yaw_rate", "pitch_rate")
        return ("ax", "ay", "az", *ang, "focal_rate", "focus_rate", "fnumber_rate")

    def angles(self, x):  # noqa: ANN001, ANN201 - numpy or casadi
        """(yaw, pitch, roll) of a state vector; roll is 0 without roll control."""
        roll = x[self.ROLL] if self.control_roll else 0.0
        return x[self.YAW], x[self.PITCH], roll


def discrete_matrices(layout: Layout, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) with x+ = A x + B u, exact for piecewise-constant inputs over dt."""
    nx, nu = layout.nx, layout.nu
    a = np.eye(nx)
    b = np.zeros((nx, nu))
    for i in range(3):
        a[i, 3 + i] = dt
        b[i, i] = 0.5 * dt * dt
        b[3 + i, i] = dt
    # every angle and lens state integrates its own rate input: state index j <- input j - 3
    for j in range(6, nx):
        b[j, j - 3] = dt
    return a, b


def step(layout: Layout, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """One exact step of the model (numpy)."""
    a, b = discrete_matrices(layout, dt)
    return a @ np.asarray(x, dtype=float) + b @ np.asarray(u, dtype=float)


def roll_out(a: np.ndarray, b: np.ndarray, x0: np.ndarray, u: np.ndarray, x_lo: np.ndarray, x_hi: np.ndarray,
             u_lo: np.ndarray, u_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """States rolled forward from x0 through x+ = A x + B u, so that every dynamics row holds exactly:
    (x (N+1, nx), u (N, nu)). Each bounded state that integrates one input of its own (velocity from
    acceleration, the angles and the lens from their rates) has that input clipped, where needed, to
    the value that lands it on its bound: a state inside its bounds stays inside (the interval always
    holds 0), so inputs within their bounds give states within theirs. Bounds per stage: x_lo, x_hi
    (N, nx) of x_1..x_N; u_lo, u_hi (N, nu)."""
    n = u.shape[0]
    x = np.empty((n + 1, a.shape[0]))
    x[0] = x0
    u = np.clip(u, u_lo, u_hi)
    eye = np.eye(a.shape[0])
    rows = [j for j in range(a.shape[0]) if np.array_equal(a[j], eye[j]) and np.count_nonzero(b[j]) == 1
            and b[j].sum() > 0]
    drive = np.array([int(np.flatnonzero(b[j])[0]) for j in rows], dtype=int)
    gain = b[rows, drive]
    for k in range(n):
        xk = x[k, rows]
        lo = np.maximum(u_lo[k, drive], (x_lo[k, rows] - xk) / gain)
        hi = np.minimum(u_hi[k, drive], (x_hi[k, rows] - xk) / gain)
        # a state already out of its bounds (an empty interval): the input's own bounds still hold
        u[k, drive] = np.clip(np.minimum(np.maximum(u[k, drive], lo), hi), u_lo[k, drive], u_hi[k, drive])
        x[k + 1] = a @ x[k] + b @ u[k]
    return x, u


def state_bounds(layout: Layout, bounds: Bounds) -> tuple[np.ndarray, np.ndarray]:
    """Hard lower/upper bounds of the state (inf where free: position, yaw)."""
    lo = np.full(layout.nx, -np.inf)
    hi = np.full(layout.nx, np.inf)
    lo[layout.V], hi[layout.V] = -bounds.speed_max_mps, bounds.speed_max_mps
    vz, climb = layout.V.start + 2, min(bounds.climb_max_mps, bounds.speed_max_mps)
    lo[vz], hi[vz] = -climb, climb
    lo[layout.PITCH], hi[layout.PITCH] = bounds.pitch_min_rad, bounds.pitch_max_rad
    if layout.control_roll:
        lo[layout.ROLL], hi[layout.ROLL] = -bounds.roll_max_rad, bounds.roll_max_rad
    lo[layout.F], hi[layout.F] = bounds.focal_length_min_mm, bounds.focal_length_max_mm
    lo[layout.S], hi[layout.S] = bounds.focus_distance_min_m, bounds.focus_distance_max_m
    lo[layout.A], hi[layout.A] = bounds.f_number_min, bounds.f_number_max
    return lo, hi


def input_bounds(layout: Layout, bounds: Bounds) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric hard bounds of the inputs."""
    hi = np.empty(layout.nu)
    hi[layout.ACC] = bounds.accel_max_mps2
    hi[layout.YAW_RATE] = bounds.yaw_rate_radps
    hi[layout.PITCH_RATE] = bounds.pitch_rate_radps
    if layout.control_roll:
        hi[layout.ROLL_RATE] = bounds.roll_rate_radps
    hi[layout.F_RATE] = bounds.focal_rate_mmps
    hi[layout.S_RATE] = bounds.focus_rate_mps
    hi[layout.A_RATE] = bounds.f_number_rate_ps
    return -hi, hi


def unwrap_near(angle: float, reference: float) -> float:
    """`angle` plus the multiple of 2 pi that brings it closest to `reference`."""
    return float(angle + 2 * np.pi * np.round((reference - angle) / (2 * np.pi)))
