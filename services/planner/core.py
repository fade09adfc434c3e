"""The planner's pure logic: instructions + states + time in, a Setpoint out (no Zenoh, no clock).

    planner = Planner(PlannerConfig())
    planner.command(Command(action="start"), now_ns)
    sp = planner.step(now_ns, instructions, vehicle_state, subject_state)

Recording timing: instruction frame k follows the time elapsed since the recording started,
k = start_frame + floor(elapsed * fps). Commands (Command.action):
- 'start' (args: start_frame=int, optional; end_frame=int, optional: the take ends before this
  frame, so the horizon never looks past it into the next shot, which is its own take): elapsed
  := 0, recording;
- 'pause': the instruction time stops (the camera keeps framing the current frame);
- 'resume': the instruction time goes on;
- 'hold': hover in place (like pause, but the vehicle holds instead of framing);
- 'stop': hold and forget the recording (a new 'start' begins at frame start_frame again).
Before 'start' (unless config.autostart) the planner commands a hold. After the last frame of a
final instruction set it keeps the last frame's targets (counters: finished=True).

Failure policy (STYLE §7): every solve's status is checked. On failure the last good plan is
flown for at most tail_max_s (mode 'track', solver_status says so), then a hold is commanded
(valid=False), the warm start is reset, and failures are counted. A Setpoint never holds NaN.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cinetransfer.services.planner import constraints as C
from cinetransfer.services.planner.camera_motion import (DOLLY_ZOOM_MASK, MOTION_MASKS, SIDE_PARAMS, STILL_ALONG,
                                                         TAKE_COLUMNS, ZOOM_MASK, MotionStyle, hold_dolly_zooms,
                                                         plan_for_setpoint_lead, read_motion_style, stage_motion)
from cinetransfer.services.planner.side_of_subject import camera_bearing, side_targets
from cinetransfer.services.planner.clear_side import clear_bearing, side_wanted_for, truck_travel
from cinetransfer.services.planner.zoom_hold import framing_error_now, settled_hold_share
from cinetransfer.services.planner.obstacles import stage_heights, stage_obstacle_params
from cinetransfer.services.planner.config import Bounds, PlannerConfig, Weights
from cinetransfer.services.planner.lens_axes import pinned_bounds
from cinetransfer.services.planner.cost import (defocus_ratio, far_keeps_subject_out, label_sharpness,
                                                near_keeps_subject_out, reciprocal_targets,
                                                subject_softness, switched_out)
from cinetransfer.services.planner.model import Layout, unwrap_near, wrap_angle
from cinetransfer.services.planner.focus_field import (ANKLE_HEIGHT_M, GROUND_BEHIND_SHARE, SHARP_SUBJECT_BLUR,
                                                       SOFT_BAND_BLUR, Band, band_subject_blur,
                                                       focus_ahead_inv_m, foreground_limits, ground_behind_inv_m,
                                                       settled_subject_blur, foreground_near_m, shifted_limits,
                                                       rack_lead_cap_s, rack_ahead_inv_m, ground_band,
                                                       narrowest_spread, three_label_focus_inv_m)
from cinetransfer.services.planner.scene_depth import ray_hits, region_medians_and_flips
from cinetransfer.services.planner.separation import (APERTURE_MARGIN, background_soft_distance_m, framing_k,
                                                      separation_distance_m)
from cinetransfer.services.planner.solver import N_DOF, MpcSolver, SolveResult, StageData
from cinetransfer.shared import camera as cam
from cinetransfer.shared import messages as M
from cinetransfer.shared.facing import by_image_side
from cinetransfer.shared.obstacles import obstacles_from
from cinetransfer.shared.surfaces import surfaces_from
from cinetransfer.shared.focus_regions import FOREGROUND_MIN_ROWS
from cinetransfer.shared.plausible import unusable_targets

log = logging.getLogger("cinetransfer.planner")

CENTRE_JOINTS = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")
FEET_JOINTS = ("left_ankle", "right_ankle")
STATES = ("idle", "recording", "paused", "holding", "stopped")
#: a subject slower than this in the pre-roll is waiting for the take: the camera settles free of the
#: style's camera motion (docs/planner.md, "Camera motion"); one already walking is met with the take's holds
SETTLE_MAX_SUBJECT_SPEED_MPS = 0.3
#: the camera-motion terms that hold the lens or the subject's distance (the zoom rate, the dolly-zoom's distance
#: rate, standing still along the axis): they give way where a row's focus choice needs the lens (lens_for_focus_rows)
LENS_MOTION_COLUMNS = [ZOOM_MASK, DOLLY_ZOOM_MASK, STILL_ALONG]


@dataclass
class Plan:
    """A good solution and when it was computed."""

    t0_ns: int
    x: np.ndarray  # (N+1, nx)
    u: np.ndarray  # (N, nu)
    dt: float
    status: str
    instruction_frame: int

    def at(self, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
        """State (interpolated) and input (piecewise constant) at tau_s after t0 (clamped to the plan)."""
        n = self.u.shape[0]
        t = np.arange(n + 1) * self.dt
        tau = float(np.clip(tau_s, 0.0, t[-1]))
        x = np.array([np.interp(tau, t, self.x[:, i]) for i in range(self.x.shape[1])])
        k = min(int(tau / self.dt), n - 1)
        return x, self.u[k].copy()

    @property
    def length_s(self) -> float:
        return self.u.shape[0] * self.dt


def _finite_lens(lens: M.LensState | None, fallback: np.ndarray) -> np.ndarray:
    if lens is None:
        return fallback.copy()
    v = np.array([lens.focal_length_mm, lens.focus_distance_m, lens.f_number], dtype=float)
    return np.where(np.isfinite(v), v, fallback)


class Planner:
    """CineMPC receding-horizon planner (DESIGN §1.3)."""

    def __init__(self, config: PlannerConfig | None = None, solver: MpcSolver | None = None) -> None:
        self.cfg = (config or PlannerConfig()).validate()
        st = self.cfg.structure
        self.layout = Layout(st.control_roll)
        self.solver = solver or MpcSolver(st, self.cfg.bounds, self.cfg.weights,
                                          max_solve_time_s=self.cfg.max_solve_time_s,
                                          max_cold_solve_time_s=self.cfg.max_cold_solve_time_s,
                                          feasibility_tol=self.cfg.feasibility_tol,
                                          accept_suboptimal=self.cfg.accept_suboptimal)
        self._obstacles = obstacles_from(self.cfg.obstacles_m)
        self._surfaces = surfaces_from(self.cfg.surfaces_m)
        self.state = "idle"
        self._elapsed_s = 0.0  # recording time accumulated before the current run
        self._run_from_ns: int | None = None  # when the current (unpaused) run began
        self.start_frame = 0
        self.end_frame: int | None = None  #: the take's frames end before this one (None: the sequence's end)
        self._plan: Plan | None = None
        self._last_good_ns: int | None = None
        self._hold_pose: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._u_prev = np.zeros(self.layout.nu)
        self._last_lens = np.array([50.0, 10.0, 4.0])
        self._pinned: tuple[tuple[str, ...], Bounds] = ((), self.solver.bounds)  # (axes held fixed, free bounds)
        self.counters: dict[str, object] = {
            "state": self.state, "instruction_frame": -1, "finished": False, "solves": 0, "failures": 0,
            "consecutive_failures": 0, "holds": 0, "tail": False, "solver_status": "", "solve_ms": float("nan"),
            "iterations": -1, "joints_ignored": 0, "commands": 0, "bad_commands": 0, "mode": "hold",
        }
        self.counters.update(scheduled=0, over_budget=0)
        self._scheduled: list[M.Command] = []
        self.last_result: SolveResult | None = None
        #: what is read from one instructions message, by name: (the message, the value) (_per_message)
        self._read_once: dict[str, tuple[object, Any]] = {}

    # ------------------------------------------------------------------ runtime parameters
    def set_weights(self, weights: Weights) -> None:
        self.solver.set_weights(weights)

    def set_bounds(self, bounds: Bounds) -> None:
        self._pinned = ((), bounds)
        self.solver.set_bounds(bounds)

    def _hold_unsupported_lens(self, vehicle: M.VehicleState, lens: np.ndarray) -> None:
        """Lens axes the camera takes no command for are planned fixed where they are (lens_axes.py)."""
        axes = tuple(sorted(getattr(vehicle, "lens_unsupported", None) or ()))
        if axes != self._pinned[0]:
            free = self._pinned[1]
            self._pinned = (axes, free)
            self.solver.set_bounds(pinned_bounds(free, axes, lens))
            log.info("lens axes held fixed: %s", ", ".join(axes) or "none")

    def refuse_instructions(self, ins: M.Instructions) -> str:
        """Why these instructions must not be flown ('' = fine); counted. See `unusable_targets`."""
        why = unusable_targets(ins)
        if why:
            self.counters["instructions_refused"] = int(self.counters.get("instructions_refused", 0)) + 1
        return why

    # ------------------------------------------------------------------ commands and timing
    def command(self, cmd: M.Command, now_ns: int) -> bool:
        """Apply a start/pause/resume/hold/stop command; False (and counted) if not understood.

        A command with `args.at_ns` later than `now_ns` is kept and applied, as of exactly that
        time, by the first `step` whose time has reached it (counter `scheduled`). This is how a
        conductor starts a take at an exact simulation time whatever the message latency.
        """
        self.counters["commands"] = int(self.counters["commands"]) + 1
        at = cmd.args.get("at_ns") if isinstance(cmd.args, dict) else None
        if at is not None:
            if isinstance(at, bool) or not isinstance(at, int):
                return self._bad_command()
            if at > now_ns:
                self._scheduled.append(cmd)
                self._scheduled.sort(key=lambda c: c.args["at_ns"])
                self.counters["scheduled"] = len(self._scheduled)
                self.counters["scheduled_at_ns"] = int(self._scheduled[-1].args["at_ns"])
                return True
            now_ns = max(now_ns, at) if at > 0 else now_ns
        return self._apply(cmd, now_ns)

    def _bad_command(self) -> bool:
        self.counters["bad_commands"] = int(self.counters["bad_commands"]) + 1
        return False

    def _apply(self, cmd: M.Command, now_ns: int) -> bool:
        a = cmd.action
        if a == "start":
            sf = cmd.args.get("start_frame", 0)
            pre = cmd.args.get("preroll_s", 0.0)
            ef = cmd.args.get("end_frame")
            if isinstance(sf, bool) or not isinstance(sf, int) or sf < 0:
                return self._bad_command()
            if ef is not None and (isinstance(ef, bool) or not isinstance(ef, int) or ef <= sf):
                return self._bad_command()
            if isinstance(pre, bool) or not isinstance(pre, (int, float)) or not 0 <= pre <= 600:
                return self._bad_command()
            self.start_frame, self.end_frame = sf, ef
            self._elapsed_s = 0.0
            # the instruction clock starts after the pre-roll; until then the planner frames the
            # start frame (with the horizon already looking into the first frames)
            self._run_from_ns = now_ns + int(round(float(pre) * 1e9))
            self.state = "recording"
            self._forget_plan()  # a take starts cold: same inputs, same flight
        elif a in ("pause", "hold"):
            if self._run_from_ns is not None:
                self._elapsed_s += (now_ns - self._run_from_ns) * 1e-9
                self._run_from_ns = None
            if a == "hold":
                self.state = "holding"
            elif self.state == "recording":
                self.state = "paused"
        elif a == "resume":
            if self.state not in ("paused", "holding"):
                return self._bad_command()
            self._run_from_ns = now_ns
            self.state = "recording"
        elif a == "stop":
            self._elapsed_s, self._run_from_ns = 0.0, None
            self._scheduled.clear()
            self.state = "stopped"
        else:
            return self._bad_command()
        self.counters["state"] = self.state
        log.info("command %r -> state %s", a, self.state)
        return True

    def _apply_due(self, now_ns: int) -> None:
        """Apply scheduled commands whose time has come, each as of its own time."""
        while self._scheduled and self._scheduled[0].args["at_ns"] <= now_ns:
            cmd = self._scheduled.pop(0)
            self._apply(cmd, int(cmd.args["at_ns"]))
        self.counters["scheduled"] = len(self._scheduled)

    def recording_time_s(self, now_ns: int) -> float:
        """Seconds of instruction time elapsed; negative during a pre-roll."""
        run = 0.0 if self._run_from_ns is None else (now_ns - self._run_from_ns) * 1e-9
        return self._elapsed_s + run

    def use_time_budget(self, max_solve_time_s: float | None) -> None:
        """Set the solver's wall-time budget per solve; None lifts it (simulation time: a solve
        then takes as long as it needs, and `over_budget` counts what real time would miss)."""
        self.solver.set_time_budget(max_solve_time_s)
        self._forget_plan()

    def _forget_plan(self) -> None:
        self.solver.reset()
        self._plan = None
        self._last_good_ns = None
        self._hold_pose = None
        self._u_prev = np.zeros(self.layout.nu)

    # ------------------------------------------------------------------ step
    def step(self, now_ns: int, instructions: M.Instructions | None, vehicle: M.VehicleState | None,
             subject: M.SubjectState | None) -> M.Setpoint:
        """One control step: solve (or fall back) and return the setpoint to publish now."""
        self._apply_due(now_ns)
        if self.state == "idle" and self.cfg.autostart and instructions is not None \
                and instructions.image_targets.shape[0]:
            self.command(M.Command(action="start"), now_ns)
        if vehicle is None:
            return self._no_vehicle(now_ns, "no vehicle state")
        refused = self._refused_inputs(now_ns, instructions, vehicle, subject)
        if refused is not None:
            return self._hold(now_ns, vehicle, refused[0], valid=refused[1])
        try:
            data, frame = self._stage_data(now_ns, instructions, vehicle, subject)
        except ValueError as e:  # e.g. no finite joint of the subject
            return self._hold(now_ns, vehicle, f"bad input: {e}", valid=False)
        return self._solve(now_ns, vehicle, data, frame)

    def _refused_inputs(self, now_ns: int, instructions: M.Instructions | None, vehicle: M.VehicleState,
                        subject: M.SubjectState | None) -> tuple[str, bool] | None:
        """Why this step holds instead of tracking (the reason, and whether the hold is valid), or None."""
        cfg = self.cfg
        stale = max(0.0, (now_ns - vehicle.stamp_ns) * 1e-9) > cfg.max_input_age_s
        if not vehicle.valid or stale:
            return "vehicle state stale or invalid", False
        if self.state in ("idle", "stopped", "holding"):
            return self.state, True
        if instructions is None or instructions.image_targets.shape[0] == 0:
            return "no instructions", False
        if unusable_targets(instructions):  # all NaN or absurd: "track" would chase nothing sane
            return "instructions refused", False
        if subject is None or not subject.valid or (now_ns - subject.stamp_ns) * 1e-9 > cfg.max_input_age_s:
            return "subject state missing, stale or invalid", False
        return None

    def _solve(self, now_ns: int, vehicle: M.VehicleState, data: StageData, frame: int) -> M.Setpoint:
        """Solve from the staged data and follow the new plan, or fall back when the solve fails."""
        shift = 0.0 if self._plan is None else (now_ns - self._plan.t0_ns) * 1e-9
        if not 0.0 <= shift <= self.solver.n * self.solver.dt:
            # the clock jumped (a simulation reset, a bridge restart): the last plan says nothing about now
            log.warning("clock moved %+.3f s since the last plan (a jump, or a long pause): warm start reset", shift)
            self.counters["warm_start_resets"] = int(self.counters.get("warm_start_resets", 0)) + 1
            self.solver.reset()
            self._plan, shift = None, 0.0
        try:
            res = self.solver.solve(data, shift_s=shift)
        except (ValueError, RuntimeError) as e:  # non-finite parameters, an exception inside casadi
            log.warning("solve raised: %s", e)
            self._count_failure(solver_status=f"error: {e}"[:200])
            return self._fallback(now_ns, vehicle, f"solver error: {e}"[:200])
        self.last_result = res
        if res.wall_s > self.cfg.max_solve_time_s:  # what a real-time run would have missed
            self.counters["over_budget"] = int(self.counters["over_budget"]) + 1
        self.counters.update(solves=int(self.counters["solves"]) + 1, solver_status=res.status,
                             solve_ms=round(res.wall_s * 1e3, 3), iterations=res.iterations, instruction_frame=frame)
        if res.ok and np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.u)):
            self._plan = Plan(now_ns, res.x.copy(), res.u.copy(), self.solver.dt, res.status, frame)
            self._last_good_ns = now_ns
            self._hold_pose = None
            self.counters.update(consecutive_failures=0, tail=False)
            sp = self._from_plan(now_ns, self._plan, res.status, valid=True)
            if sp is not None:
                return sp
        self._count_failure()
        return self._fallback(now_ns, vehicle, f"failed: {res.status}")

    def _seen_now(self, x0: np.ndarray, joints_w: np.ndarray, weights: np.ndarray, *, by_name: bool) -> np.ndarray:
        """Where the controlled joints are seen from the current camera (E, 2), for matching left and
        right by image side; all NaN (no view: left meets left) when matching `by_name`."""
        if by_name:
            return np.full((joints_w.shape[0], 2), np.nan)
        lay = self.layout
        seen = cam.project_world(joints_w, x0[lay.P], np.array(lay.angles(x0)), float(x0[lay.F]))
        seen[weights == 0] = np.nan  # no joint or not controlled: does not say which way it faces
        return seen

    def _zoom_hold_share(self, x0: np.ndarray, joints_w: np.ndarray, targets: np.ndarray, weights: np.ndarray) -> float:
        """The share of the zoom's hold along the axis that applies now: full once the framing has settled,
        none while it still needs the travel along the axis (zoom_hold.py)."""
        lay = self.layout
        seen = cam.project_world(joints_w, x0[lay.P], np.array(lay.angles(x0)), float(x0[lay.F]))
        share = settled_hold_share(framing_error_now(seen, targets, weights))
        self.counters["zoom_hold_share"] = round(share, 2)
        return share

    def _hold_dolly_zooms(self, motion: np.ndarray, ins: M.Instructions, rows: list[int], x0: np.ndarray,
                          centre: np.ndarray) -> None:
        """A dolly-zoom's zoom held by the camera's travel along its axis now (camera_motion.hold_dolly_zooms)."""
        lay = self.layout
        forward = cam.rotation_ypr(*lay.angles(x0))[:, 0]
        along = float(np.dot(np.asarray(x0[lay.V], dtype=float), forward))
        distance = float(np.linalg.norm(np.asarray(x0[lay.P], dtype=float) - np.asarray(centre, dtype=float)))
        hold_dolly_zooms(motion, self._motion_style(ins), rows, along, distance)

    def _count_failure(self, **more: object) -> None:
        self.counters.update(failures=int(self.counters["failures"]) + 1,
                             consecutive_failures=int(self.counters["consecutive_failures"]) + 1, **more)

    # ------------------------------------------------------------------ stage data
    def _stage_data(self, now_ns: int, ins: M.Instructions, vehicle: M.VehicleState,
                    subject: M.SubjectState) -> tuple[StageData, int]:
        st = self.cfg.structure
        n, e_max, dt = st.horizon_steps, st.max_joints, st.dt_s
        x0 = self._measured_state(now_ns, vehicle)
        subj = predict_subject(subject, now_ns)
        # --- controlled joints
        ctrl = list(ins.joint_names)
        if len(ctrl) > e_max:
            self.counters["joints_ignored"] = len(ctrl) - e_max
        ctrl = ctrl[:e_max]
        jw = np.zeros((e_max, 3))
        jmask = np.zeros(e_max)
        for j, name in enumerate(ctrl):
            if name in subj.names and subj.finite[subj.names.index(name)]:
                jw[j] = subj.joints[subj.names.index(name)]
                jmask[j] = self.cfg.joint_weight(name)  # 1 unless config.joint_weights says otherwise
        rows, frame = self._rows(now_ns, ins, n, dt)
        # by name only where the camera can fly round to the side the style shows: a subject with a heading
        heading = float(getattr(subject, "heading_rad", math.nan))
        by_name = self.cfg.left_right == "name" and math.isfinite(heading)
        seen = self._seen_now(x0, jw[:len(ctrl)], jmask[:len(ctrl)], by_name=by_name)
        image_targets = np.asarray(ins.image_targets, dtype=float)
        targets, mask = stage_targets(image_targets, rows, ctrl, jmask, seen)
        lens_range = (self.solver.bounds.focal_length_min_mm, self.solver.bounds.focal_length_max_mm)
        motion = stage_motion(self._motion_style(ins), rows, control_roll=self.layout.control_roll,
                              focal_range_mm=lens_range)
        self._hold_dolly_zooms(motion, ins, rows, x0, subj.centre)
        plan_for_setpoint_lead(motion, flown_rate_factor(self.cfg.setpoint_lead_s, self.cfg.rate_hz))
        waits = float(np.linalg.norm(subj.vel[:2])) < SETTLE_MAX_SUBJECT_SPEED_MPS
        settle = self._settle_stages(now_ns, n, dt)
        if waits:
            # the pre-roll is not filmed: round a subject who waits on his mark it only settles the framing
            # (held to the take's moves, the camera could not get round him to the first frame's bearing)
            motion[settle, TAKE_COLUMNS] = 0.0
        motion[:, STILL_ALONG] *= self._zoom_hold_share(x0, jw, targets[0], mask[0])
        lens_yields = self._lens_for_focus(ins)[rows]
        motion[np.ix_(lens_yields, LENS_MOTION_COLUMNS)] = 0.0
        self.counters["zoom_yields_to_focus"] = bool(lens_yields.any())
        if by_name:
            bearing = camera_bearing(x0[self.layout.P], subj.centre)
            ne = min(len(ctrl), image_targets.shape[1])
            motion[:, SIDE_PARAMS] = side_targets(image_targets[:, :ne], rows, ctrl[:ne], heading, bearing)
        if waits and settle.any():
            self._truck_clear_side(motion, settle, ins, x0, subj.centre)
        self.counters.update(left_right="name" if by_name else "image_side",
                             side_of_subject=bool(motion[:, SIDE_PARAMS.stop - 1].any()),
                             camera_motion=bool(motion[:, MOTION_MASKS].any()))
        now_row = int(np.clip(frame - ins.first_frame, 0, ins.image_targets.shape[0] - 1))
        dof, dref = self._dof_targets(now_ns, ins, rows, now_row, x0, subj)
        standoff = self._separation_m(ins, now_row, jw, jmask)
        self.counters["separation_m"] = round(standoff, 2)
        u_prev = self._u_prev
        if self._plan is not None:
            _, u_prev = self._plan.at((now_ns - self._plan.t0_ns) * 1e-9)
        data = StageData(x0=x0, u_prev=u_prev, joints_w=jw, subject_centre_w=subj.centre, subject_velocity=subj.vel,
                         targets=targets, mask=mask, dof=dof, distance_ref=dref, motion=motion,
                         min_distance_m=standoff, obstacles=self._obstacle_slots(now_ns, x0))
        return data, frame

    def _truck_clear_side(self, motion: np.ndarray, settle: np.ndarray, ins: M.Instructions, x0: np.ndarray,
                          centre: np.ndarray) -> None:
        """On the pre-roll's stages, the side-of-subject term asks the bearing round the waiting subject from
        which the take's truck misses the keep-outs (clear_side.py), where the camera's own bearing does not;
        the stages are left as they are otherwise."""
        style = self._motion_style(ins)
        self.counters["truck_clear_side_deg"] = 0.0
        if style is None or not self._obstacles:
            return
        p = x0[self.layout.P]
        travel = self._take_truck_travel(ins, style, float(np.linalg.norm(np.asarray(p[:2]) - centre[:2])))
        if not travel.any():
            return
        now = camera_bearing(p, centre)
        clear = clear_bearing(centre, p, float(p[2]), travel, self._obstacles,
                              self.solver.bounds.min_obstacle_distance_m)
        want = side_wanted_for(now, clear)
        if math.isfinite(want):
            motion[settle, SIDE_PARAMS] = (math.cos(want), math.sin(want), 1.0)
            self.counters["truck_clear_side_deg"] = round(math.degrees(math.remainder(clear - now, 2 * math.pi)), 1)

    def _take_truck_travel(self, ins: M.Instructions, style: MotionStyle, distance_m: float) -> np.ndarray:
        """The take's truck travel in the camera's frame (clear_side.truck_travel) at `distance_m` from the subject:
        each row's swing round him as read, or as last read where the source lost him (swing_held_rate)."""
        lo = max(self.start_frame - int(ins.first_frame), 0)
        hi = len(style.classes) if self.end_frame is None else max(self.end_frame - int(ins.first_frame), lo)
        swing = style.bearing_rate if style.bearing_rate is not None else np.full(len(style.classes), np.nan)
        if style.swing_held_rate is not None:
            swing = np.where(np.isfinite(swing), swing, style.swing_held_rate)
        return truck_travel(style.classes[lo:hi], style.travel[lo:hi], swing[lo:hi], _fps(ins), distance_m)

    def _obstacle_slots(self, now_ns: int, x0: np.ndarray) -> np.ndarray:
        """(N, STAGE_SIZE) the obstacle slots of a solve from `x0` at `now_ns`: per stage, the nearest keep-outs the
        horizon can reach at the speed limit, each at the stage's height in the last plan (stage_heights)."""
        b, st = self.solver.bounds, self.cfg.structure
        reach = b.speed_max_mps * st.horizon_steps * st.dt_s
        p = x0[self.layout.P]
        plan = self._plan
        heights = stage_heights(None if plan is None else plan.x[:, self.layout.P][:, 2], st.dt_s,
                                0.0 if plan is None else (now_ns - plan.t0_ns) * 1e-9, st.horizon_steps, float(p[2]))
        return stage_obstacle_params(self._obstacles, p, heights, clearance_m=b.min_obstacle_distance_m, reach_m=reach)

    def _separation_m(self, ins: M.Instructions, now_row: int, jw: np.ndarray, jmask: np.ndarray) -> float:
        """The subject distance the rows of the next `separation_lookahead_s` (within the take) need for
        a subject soft before a sharp background, or sharp before a soft one `background_behind_m`
        behind it (when that is known), each at the framing it asks for (separation.py); 0 if none.
        Both halves of a rack focus ask to back off, so the larger of the two is kept."""
        st, b = self.cfg.structure, self.solver.bounds
        focus = self._planned_focus(ins)
        if self.cfg.separation_lookahead_s <= 0 or focus.ndim != 2 or focus.shape[1:] != (3,):
            return 0.0
        last = min(focus.shape[0], ins.image_targets.shape[0]) - 1
        if self.end_frame is not None:
            last = min(last, self.end_frame - 1 - int(ins.first_frame))
        hi = min(last, now_row + int(math.ceil(self.cfg.separation_lookahead_s * _fps(ins))))
        absent, smoothed = absent_regions(ins), smoothed_focus(ins)
        ratio = st.defocus_coc_ratio / st.sharp_coc_ratio
        ne = min(jw.shape[0], ins.image_targets.shape[1])
        z = np.where(jmask[:ne] > 0, jw[:ne, 2], np.nan)
        keep_outs_m = self._keep_outs_m(ins)
        rows = {"subject_soft": ([], [], []), "background_soft": ([], [], [])}
        for r in range(max(now_row, 0), hi + 1):
            kind = separation_kind(focus[r], absent[r])
            if kind is None:
                continue
            region = 1 if kind == "subject_soft" else 2
            soft = subject_softness(float(smoothed[r, region]), float(ins.theta)) if len(smoothed) > r else 1.0
            rows[kind][0].append(framing_k(np.asarray(ins.image_targets[r, :ne, 1], float), z, st.sensor_height_mm))
            rows[kind][1].append(defocus_ratio(True, ratio, soft))
            rows[kind][2].append(float(keep_outs_m[r]))
        ks, ratios, keep_outs = rows["subject_soft"]
        subject_soft = separation_distance_m(ks, ratios, f_number_min=b.f_number_min, coc_mm=st.plan_coc_mm,
                                             mu_m=keep_outs, focus_max_m=b.focus_distance_max_m,
                                             focal_max_mm=b.focal_length_max_mm)
        background_soft = 0.0 if math.isinf(self.cfg.background_behind_m) else background_soft_distance_m(
            *rows["background_soft"][:2], f_number_min=b.f_number_min, coc_mm=st.plan_coc_mm,
            behind_m=self.cfg.background_behind_m, focal_max_mm=b.focal_length_max_mm)
        self.counters["separation_background_soft_m"] = round(background_soft, 2)
        return max(subject_soft, background_soft)

    def _planned_focus(self, ins: M.Instructions) -> np.ndarray:
        """The style's focus rows as the planner films them (planned_focus_rows), once per instructions message."""
        max_rows = int(round(RACK_THROUGH_MAX_S * _fps(ins)))
        return self._per_message("focus", ins, lambda: planned_focus_rows(ins.focus_in, absent_regions(ins), max_rows,
                                                                        getattr(ins, "shot_start", None)))

    def _rack_ahead(self, ins: M.Instructions) -> np.ndarray:
        """(K,) the switch row of the rack away from the subject each row may plan ahead of (rack_switch_ahead),
        -1 for none, once per instructions message."""
        fps = _fps(ins)
        lead, hold = int(round(self.cfg.rack_lead_max_s * fps)), int(round(self.cfg.rack_lead_min_hold_s * fps))
        return self._per_message("rack_ahead", ins, lambda: rack_switch_ahead(
            self._planned_focus(ins), absent_regions(ins), lead, hold, getattr(ins, "shot_start", None)))

    def _rack_settle_rows(self, ins: M.Instructions) -> np.ndarray:
        """(K,) bool: the rows of keep_out_settle_s from each rack away from the subject inside a shot
        (rack_settle_rows), once per instructions message."""
        fps = _fps(ins)
        settle, hold = int(round(self.cfg.keep_out_settle_s * fps)), int(round(self.cfg.rack_lead_min_hold_s * fps))
        return self._per_message("rack_settle", ins, lambda: rack_settle_rows(
            self._planned_focus(ins), absent_regions(ins), settle, hold, getattr(ins, "shot_start", None)))

    def _subject_travel_s(self, depth_m: float, focal_mm: float) -> float:
        """How long the focus takes at the lens's rate from the subject `depth_m` away to where he is one circle
        soft behind it (1/s = 1/d - sigma, the one circle's spread at the aperture planned for, as
        _subject_only_limits; the lens's far end where that lies beyond it)."""
        b = self.solver.bounds
        spread = self._planned_spread(focal_mm)
        x1 = 1.0 / depth_m - spread
        s1 = min(1.0 / x1, b.focus_distance_max_m) if x1 > 0 else b.focus_distance_max_m
        return max(s1 - depth_m, 0.0) / b.focus_rate_mps

    def _rack_lead_s(self, xk: np.ndarray, subj: PredictedSubject, t: float, depth_m: float) -> float:
        """How long before a rack away from the subject `depth_m` away a stage plans the switch's row [s]: half the
        focus's travel to where he is one circle soft (_subject_travel_s, RACK_LEAD_SHARE), and with
        rack_lead_background_gate no longer than the focus may travel before the background enters the field
        (focus_field.rack_lead_cap_s): the background `background_behind_m` behind him where that is given, else
        the ground behind him the planned camera sees (ground_behind_inv_m, GROUND_BEHIND_SHARE); no lead with
        neither known. Ungated, the dancer's background 30 m behind her went sharp 5-10 frames before her switch."""
        focal = float(xk[self.layout.F])
        lead = RACK_LEAD_SHARE * self._subject_travel_s(depth_m, focal)
        if not self.cfg.rack_lead_background_gate:
            return lead
        if math.isfinite(self.cfg.background_behind_m):
            background = 1.0 / (depth_m + self.cfg.background_behind_m)
        else:
            background = self._ground_behind_inv_m(xk, subj, t)
            if background is None:
                return 0.0
        cap = rack_lead_cap_s(depth_m, background, spread=self._planned_spread(focal),
                              rate_mps=self.solver.bounds.focus_rate_mps)
        return min(lead, cap)

    def _rack_ahead_inv_m(self, xk: np.ndarray, subj: PredictedSubject, t: float, depth_m: float) -> float:
        """How far in front of the subject `depth_m` away a row wanting only him sharp before a rack away from him puts
        the focus [1/m]: until the ground behind him the planned camera sees (ground_behind_inv_m at
        GROUND_BEHIND_SHARE) is SOFT_BAND_BLUR circles soft, at most `rack_ahead_max_circles`, the one circle's spread
        taken at the aperture planned for (focus_field.rack_ahead_inv_m); 0 with no ankle seen."""
        most = self.cfg.rack_ahead_max_circles
        background = self._ground_behind_inv_m(xk, subj, t) if most > 0 else None
        if background is None:
            return 0.0
        return rack_ahead_inv_m(depth_m, background, spread=self._planned_spread(float(xk[self.layout.F])),
                                background_blur=SOFT_BAND_BLUR, most=most)

    def _soft_background_ahead_inv_m(self, focal_mm: float) -> float:
        """How far in front of the subject a row pinned round him before a soft background with no foreground
        puts the focus [1/m] (pins_field_before_soft_background): focus_field.SHARP_SUBJECT_BLUR of the one circle's
        spread at the aperture planned for, whatever the ground behind him. The planner knows no depth of the
        background but the ground's, and by it tos_clip01's background was soft already; centred on him, what the
        truth saw 14-20 m behind him was about 1.0-1.4 circles soft and read sharp to the focus estimator (raw
        0.46-0.61 against 0.5)."""
        return SHARP_SUBJECT_BLUR * self._planned_spread(focal_mm)

    def _planned_spread(self, focal_mm: float) -> float:
        """The one circle's spread [1/m] at `focal_mm` and the aperture planned for (APERTURE_MARGIN times the
        widest; focus_field.narrowest_spread)."""
        return narrowest_spread(focal_mm, APERTURE_MARGIN * self.solver.bounds.f_number_min, self.cfg.structure.coc_mm)

    def _mu_m(self, ins: M.Instructions) -> float:
        """The instructions' depth-of-field margin mu [m], or `mu_default_m` when they carry none."""
        return float(ins.mu_m) if math.isfinite(ins.mu_m) and ins.mu_m > 0 else self.cfg.mu_default_m

    def _keep_outs_m(self, ins: M.Instructions) -> np.ndarray:
        """How far past the subject's centre each row keeps him out [m] (K,): `_keep_out_m` on the rows
        of keep_out_rows, mu on the others."""
        mu = self._mu_m(ins)
        return np.where(self._keep_out_rows(ins), self._keep_out_m(mu), mu)

    def _keep_out_rows(self, ins: M.Instructions) -> np.ndarray:
        """The rows that keep the subject out by `subject_keep_out_m` (keep_out_rows), once per instructions message."""
        settle = int(round(self.cfg.keep_out_settle_s * _fps(ins)))
        return self._per_message("keep_out", ins,
                                 lambda: keep_out_rows(self._planned_focus(ins), absent_regions(ins), settle))

    def _lens_for_focus(self, ins: M.Instructions) -> np.ndarray:
        """(K,) bool: the rows whose zoom and distance motion terms give way to the focus choice
        (lens_for_focus_rows), once per instructions message."""
        fps = _fps(ins)
        lead = int(round(self.cfg.zoom_yield_lead_s * fps)) if self.cfg.zoom_yields_to_focus else -1
        settle = int(round(self.cfg.keep_out_settle_s * fps))
        return self._per_message("lens", ins, lambda: lens_for_focus_rows(
            self._planned_focus(ins), absent_regions(ins), lead, settle, getattr(ins, "shot_start", None)))

    def _centred_before_rack(self, ins: M.Instructions) -> np.ndarray:
        """(K,) bool: the rows of a shot before a switch of the subject's label in it (a rack focus;
        lens_for_focus_rows with a lead of the whole style), where only the subject sharp is not moved by the
        foreground band (focus_ahead_inv_m) but by the ground behind him, at most rack_ahead_max_circles
        (_rack_ahead_inv_m): the focus in front of him has farther to travel past him at the switch
        (docs/planner.md)."""
        k = len(ins.focus_in) if ins.focus_in is not None else 0
        return self._per_message("centred", ins, lambda: lens_for_focus_rows(
            self._planned_focus(ins), absent_regions(ins), k, 0, getattr(ins, "shot_start", None)))

    def _shot_held(self, ins: M.Instructions) -> tuple[np.ndarray, np.ndarray]:
        """(shot numbers, last labelled row of each row's shot) of shot_choice_held, once per instructions message;
        every row in one shot with the option later_shot_after_choice off."""
        def read() -> tuple[np.ndarray, np.ndarray]:
            absent = absent_regions(ins)
            if not self.cfg.later_shot_after_choice:
                return np.ones(len(absent), dtype=int), np.full(len(absent), -1, dtype=int)
            return shot_choice_held(absent, getattr(ins, "shot_start", None),
                                    int(round(self.cfg.later_shot_hold_min_s * _fps(ins))))
        return self._per_message("shot_held", ins, read)

    def _motion_style(self, ins: M.Instructions) -> MotionStyle | None:
        """The instructions' camera-motion style, read once per instructions message."""
        return self._per_message("motion", ins, lambda: read_motion_style(ins))

    def _per_message(self, name: str, ins: M.Instructions, read: Callable[[], Any]) -> Any:
        """`read()` once per instructions message: kept under `name` until another message comes."""
        held = self._read_once.get(name)
        if held is None or held[0] is not ins:
            held = self._read_once[name] = (ins, read())
        return held[1]

    def _measured_state(self, now_ns: int, vehicle: M.VehicleState) -> np.ndarray:
        """The state x0 the solve starts from: the vehicle's, position predicted to `now`, yaw
        unwrapped near the plan's, lens from the last finite values, clamped into the bounds."""
        lay = self.layout
        x0 = np.zeros(lay.nx)
        dt_v = max(0.0, (now_ns - vehicle.stamp_ns) * 1e-9)
        x0[lay.P] = np.asarray(vehicle.position_m, dtype=float) + np.asarray(vehicle.velocity_mps) * dt_v
        x0[lay.V] = vehicle.velocity_mps
        ypr = np.asarray(vehicle.camera_ypr_rad, dtype=float)
        ref_yaw = float(self._plan.x[0, lay.YAW]) if self._plan is not None else float(ypr[0])
        x0[lay.YAW] = unwrap_near(float(ypr[0]), ref_yaw)
        x0[lay.PITCH] = ypr[1]
        if lay.control_roll:
            x0[lay.ROLL] = ypr[2]
        lens = _finite_lens(vehicle.lens, self._last_lens)
        self._hold_unsupported_lens(vehicle, lens)
        x0[lay.F], x0[lay.S], x0[lay.A] = lens
        x0, _ = C.clamp_state(lay, self.solver.bounds, x0, self.cfg.clamp_tolerance)
        if not np.all(np.isfinite(x0)):
            raise ValueError("non-finite vehicle state")
        return x0

    def _stage_view(self, now_ns: int, t: float, x0: np.ndarray, subj: PredictedSubject) -> tuple[np.ndarray, float]:
        """(the planned state `t` s ahead, or x0 with no plan; the predicted subject's depth from it, >= 0.5 m)."""
        lay = self.layout
        xk = x0 if self._plan is None else self._plan.at((now_ns - self._plan.t0_ns) * 1e-9 + t)[0]
        yaw, pitch, roll = lay.angles(xk)
        depth = float(cam.world_to_camera(subj.centre + subj.vel * t, xk[lay.P], np.array([yaw, pitch, roll]))[0])
        return xk, max(depth, 0.5)

    def _dof_targets(self, now_ns: int, ins: M.Instructions, rows: list[int], now_row: int, x0: np.ndarray,
                     subj: PredictedSubject) -> tuple[np.ndarray, np.ndarray]:
        """Depth-of-field targets (n, N_DOF) of the stages and the subject distance along the planned
        camera (n,), from the predicted subject depth (the plan's state, or x0 with no plan);
        `now_row` is the instruction row followed now (visible defocus: cost.switched_out)."""
        st, lay = self.cfg.structure, self.layout
        n, dt = len(rows), st.dt_s
        mu = self._mu_m(ins)
        focus = self._planned_focus(ins)
        absent = absent_regions(ins)
        b_all = smoothed_focus(ins)
        b_subject = smoothed_subject_focus(ins)
        rows3 = focus.tolist() if focus.shape[-1:] == (3,) else []
        keeps_out = [far_keeps_subject_out(*row) for row in rows3]
        near_out = [near_keeps_subject_out(*row) for row in rows3]
        ratio = st.defocus_coc_ratio / st.sharp_coc_ratio
        keep, keep_outs_m = self._keep_out_rows(ins), self._keep_outs_m(ins)
        settling = self._rack_settle_rows(ins)
        rack_ahead, fps = self._rack_ahead(ins), _fps(ins)
        # rows centred on the subject whatever the background: marked as if it were absent
        centred = np.zeros_like(absent)
        centred[:, 2] = self._centred_before_rack(ins)
        near_free = unmeasured_subject_rows(absent) if self.cfg.unmeasured_subject_near_free \
            else np.zeros(len(absent), dtype=bool)
        shot_held = self._shot_held(ins)
        dof = np.zeros((n, N_DOF))
        dof[:, 6:8] = 1.0  # the far and near limits' circle-of-confusion ratios (cost.defocus_ratio)
        dref = np.zeros(n)
        made = -1  # the switch a stage of this horizon plans as made (the lead): the stages past it plan it so too
        switch_now = int(rack_ahead[now_row]) if 0 <= now_row < len(rack_ahead) else -1  # the switch led to now
        for k, r in enumerate(rows):
            t = (k + 1) * dt
            xk, depth = self._stage_view(now_ns, t, x0, subj)
            dref[k] = depth
            if not later_shot_previewed(shot_held, now_row, r):
                continue  # a later shot flown in this take asks nothing yet: the lens keeps this shot's choice
            ahead = int(rack_ahead[r]) if r < len(rack_ahead) else -1
            made = self._switch_made(made, switch_now, now_row, r, fps, (xk, subj, t, depth))
            now_k = max(now_row, made) if 0 <= made <= r else now_row
            own = r  # the stage's own row, before a lead plans it as the switch's
            if ahead >= 0 and (ahead - r) / fps <= self._rack_lead_s(xk, subj, t, depth):
                # the rack away from him starts so that his travel to soft straddles the switch, planned as made:
                # previewed by the sharpness circle alone the focus stopped half-way (him 0.5 circles soft, his
                # foreground sharp) and left the rest of the travel for after the switch
                r = now_k = made = ahead
            # a row with no region labelled (a shot without a focus measurement) leaves the lens free
            if focus.shape[0] > r and focus.shape[1] == 3 and not absent[r].all():
                band = self._foreground_band(xk, subj, t)
                soft = subject_softness(float(b_subject[r]), float(ins.theta)) if len(b_subject) > r else 1.0
                dof[k, 6] = defocus_ratio(keeps_out[r] and switched_out(keeps_out, now_row, r), ratio, soft)
                near, far = self._row_limits(focus[r], depth, mu, band, float(xk[lay.F]), dof[k, 6],
                                             keep_out_m=float(keep_outs_m[r]),
                                             absent_row=absent[r] | centred[r],
                                             map_medians=self._together_medians(focus[r], absent[r] | centred[r],
                                                                                xk, subj, t))
                if centred[r, 2] and not absent[r, 2] and tuple(focus[r]) == (False, True, False):
                    near, far = shifted_limits(near, far, self._rack_ahead_inv_m(xk, subj, t, depth))
                free = bool(r < len(near_free) and near_free[r]) and near > 0
                near = math.inf if free else near
                kept_out = near_out[r] and not free
                # a near limit that keeps the subject out stays two-sided, and so does one that pins the field
                # round him before a soft background (pins_field_before_soft_background)
                pinned = self.cfg.soft_background_pins_near and not free and pins_field_before_soft_background(
                    focus[r], absent[r] | centred[r])
                if pinned and absent[r, 0]:
                    near, far = shifted_limits(near, far, self._soft_background_ahead_inv_m(float(xk[lay.F])))
                # with the subject kept out by the near limit the far limit of the sharpness circle (3/8 of
                # the one circle) at infinity is margin enough: the extra margin would cap the focus at half
                # its longest and the subject's blur with it (separation.py)
                dof[k, :6] = reciprocal_targets(near, far, near_foreground_m=st.near_foreground_m,
                                                far_margin_inv_m=0.0 if kept_out else st.far_margin_inv_m,
                                                fg_absent=bool(absent[r, 0]) and not (near_out[r] or pinned))
                dof[k, 7] = defocus_ratio(near_out[r] and switched_out(near_out, now_k, r), ratio, soft)
                if own == r and r < len(settling) and settling[r] and switched_out(near_out, now_k, r):
                    # past the switch the focus travels at its rate; the parkour framing meanwhile zoomed out
                    # at the zoom's rate (88 -> 71 mm), widening the field by half, and the runner fell back
                    # to 1.03-1.10 circles, read sharp in 8 frames: weighted (x2), the near limit held the
                    # focal (77 mm) and him 1.14-1.20 circles soft
                    dof[k, 0] *= self.cfg.rack_settle_near_weight
                if focus[r, 0] and not absent[r, 0] and len(b_all) > r:
                    # a borderline foreground label asks its near limit as little as it is sharp
                    dof[k, 0] *= label_sharpness(float(b_all[r, 0]), float(ins.theta))
                if free and math.isinf(far) and far > 0:
                    # nothing pins the focus: a far limit at infinity is met by stopping down (f/9 in tos_clip01's
                    # take 3), so it reaches the ground behind him the camera sees, where one is seen
                    ground = self._ground_behind_inv_m(xk, subj, t)
                    dof[k, 3] = ground if ground else dof[k, 3]
                if kept_out and keep[r]:
                    # settled on the subject soft, the background needs only the one circle's far limit at
                    # infinity, not the sharpness circle's: the parkour rack's soft runner read soft in 10
                    # more of its last frames (the focus a little farther), nothing else measured moved
                    dof[k, 6] = 1.0 / st.sharp_coc_ratio
                    blur = self._settled_blur(xk, subj, t, depth + float(keep_outs_m[r]))
                    settled_ratio = blur / st.sharp_coc_ratio
                    dof[k, 7] = defocus_ratio(switched_out(near_out, now_row, r), settled_ratio, soft)
                dof[k, 2] *= float(far_previewed(focus, near_out, now_k, r))
            if self._lead_holds_subject(focus, absent, own, r, fps):
                dof[k] = held_lead_dof(depth, blur=LEAD_HOLD_BLUR, sharp_coc_ratio=st.sharp_coc_ratio,
                                       weight=LEAD_HOLD_WEIGHT)
        return dof, dref

    def _switch_made(self, made: int, switch_now: int, now_row: int, row: int, fps: float, view: tuple) -> int:
        """The switch a stage at `row` plans as made: `made` where a stage before it set one, else `switch_now` (the
        switch the row followed now leads to) where the stage lies at or past it with that row inside its lead
        (`view`: the stage's planned state, subject, time ahead and depth for _rack_lead_s), else none (-1). With the
        horizon's first stage past it no stage was a lead stage, these previewed it, and the parkour rack's lens
        stopped down to f/1.36 on its last two rows before it (runner and band sharp three more frames)."""
        if made >= 0 or not 0 <= switch_now <= row:
            return made
        return switch_now if (switch_now - now_row) / fps <= self._rack_lead_s(*view) else made

    def _lead_holds_subject(self, focus: np.ndarray, absent: np.ndarray, own: int, switch: int, fps: float) -> bool:
        """Whether a stage whose own row `own` a lead plans as the row `switch` (a later row: the rack's switch) holds
        the subject sharp (held_lead_dof) rather than planning him soft already: the own row wants him sharp and
        the switch the background sharp (a rack onto the background), at most rack_lead_hold_s ahead of it."""
        return (0 < switch - own <= self.cfg.rack_lead_hold_s * fps and focus.shape[-1:] == (3,)
                and bool(focus[own, 1]) and not absent[own, 1] and bool(focus[switch, 2]) and not absent[switch, 2])

    def _row_limits(self, row: np.ndarray, depth: float, mu: float, band: Band | None,
                    focal_mm: float, far_ratio: float, keep_out_m: float,
                    absent_row: np.ndarray, map_medians: tuple[float, ...] | None = None) -> tuple[float, float]:
        """Target limits (D_n*, D_f*) [m] of a row's labels (shared.camera.desired_dof_limits), with
        "only the background sharp" keeping the subject out by `keep_out_m` past his centre (the row's
        keep-out, _keep_outs_m), "only the subject sharp" before a present background moved in front of
        him (_subject_only_limits; with the scene's map, `map_medians`, where the three labels come together), and
        "only the foreground sharp" aimed
        at the ground the foreground band shows (focus_field; the far limit's circle is `far_ratio` times
        the planning circle)."""
        st = self.cfg.structure
        fg, subject, bg = cam.realisable_labels(*(bool(v) for v in row))
        near, far = cam.desired_dof_limits(fg, subject, bg, depth, mu, defocus_when_none=st.defocus_when_none)
        if subject and not (fg or bg) and not absent_row[2] and near > 0:
            return self._subject_only_limits(near, far, depth, band, focal_mm, fg_absent=bool(absent_row[0]),
                                             map_medians=map_medians)
        if bg and not subject:
            # only the subject is kept out, by the visible circle's near limit: with a keep-out given, past his
            # own back rather than mu past his centre (parkour, subject soft: the lawn right behind him went soft)
            near = depth + keep_out_m
        if fg and not subject and band is not None:
            # with the subject sharp too the field is deep and 1 m holds whatever the band shows: focus_hedge's
            # hedge 1.7 m away in tos_clip01 went soft when aimed at the ground (foreground 1.00 -> 0.00)
            spread = narrowest_spread(focal_mm, APERTURE_MARGIN * self.solver.bounds.f_number_min, st.plan_coc_mm)
            blur = band_subject_blur(depth, band, spread=spread / st.sharp_coc_ratio)
            limits = foreground_limits(depth, spread=spread, sharp_ratio=st.sharp_coc_ratio, far_ratio=far_ratio,
                                       subject_blur=blur)
            near, far = limits or (foreground_near_m(band, far, spread_min=spread,
                                                     soft_ratio=st.defocus_coc_ratio / st.sharp_coc_ratio), far)
        return near, far

    def _subject_only_limits(self, near: float, far: float, depth: float, band: Band | None, focal_mm: float, *,
                             fg_absent: bool, map_medians: tuple[float, ...] | None = None) -> tuple[float, float]:
        """(D_n*, D_f*) [m] of "only the subject sharp" with the background present: d -+ mu moved in front of
        him by focus_ahead_inv_m, the one circle's spread taken at the widest aperture planned for. Centred on
        him, a field wider than he is deep left parkour's backdrop 1.0-1.35 circles soft: sharp to the focus
        estimator (docs/planner.md, "Only the subject sharp: the focus in front of him"). With the scene's map
        (`map_medians`, the band's and the background's median inverse depths and flips) the focus goes where both are
        softest together, wide open, as far as that is within reach (focus_field.three_label_focus_inv_m)."""
        if not self.cfg.subject_only_focus_ahead and map_medians is None:
            return near, far
        b, coc = self.solver.bounds, self.cfg.structure.coc_mm
        ahead = 0.0
        if self.cfg.subject_only_focus_ahead:
            spread = narrowest_spread(focal_mm, APERTURE_MARGIN * b.f_number_min, coc)
            ahead = focus_ahead_inv_m(depth, band, fg_absent=fg_absent, spread=spread)
        if map_medians is not None:
            spread = narrowest_spread(focal_mm, b.f_number_min, coc)
            ahead = three_label_focus_inv_m(depth, *map_medians[:2], spread=spread, otherwise_inv_m=ahead,
                                            flips=map_medians[2:])
        return shifted_limits(near, far, ahead)

    def _together_medians(self, row: np.ndarray, absent_row: np.ndarray, xk: np.ndarray, subj: PredictedSubject,
                          t: float) -> tuple[float, ...] | None:
        """For a row with only the subject sharp before a present foreground and background, what the scene's map
        shows the planned camera `xk` `t` s ahead (_map_medians); None where no map is given or the row is another."""
        if not self._surfaces or tuple(cam.realisable_labels(*(bool(v) for v in row))) != (False, True, False) \
                or bool(absent_row[0]) or bool(absent_row[2]):
            return None
        return self._map_medians(xk, subj, t)

    def _map_medians(self, xk: np.ndarray, subj: PredictedSubject, t: float) -> tuple[float, ...] | None:
        """(foreground band, background) median inverse depths [1/m] the planned camera `xk` sees `t` s ahead on the
        scene's map (the ground and the known surfaces, scene_depth.region_medians_and_flips), then the focus
        estimator's flips [circles] on what their medians show; None without an ankle."""
        view = self._ground_view(xk, subj, t)
        if view is None:
            return None
        st, lay = self.cfg.structure, self.layout
        ypr = np.array([float(a) for a in lay.angles(xk)])
        sensor = cam.Sensor(st.sensor_width_mm, st.sensor_height_mm)
        pos, focal = xk[lay.P], float(xk[lay.F])
        ground_z = self.cfg.ground_z_m if math.isfinite(self.cfg.ground_z_m) else float(pos[2]) - view[1]["height_m"]
        return region_medians_and_flips(view[0], lambda pts: ray_hits(
            pts, pos, ypr, focal_mm=focal, sensor=sensor, ground_z_m=ground_z, surfaces=self._surfaces))

    def _keep_out_m(self, mu: float) -> float:
        """How far past the subject's centre a row wanting only the background sharp keeps him out [m]:
        `subject_keep_out_m`, or mu when that is 0."""
        return self.cfg.subject_keep_out_m if self.cfg.subject_keep_out_m > 0 else mu

    def _foreground_band(self, xk: np.ndarray, subj: PredictedSubject, t: float) -> Band | None:
        """The ground the foreground band shows from the planned camera `xk`, `t` s ahead: below the
        subject's ankles, from the row of his soles down (focus_field.ground_band); None without an ankle."""
        view = self._ground_view(xk, subj, t)
        return None if view is None else ground_band(view[0], **view[1], min_rows=FOREGROUND_MIN_ROWS)

    def _ground_view(self, xk: np.ndarray, subj: PredictedSubject, t: float) -> tuple[float, dict] | None:
        """The row of the subject's soles from the planned camera `xk`, `t` s ahead, and how that camera sees
        the ground they stand on (focus_field.ground_inverse_depth's keywords); None without an ankle."""
        idx = [subj.names.index(n) for n in FEET_JOINTS if n in subj.names and subj.finite[subj.names.index(n)]]
        if not idx:
            return None
        st, lay = self.cfg.structure, self.layout
        soles = subj.joints[idx] + subj.vel * t
        ground_z = float(soles[:, 2].min()) - ANKLE_HEIGHT_M
        soles[:, 2] = ground_z
        ypr = np.array([float(a) for a in lay.angles(xk)])
        v = cam.project_world(soles, xk[lay.P], ypr, float(xk[lay.F]),
                              cam.Sensor(st.sensor_width_mm, st.sensor_height_mm))[:, 1]
        if not np.isfinite(v).any():
            return None
        return float(np.nanmax(v)), {"height_m": float(xk[lay.P][2]) - ground_z, "pitch_rad": float(ypr[1]),
                                     "focal_mm": float(xk[lay.F]), "sensor_height_mm": st.sensor_height_mm}

    def _ground_behind_inv_m(self, xk: np.ndarray, subj: PredictedSubject, t: float) -> float | None:
        """The inverse depth [1/m] of the ground behind the subject that the planned camera `xk` sees `t` s ahead
        (focus_field.ground_behind_inv_m at GROUND_BEHIND_SHARE; 0: that row sees no ground); None without an
        ankle."""
        view = self._ground_view(xk, subj, t)
        return None if view is None else ground_behind_inv_m(view[0], GROUND_BEHIND_SHARE, **view[1])

    def _settled_blur(self, xk: np.ndarray, subj: PredictedSubject, t: float, back_m: float) -> float:
        """The blur [circles] a settled soft subject is asked with only the background sharp: settled_subject_blur,
        less where the ground behind him (focus_field.ground_behind_inv_m) needs the sharp zone nearer, never
        under focus_field.LEAST_SOFT_SUBJECT_BLUR (focus_field.settled_subject_blur; option
        settled_blur_from_ground)."""
        most = self.cfg.settled_subject_blur
        ground = self._ground_behind_inv_m(xk, subj, t) if self.cfg.settled_blur_from_ground else None
        if ground is None:
            return most
        return settled_subject_blur(back_m, ground, spread=self._planned_spread(float(xk[self.layout.F])), most=most)

    def _settle_stages(self, now_ns: int, n: int, dt: float) -> np.ndarray:
        """Which of stages 1..n still lie in the take's pre-roll (recording, before instruction time 0)."""
        t = self.recording_time_s(now_ns) + dt * np.arange(1, n + 1)
        return (t < 0.0) & (self.state == "recording")

    def _rows(self, now_ns: int, ins: M.Instructions, n: int, dt: float) -> tuple[list[int], int]:
        """Instruction rows of stages 1..n and the source frame index followed now."""
        k_rows = ins.image_targets.shape[0]
        fps = _fps(ins)
        t = self.recording_time_s(now_ns)
        moving = self.state == "recording"
        self.counters["phase"] = "settle" if moving and t < 0 else ("take" if moving else self.state)

        def frame_at(tt: float) -> int:
            return self.start_frame + int(math.floor(tt * fps + 1e-9))

        frame = max(frame_at(t), self.start_frame)  # (a pre-roll frames the start frame)
        rows = []
        for k in range(1, n + 1):
            # stages still in the pre-roll frame the start frame too, never the rows before it (a
            # later take's settle would otherwise fly the previous shot's framing backwards)
            f = max(frame_at(t + k * dt), self.start_frame) if moving else frame
            if moving and self.end_frame is not None:
                # nor past the take's last frame: the next shot is filmed as its own take after a
                # settle, so anticipating it would only spoil this take's last frames
                f = min(f, self.end_frame - 1)
            rows.append(int(np.clip(f - ins.first_frame, 0, k_rows - 1)))
        self.counters["finished"] = bool(ins.final and frame - ins.first_frame >= k_rows)
        return rows, frame

    # ------------------------------------------------------------------ outputs
    def _from_plan(self, now_ns: int, plan: Plan, status: str, *, valid: bool) -> M.Setpoint | None:
        lay = self.layout
        age = (now_ns - plan.t0_ns) * 1e-9
        x, u = plan.at(age + self.cfg.setpoint_lead_s)
        _, self._u_prev = plan.at(age)
        yaw, pitch, roll = lay.angles(x)
        ypr = np.array([wrap_angle(float(yaw)), float(pitch), float(roll)])
        hx = plan.x
        n1 = hx.shape[0]
        h_ypr = np.zeros((n1, 3))
        h_ypr[:, 0] = wrap_angle(hx[:, lay.YAW])
        h_ypr[:, 1] = hx[:, lay.PITCH]
        if lay.control_roll:
            h_ypr[:, 2] = hx[:, lay.ROLL]
        h_lens = np.stack([hx[:, lay.F], hx[:, lay.S], hx[:, lay.A]], axis=1)
        self._last_lens = np.array([x[lay.F], x[lay.S], x[lay.A]], dtype=float)
        sp = M.Setpoint(
            stamp_ns=now_ns, valid=valid, mode="track", position_m=np.asarray(x[lay.P], dtype=float),
            velocity_mps=np.asarray(x[lay.V], dtype=float), acceleration_mps2=np.asarray(u[lay.ACC], dtype=float),
            camera_ypr_rad=ypr, lens=self._lens_msg(self._last_lens), instruction_frame=plan.instruction_frame,
            horizon_t_s=np.arange(n1) * plan.dt - age, horizon_position_m=np.asarray(hx[:, lay.P], dtype=float),
            horizon_camera_ypr_rad=h_ypr, horizon_lens=h_lens, solver_status=status)
        if not _setpoint_finite(sp):
            return None
        self.counters["mode"] = "track"
        return sp

    def _lens_msg(self, lens: np.ndarray) -> M.LensState:
        st = self.cfg.structure
        return M.LensState(focal_length_mm=float(lens[0]), focus_distance_m=float(lens[1]), f_number=float(lens[2]),
                           sensor_width_mm=st.sensor_width_mm, sensor_height_mm=st.sensor_height_mm,
                           coc_mm=st.coc_mm)

    def _fallback(self, now_ns: int, vehicle: M.VehicleState, reason: str) -> M.Setpoint:
        plan = self._plan
        if plan is not None and self._last_good_ns is not None:
            age = (now_ns - self._last_good_ns) * 1e-9
            if age <= min(self.cfg.tail_max_s, plan.length_s - self.cfg.setpoint_lead_s):
                sp = self._from_plan(now_ns, plan, f"{reason}; flying last plan ({age:.2f} s old)", valid=True)
                if sp is not None:
                    self.counters["tail"] = True
                    return sp
        return self._hold(now_ns, vehicle, f"{reason}; holding", valid=False)

    def _hold(self, now_ns: int, vehicle: M.VehicleState, reason: str, *, valid: bool) -> M.Setpoint:
        if self._hold_pose is None:
            lens = _finite_lens(vehicle.lens, self._last_lens)
            ypr = np.asarray(vehicle.camera_ypr_rad, dtype=float)
            pos = np.asarray(vehicle.position_m, dtype=float)
            if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(ypr))):
                return self._no_vehicle(now_ns, reason)
            self._hold_pose = (pos.copy(), ypr.copy(), lens)
            self.counters["holds"] = int(self.counters["holds"]) + 1
            # a hold ends the plan: the next solve starts cold
            self.solver.reset()
            self._plan = None
            self._last_good_ns = None
            self._u_prev = np.zeros(self.layout.nu)
            log.info("hold: %s", reason)
        pos, ypr, lens = self._hold_pose
        self.counters.update(mode="hold", tail=False)
        return _hold_setpoint(now_ns, pos, ypr, self._lens_msg(lens), reason, valid,
                              int(self.counters.get("instruction_frame", -1)))  # type: ignore[arg-type]

    def _no_vehicle(self, now_ns: int, reason: str) -> M.Setpoint:
        self.counters.update(mode="hold", tail=False)
        return M.Setpoint(stamp_ns=now_ns, valid=False, mode="hold", position_m=np.zeros(3),
                          velocity_mps=np.zeros(3), acceleration_mps2=np.zeros(3), camera_ypr_rad=np.zeros(3),
                          lens=self._lens_msg(self._last_lens), horizon_t_s=np.zeros(1),
                          horizon_position_m=np.zeros((1, 3)), horizon_camera_ypr_rad=np.zeros((1, 3)),
                          horizon_lens=self._last_lens.reshape(1, 3).copy(), solver_status=reason)


