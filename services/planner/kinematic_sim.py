"""A closed-loop harness the planner owns, for its tests, the benchmark and `cinetransfer plan`.

The vehicle is the built-in simulator's own (shared/dynamics.py, limits
from the vehicle profile): a saturated velocity loop with a first-order lag under a position
loop, a rate-limited gimbal and lens, so the planner is tested against the same machine the
bridge's simulator flies (one dynamics model).
The subject is a COCO-17 skeleton that stands or walks (constant-velocity segments, limbs
swinging with the stride), so the planner's constant-velocity prediction is good but not exact.

Ground truth comes from `cinetransfer.shared.camera` (not from the planner's casadi code), so a
closed loop checks the planner's projection against an independent implementation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cinetransfer.shared import camera as cam
from cinetransfer.shared import messages as M
from cinetransfer.shared.dynamics import DynamicsLimits, VehicleDynamics
from cinetransfer.shared.facing import subject_heading
from cinetransfer.shared.vehicle import VehicleProfile, load_vehicle

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
    """The built-in simulator's vehicle, gimbal and lens (shared/dynamics.py: the one dynamics model
    of the project) flying the planner's setpoints, and a kinematic subject, stepped at `dt_s`."""

    def __init__(self, scene: KinematicScene | None = None, *, vehicle: VehicleProfile | None = None,
                 dt_s: float = 0.01, follow_horizon: bool = False, lead_s: float = 0.1) -> None:
        """`vehicle`: the profile whose limits the vehicle flies (default: the default profile).
        `follow_horizon`: between setpoints, track the published horizon (interpolated, looking
        `lead_s` ahead) instead of the single setpoint: what a bridge that flies the planned path
        does; it matters for planners that publish rarely (CineMPC: 2.5 Hz)."""
        self.scene = sc = scene or KinematicScene()
        self.follow_horizon, self.lead_s, self.dt_s = follow_horizon, lead_s, dt_s
        self._t_apply = 0.0
        self.t_s = 0.0
        self.dyn = VehicleDynamics(limits=DynamicsLimits.from_vehicle(vehicle or load_vehicle()),
                                   position=np.asarray(sc.vehicle_position_m, float),
                                   camera_ypr=np.asarray(sc.camera_ypr_rad, float),
                                   focal_mm=float(sc.lens[0]), focus_m=float(sc.lens[1]), f_number=float(sc.lens[2]))
        self.dyn.velocity = np.asarray(sc.vehicle_velocity_mps, float).copy()
        self.subject = Subject(sc.subject_position_m, sc.subject_heading_rad, sc.walks)
        self._sp: M.Setpoint | None = None

    # ------------------------------------------------------------------ state
    @property
    def p(self) -> np.ndarray:
        return self.dyn.position

    @property
    def v(self) -> np.ndarray:
        return self.dyn.velocity

    @property
    def ypr(self) -> np.ndarray:
        return self.dyn.camera_ypr

    @property
    def lens(self) -> np.ndarray:
        return np.array([self.dyn.focal_mm, self.dyn.focus_m, self.dyn.f_number])

    @property
    def holding(self) -> bool:
        return self.dyn.holding

    # ------------------------------------------------------------------ commands
    def apply(self, sp: M.Setpoint) -> None:
        if sp.mode == "hold" or not sp.valid:
            self.hold()
            return
        self._sp = sp
        self._t_apply = self.t_s
        self._track()

    def hold(self) -> None:
        self.dyn.hold()

    def _track(self) -> None:
        sp = self._sp
        if self.follow_horizon and sp.horizon_t_s.size >= 2:
            pos, vel, ypr, lens = self._horizon_targets(sp)
            self.dyn.set_target(position=pos, velocity=vel, camera_ypr=ypr, lens=tuple(lens))
            return
        lens = (sp.lens.focal_length_mm, sp.lens.focus_distance_m, sp.lens.f_number)
        self.dyn.set_target(position=np.asarray(sp.position_m), velocity=np.asarray(sp.velocity_mps),
                            acceleration=np.asarray(sp.acceleration_mps2), camera_ypr=np.asarray(sp.camera_ypr_rad),
                            lens=tuple(float(x) for x in lens))

    # ------------------------------------------------------------------ integration
    def step(self, duration_s: float) -> None:
        n = max(1, int(round(duration_s / self.dt_s)))
        for _ in range(n):
            if self.follow_horizon and self._sp is not None and not self.holding:
                self._track()  # the horizon point to aim at moves on between setpoints
            self.dyn.advance(self.dt_s)
            self.subject.step(self.t_s, self.dt_s)
            self.t_s += self.dt_s

    def _horizon_targets(self, sp: M.Setpoint) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(sp.horizon_t_s, dtype=float)
        tau = float(np.clip(self.t_s - self._t_apply + self.lead_s, t[0], t[-1]))
        hp = np.asarray(sp.horizon_position_m, dtype=float)
        pos = np.array([np.interp(tau, t, hp[:, i]) for i in range(3)])
        k = int(np.clip(np.searchsorted(t, tau, side="right") - 1, 0, len(t) - 2))
        vel = (hp[k + 1] - hp[k]) / max(t[k + 1] - t[k], 1e-6)
        ang = np.asarray(sp.horizon_camera_ypr_rad, dtype=float).copy()
        ang[:, 0] = np.unwrap(ang[:, 0])
        ypr = np.array([np.interp(tau, t, ang[:, i]) for i in range(3)])
        hl = np.asarray(sp.horizon_lens, dtype=float)
        lens = np.array([np.interp(tau, t, hl[:, i]) for i in range(3)])
        return pos, vel, ypr, lens

    # ------------------------------------------------------------------ messages
    def vehicle_state(self, stamp_ns: int) -> M.VehicleState:
        lens = M.LensState(focal_length_mm=float(self.lens[0]), focus_distance_m=float(self.lens[1]),
                           f_number=float(self.lens[2]), sensor_width_mm=cam.SENSOR_WIDTH_MM,
                           sensor_height_mm=cam.SENSOR_HEIGHT_MM, coc_mm=cam.COC_MM)
        return M.VehicleState(stamp_ns=stamp_ns, position_m=self.p.copy(), velocity_mps=self.v.copy(),
                              attitude_ypr_rad=np.array([self.ypr[0], 0.0, 0.0]), camera_ypr_rad=self.ypr.copy(),
                              lens=lens, mode="sim", armed=True, holding=self.holding, backend="kinematic")

    def subject_state(self, stamp_ns: int) -> M.SubjectState:
        joints = self.subject.joints()
        return M.SubjectState(stamp_ns=stamp_ns, subject_id="kinematic", joint_names=list(M.COCO17_NAMES),
                              joints_m=joints, velocity_mps=self.subject.velocity.copy(),
                              heading_rad=subject_heading(self.subject.heading, M.COCO17_NAMES, joints))

    # ------------------------------------------------------------------ truth
    def image_points(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Exact normalised image positions (E, 2) of the named joints (shared.camera)."""
        return cam.project_world(self.subject.joints(tuple(names)), self.p, self.ypr, float(self.lens[0]))

    def subject_depth_m(self) -> float:
        """Subject centre's distance along the optical axis [m]."""
        return float(cam.world_to_camera(self.subject.centre(), self.p, self.ypr)[0])

    def dof_limits_m(self) -> tuple[float, float]:
        return cam.dof_limits_m(float(self.lens[0]), float(self.lens[2]), float(self.lens[1]))
