"""A minimal multirotor + gimbal + lens model used by `cinetransfer sim-vehicle`.

Pure numpy, no clock: `step(dt)` advances it. World frame ENU, z up, metres, radians.

- Position loop: v_cmd = v_ff + kp (p* - p), |v_cmd| <= max speed; the velocity follows v_cmd
  with a first-order lag (time constant tau) and |a| <= max acceleration. Ground at z = ground_z.
- Body yaw follows its target at a bounded rate; body roll/pitch are the tilt needed for the
  horizontal acceleration (a multirotor tilts to accelerate).
- Gimbal (camera yaw/pitch/roll, world frame) follows its target at a bounded rate.
- Lens: focal length, focus distance and f-number follow their targets at bounded rates.
- Disarmed: no control; the vehicle stops where it is (landing physics are not modelled).

The built-in simulator (services/autopilot_bridge/sim/) has its own, richer model; this one is
kept small on purpose so that the MAVLink vehicle has no dependency on the renderer.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cinetransfer.shared.angles import wrap_angle

G = 9.81


def _toward(x: float, target: float, max_step: float) -> float:
    d = target - x
    return target if abs(d) <= max_step else x + math.copysign(max_step, d)


def _toward_angle(x: float, target: float, max_step: float) -> float:
    d = wrap_angle(target - x)
    return wrap_angle(target) if abs(d) <= max_step else wrap_angle(x + math.copysign(max_step, d))


@dataclass(frozen=True)
class ModelParams:
    """Limits and gains of the simple vehicle model."""

    max_speed_mps: float = 5.0
    max_accel_mps2: float = 3.0
    kp_pos: float = 1.2  # [1/s] position gain
    tau_vel_s: float = 0.25  # velocity first-order lag
    max_yaw_rate_rps: float = math.radians(90.0)
    gimbal_rate_rps: float = math.radians(120.0)
    gimbal_pitch_range_rad: tuple[float, float] = (-math.pi / 2, math.radians(30.0))
    focal_rate_mmps: float = 60.0
    focus_rate_mps: float = 15.0
    f_number_rate_ps: float = 3.0
    focal_range_mm: tuple[float, float] = (10.0, 500.0)
    focus_range_m: tuple[float, float] = (0.3, 1000.0)
    f_number_range: tuple[float, float] = (1.0, 22.0)
    ground_z_m: float = 0.0


@dataclass
class VehicleModel:
    """State and targets of the simulated vehicle (mutable, advanced by `step`)."""

    params: ModelParams = field(default_factory=ModelParams)
    position_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw_rad: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    camera_ypr_rad: np.ndarray = field(default_factory=lambda: np.zeros(3))
    focal_length_mm: float = 35.0
    focus_distance_m: float = 10.0
    f_number: float = 4.0
    armed: bool = False
    # targets
    target_position_m: np.ndarray | None = None
    target_velocity_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    target_yaw_rad: float | None = None
    target_camera_ypr_rad: np.ndarray | None = None
    target_focal_length_mm: float | None = None
    target_focus_distance_m: float | None = None
    target_f_number: float | None = None

    # -- the interface SimVehicle uses (also implemented by SimDynamicsAdapter) --------------
    @property
    def ground_z_m(self) -> float:
        return self.params.ground_z_m

    @property
    def lens_ranges(self) -> dict[str, tuple[float, float]]:
        p = self.params
        return {"focal_length_mm": p.focal_range_mm, "focus_distance_m": p.focus_range_m, "f_number": p.f_number_range}

    def track(self, position: np.ndarray | None, velocity: np.ndarray, yaw: float | None) -> None:
        """Position (+ velocity feed-forward) target; position None = velocity only."""
        self.target_position_m = None if position is None else np.asarray(position, float).copy()
        self.target_velocity_mps = np.asarray(velocity, float).copy()
        if yaw is not None:
            self.target_yaw_rad = yaw

    def point_camera(self, ypr: np.ndarray) -> None:
        self.target_camera_ypr_rad = np.asarray(ypr, float).copy()

    def set_lens(self, name: str, value: float) -> None:
        setattr(self, {"focal_length_mm": "target_focal_length_mm", "focus_distance_m": "target_focus_distance_m",
                       "f_number": "target_f_number"}[name], float(value))

    def hold_here(self) -> None:
        """Position target = where the vehicle is now, zero velocity."""
        self.target_position_m = self.position_m.copy()
        self.target_velocity_mps = np.zeros(3)
        self.target_yaw_rad = self.yaw_rad

    @property
    def landed(self) -> bool:
        return self.position_m[2] <= self.params.ground_z_m + 0.05 and abs(self.velocity_mps[2]) < 0.1

    def step(self, dt: float) -> None:
        if dt <= 0:
            return
        p = self.params
        if self.armed and self.target_position_m is not None:
            v_cmd = self.target_velocity_mps + p.kp_pos * (self.target_position_m - self.position_m)
            n = float(np.linalg.norm(v_cmd))
            if n > p.max_speed_mps:
                v_cmd *= p.max_speed_mps / n
        else:
            v_cmd = np.zeros(3)
        acc = (v_cmd - self.velocity_mps) / max(p.tau_vel_s, dt)
        n = float(np.linalg.norm(acc))
        if n > p.max_accel_mps2:
            acc *= p.max_accel_mps2 / n
        self.velocity_mps = self.velocity_mps + acc * dt
        self.position_m = self.position_m + self.velocity_mps * dt
        if self.position_m[2] < p.ground_z_m:
            self.position_m[2] = p.ground_z_m
            self.velocity_mps[2] = max(self.velocity_mps[2], 0.0)
        if not self.armed and self.landed:
            self.velocity_mps[:] = 0.0
        # body attitude: yaw to target, tilt from horizontal acceleration
        if self.armed and self.target_yaw_rad is not None:
            self.yaw_rad = _toward_angle(self.yaw_rad, self.target_yaw_rad, p.max_yaw_rate_rps * dt)
        cy, sy = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        a_fwd = acc[0] * cy + acc[1] * sy
        a_left = -acc[0] * sy + acc[1] * cy
        self.pitch_rad = -math.atan2(a_fwd, G)
        self.roll_rad = -math.atan2(a_left, G)
        # gimbal
        if self.target_camera_ypr_rad is not None:
            t = self.target_camera_ypr_rad
            s = p.gimbal_rate_rps * dt
            lo, hi = p.gimbal_pitch_range_rad
            self.camera_ypr_rad = np.array([
                _toward_angle(float(self.camera_ypr_rad[0]), float(t[0]), s),
                _toward(float(self.camera_ypr_rad[1]), min(max(float(t[1]), lo), hi), s),
                _toward(float(self.camera_ypr_rad[2]), float(t[2]), s),
            ])
        # lens
        if self.target_focal_length_mm is not None:
            lo, hi = p.focal_range_mm
            self.focal_length_mm = _toward(self.focal_length_mm, min(max(self.target_focal_length_mm, lo), hi),
                                           p.focal_rate_mmps * dt)
        if self.target_focus_distance_m is not None:
            lo, hi = p.focus_range_m
            self.focus_distance_m = _toward(self.focus_distance_m,
                                            min(max(self.target_focus_distance_m, lo), hi), p.focus_rate_mps * dt)
        if self.target_f_number is not None:
            lo, hi = p.f_number_range
            self.f_number = _toward(self.f_number, min(max(self.target_f_number, lo), hi), p.f_number_rate_ps * dt)


class SimDynamicsAdapter:
    """The built-in simulator's `sim.dynamics.VehicleDynamics` behind the interface SimVehicle uses.

    Adds what a MAVLink vehicle has and the simulator does not model: arming (disarmed = no
    thrust, it stays put) and the ground (z >= ground_z). The simulator's convention that the
    body yaw follows the camera yaw is kept; a SET_POSITION_TARGET yaw turns the camera when no
    gimbal command has been received.
    """

    def __init__(self, start_m=(0.0, 0.0, 0.0), limits=None, ground_z_m: float = 0.0) -> None:
        from cinetransfer.services.autopilot_bridge.sim.dynamics import DynamicsLimits, VehicleDynamics

        if limits is None:  # a vehicle a little more agile than the paper's run (the bridge limits it)
            limits = DynamicsLimits(max_speed_xy_mps=5.0, max_speed_z_mps=3.0, max_accel_mps2=3.0,
                                    yaw_rate_rps=math.radians(90.0), pitch_rate_rps=math.radians(120.0),
                                    roll_rate_rps=math.radians(120.0), focal_min_mm=10.0, focal_rate_mmps=60.0,
                                    focus_min_m=0.3, focus_max_m=1000.0)
        self.dyn = VehicleDynamics(limits=limits, position=np.asarray(start_m, float))
        self.ground_z_m = ground_z_m
        self.armed = False
        self._gimbal_commanded = False
        self.dyn.hold()

    @property
    def lens_ranges(self) -> dict[str, tuple[float, float]]:
        lim = self.dyn.limits
        return {"focal_length_mm": (lim.focal_min_mm, lim.focal_max_mm),
                "focus_distance_m": (lim.focus_min_m, lim.focus_max_m),
                "f_number": (lim.f_number_min, lim.f_number_max)}

    position_m = property(lambda self: self.dyn.position)
    velocity_mps = property(lambda self: self.dyn.velocity)
    camera_ypr_rad = property(lambda self: self.dyn.camera_ypr)
    focal_length_mm = property(lambda self: self.dyn.focal_mm)
    focus_distance_m = property(lambda self: self.dyn.focus_m)
    f_number = property(lambda self: self.dyn.f_number)
    yaw_rad = property(lambda self: float(self.dyn.camera_ypr[0]))
    pitch_rad = property(lambda self: float(self.dyn.body_attitude_ypr()[1]))
    roll_rad = property(lambda self: float(self.dyn.body_attitude_ypr()[2]))

    @property
    def landed(self) -> bool:
        return self.dyn.position[2] <= self.ground_z_m + 0.05 and abs(self.dyn.velocity[2]) < 0.1

    def track(self, position: np.ndarray | None, velocity: np.ndarray, yaw: float | None) -> None:
        # velocity only: the position target is where the vehicle is (pure velocity tracking)
        pos = self.dyn.position.copy() if position is None else np.asarray(position, float)
        cam = None
        if yaw is not None and not self._gimbal_commanded:
            cam = np.array([yaw, np.nan, np.nan])
        self.dyn.set_target(position=pos, velocity=np.asarray(velocity, float), camera_ypr=cam)

    def point_camera(self, ypr: np.ndarray) -> None:
        self._gimbal_commanded = True
        self.dyn.sp_camera_ypr = np.asarray(ypr, float).copy()

    def set_lens(self, name: str, value: float) -> None:
        f, s, a = self.dyn.sp_lens
        i = ("focal_length_mm", "focus_distance_m", "f_number").index(name)
        vals = [f, s, a]
        vals[i] = float(value)
        self.dyn.sp_lens = tuple(vals)

    def hold_here(self) -> None:
        """Stop and hold position; the gimbal and the lens keep their targets (a flight mode
        change does not touch the payload)."""
        cam, lens = self.dyn.sp_camera_ypr.copy(), self.dyn.sp_lens
        self.dyn.holding = False  # re-latch at the current position
        self.dyn.hold()
        self.dyn.sp_camera_ypr, self.dyn.sp_lens = cam, lens

    def step(self, dt: float) -> None:
        if dt <= 0:
            return
        if not self.armed and not self.dyn.holding:
            self.hold_here()
        if not self.armed and self.landed:
            self.dyn.velocity = np.zeros(3)
        self.dyn.advance(dt)
        if self.dyn.position[2] < self.ground_z_m:
            self.dyn.position[2] = self.ground_z_m
            self.dyn.velocity[2] = max(self.dyn.velocity[2], 0.0)
