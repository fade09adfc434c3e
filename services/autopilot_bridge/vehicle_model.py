"""The MAVLink sim-vehicle's model: the built-in simulator's dynamics plus what a flight controller adds.

`SimDynamicsAdapter` wraps `shared.dynamics.VehicleDynamics` (the one vehicle model of the
simulator) with arming and the ground, behind the interface `SimVehicle` uses. World frame ENU,
z up, metres, radians; `step(dt)` advances it (no clock).
"""
from __future__ import annotations

import numpy as np

from cinetransfer.shared.dynamics import DynamicsLimits, VehicleDynamics
from cinetransfer.shared.vehicle import load_vehicle


class SimDynamicsAdapter:
    """The built-in simulator's `shared.dynamics.VehicleDynamics` behind the interface SimVehicle uses.

    Adds what a MAVLink vehicle has and the simulator does not model: arming (disarmed = no
    thrust, it stays put) and the ground (z >= ground_z). The simulator's convention that the
    body yaw follows the camera yaw is kept; a SET_POSITION_TARGET yaw turns the camera when no
    gimbal command has been received.
    """

    def __init__(self, start_m=(0.0, 0.0, 0.0), limits: DynamicsLimits | None = None,
                 ground_z_m: float = 0.0) -> None:
        if limits is None:  # the default vehicle profile's
            limits = DynamicsLimits.from_vehicle(load_vehicle())
        self.dyn = VehicleDynamics(limits=limits, position=np.asarray(start_m, float))
        self.ground_z_m = ground_z_m
        self.armed = False
        self._gimbal_commanded = False
        self.dyn.hold()

    @property
    def lens_ranges(self) -> dict[str, tuple[float, float]]:
        lim = self.dyn.limits
        return {"focal_length_mm": (lim.focal_length_min_mm, lim.focal_length_max_mm),
                "focus_distance_m": (lim.focus_distance_min_m, lim.focus_distance_max_m),
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