def _hold_setpoint(now_ns: int, pos: np.ndarray, ypr: np.ndarray, lens: M.LensState, reason: str, valid: bool,
                   frame: int) -> M.Setpoint:
    lv = np.array([[lens.focal_length_mm, lens.focus_distance_m, lens.f_number]])
    return M.Setpoint(stamp_ns=now_ns, valid=valid, mode="hold", position_m=pos.copy(), velocity_mps=np.zeros(3),
                      acceleration_mps2=np.zeros(3), camera_ypr_rad=ypr.copy(), lens=lens, instruction_frame=frame,
                      horizon_t_s=np.zeros(1), horizon_position_m=pos.reshape(1, 3).copy(),
                      horizon_camera_ypr_rad=ypr.reshape(1, 3).copy(), horizon_lens=lv, solver_status=reason)


def _setpoint_finite(sp: M.Setpoint) -> bool:
    arrays = [sp.position_m, sp.velocity_mps, sp.acceleration_mps2, sp.camera_ypr_rad, sp.horizon_t_s,
              sp.horizon_position_m, sp.horizon_camera_ypr_rad, sp.horizon_lens]
    lens = [sp.lens.focal_length_mm, sp.lens.focus_distance_m, sp.lens.f_number]
    return all(np.all(np.isfinite(a)) for a in arrays) and all(math.isfinite(v) for v in lens)


