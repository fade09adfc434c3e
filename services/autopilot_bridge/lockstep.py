"""Simulation time: the bridge owns the clock and advances it in lockstep with the planner.

One step of `period` simulated seconds (the control period, 0.05 s by default):

    1. publish the vehicle and subject state at t, then the SimClock tick t
    2. publish the frames rendered during the previous step (their renders ran while the
       planner was solving for t: the two cores work in parallel)
    3. if a planner is alive: wait for its setpoint stamped t (bounded wait, counted when hit)
    4. safety layer + watchdog at t (in simulation time), drive the simulated vehicle to t + period
       in sub-ticks at the bridge rate; every camera frame slot crossed is rendered
    5. pace: sleep so that simulated time runs at `pace` x wall time (0 = as fast as possible);
       a command ends the sleep (it is handled in the next step at once), and so does a planner
       that comes alive or goes (it gets its first tick at once)

Where a step's wall time goes is counted in the Health counters (seconds, summed over the
`waits_steps` steps since the last reset): `publish_s` (state, clock and frames out),
`wait_render_s` (frames of the previous step still rendering when they are due out),
`wait_setpoint_s` (the planner's solve and the round trip), `advance_s` (safety layer, dynamics,
render hand-off) and `pace_s` (sleeping to the pace).

Machine load changes how long a step takes, never what it computes: the same scene, commands
and planner give the same flight and the same frames. Bridge commands handled here:
- 'reset' (args: epoch_ns=int, optional fps=float, pace=float, pictures=[[lo, hi], ...]): start
  the simulation over at time `epoch_ns` (scene's initial state, frame 0 next), forgetting
  setpoints and holds; with `pictures`, only frames with an index in one of the ranges [lo, hi)
  are rendered and published, the others before the last range's end get their ground truth only
  (a take's recording keeps no pre-roll frame: rendering them was a third of the README flight's
  renders), and those after it nothing (nobody records them: the simulation after the takes);
- 'clock' (args: pace=float, optional): change the pace; without a pace it changes nothing, but
  like every command it ends the pacing sleep, so the next step (and its clock tick) comes at
  once: a take about to begin asks for a tick so, whatever the idle pace.
"""
from __future__ import annotations

import collections
import contextlib
import logging
import math
import time
from typing import Any, Iterator

from cinetransfer.shared import keys
from cinetransfer.shared import messages as M
from cinetransfer.shared.node import Presence

log = logging.getLogger("cinetransfer.autopilot_bridge.clock")

CLOCK_ACTIONS = ("reset", "clock")


def step_stamp_ns(epoch_ns: int, step: int, period_ns: int) -> int:
    """Simulation time of a step: exact integer arithmetic, no accumulated rounding."""
    return epoch_ns + step * period_ns


def substeps(period_s: float, rate_hz: float) -> int:
    """Control sub-ticks per clock step so that the safety layer still runs near `rate_hz`."""
    return max(1, int(round(period_s * rate_hz)))


def parse_reset(args: dict[str, Any]) -> tuple[int, float | None, float | None]:
    """(epoch_ns, fps or None, pace or None) of a 'reset' command; ValueError naming the bad argument."""
    epoch = args.get("epoch_ns")
    if isinstance(epoch, bool) or not isinstance(epoch, int) or epoch < 0:
        raise ValueError(f"reset: epoch_ns must be an integer >= 0, got {epoch!r}")
    fps = _opt_number(args, "fps", 1.0, 240.0)
    pace = _opt_number(args, "pace", 0.0, 1000.0)
    return epoch, fps, pace


def parse_pictures(args: dict[str, Any]) -> list[tuple[int, int]] | None:
    """The 'pictures' of a 'reset' (None when absent: every frame); ValueError when malformed."""
    v = args.get("pictures")
    if v is None:
        return None
    ok = isinstance(v, (list, tuple)) and all(
        isinstance(r, (list, tuple)) and len(r) == 2 and all(isinstance(x, int) and not isinstance(x, bool)
                                                             for x in r) and 0 <= r[0] <= r[1] for r in v)
    if not ok:
        raise ValueError(f"reset: pictures must be a list of [lo, hi] frame index ranges, 0 <= lo <= hi; got {v!r}")
    return [(int(a), int(b)) for a, b in v]


def _opt_number(args: dict[str, Any], name: str, lo: float, hi: float) -> float | None:
    v = args.get(name)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"{name} must be a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


class StepWaits:
    """Wall seconds of the simulation steps, summed by part (what each step waits on)."""

    PARTS = ("publish_s", "wait_render_s", "wait_setpoint_s", "advance_s", "pace_s")

    def __init__(self) -> None:
        self.totals = dict.fromkeys(self.PARTS, 0.0)
        self.steps = 0

    @contextlib.contextmanager
    def timing(self, part: str) -> Iterator[None]:
        t = time.perf_counter()
        try:
            yield
        finally:
            self.totals[part] += time.perf_counter() - t

    def counters(self) -> dict[str, float]:
        return {**{k: round(v, 3) for k, v in self.totals.items()}, "waits_steps": self.steps}


