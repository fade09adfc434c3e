"""A kinematic simulator the planner owns, for closed-loop tests, the benchmark and `cinetransfer plan`.

The vehicle integrates the MPC model's own dynamics (model.py: double integrator for the
position, rate-integrated camera angles and lens) with a first-order lag between what the
setpoint asks and what the vehicle does:
- position: a_cmd = a_ff + kp (p_sp - p) + kd (v_sp - v), clipped; the real acceleration follows
  a_cmd with time constant `tau_s`;
- camera angles and lens: each rate = (setpoint - value) / tau_s, clipped to the rate limits.
With the planner's setpoint lead equal to tau_s, a ramp is tracked without steady lag.
The subject is a COCO-17 skeleton that stands or walks (constant-velocity segments, limbs
swinging with the stride), so the planner's constant-velocity prediction is good but not exact.

Ground truth comes from `cinetransfer.shared.camera` (not from the planner's casadi code), so a
closed loop checks the planner's projection against an independent implementation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cinetransfer.services.planner.config import Bounds
from cinetransfer.shared import camera as cam
from cinetransfer.shared.angles import wrap_angle
from cinetransfer.shared import messages as M

#: COCO-17 joints of a 1.75 m person standing upright, body frame (x forward, y left, z up) [m].
BODY_JOINTS: dict[str, tuple[float, float, float]] = {
    "nose": (0.10, 0.0, 1.62), "left_eye": (0.08, 0.035, 1.66), "right_eye": (0.08, -0.035, 1.66),
    "left_ear": (0.0, 0.075, 1.63), "right_ear": (0.0, -0.075, 1.63),
    "left_shoulder": (0.0, 0.19, 1.44), "right_shoulder": (0.0, -0.19, 1.44),
    "left_elbow": (0.0, 0.23, 1.14), "right_elbow": (0.0, -0.23, 1.14),
    "left_wrist": (0.04, 0.24, 0.88), "right_wrist": (0.04, -0.24, 0.88),
    "left_hip": (0.0, 0.11, 0.95), "right_hip": (0.0, -0.11, 0.95),
    "left_knee": (0.03, 0.11, 0.52), "right_knee": (0.03, -0.11, 0.52),
    "left_ankle": (0.0, 0.11, 0.08), "right_ankle": (0.0, -0.11, 0.08),
}
_SWING = {"left_wrist": 1, "left_elbow": 0.5, "right_wrist": -1, "right_elbow": -0.5,
          "left_ankle": -1, "left_knee": -0.5, "right_ankle": 1, "right_knee": 0.5}


@dataclass
class Walk:
    """The subject moves at `velocity_mps` (world) between t0_s and t1_s of simulated time."""

    t0_s: float
    t1_s: float
    velocity_mps: tuple[float, float, float]


@dataclass
class KinematicScene:
    """Initial conditions of a kinematic simulation."""

    name: str = "standing"
    vehicle_position_m: tuple[float, float, float] = (-6.0, 0.0, 1.6)
    vehicle_velocity_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    camera_ypr_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lens: tuple[float, float, float] = (50.0, 6.0, 4.0)  # focal [mm], focus [m], f-number
    subject_position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # ground point under the pelvis
    subject_heading_rad: float = math.pi  # the way the subject faces (pi: towards -x)
    walks: list[Walk] = field(default_factory=list)


#: Built-in scenes for `cinetransfer plan --scene NAME` when the bridge simulator is not installed.
SCENES: dict[str, KinematicScene] = {
    "standing": KinematicScene(),
    "walking": KinematicScene(name="walking", walks=[Walk(1.0, 1e9, (0.0, 0.8, 0.0))]),
    "approach": KinematicScene(name="approach", vehicle_position_m=(-9.0, 2.0, 2.5),
                               camera_ypr_rad=(0.4, -0.2, 0.0), lens=(35.0, 10.0, 8.0),
                               walks=[Walk(0.5, 6.0, (-0.5, 0.3, 0.0))]),
}


class Subject:
    """A COCO-17 skeleton standing or walking on the ground plane."""

    def __init__(self, position_m: tuple[float, float, float], heading_rad: float, walks: list[Walk]) -> None:
        self.position = np.asarray(position_m, dtype=float)
        self.heading = float(heading_rad)
        self.walks = list(walks)
        self.velocity = np.zeros(3)
        self.stride_phase = 0.0

    def step(self, t_s: float, dt: float) -> None:
        v = np.zeros(3)
        for w in self.walks:
            if w.t0_s <= t_s < w.t1_s:
                v = np.asarray(w.velocity_mps, dtype=float)
        self.velocity = v
        self.position = self.position + v * dt
        speed = float(np.linalg.norm(v[:2]))
        self.stride_phase += speed * dt / 1.4 * 2 * math.pi  # one stride per 1.4 m

    def joints(self, names: tuple[str, ...] = M.COCO17_NAMES) -> np.ndarray:
        c, s = math.cos(self.heading), math.sin(self.heading)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        amp = 0.25 * math.sin(self.stride_phase) if float(np.linalg.norm(self.velocity[:2])) > 1e-3 else 0.0
        out = np.empty((len(names), 3))
        for i, n in enumerate(names):
            b = np.asarray(BODY_JOINTS[n], dtype=float)
            b = b + np.array([amp * _SWING.get(n, 0.0), 0.0, 0.0])
            out[i] = self.position + rot @ b
        return out

    def centre(self) -> np.ndarray:
        j = self.joints(("left_shoulder", "right_shoulder", "left_hip", "right_hip"))
        return j.mean(axis=0)


class KinematicSim:
    """Vehicle (the MPC model + first-order lag) and subject, stepped at a fixed `dt_s`."""

    def __init__(self, scene: KinematicScene | None = None, *, bounds: Bounds | None = None, tau_s: float = 0.1,
                 kp: float = 4.0, kd: float = 3.5, accel_limit_factor: float = 1.5, dt_s: float = 0.01,
                 follow_horizon: bool = False) -> None:
        """`follow_horizon`: between setpoints, track the published horizon (interpolated, looking
        tau_s ahead) instead of the single setpoint: what a bridge that flies the planned path does;
        it matters for planners that publish rarely (CineMPC: 2.5 Hz)."""
        self.scene = scene or KinematicScene()
        self.follow_horizon = follow_horizon
        self._t_apply = 0.0
        self.bounds = bounds or Bounds()
        self.tau_s, self.kp, self.kd, self.dt_s = tau_s, kp, kd, dt_s
        self.accel_limit = accel_limit_factor * self.bounds.accel_max_mps2
        sc = self.scene
        self.t_s = 0.0
        self.p = np.asarray(sc.vehicle_position_m, dtype=float).copy()
        self.v = np.asarray(sc.vehicle_velocity_mps, dtype=float).copy()
        self.a = np.zeros(3)
        self.ypr = np.asarray(sc.camera_ypr_rad, dtype=float).copy()
        self.lens = np.asarray(sc.lens, dtype=float).copy()
        self.subject = Subject(sc.subject_position_m, sc.subject_heading_rad, sc.walks)
        self._sp: M.Setpoint | None = None
        self._hold: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.holding = False

    # ------------------------------------------------------------------ commands
    def apply(self, sp: M.Setpoint) -> None:
        if sp.mode == "hold" or not sp.valid:
            self.hold()
            return
        self._sp = sp
        self._t_apply = self.t_s
        self.holding = False

    def hold(self) -> None:
        if not self.holding:
            self._hold = (self.p.copy(), self.ypr.copy(), self.lens.copy())
        self.holding = True

    # ------------------------------------------------------------------ integration
    def step(self, duration_s: float) -> None:
        n = max(1, int(round(duration_s / self.dt_s)))
        for _ in range(n):
            self._step_once(self.dt_s)

    def _targets(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if self.holding or self._sp is None:
            if self._hold is None:
                self._hold = (self.p.copy(), self.ypr.copy(), self.lens.copy())
            p, ypr, lens = self._hold
            return p, np.zeros(3), np.zeros(3), ypr, lens
        sp = self._sp
        if self.follow_horizon and sp.horizon_t_s.size >= 2:
            return self._horizon_targets(sp)
        lens = np.array([sp.lens.focal_length_mm, sp.lens.focus_distance_m, sp.lens.f_number])
        lens = np.where(np.isfinite(lens), lens, self.lens)
        return (np.asarray(sp.position_m), np.asarray(sp.velocity_mps), np.asarray(sp.acceleration_mps2),
                np.asarray(sp.camera_ypr_rad), lens)

    def _horizon_targets(self, sp: M.Setpoint) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(sp.horizon_t_s, dtype=float)
        tau = float(np.clip(self.t_s - self._t_apply + self.tau_s, t[0], t[-1]))
        hp = np.asarray(sp.horizon_position_m, dtype=float)
        pos = np.array([np.interp(tau, t, hp[:, i]) for i in range(3)])
        k = int(np.clip(np.searchsorted(t, tau, side="right") - 1, 0, len(t) - 2))
        vel = (hp[k + 1] - hp[k]) / max(t[k + 1] - t[k], 1e-6)
        ang = np.asarray(sp.horizon_camera_ypr_rad, dtype=float).copy()
        ang[:, 0] = np.unwrap(ang[:, 0])
        ypr = np.array([np.interp(tau, t, ang[:, i]) for i in range(3)])
        hl = np.asarray(sp.horizon_lens, dtype=float)
        lens = np.array([np.interp(tau, t, hl[:, i]) for i in range(3)])
        return pos, vel, np.zeros(3), ypr, lens

    def _step_once(self, dt: float) -> None:
        b = self.bounds
        p_sp, v_sp, a_ff, ypr_sp, lens_sp = self._targets()
        a_cmd = a_ff + self.kp * (p_sp - self.p) + self.kd * (v_sp - self.v)
        a_cmd = np.clip(a_cmd, -self.accel_limit, self.accel_limit)
        alpha = dt / (self.tau_s + dt)
        self.a = self.a + alpha * (a_cmd - self.a)
        self.p = self.p + self.v * dt + 0.5 * self.a * dt * dt
        self.v = self.v + self.a * dt
        rate_max = np.array([b.yaw_rate_max_radps, b.pitch_rate_max_radps, b.roll_rate_max_radps])
        err = np.array([wrap_angle(ypr_sp[0] - self.ypr[0]), ypr_sp[1] - self.ypr[1], ypr_sp[2] - self.ypr[2]])
        self.ypr = self.ypr + np.clip(err / self.tau_s, -rate_max, rate_max) * dt
        self.ypr[0] = wrap_angle(self.ypr[0])
        lens_rate = np.array([b.focal_rate_max_mmps, b.focus_rate_max_mps, b.fnumber_rate_max_ps])
        self.lens = self.lens + np.clip((lens_sp - self.lens) / self.tau_s, -lens_rate, lens_rate) * dt
        self.subject.step(self.t_s, dt)
        self.t_s += dt

    # ------------------------------------------------------------------ messages
    def vehicle_state(self, stamp_ns: int) -> M.VehicleState:
        lens = M.LensState(focal_length_mm=float(self.lens[0]), focus_distance_m=float(self.lens[1]),
                           f_number=float(self.lens[2]), sensor_width_mm=cam.SENSOR_WIDTH_MM,
                           sensor_height_mm=cam.SENSOR_HEIGHT_MM, coc_mm=cam.COC_MM)
        return M.VehicleState(stamp_ns=stamp_ns, position_m=self.p.copy(), velocity_mps=self.v.copy(),
                              attitude_ypr_rad=np.array([self.ypr[0], 0.0, 0.0]), camera_ypr_rad=self.ypr.copy(),
                              lens=lens, mode="sim", armed=True, holding=self.holding, backend="kinematic")

    def subject_state(self, stamp_ns: int) -> M.SubjectState:
        return M.SubjectState(stamp_ns=stamp_ns, subject_id="kinematic", joint_names=list(M.COCO17_NAMES),
                              joints_m=self.subject.joints(), velocity_mps=self.subject.velocity.copy())

    # ------------------------------------------------------------------ truth
    def image_points(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Exact normalised image positions (E, 2) of the named joints (shared.camera)."""
        return cam.project_world(self.subject.joints(tuple(names)), self.p, self.ypr, float(self.lens[0]))

    def subject_depth_m(self) -> float:
        """Subject centre's distance along the optical axis [m]."""
        return float(cam.world_to_camera(self.subject.centre(), self.p, self.ypr)[0])

    def dof_limits_m(self) -> tuple[float, float]:
        return cam.dof_limits_m(float(self.lens[0]), float(self.lens[2]), float(self.lens[1]))