@dataclass(frozen=True, eq=False)
class PredictedSubject:
    """The subject at `now`, predicted at constant velocity from its last state [m, world]."""

    names: list[str]
    joints: np.ndarray  #: (J, 3), NaN rows where a joint is unknown
    vel: np.ndarray  #: (3,)
    finite: np.ndarray  #: (J,) the joint is known
    centre: np.ndarray  #: (3,) mean of the centre joints known (else of all known joints)


def held_lead_dof(depth_m: float, *, blur: float, sharp_coc_ratio: float, weight: float) -> np.ndarray:
    """(N_DOF,) the depth-of-field targets of a lead stage before a rack from the subject onto the background: his
    centre `depth_m` away at most `blur` circles of the one circle soft (the near limit of that circle, a
    `blur` / `sharp_coc_ratio` multiple of the planning circle, at or nearer than him; its weight `weight` times
    dof_near) and the far limit free. The focus travels on as the stages past the switch ask (planned as made)
    and the f-number rises to keep him sharp; at the switch the aperture, which opens 3 f-stops' worth a second
    while the focus moves 15 m/s, leaves him soft. Planned soft instead, the parkour runner went soft 10 frames
    before his switch."""
    row = np.zeros(N_DOF)
    row[0], row[1], row[5] = weight, 1.0 / depth_m, 1.0
    row[6], row[7] = 1.0, blur / sharp_coc_ratio
    return row


