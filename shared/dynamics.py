"""Vehicle, gimbal and lens dynamics of the built-in simulator (pure numpy, no clock).

Multirotor: the autopilot is modelled as a velocity loop with a first-order lag and a position
loop on top, both saturated:

    v_cmd = v_sp + k_p (p_sp - p),            |v_cmd| <= v_max (horizontal and vertical apart)
    a     = a_ff + (v_cmd - v) / tau,          |a| <= a_max
    v    += a dt  (then |v| clamped again),    p += v dt

With k_p tau = 1/4 the position loop is critically damped. A constant velocity setpoint is
reached with time constant tau (63 % after tau) when the acceleration limit is not hit.

Gimbal: a new angle command is reached along a straight line over `gimbal_ramp_s` (one setpoint
period), not at once: a gimbal that jumped to each 20 Hz command and held it there turned in steps,
and 24 fps frames sampling those steps saw the pan stop once every six frames (a 4 Hz beat). The
commanded angles move at no more than the rate limits (yaw along the shortest way round), pitch and
roll stay within their mechanical range.
Lens: focal length, focus distance and f-number move towards their targets at their rate limits,
within their ranges. Integration uses fixed sub-steps so that results do not depend on how
often `advance` is called.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import ClassVar

import numpy as np

from cinetransfer.shared.angles import wrap_angle
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.nodeconfig import renamed_aliases
from cinetransfer.shared.limits import (GimbalLimits, GimbalRateLimits, LensLimits, LensRateLimits, MotionLimits,
                                        vehicle_fields)
from cinetransfer.shared.vehicle import VehicleProfile


@dataclass(frozen=True)
class DynamicsLimits(LensRateLimits, LensLimits, GimbalRateLimits, GimbalLimits, MotionLimits):
    """Limits and time constants of the simulated vehicle.

    The limits (declared once in shared/limits.py) come from the vehicle profile (`from_vehicle`);
    the defaults are the default profile's (deploy/vehicles/cinempc.yaml, CineMPC's camera, DESIGN
    §4). The time constants and gains are the simulated autopilot's own. SETTING_ALIASES are the
    earlier spellings a scene's `limits:` may use."""

    SETTING_ALIASES: ClassVar[dict[str, str]] = {
        "max_speed_xy_mps": "speed_max_mps", "max_speed_z_mps": "climb_max_mps", "max_accel_mps2": "accel_max_mps2",
        "yaw_rate_rps": "yaw_rate_radps", "pitch_rate_rps": "pitch_rate_radps", "roll_rate_rps": "roll_rate_radps",
        "focal_min_mm": "focal_length_min_mm", "focal_max_mm": "focal_length_max_mm",
        "focus_min_m": "focus_distance_min_m", "focus_max_m": "focus_distance_max_m"}

    lag_tau_s: float = 0.25
    position_gain_per_s: float = 1.0
    substep_s: float = 0.005
    #: a new gimbal angle command is approached along a straight line over this time [s] (the planner's
    #: setpoint period), so a steady pan commanded in steps turns at a steady rate between them
    gimbal_ramp_s: float = 0.05

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ConfigError(f"limits.{f.name}: must be a finite number, got {v!r}")
            if f.name not in ("pitch_min_rad",) and v <= 0:
                raise ConfigError(f"limits.{f.name}: must be > 0, got {v!r}")
        if not self.pitch_min_rad < self.pitch_max_rad:
            raise ConfigError("limits: pitch_min_rad must be < pitch_max_rad")
        for lo, hi in (("focal_length_min_mm", "focal_length_max_mm"), ("focus_distance_min_m", "focus_distance_max_m"),
                       ("f_number_min", "f_number_max")):
            if not getattr(self, lo) < getattr(self, hi):
                raise ConfigError(f"limits: {lo} must be < {hi}")

    @classmethod
    def from_vehicle(cls, v: VehicleProfile, base: "DynamicsLimits | None" = None) -> "DynamicsLimits":
        """The vehicle's limits; time constants, gains and sub-step from `base` (default: the defaults)."""
        return replace(base or cls(), **vehicle_fields(cls, v))

    @classmethod
    def from_dict(cls, d: dict | None) -> "DynamicsLimits":
        d = renamed_aliases(cls, dict(d or {}), "scene", "limits.")
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ConfigError(f"limits: unknown field(s) {unknown}; allowed: {sorted(names)}")
        return cls(**{k: float(v) for k, v in d.items()})


def _toward(x: float, target: float, max_step: float) -> float:
    d = target - x
    if d > max_step:
        return x + max_step
    if d < -max_step:
        return x - max_step
    return target


