"""Closed-loop scenarios for tests, the benchmark and `cinetransfer plan`.

`reference_instructions` films a kinematic subject with a scripted reference camera and turns
what that camera saw into Instructions (normalised joint targets + focus booleans), so every
target is reachable by construction. `run_closed_loop` flies a Planner against a simulator
(the planner's KinematicSim, or anything with the same small interface) and records achieved
vs desired framing and depth of field, measured with `cinetransfer.shared.camera`.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from cinetransfer.services.planner.config import PlannerConfig
from cinetransfer.services.planner.core import Planner, absent_regions, instructions_from_arrays
from cinetransfer.services.planner.kinematic_sim import KinematicScene, Subject, Walk
from cinetransfer.shared import camera as cam
from cinetransfer.shared import messages as M

DEFAULT_JOINTS = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")


class SimLike(Protocol):
    t_s: float

    def apply(self, sp: M.Setpoint) -> None: ...
    def step(self, duration_s: float) -> None: ...
    def vehicle_state(self, stamp_ns: int) -> M.VehicleState: ...
    def subject_state(self, stamp_ns: int) -> M.SubjectState: ...


@dataclass
class ReferenceShot:
    """A scripted reference camera relative to the subject centre (functions of time [s])."""

    offset_m: Callable[[float], np.ndarray]  # camera position minus subject centre (world)
    focal_mm: Callable[[float], float]
    focus: Callable[[float], tuple[bool, bool, bool]]  # (foreground, subject, background) in focus


def look_at(cam_pos: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera (yaw, pitch, 0) that puts `target` on the optical axis."""
    d = np.asarray(target, dtype=float) - np.asarray(cam_pos, dtype=float)
    return np.array([math.atan2(d[1], d[0]), math.atan2(d[2], math.hypot(d[0], d[1])), 0.0])


def reference_instructions(scene: KinematicScene, shot: ReferenceShot, *, duration_s: float, fps: float = 24.0,
                           joints: tuple[str, ...] = DEFAULT_JOINTS, mu_m: float = 1.0,
                           sim_dt_s: float = 0.01) -> M.Instructions:
    """Instructions that film `scene`'s subject the way `shot` does."""
    subj = Subject(scene.subject_position_m, scene.subject_heading_rad, copy.deepcopy(scene.walks))
    k_frames = int(round(duration_s * fps))
    targets = np.zeros((k_frames, len(joints), 2), dtype=np.float32)
    focus = np.zeros((k_frames, 3), dtype=bool)
    t = 0.0
    for k in range(k_frames):
        tk = k / fps
        while t < tk - 1e-9:
            subj.step(t, sim_dt_s)
            t += sim_dt_s
        c = subj.centre()
        pos = c + shot.offset_m(tk)
        targets[k] = cam.project_world(subj.joints(joints), pos, look_at(pos, c), shot.focal_mm(tk))
        focus[k] = shot.focus(tk)
    return instructions_from_arrays(targets=targets, joint_names=list(joints), focus_in=focus, fps=fps, mu_m=mu_m)


def standing_shot(focus: tuple[bool, bool, bool] = (False, True, False)) -> ReferenceShot:
    """Fixed medium shot: 5 m in front, slightly to the side, 60 mm."""
    return ReferenceShot(offset_m=lambda t: np.array([-5.0, 0.5, 0.3]), focal_mm=lambda t: 60.0,
                         focus=lambda t: focus)


def dolly_zoom_shot(duration_s: float = 10.0) -> ReferenceShot:
    """The camera backs away from 4 m to 8 m while zooming 40 -> 80 mm (a dolly zoom), the focus
    moves from the subject to the background half way."""
    def frac(t: float) -> float:
        return min(max(t / duration_s, 0.0), 1.0)

    return ReferenceShot(offset_m=lambda t: np.array([-(4.0 + 4.0 * frac(t)), 1.0, 0.4]),
                         focal_mm=lambda t: 40.0 + 40.0 * frac(t),
                         focus=lambda t: (False, True, False) if t < duration_s / 2 else (False, False, True))


def wrong_start_scene(walks: list[Walk] | None = None) -> KinematicScene:
    """The vehicle starts off the shot: too far, to the side, too high, looking away, wrong lens."""
    return KinematicScene(name="wrong-start", vehicle_position_m=(-7.0, 2.0, 2.5), camera_ypr_rad=(0.4, -0.2, 0.0),
                          lens=(40.0, 8.0, 6.0), walks=list(walks or []))


def planner_maker(cfg: PlannerConfig) -> Callable[[], Planner]:
    """A maker of fresh planners that share one solver: building a casadi solver takes seconds, and
    a reset one behaves as new. The loop's clock waits for every solve, so the wall-time budget is
    lifted as in the simulator's lockstep: a loaded machine must not change what a loop flies."""
    from cinetransfer.services.planner.solver import MpcSolver
    solver = MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=cfg.max_solve_time_s)
    solver.set_time_budget(None)

    def make() -> Planner:
        solver.reset()
        return Planner(cfg, solver=solver)
    return make