def realisable_rows(focus_in: np.ndarray) -> np.ndarray:
    """The style's focus rows (K, 3) as one depth of field can give them (shared.camera.realisable_labels)."""
    focus = np.asarray(focus_in, dtype=bool)
    if focus.ndim != 2 or focus.shape[1] != 3:
        return focus
    return np.array([cam.realisable_labels(*row) for row in focus.tolist()], dtype=bool).reshape(focus.shape)


#: the subject's blur [circles of the one circle] a lead stage before a rack onto the background holds him at
#: (held_lead_dof), with margin under the one circle: the estimator read the parkour runner soft at 0.92-0.97
LEAD_HOLD_BLUR = 0.7
#: that hold's weight, as a factor of dof_near: once, the lens stopped down only to f/1.13 and let him reach 0.93
#: circles (read soft); twice, f/1.24 and 0.80-0.95 circles to the switch (read sharp)
LEAD_HOLD_WEIGHT = 2.0
#: the share of the focus's travel past the subject that a rack away from him is planned ahead
#: (Planner._dof_targets): half, so that the frames the travel costs fall either side of the switch
RACK_LEAD_SHARE = 0.5
#: the longest run of "nothing in focus" rows [s] right before a background-only row that the planner
#: films as background-only (planned_focus_rows)
RACK_THROUGH_MAX_S = 1.0