class SimClockLoop:
    """Runs the bridge on simulation time (see the module doc)."""

    def __init__(self, node: Any, cfg: Any, bridge: Any) -> None:
        self.node, self.cfg, self.bridge = node, cfg, bridge
        self.backend = bridge.backend
        self.period_ns = int(round(cfg.step_s * 1e9))
        self.n_sub = substeps(cfg.step_s, cfg.rate_hz)
        self.pace = cfg.pace
        self.clock_pub = node.publisher(keys.SIM_CLOCK)
        self.planner = Presence(node.session, node.rig, "planner")  # only a live planner is waited for
        self.counters = {"sim_steps": 0, "sim_time_s": 0.0, "setpoint_waits_timed_out": 0, "sp_stale": 0,
                         "resets": 0, "frames_published": 0, "lockstep": False}
        self._step_ms: collections.deque[float] = collections.deque(maxlen=2000)
        self.waits = StepWaits()
        #: the frame index after the last pictured one (None: every frame is pictured)
        self.pictures_end: int | None = None
        self.paused = False  #: past a take's last pictured frame: no step until a command arrives
        if not cfg.frames_before_reset:  # idle until a take resets the simulation: no pictures
            self.backend.pictures = ()
        self._begin(int(self.backend._epoch_ns or M.now_ns()))

    def _begin(self, epoch_ns: int) -> None:
        self.epoch_ns = epoch_ns
        self.step = 0
        self.backend.step(0.0)  # time zero: frame 0 is rendered from the initial state
        self._pace_origin = (time.monotonic(), 0)

    def run(self) -> None:
        try:
            while self.node.running:
                with self.node.guard(self.clock_pub.key, "simulation step"):  # no exception ends the loop
                    self.run_step()
        finally:
            self.planner.undeclare()

    def now_ns(self) -> int:
        return step_stamp_ns(self.epoch_ns, self.step, self.period_ns)

    def run_step(self) -> None:
        node, bridge = self.node, self.bridge
        t_ns = self.now_ns()
        t_wall = time.perf_counter()
        node.clock_ns = t_ns
        lockstep = self.planner.alive
        waits = self.waits
        with node.timed():
            with waits.timing("publish_s"):
                bridge.publish_state(t_ns)
                self.clock_pub.put(M.SimClock(stamp_ns=t_ns, epoch_ns=self.epoch_ns, step=self.step,
                                              period_s=self.period_ns * 1e-9, lockstep=lockstep, pace=self.pace))
            with waits.timing("wait_render_s"):
                self.backend.flush()
            with waits.timing("publish_s"):
                self.counters["frames_published"] += self.bridge.publish_frames()
        with waits.timing("wait_setpoint_s"):
            sps = self._await_setpoint(t_ns) if lockstep else self._setpoints_on_clock(t_ns)
        with node.consistent():  # one Health report holds a whole step or none of it
            with waits.timing("advance_s"):
                if not self._advance(t_ns, sps, lockstep):
                    return
            waits.steps += 1
            self._step_ms.append((time.perf_counter() - t_wall) * 1e3)
            ms = sorted(self._step_ms)
            self.counters["step_wall_ms_p50"] = round(ms[len(ms) // 2], 2)
            node.counters.update(self.counters, **waits.counters(), pace=self.pace)
        self._past_pictures()
        with waits.timing("pace_s"):
            self._wait_for_pace()

    def _advance(self, t_ns: int, sps: list[M.Setpoint], lockstep: bool) -> bool:
        """Commands, setpoints and the vehicle from t to t + period; False if a reset started over."""
        node, bridge = self.node, self.bridge
        with node.timed():
            if self._commands():  # a reset starts this step over at the new time zero
                return False
            t_s = self._sim_s(t_ns)
            bridge.handle_setpoints(sps, t_s, t_ns)
            h = self.period_ns * 1e-9 / self.n_sub
            for j in range(self.n_sub):
                bridge.control(t_s + j * h, step_to=self._sim_s(t_ns) + (j + 1) * h)
        self.step += 1
        bridge.ticks += 1
        self.counters.update(sim_steps=self.counters["sim_steps"] + 1, sim_time_s=round(self._sim_s(t_ns), 3),
                             lockstep=lockstep)
        bridge.update_health()
        return True

    def _sim_s(self, t_ns: int) -> float:
        return (t_ns - self.epoch_ns) * 1e-9

    def _await_setpoint(self, t_ns: int) -> list[M.Setpoint]:
        """The planner's setpoint for this step (older ones are stale; a wall timeout is counted)."""
        deadline = time.monotonic() + self.cfg.setpoint_wait_s
        while self.node.running:
            sp = self.bridge.sp_in.get(timeout=max(0.0, min(0.2, deadline - time.monotonic())))
            if sp is not None and sp.stamp_ns == t_ns:
                return [sp]
            if sp is not None and sp.stamp_ns < t_ns:
                self.counters["sp_stale"] += 1
            elif sp is not None:
                self.node.reject(f"setpoint stamped {sp.stamp_ns} is ahead of the simulation clock {t_ns}")
            if time.monotonic() >= deadline or not self.planner.alive:
                break
        if self.node.running and self.planner.alive:
            self.counters["setpoint_waits_timed_out"] += 1
            self.node.error(f"no setpoint for simulation step {self.step} within {self.cfg.setpoint_wait_s:g} s",
                            "clock")
        return []

    def _setpoints_on_clock(self, t_ns: int) -> list[M.Setpoint]:
        """Without a planner to wait for: what arrived, if stamped on this clock (a setpoint stamped
        ahead of simulated time, e.g. on the wall clock, would poison the ordering check)."""
        out = []
        for sp in self.bridge.sp_in.drain():
            if sp.stamp_ns <= t_ns:
                out.append(sp)
            else:
                self.node.reject(f"setpoint stamped {sp.stamp_ns} is ahead of the simulation clock {t_ns}")
        return out

    def _commands(self) -> bool:
        """Handle clock commands; pass the rest to the bridge. True if the simulation was reset."""
        passed, reset = [], False
        for cmd in self.bridge.cmd_in.drain():
            if cmd.action not in CLOCK_ACTIONS:
                passed.append(cmd)
                continue
            try:
                reset = self._clock_command(cmd) or reset
            except ValueError as e:
                self.node.reject(str(e))
        self.bridge.handle_commands(passed)
        return reset

    def _clock_command(self, cmd: M.Command) -> bool:
        if cmd.action == "clock":
            pace = _opt_number(cmd.args, "pace", 0.0, 1000.0)
            if pace is not None:  # without a pace the command only woke the step: a tick now
                self.pace = pace
                self._pace_origin = (time.monotonic(), self.step)
            return False
        epoch, fps, pace = parse_reset(cmd.args)
        pictures = parse_pictures(cmd.args)
        if pace is not None:
            self.pace = pace
        self.backend.reset(epoch, fps, pictures=pictures)
        self.pictures_end = max((b for _, b in pictures), default=0) if pictures is not None else None
        self.bridge.reset_core()
        self.counters["resets"] += 1
        self.waits = StepWaits()  # the breakdown describes the take that starts now
        log.info("simulation reset: time zero = %d ns, camera %.3g fps, pace %g", epoch, self.backend.fps, self.pace)
        self._begin(epoch)
        return True

    def _past_pictures(self) -> None:
        """Once the last pictured frame is rendered nobody waits for the simulation any more: its
        frames are published and it stops until the next command (the transfer's stop: hold, then
        real-time pace). Running on, each step's solve and truth took the CPU that a recorder still
        catching up needs (at load ~15: 510 steps past the take, 37 CPU s of the bridge's, 7 of the
        planner's). A reset that pictures nothing goes on at real-time pace."""
        end = self.pictures_end
        if end is None or self.pace != 0 or self.backend.sim_time_s * self.backend.fps < end:
            return
        self.pictures_end = None
        if end > 0:
            log.info("past the last pictured frame (%d): stopped until the next command", end - 1)
            self.backend.flush()
            self.counters["frames_published"] += self.bridge.publish_frames()
            self.paused = True
            return
        log.info("past the last pictured frame (%d): real-time pace", end - 1)
        self.pace = 1.0
        self._pace_origin = (time.monotonic(), self.step)

    def _wait_for_pace(self) -> None:
        if self.paused:
            cmds = self.bridge.cmd_in
            self.node.sleep_until(math.inf, lambda: len(cmds) > 0)
            self.paused = False
            self._pace_origin = (time.monotonic(), self.step)
            return
        if self.pace <= 0:
            return
        wall0, step0 = self._pace_origin
        due = wall0 + (self.step - step0) * self.period_ns * 1e-9 / self.pace
        delay = due - time.monotonic()
        if delay < -1.0:  # far behind (slow renders): don't burst to catch up
            self._pace_origin = (time.monotonic(), self.step)
        elif delay > 0:
            # a command, or a planner that comes or goes, ends the wait: a slow idle pace never delays a
            # take's reset, and a planner that has just started gets its first tick at once
            alive, cmds = self.planner.alive, self.bridge.cmd_in
            self.node.sleep_until(delay, lambda: len(cmds) > 0 or self.planner.alive != alive)