def _clamp_xy_z(v: np.ndarray, vmax_xy: float, vmax_z: float) -> np.ndarray:
    out = v.copy()
    n = math.hypot(out[0], out[1])
    if n > vmax_xy:
        out[:2] *= vmax_xy / n
    out[2] = min(max(out[2], -vmax_z), vmax_z)
    return out


def ramp_angles(cmd: np.ndarray, target: np.ndarray, share: float) -> np.ndarray:
    """`cmd` moved `share` (0..1) of the way to `target` (yaw, pitch, roll [rad]; yaw the short way round)."""
    d = np.asarray(target, float) - np.asarray(cmd, float)
    d[0] = wrap_angle(float(d[0]))
    out = np.asarray(cmd, float) + min(max(share, 0.0), 1.0) * d
    out[0] = wrap_angle(float(out[0]))
    return out


@dataclass
class VehicleDynamics:
    """State and integrator of the multirotor + gimbal + lens."""

    limits: DynamicsLimits = field(default_factory=DynamicsLimits)
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(3))
    camera_ypr: np.ndarray = field(default_factory=lambda: np.zeros(3))
    focal_mm: float = 35.0
    focus_m: float = 10.0
    f_number: float = 4.0
    # targets
    sp_position: np.ndarray | None = None
    sp_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sp_accel: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sp_camera_ypr: np.ndarray | None = None
    sp_lens: tuple[float, float, float] | None = None
    holding: bool = False
    _hold_latched: bool = False
    _rem_s: float = 0.0
    _cam_cmd: np.ndarray | None = None  # the gimbal's angle command on its ramp to sp_camera_ypr
    _cam_ramp_left_s: float = 0.0
    _cam_rate: np.ndarray = field(default_factory=lambda: np.zeros(3))  # over the last sub-step [rad/s]
    _focal_rate: float = 0.0  # over the last sub-step [mm/s]

    def __post_init__(self) -> None:
        self.position = np.asarray(self.position, float).copy()
        self.camera_ypr = np.asarray(self.camera_ypr, float).copy()
        self.clamp_lens()
        if self.sp_position is None:
            self.sp_position = self.position.copy()
        if self.sp_camera_ypr is None:
            self.sp_camera_ypr = self.camera_ypr.copy()
        if self.sp_lens is None:
            self.sp_lens = (self.focal_mm, self.focus_m, self.f_number)

    def clamp_lens(self) -> None:
        lim = self.limits
        self.focal_mm = min(max(self.focal_mm, lim.focal_length_min_mm), lim.focal_length_max_mm)
        self.focus_m = min(max(self.focus_m, lim.focus_distance_min_m), lim.focus_distance_max_m)
        self.f_number = min(max(self.f_number, lim.f_number_min), lim.f_number_max)

    # -- commands ---------------------------------------------------------------------------
    def set_target(self, *, position: np.ndarray, velocity: np.ndarray | None = None,
                   acceleration: np.ndarray | None = None, camera_ypr: np.ndarray | None = None,
                   lens: tuple[float, float, float] | None = None) -> None:
        """Track this target. NaN in `lens` components or `camera_ypr` keeps that target."""
        self.holding = False
        self._hold_latched = False
        self.sp_position = np.asarray(position, float).copy()
        self.sp_velocity = np.zeros(3) if velocity is None else np.asarray(velocity, float).copy()
        self.sp_accel = np.zeros(3) if acceleration is None else np.asarray(acceleration, float).copy()
        if camera_ypr is not None:
            c = np.asarray(camera_ypr, float)
            new = np.where(np.isfinite(c), c, self.sp_camera_ypr)
            if not np.array_equal(new, self.sp_camera_ypr):  # the same command repeated keeps its ramp
                self._cam_cmd = self.camera_command().copy()
                self._cam_ramp_left_s = self.limits.gimbal_ramp_s
            self.sp_camera_ypr = new
        if lens is not None:
            old = self.sp_lens
            self.sp_lens = tuple(n if math.isfinite(n) else o for n, o in zip(lens, old))

    def hold(self) -> None:
        """Decelerate to a stop (at the acceleration limit), then hold that position.

        Gimbal and lens stop where they are."""
        if not self.holding:
            self.holding = True
            self._hold_latched = False
            self.sp_velocity = np.zeros(3)
            self.sp_accel = np.zeros(3)
            self.sp_camera_ypr = self.camera_ypr.copy()
            self._cam_cmd, self._cam_ramp_left_s = None, 0.0
            self.sp_lens = (self.focal_mm, self.focus_m, self.f_number)

    def camera_command(self) -> np.ndarray:
        """The gimbal's angle command now: on its ramp to `sp_camera_ypr`, or that target."""
        return self.sp_camera_ypr if self._cam_cmd is None else self._cam_cmd

    # -- integration ------------------------------------------------------------------------
    def advance(self, dt: float) -> None:
        """Integrate `dt` seconds in fixed sub-steps (a remainder is carried to the next call)."""
        if dt < 0:
            raise ValueError("dt must be >= 0")
        self._rem_s += dt
        h = self.limits.substep_s
        while self._rem_s >= h - 1e-12:
            self._substep(h)
            self._rem_s -= h

    def _substep(self, h: float) -> None:
        lim = self.limits
        if self.holding and not self._hold_latched:
            v_cmd = np.zeros(3)
            if float(np.linalg.norm(self.velocity)) < 0.02:
                self._hold_latched = True
                self.sp_position = self.position.copy()
        else:
            v_cmd = self.sp_velocity + lim.position_gain_per_s * (self.sp_position - self.position)
        v_cmd = _clamp_xy_z(v_cmd, lim.speed_max_mps, lim.climb_max_mps)
        a = self.sp_accel + (v_cmd - self.velocity) / lim.lag_tau_s
        n = float(np.linalg.norm(a))
        if n > lim.accel_max_mps2:
            a *= lim.accel_max_mps2 / n
        self.acceleration = a
        v_new = _clamp_xy_z(self.velocity + a * h, lim.speed_max_mps, lim.climb_max_mps)
        self.position = self.position + 0.5 * (self.velocity + v_new) * h
        self.velocity = v_new
        # gimbal
        y, p, r = self.camera_ypr
        ty, tp, tr = self._ramp_camera_command(h)
        dy = wrap_angle(ty - y)
        y = wrap_angle(y + max(-lim.yaw_rate_radps * h, min(lim.yaw_rate_radps * h, dy)))
        tp = min(max(tp, lim.pitch_min_rad), lim.pitch_max_rad)
        tr = min(max(tr, -lim.roll_max_rad), lim.roll_max_rad)
        p = _toward(p, tp, lim.pitch_rate_radps * h)
        r = _toward(r, tr, lim.roll_rate_radps * h)
        new_ypr = np.array([y, p, r])
        d = new_ypr - self.camera_ypr
        d[0] = wrap_angle(float(d[0]))
        self._cam_rate, self.camera_ypr = d / h, new_ypr
        focal_before = self.focal_mm
        # lens
        fl, fs, fa = self.sp_lens
        self.focal_mm = _toward(self.focal_mm, min(max(fl, lim.focal_length_min_mm), lim.focal_length_max_mm),
                                lim.focal_rate_mmps * h)
        self.focus_m = _toward(self.focus_m, min(max(fs, lim.focus_distance_min_m), lim.focus_distance_max_m),
                               lim.focus_rate_mps * h)
        self.f_number = _toward(self.f_number, min(max(fa, lim.f_number_min), lim.f_number_max),
                                lim.f_number_rate_ps * h)
        self._focal_rate = (self.focal_mm - focal_before) / h

    def _ramp_camera_command(self, h: float) -> np.ndarray:
        """Move the angle command `h` seconds along its ramp (the target once the ramp has ended)."""
        if self._cam_cmd is None or self._cam_ramp_left_s <= 0.5 * h:
            self._cam_cmd, self._cam_ramp_left_s = None, 0.0
            return self.sp_camera_ypr
        self._cam_cmd = ramp_angles(self._cam_cmd, self.sp_camera_ypr, h / self._cam_ramp_left_s)
        self._cam_ramp_left_s -= h
        return self._cam_cmd

    def pose_now(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Position, camera yaw/pitch/roll and focal length at the time `advance` was asked for: the
        state of the last whole sub-step carried over the remainder at its rates. A 24 fps frame falls
        between 5 ms sub-steps (8, 8, then 9 of them a frame): drawn at the sub-step, a steady pan read
        0.96, 0.96, 1.08 of its rate frame by frame."""
        r = self._rem_s
        ypr = self.camera_ypr + self._cam_rate * r
        ypr[0] = wrap_angle(float(ypr[0]))
        return self.position + self.velocity * r, ypr, self.focal_mm + self._focal_rate * r

    def body_attitude_ypr(self) -> np.ndarray:
        """Body yaw follows the camera yaw; pitch/roll tilt with the horizontal acceleration."""
        yaw = float(self.camera_ypr[0])
        g = 9.81
        ax, ay = self.acceleration[0], self.acceleration[1]
        fwd = math.cos(yaw) * ax + math.sin(yaw) * ay
        left = -math.sin(yaw) * ax + math.cos(yaw) * ay
        return np.array([yaw, -math.atan2(fwd, g), -math.atan2(left, g)])