def shot_numbers(shot_start: np.ndarray | None, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) bool where each shot begins (row 0 always; `shot_start` of another length is ignored as
    absent) and (n,) int the shot each row belongs to, counted from 1."""
    starts = np.zeros(n, dtype=bool)
    if shot_start is not None and np.shape(shot_start) == (n,):
        starts = np.asarray(shot_start, dtype=bool).copy()
    starts[:1] = True
    return starts, np.cumsum(starts)


def shot_choice_held(absent: np.ndarray, shot_start: np.ndarray | None,
                     min_rows: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(K,) int the shot each row belongs to (shot_numbers) and (K,) int the last row of that shot with a region
    labelled, for later_shot_previewed; -1 where the shot labels none or is shorter than `min_rows` (a flash cut
    holds no choice back from the ones after it)."""
    absent = np.asarray(absent, dtype=bool)
    n = len(absent)
    shot = shot_numbers(shot_start, n)[1]
    labelled = ~absent.all(axis=1) if absent.ndim == 2 else np.zeros(n, dtype=bool)
    last = np.full(n, -1, dtype=int)
    for s in np.unique(shot):
        rows = np.flatnonzero(shot == s)
        marked = rows[labelled[rows]]
        if len(marked) and len(rows) >= min_rows:
            last[rows] = marked[-1]
    return shot, last