@dataclass
class LoopLog:
    """Samples on a fixed time grid (framing, depth of field) and, per planner step, what it did."""

    # --- per evaluation sample
    t_s: list[float] = field(default_factory=list)
    plan_index: list[int] = field(default_factory=list)  # index of the setpoint in force
    frame: list[int] = field(default_factory=list)
    image_error: list[float] = field(default_factory=list)  # max over controlled joints of |im - im*| (norm.)
    image_sq: list[float] = field(default_factory=list)  # sum over controlled joints of |im - im*|^2
    depth_m: list[float] = field(default_factory=list)  # subject centre along the optical axis
    near_m: list[float] = field(default_factory=list)
    far_m: list[float] = field(default_factory=list)  # inf when s >= H
    focus_in: list[tuple[bool, bool, bool]] = field(default_factory=list)
    dof_cost: list[float] = field(default_factory=list)  # (d (1/D - 1/D*))^2 summed over the controlled limits
    # --- per planner step
    solve_ms: list[float] = field(default_factory=list)
    status: list[str] = field(default_factory=list)
    mode: list[str] = field(default_factory=list)
    setpoints: list[M.Setpoint] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) for k, v in self.__dict__.items() if k not in ("setpoints", "status", "mode",
                                                                                 "focus_in", "solve_ms")}

    def tracking_cost(self, w_image: float = 200.0, w_dof: float = 5.0) -> float:
        """Mean over the run of w_image * sum |im - im*|^2 + w_dof * DoF error (truth, not the model)."""
        im = np.nan_to_num(np.asarray(self.image_sq), nan=0.0)
        return float(np.mean(w_image * im + w_dof * np.asarray(self.dof_cost)))


def _dof_error(depth: float, near: float, far: float, focus: tuple[bool, bool, bool], mu: float,
               absent: tuple[bool, bool, bool] = (False, False, False)) -> float:
    """Squared DoF error against the focus booleans; as the planner aims (cost.reciprocal_targets),
    a near limit that only keeps an absent foreground out of focus counts only when it is too far."""
    dn, df = cam.desired_dof_limits(*focus, depth, mu)
    d = max(depth, 0.5)
    e = 0.0
    if math.isfinite(dn):
        r = 1.0 / near - 1.0 / max(dn, 1.0)
        e += (d * (min(r, 0.0) if absent[0] and dn > 0 else r)) ** 2
    if math.isinf(df) and df > 0:
        e += (d * max(0.0, 1.0 / far if math.isfinite(far) else 0.0)) ** 2
    elif math.isfinite(df):
        e += (d * ((0.0 if math.isinf(far) else 1.0 / far) - 1.0 / max(df, 0.1))) ** 2
    return e


def run_closed_loop(planner: Planner, sim: SimLike, instructions: M.Instructions, *, duration_s: float,
                    rate_hz: float | None = None, t0_ns: int = 1_700_000_000_000_000_000, start: bool = True,
                    eval_period_s: float = 0.05,
                    truth: Callable[[SimLike, list[str]], tuple[np.ndarray, float, float, float]] | None = None,
                    on_step: Callable[[int, M.Setpoint], None] | None = None) -> LoopLog:
    """Fly `planner` against `sim` for `duration_s` of simulated time (solves do not advance it).

    The planner runs every 1/rate_hz; framing and depth of field are sampled every eval_period_s
    whatever the planner's rate, so planners at different rates are measured on the same grid.
    `truth(sim, joint_names) -> (image points (E, 2), depth, near, far)`; default: a KinematicSim.
    """
    rate = rate_hz or planner.cfg.rate_hz
    period = 1.0 / rate
    names = list(instructions.joint_names)
    absent_all = absent_regions(instructions)  # (K, 3): regions the source does not show
    fps = instructions.fps
    k_rows = instructions.image_targets.shape[0]
    if truth is None:
        def truth(s, jn):  # noqa: ANN001, ANN202
            near, far = s.dof_limits_m()
            return s.image_points(jn), s.subject_depth_m(), near, far
    log = LoopLog()
    if start:
        planner.command(M.Command(action="start"), t0_ns)
    eps = 1e-9
    t = 0.0
    next_plan, next_eval = 0.0, eval_period_s
    i = 0
    while t < duration_s - eps:
        now = t0_ns + int(round(t * 1e9))
        if t >= next_plan - eps:
            sp = planner.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
            sim.apply(sp)
            log.setpoints.append(sp)
            log.solve_ms.append(float(planner.counters.get("solve_ms", float("nan"))))
            log.status.append(sp.solver_status)
            log.mode.append(sp.mode)
            if on_step is not None:
                on_step(i, sp)
            i += 1
            next_plan += period
        t_next = min(next_plan, next_eval, duration_s)
        sim.step(t_next - t)
        t = t_next
        if t < next_eval - eps:
            continue
        next_eval += eval_period_s
        now = t0_ns + int(round(t * 1e9))
        t_rec = planner.recording_time_s(now)
        k = min(planner.start_frame + int(math.floor(t_rec * fps + 1e-9)) - instructions.first_frame, k_rows - 1)
        pts, depth, near, far = truth(sim, names)
        tgt = np.asarray(instructions.image_targets[max(k, 0)], dtype=float)
        ok = np.all(np.isfinite(tgt), axis=1)
        err = np.linalg.norm(pts[ok] - tgt[ok], axis=1) if ok.any() else np.array([np.nan])
        err = np.where(np.isfinite(err), err, 10.0)  # behind the camera: a large error, not NaN
        focus = tuple(bool(b) for b in instructions.focus_in[max(k, 0)])
        absent = tuple(bool(b) for b in absent_all[max(k, 0)])
        log.t_s.append(t)
        log.frame.append(k)
        log.plan_index.append(len(log.setpoints) - 1)
        log.image_error.append(float(np.max(err)))
        log.image_sq.append(float(np.sum(err ** 2)))
        log.depth_m.append(depth)
        log.near_m.append(near)
        log.far_m.append(far)
        log.focus_in.append(focus)  # type: ignore[arg-type]
        log.dof_cost.append(_dof_error(depth, near, far, focus, instructions.mu_m, absent))  # type: ignore[arg-type]
    return log
