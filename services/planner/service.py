"""`cinetransfer planner`: the CineMPC planner as a Zenoh node.

In:  keys.INSTRUCTIONS (Instructions, no-drop; the newest set is followed),
     keys.VEHICLE_STATE, keys.SUBJECT_STATE (latest wins),
     keys.PLANNER_COMMAND (Command: start / pause / resume / hold / stop, no-drop; `args.at_ns`
     schedules it at an exact time), keys.SIM_CLOCK (simulation time, when a simulator owns it).
Out: keys.SETPOINT (Setpoint with the planned horizon): at a fixed wall rate (config.rate_hz),
     or one per simulation clock tick, stamped with the tick; Health counters: state,
     instruction_frame, solver_status, solve_ms, over_budget (solves slower than the real-time
     budget), sim_time, clock_ticks, ...

The solver is built (or its generated code loaded from cache) and warmed up before the node
declares itself ready.
"""
from __future__ import annotations

import argparse
import collections
import logging
import time
from typing import Any

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.core import Planner
from cinetransfer.shared import keys, nodeconfig
from cinetransfer.shared import messages as M
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.node import add_node_arguments, call_periodically, node_from_args
from cinetransfer.shared.vehicle import add_vehicle_argument, load_vehicle

log = logging.getLogger("cinetransfer.planner")


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    nodeconfig.add_config_arguments(p, "planner")
    add_vehicle_argument(p)
    nodeconfig.add_settings_arguments(p, pc.PlannerConfig, "planner")


def config_from_args(args: argparse.Namespace) -> pc.PlannerConfig:
    """The vehicle profile's bounds, then the node's settings (shared/nodeconfig.py), then flags (STYLE §5).

    The settings may name the vehicle (`vehicle: NAME|PATH`); --vehicle overrides it."""
    section = nodeconfig.args_section(args, "planner")
    vehicle = load_vehicle(getattr(args, "vehicle", None) or section.pop("vehicle", None))
    if isinstance(section.get("joint_weights"), dict):  # {name: factor} in a file
        section["joint_weights"] = pc.joint_weights_from(section["joint_weights"])
    base = pc.with_vehicle(pc.PlannerConfig(), vehicle)
    return nodeconfig.config_from_args(pc.PlannerConfig, args, "planner", base=base, section=section)


#: in simulation time, how long to wait for the state of a clock tick before solving without it [s]
STATE_WAIT_S = 2.0
#: where the simulation-time loop's wall time goes (Health counters, seconds since the clock's reset)
WAIT_PARTS = ("wait_tick_s", "wait_state_s", "step_s")