def later_shot_previewed(held: tuple[np.ndarray, np.ndarray], now_row: int, row: int) -> bool:
    """Whether a stage's `row` asks its focus choice of the lens when the row followed now is `now_row`
    (`held`: shot_choice_held): yes in the shot followed now, and in a later shot only once the shot followed now
    has no labelled row left ahead (from its last labelled row on, or at once when it labels none). A shot
    shorter than a take is flown inside the take before it (--min-take), and the lens cannot change its choice
    at the cut: tos_clip01's one- and two-row shots 192-203 ask the subject and a background at infinity sharp,
    and previewed over the horizon their deep field stopped rows 158-184 down where the shot asks the background
    soft (truth and extraction read it sharp in 167-184): 18 frames of that shot for 2-3 of theirs. Their own
    choice is planned from the shot's end on, as far as the lens's rates reach; a shot itself that short holds
    nothing back (shot_choice_held's `min_rows`): previewed only at each 2-row shot's end, the background-only
    rows 196-203 came sharp a frame later."""
    shot, last = held
    if not (0 <= now_row < len(shot) and 0 <= row < len(shot)) or shot[row] == shot[now_row]:
        return True
    return now_row >= last[now_row]


def held_subject_labels(focus_in: np.ndarray, absent: np.ndarray,
                        shot_start: np.ndarray | None = None) -> np.ndarray:
    """The style's focus rows (K, 3) with the subject's label held from the nearest earlier row of the
    same shot that measured him (the shot's first such row for the rows before it) where the source has
    no label for him but has one for another region. His label is False there only because nothing was
    measured: read as "the subject soft", a walker who left the rendered truck's and orbit's frames
    10-14 rows before the end turned the take's last 1.5 s into a rack (the zoom gave way) and planned
    the lens long to blur him (the output zoomed in where the source held). Never across a cut
    (`shot_start`: the rows where each shot begins): another shot's label is another choice, and
    tos_clip01's last shot, which asks nothing sharp, took "subject sharp" from the shot before, read
    as a rack and left its background sharp. A shot that never measures him, and rows with no region
    labelled, stay as they are."""
    focus = np.asarray(focus_in, dtype=bool)
    if focus.ndim != 2 or focus.shape[1] != 3 or absent.shape != focus.shape:
        return focus
    missing = unmeasured_subject_rows(absent)
    if not missing.any():
        return focus
    shot = shot_numbers(shot_start, len(focus))[1]
    out = focus.copy()
    for s in np.unique(shot[missing]):
        seen = np.flatnonzero(~absent[:, 1] & (shot == s))
        if not len(seen):
            continue
        rows = np.flatnonzero(missing & (shot == s))
        before = np.searchsorted(seen, rows) - 1  # the last row of the shot measuring him before each, -1 = none
        out[rows, 1] = focus[seen[np.maximum(before, 0)], 1]
    return out


def unmeasured_subject_rows(absent: np.ndarray) -> np.ndarray:
    """(K,) bool: the rows where the source has no label for the subject but has one for another region.
    The planner leaves his near limit free there (option unmeasured_subject_near_free) whatever label
    held_subject_labels gives him, and a far limit at infinity aims at the ground behind him instead
    (Planner._dof_targets): that label only keeps a shot's choice from reading as a rack, nothing in the
    source asks it of his depth. Held sharp while only the background was asked sharp, tos_clip01's take 3
    planned him and a background at infinity sharp together and stopped down to f/9 just before rows that
    asked the lens wide open (docs/planner.md, "An unmeasured subject asks no limit")."""
    absent = np.asarray(absent, dtype=bool)
    if absent.ndim != 2 or absent.shape[1] != 3:
        return np.zeros(len(absent), dtype=bool)
    return absent[:, 1] & ~absent.all(axis=1)


def planned_focus_rows(focus_in: np.ndarray, absent: np.ndarray, max_rows: int,
                       shot_start: np.ndarray | None = None) -> np.ndarray:
    """The style's focus rows (K, 3) as the planner films them: the subject's label held over rows that
    do not measure him within a shot (held_subject_labels), as one depth of field can give them
    (realisable_rows), and a run of at most `max_rows` rows with nothing in focus right before a row
    with only the background in focus as background-only. That run is how a rack focus from the
    subject to the background reads through the smoother's window (a few frames with nothing sharp
    while the focus travels); planned as asked, its depth of field in front of the subject pulled the
    focus the other way just before the longest move of the rack (dance-twirl's rack focus: 7 rows,
    the subject still sharp 8 frames after the switch)."""
    if absent.shape == np.shape(focus_in):
        focus_in = held_subject_labels(focus_in, absent, shot_start)
    focus = realisable_rows(focus_in)
    if focus.ndim != 2 or focus.shape[1] != 3 or absent.shape != focus.shape:
        return focus
    out = focus.copy()
    none = ~focus.any(axis=1) & ~absent.all(axis=1)
    background_only = np.array([near_keeps_subject_out(*row) for row in focus.tolist()], dtype=bool)
    k = 0
    while k < len(focus):
        if not none[k]:
            k += 1
            continue
        end = k
        while end < len(focus) and none[end]:
            end += 1
        if end < len(focus) and background_only[end] and end - k <= max_rows:
            out[k:end] = (False, False, True)
        k = end
    return out


def rack_switch_ahead(focus: np.ndarray, absent: np.ndarray, lead_rows: int, min_hold_rows: int,
                      shot_start: np.ndarray | None = None) -> np.ndarray:
    """(K,) int: for the rows at most `lead_rows` before a rack away from the subject (his label sharp -> soft
    between two labelled rows of one shot, the rows before it sharp and labelled), the switch's row; -1
    elsewhere. Only where he then stays soft for at least `min_hold_rows` labelled rows: a brief excursion is
    not led, the rows it would cost before the switch are more than it gains. The planner plans such a row
    as the switch's once half the focus's travel past the subject takes longer than the time left
    (Planner._subject_travel_s, RACK_LEAD_SHARE): started at the switch, that travel left the parkour runner
    sharp for 22 frames after it (docs/planner.md, "A rack away from the subject, planned ahead")."""
    focus = np.asarray(focus, dtype=bool)
    out = np.full(len(focus), -1, dtype=int)
    if lead_rows <= 0 or focus.ndim != 2 or focus.shape[1] != 3 or absent.shape != focus.shape:
        return out
    labelled = ~absent.all(axis=1)
    starts, shot = shot_numbers(shot_start, len(focus))
    for k in np.flatnonzero(focus[:-1, 1] & ~focus[1:, 1] & labelled[:-1] & labelled[1:] & ~starts[1:]) + 1:
        end = k
        while end < len(focus) and not focus[end, 1] and labelled[end] and shot[end] == shot[k]:
            end += 1
        if end - k < min_hold_rows:
            continue
        first = k
        while first > 0 and k - first < lead_rows and shot[first - 1] == shot[k] and labelled[first - 1] \
                and focus[first - 1, 1]:
            first -= 1
        out[first:k] = k
    return out