class PlannerShell:
    """The service loop around `Planner`: inputs in, one setpoint out per tick.

    Without a simulation clock it ticks at `rate_hz` on the wall clock. When the bridge
    publishes `sim/clock` ticks it follows them from then on: one solve per tick, stamped
    with the tick's time, using the vehicle and subject state of that very tick.
    """

    def __init__(self, node: Any, cfg: pc.PlannerConfig, planner: Planner) -> None:
        self.node, self.cfg, self.planner = node, cfg, planner
        self.ins_in = node.subscribe(keys.INSTRUCTIONS, maxlen=64)
        self.veh_in = node.subscribe(keys.VEHICLE_STATE, maxlen=8)
        self.sub_in = node.subscribe(keys.SUBJECT_STATE, maxlen=8)
        self.cmd_in = node.subscribe(keys.PLANNER_COMMAND)
        self.clk_in = node.subscribe(keys.SIM_CLOCK, maxlen=100_000)
        self.pub = node.publisher(keys.SETPOINT)
        self.latest: dict[str, Any] = {"ins": None, "veh": None, "sub": None}
        self.sim_time = False
        self.counters: dict[str, Any] = {"clock_ticks": 0, "state_waits_timed_out": 0}
        self.solve_ms: collections.deque[float] = collections.deque(maxlen=5000)
        self._solves_seen = 0
        self._epoch_ns: int | None = None

    def run(self) -> None:
        period = 1.0 / self.cfg.rate_hz
        while self.node.running and not self.sim_time:
            call_periodically(period, self.node, self._guarded_wall_tick, until=lambda: len(self.clk_in) > 0)
            if len(self.clk_in):
                self._enter_sim_time()
        while self.node.running:
            t = time.perf_counter()
            tick = self.clk_in.get(timeout=0.2)
            self._spent("wait_tick_s", t)
            if tick is not None:
                with self.node.guard(self.clk_in.key, "clock tick"):  # no exception ever ends the loop
                    self._sim_tick(tick)

    def _guarded_wall_tick(self) -> None:
        with self.node.guard("wall clock", "control step"):
            self._wall_tick()

    def _enter_sim_time(self) -> None:
        log.info("simulation clock seen: following it (solve budget lifted, over-budget solves counted)")
        self.planner.use_time_budget(None)
        self.sim_time = True

    def _wall_tick(self) -> None:
        self._inputs(M.now_ns())
        self._solve(M.now_ns())

    def _sim_tick(self, tick: M.SimClock) -> None:
        now = int(tick.stamp_ns)
        if tick.epoch_ns != self._epoch_ns:  # the simulation started over: so does the breakdown
            self._epoch_ns = tick.epoch_ns
            self.counters.update(dict.fromkeys(WAIT_PARTS, 0.0))
        self.node.clock_ns = now
        self.counters["clock_ticks"] += 1
        self._inputs(now)
        deadline, t = time.monotonic() + STATE_WAIT_S, time.perf_counter()
        while not self._have_state_at(now) and self.node.running and time.monotonic() < deadline:
            self.node.wait(0.05)
            self._states()
        self._spent("wait_state_s", t)
        if not self._have_state_at(now) and self.node.running:
            self.counters["state_waits_timed_out"] += 1
            v, s = self.latest["veh"], self.latest["sub"]
            self.node.error(f"no state for clock tick {now} within {STATE_WAIT_S:g} s (vehicle "
                            f"{None if v is None else v.stamp_ns}, subject {None if s is None else s.stamp_ns})",
                            "clock")
        self._solve(now)

    def _spent(self, part: str, since: float) -> None:
        """Count the wall seconds since `since` under `part` (where the simulation-time loop's time
        goes: waiting for a tick, for its state, or stepping the planner)."""
        self.counters[part] = round(self.counters.get(part, 0.0) + time.perf_counter() - since, 4)

    def _have_state_at(self, now: int) -> bool:
        v, s = self.latest["veh"], self.latest["sub"]
        return v is not None and s is not None and v.stamp_ns >= now and s.stamp_ns >= now

    def _inputs(self, now: int) -> None:
        for cmd in self.cmd_in.drain():
            with self.node.guard(self.cmd_in.key, "command"):  # one bad command never ends the loop
                if not self.planner.command(cmd, now):
                    self.node.reject(f"unknown or malformed planner command {cmd.action!r}")
            self.node.counters.update(self.planner.counters)
            self.node.publish_health_now()  # acknowledges the command (e.g. a scheduled start)
        for ins in self.ins_in.drain():
            if ins.image_targets.shape[0] == 0:
                self.node.reject("instructions with no frames")
                continue
            why = self.planner.refuse_instructions(ins)
            if why:
                self.node.reject(f"instructions refused: {why}")
                continue
            self.latest["ins"] = ins
        self._states()

    def _states(self) -> None:
        v = self.veh_in.latest()
        if v is not None:
            self.latest["veh"] = v
        s = self.sub_in.latest()
        if s is not None:
            self.latest["sub"] = s

    def _solve(self, now: int) -> None:
        node, planner, latest = self.node, self.planner, self.latest
        t = time.perf_counter()
        with node.timed():
            sp = planner.step(now, latest["ins"], latest["veh"], latest["sub"])
        self.pub.put(sp)
        self._spent("step_s", t)
        if planner.last_result is not None and planner.counters["solves"] != self._solves_seen:
            self._solves_seen = planner.counters["solves"]
            self.solve_ms.append(planner.last_result.wall_s * 1e3)
            ms = sorted(self.solve_ms)
            self.counters.update(solve_ms_p50=round(ms[len(ms) // 2], 2),
                                 solve_ms_p95=round(ms[min(len(ms) - 1, int(0.95 * len(ms)))], 2))
        node.counters.update(planner.counters)
        node.counters.update(self.counters, sim_time=self.sim_time)
        node.healthy = bool(sp.valid)
        if not sp.valid:
            node.error(f"setpoint invalid: {sp.solver_status}", "invalid")


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer planner", description=__doc__.split("\n")[0])
    add_node_arguments(p)
    add_config_arguments(p)
    args = p.parse_args(argv)
    try:
        cfg = config_from_args(args)
    except ConfigError as e:
        return report_config_error(e, "cinetransfer planner")
    node = node_from_args("planner", args, config=cfg)
    with node:
        t = time.perf_counter()
        planner = Planner(cfg)
        log.info("solver ready in %.2f s (N=%d, dt=%.3f s, codegen=%s)", time.perf_counter() - t,
                 cfg.structure.horizon_steps, cfg.structure.dt_s, cfg.structure.codegen)
        shell = PlannerShell(node, cfg, planner)
        node.counters.update(planner.counters)
        node.ready()
        shell.run()
    return 0


__all__ = ["main", "config_from_args", "PlannerShell"]