def rack_settle_rows(focus: np.ndarray, absent: np.ndarray, settle_rows: int, min_hold_rows: int,
                     shot_start: np.ndarray | None = None) -> np.ndarray:
    """(K,) bool: the first `settle_rows` rows from each rack away from the subject inside a shot (his label
    sharp -> soft between two labelled rows, held soft at least `min_hold_rows`: the switches rack_switch_ahead
    leads to), where the focus is still travelling past him. A change of label at a cut is no rack: each shot
    is its own choice (tos_clip01's one- and two-row shots at rows 196-203)."""
    switches = rack_switch_ahead(focus, absent, 1, min_hold_rows, shot_start)
    out = np.zeros(len(switches), dtype=bool)
    for k in np.unique(switches[switches >= 0]):
        out[k:k + settle_rows] = True
    return out


def keep_out_rows(focus: np.ndarray, absent: np.ndarray, settle_rows: int) -> np.ndarray:
    """(K,) bool: the rows wanting only the background sharp (focus: the planned rows, planned_focus_rows)
    that keep the subject out by his own depth (`subject_keep_out_m`) rather than mu: all of them but
    the first `settle_rows` after a switch from a labelled row that kept him in (a rack focus onto the
    background). Right after the switch the focus is still travelling past the subject, and the nearer
    near limit let it arrive later: in the closed-loop rack his blur 1 s after the switch fell from
    above 1.1 circles to 1.095. A shot that asks for it from its first row, or after rows without a
    label, keeps him out by his own depth throughout."""
    focus = np.asarray(focus, dtype=bool)
    if focus.ndim != 2 or focus.shape[1] != 3:
        return np.zeros(len(focus), dtype=bool)
    out = np.array([near_keeps_subject_out(*row) for row in focus.tolist()], dtype=bool)
    labelled = ~absent.all(axis=1) if absent.shape == focus.shape else np.ones(len(focus), dtype=bool)
    keep = out.copy()
    for k in np.flatnonzero(out[1:] & ~out[:-1] & labelled[:-1]) + 1:
        keep[k:k + settle_rows] = False
    return keep


def lens_for_focus_rows(focus: np.ndarray, absent: np.ndarray, lead_rows: int, settle_rows: int,
                        shot_start: np.ndarray | None = None) -> np.ndarray:
    """(K,) bool: the rows round a switch of the subject's label between two labelled rows of one shot (a
    rack focus): the `lead_rows` rows before the switch and the `settle_rows` from it, within the shot
    (`shot_start`: the rows where each shot begins; a new shot is its own take), none when `lead_rows` < 0.
    There the lens travels to the new focus choice; the source's zoom, held by its camera for its own
    reasons, pulled the other way and held the parkour rack's subject sharp through its soft half
    (docs/planner.md, "Which gives way"). In a settled choice the standoff gives it and the zoom is flown."""
    focus = np.asarray(focus, dtype=bool)
    out = np.zeros(len(focus), dtype=bool)
    if lead_rows < 0 or focus.ndim != 2 or focus.shape[1] != 3:
        return out
    labelled = ~absent.all(axis=1) if absent.shape == focus.shape else np.ones(len(focus), dtype=bool)
    starts, shot = shot_numbers(shot_start, len(focus))
    switched = (focus[1:, 1] != focus[:-1, 1]) & labelled[1:] & labelled[:-1] & ~starts[1:]
    for k in np.flatnonzero(switched) + 1:
        rows = np.arange(max(0, k - lead_rows), min(len(focus), k + settle_rows))
        out[rows[shot[rows] == shot[k]]] = True
    return out


def far_previewed(focus: np.ndarray, near_out: list[bool], now_row: int, row: int) -> bool:
    """Whether a stage's far-limit target counts: not where the row followed now keeps the background
    soft and the stage lies past a switch, still ahead, to background-only. Opening the far limit is
    quick (the aperture), moving the near limit past the subject is the focus's long travel: previewed
    together, the least-squares plan opened the far limit first, the background sharp 7-14 frames
    before the switch while the subject was still sharp (dance-twirl's rack focus). The near limit
    stays previewed."""
    if not near_out[row] or switched_out(near_out, now_row, row):
        return True
    return bool(focus[now_row, 2]) if 0 <= now_row < len(focus) else True


def _fps(ins: M.Instructions) -> float:
    """Instruction rows per second of recording."""
    return ins.fps if ins.fps > 0 else (1.0 / ins.frame_duration_s if ins.frame_duration_s > 0 else 24.0)


def predict_subject(subject: M.SubjectState, now_ns: int) -> PredictedSubject:
    """The subject's joints moved on at its velocity to `now`; ValueError when none is finite."""
    names = list(subject.joint_names)
    joints = np.asarray(subject.joints_m, dtype=float)
    vel = np.asarray(subject.velocity_mps, dtype=float)
    if joints.shape[0] != len(names):
        raise ValueError("subject joints and names differ in length")
    joints = joints + vel * max(0.0, (now_ns - subject.stamp_ns) * 1e-9)
    finite = np.all(np.isfinite(joints), axis=1)
    if not finite.any():
        raise ValueError("no finite subject joint")
    ci = [names.index(j) for j in CENTRE_JOINTS if j in names and finite[names.index(j)]]
    centre = joints[ci].mean(axis=0) if ci else joints[finite].mean(axis=0)
    return PredictedSubject(names, joints, vel, finite, centre)


def flown_rate_factor(lead_s: float, rate_hz: float) -> float:
    """How many times faster than planned the lens zooms in closed loop.

    The lens reaches each setpoint within a step (the simulators' lens moves to it at its rate
    limits), and the setpoint is the plan `lead_s` ahead, so each step moves it by `lead_s` of
    planned motion and the next solve starts from there: over a step of 1/rate_hz it moves
    lead_s * rate_hz times as far as the plan says (2 at 0.1 s and 20 Hz). Measured in the
    closed-loop zoom test: 0.163 /s flown for 0.1 /s planned; 0.088 /s with the zoom rate planned
    this much slower. The framing barely resists (the lead changes the subject's size by 1 %). The
    camera's angles run ahead the same way, but there the framing pins them (a lead in yaw shifts
    the subject by several % of the image): a pan was flown at 4.19 deg/s for the source's 4.24
    as planned, and at 2.96 planned half as fast, so angular rates are not scaled; nor are rates
    of travel (the vehicle lags its setpoint: the lead covers that)."""
    f = lead_s * rate_hz
    return min(max(f, 0.25), 4.0) if f > 0 else 1.0


def absent_regions(ins: M.Instructions) -> np.ndarray:
    """(K, 3) bool: the source has no focus label for the region (foreground, subject, background)
    in the frame: its smoothed B is NaN, as the fidelity report reads it (the region is absent,
    or its shot never measured it; a frame where the subject was bridged has labels from its
    neighbours). All False when the instructions carry no smoothed B."""
    focus = np.asarray(ins.focus_in, dtype=bool)
    sm = np.asarray(ins.focus_smoothed, dtype=float) if ins.focus_smoothed is not None else np.zeros((0, 3))
    return ~np.isfinite(sm) if sm.shape == focus.shape else np.zeros(focus.shape, dtype=bool)


def separation_kind(row: np.ndarray, absent: np.ndarray) -> str | None:
    """Which standoff a realisable focus row asks for (separation.py): "subject_soft" (only the
    background sharp), "background_soft" (the subject sharp, a background present and soft) or None."""
    b_fg, b_subject, b_bg = (bool(v) for v in row)
    if absent.all():
        return None
    if near_keeps_subject_out(b_fg, b_subject, b_bg):
        return "subject_soft"
    if b_subject and not b_bg and not absent[2]:
        return "background_soft"
    return None


def pins_field_before_soft_background(row: np.ndarray, absent: np.ndarray) -> bool:
    """Whether a realisable focus row's near limit stays two-sided with no foreground in the source: only the
    subject sharp before a present, soft background (separation_kind "background_soft"). His far limit alone
    leaves a valley (every f-number whose field ends at d + mu costs the same, the near limit one-sided), so the
    aperture follows whatever else pulls: tos_clip01's take 3 stopped down f/4.4 -> f/8.2 over rows 147-184
    and its background 14-20 m behind him read sharp. Both limits asked pin the field round him, wide open."""
    return separation_kind(row, absent) == "background_soft"


def smoothed_focus(ins: M.Instructions) -> np.ndarray:
    """(K, 3) the source's smoothed focus B per row and region; (0, 3) when the instructions carry none."""
    b = np.asarray(ins.focus_smoothed, dtype=float) if ins.focus_smoothed is not None else np.zeros((0, 3))
    return b if b.ndim == 2 and b.shape[1] == 3 else np.zeros((0, 3))


def smoothed_subject_focus(ins: M.Instructions) -> np.ndarray:
    """(K,) the source's smoothed subject focus B per row; empty when the instructions carry none
    (visible defocus then takes the subject as plainly soft: cost.subject_softness)."""
    return smoothed_focus(ins)[:, 1]


def stage_targets(image_targets: np.ndarray, rows: list[int] | np.ndarray, ctrl: list[str], jmask: np.ndarray,
                  seen_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(targets (N, E_max, 2), weights (N, E_max)) of the horizon's stages from the instruction rows.

    `ctrl`: the controlled joints' names (the instructions' order), `jmask` their weights (0 = no
    joint or not controlled), `seen_xy` (len(ctrl), 2) where the subject's joints are seen now.
    A target counts where it is finite and its joint is controlled. A row whose person faces the
    other way from the subject as seen now (a front-view style on a subject seen from behind) is
    met by image side: its left/right targets are swapped (shared/facing.py; docs/planner.md,
    "Back views").
    """
    n, e_max = len(rows), jmask.shape[0]
    targets = np.zeros((n, e_max, 2))
    mask = np.zeros((n, e_max))
    ne = min(len(ctrl), image_targets.shape[1])
    names = list(ctrl[:ne])
    for k, r in enumerate(rows):
        t, _ = by_image_side(seen_xy[:ne], image_targets[r, :ne], names)
        ok = np.all(np.isfinite(t), axis=1) & (jmask[:ne] > 0)
        targets[k, :ne][ok] = t[ok]
        mask[k, :ne] = ok * jmask[:ne]
    return targets, mask


def instructions_from_arrays(*, targets: np.ndarray, joint_names: list[str], focus_in: np.ndarray | None = None,
                             fps: float = 24.0, mu_m: float = 1.0, first_frame: int = 0) -> M.Instructions:
    """Instructions built from plain arrays (tests, tools)."""
    targets = np.asarray(targets, dtype=np.float32)
    k = targets.shape[0]
    fi = np.zeros((k, 3), dtype=bool) if focus_in is None else np.asarray(focus_in, dtype=bool)
    return M.Instructions(fps=fps, frame_duration_s=1.0 / fps, first_frame=first_frame, joint_names=list(joint_names),
                          image_targets=targets, subject_visible=np.ones(k, dtype=bool),
                          subject_box=np.full((k, 4), np.nan, dtype=np.float32),
                          focus_raw=fi.astype(np.float32), focus_smoothed=fi.astype(np.float32), focus_in=fi, mu_m=mu_m)


__all__ = ["Planner", "Plan", "instructions_from_arrays", "STATES"]
