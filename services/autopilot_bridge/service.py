"""`cinetransfer autopilot_bridge`: where setpoints meet a vehicle.

    cinetransfer autopilot_bridge --backend sim --scene NAME               # built-in simulator
    cinetransfer autopilot_bridge --backend mavlink --mavlink udpin:0.0.0.0:14540 --engage

A thin shell around `core.BridgeCore` (safety layer + watchdog) and a `VehiclePort` backend.
Every tick (--rate, 50 Hz by default): drain bridge commands, check the newest setpoints,
decide track/hold, drive the backend, publish VehicleState (and SubjectState, Frames and
GroundTruth when the backend has them). Health carries every safety counter.

With the simulator the bridge owns time (lockstep.py): it publishes SIM_CLOCK ticks and a step
completes only once the planner's setpoint for it has arrived; `--realtime` keeps the wall
clock instead. A real vehicle (mavlink) always runs on the wall clock.

Keys in:  SETPOINT (drop-oldest), BRIDGE_COMMAND (no-drop), SUBJECT_STATE (drop-oldest; only
          with backends that do not know the subject themselves, i.e. mavlink)
Keys out: VEHICLE_STATE, SUBJECT_STATE, FRAME (raw, or JPEG with --jpeg Q), SIM_TRUTH and
          SIM_CLOCK (sim only)
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from typing import Any

from cinetransfer.services.autopilot_bridge.config import (
    BridgeConfig, ConfigError, MavlinkConfig, SafetyConfig)
from cinetransfer.services.autopilot_bridge.core import BridgeCore
from cinetransfer.services.autopilot_bridge.port import VehiclePort
from cinetransfer.shared import keys, nodeconfig
from cinetransfer.shared import messages as M
from cinetransfer.shared.errors import report_config_error
from cinetransfer.shared.node import add_node_arguments, call_periodically, node_from_args
from cinetransfer.shared.vehicle import add_vehicle_argument, load_vehicle

log = logging.getLogger("cinetransfer.autopilot_bridge")
NODE_NAME = "autopilot_bridge"
SIM_MAX_FRAME_LAG_S = 0.2


# ----------------------------------------------------------------------------- config
def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cinetransfer autopilot_bridge",
                                 description="vehicle bridge: safety layer + built-in simulator or MAVLink")
    nodeconfig.add_config_arguments(ap, NODE_NAME)
    add_vehicle_argument(ap)
    nodeconfig.add_settings_arguments(ap, BridgeConfig, "bridge")
    add_node_arguments(ap)
    return ap


def config_from_args(args: argparse.Namespace) -> BridgeConfig:
    """The vehicle profile's limits, then the node's settings (shared/nodeconfig.py), then flags.

    Bridge fields stand at the top of the settings (a deploy config) or under `bridge:` (a file
    of the bridge's own), beside the `safety:` and `mavlink:` groups. Raises ConfigError naming
    the field."""
    section = nodeconfig.args_section(args, NODE_NAME)
    bridge = section.pop("bridge", None) or {}
    if not isinstance(bridge, dict):
        raise ConfigError(f"{NODE_NAME} config: bridge must be a mapping")
    section.update(bridge)
    if getattr(args, "vehicle", None):
        section["vehicle"] = args.vehicle
    vehicle = load_vehicle(section.get("vehicle") or None)
    cam = vehicle.camera
    base = BridgeConfig(safety=SafetyConfig.from_vehicle(vehicle),
                        mavlink=MavlinkConfig(sensor_width_mm=cam.sensor_width_mm,
                                              sensor_height_mm=cam.sensor_height_mm, coc_mm=cam.coc_mm,
                                              focal_length_range_mm=tuple(vehicle.lens.focal_length_mm)))
    return nodeconfig.config_from_args(BridgeConfig, args, NODE_NAME, base=base, section=section)


# ----------------------------------------------------------------------------- backends
def make_backend(cfg: BridgeConfig) -> VehiclePort:
    if cfg.backend == "mavlink":
        from cinetransfer.services.autopilot_bridge.mavlink import MavlinkBackend

        return MavlinkBackend(cfg.mavlink)
    # The built-in simulator is imported lazily (renderer, assets: heavier imports).
    from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend, load_scene

    # Frames render on a worker thread. In real time the control loop (safety layer, watchdog,
    # state at `rate_hz`) never waits for the renderer: a frame already late by more than a few
    # frame periods, or due while two are still rendering, is skipped (counted). In simulation
    # time nothing is skipped: rendering overlaps the planner's solve, and a step ends with its
    # frames.
    lag = SIM_MAX_FRAME_LAG_S if cfg.sim_clock == "realtime" else None
    from cinetransfer.services.autopilot_bridge.sim.scene import with_vehicle

    scene = with_vehicle(load_scene(cfg.scene, subject=cfg.subject or None), load_vehicle(cfg.vehicle or None))
    return SimBackend(scene, max_frame_lag_s=lag, async_render=True)


# ----------------------------------------------------------------------------- service
class Bridge:
    """The loop body, kept apart from main() so that it can be driven in-process.

    `tick(now)` is one wall-clock control step (real-time mode). The simulation clock
    (`lockstep.SimClockLoop`) drives the same pieces: `handle_commands`, `handle_setpoints`,
    `control`, `publish_state`, `publish_frames`.
    """

    def __init__(self, node: Any, cfg: BridgeConfig, backend: VehiclePort, *, lossless_frames: bool = False) -> None:
        self.node, self.cfg, self.backend = node, cfg, backend
        self.core = BridgeCore(cfg.safety)
        self.sp_in = node.subscribe(keys.SETPOINT, maxlen=64)
        self.cmd_in = node.subscribe(keys.BRIDGE_COMMAND)
        self.subject_in = node.subscribe(keys.SUBJECT_STATE, maxlen=2) if cfg.backend == "mavlink" else None
        # in simulation time every state and frame must arrive: publishers block, never drop
        block = True if lossless_frames else None
        self.state_pub = node.publisher(keys.VEHICLE_STATE, block=block)
        self.subject_pub = node.publisher(keys.SUBJECT_STATE, block=block) if cfg.backend != "mavlink" else None
        self.frame_pub = node.publisher(keys.FRAME, jpeg_quality=cfg.jpeg_quality or None, block=block)
        self.truth_pub = node.publisher(keys.SIM_TRUTH, block=block) if cfg.backend == "sim" else None
        self.vehicle: M.VehicleState | None = None
        self.subject: M.SubjectState | None = None
        self.subject_rx_s = -1e9
        self.ticks = 0
        self.decision_hold = True
        self.breach = False
        #: the link as the tick's decision saw it: state, Health and hold reason all use this one sample
        #: (the backend's own flag flips on its reader thread, between two reads of one tick)
        self.link_up = bool(backend.connected)

    def reset_core(self) -> None:
        """Forget setpoints, holds and rate limits (the simulation started over)."""
        self.core = BridgeCore(self.cfg.safety)
        self.vehicle = None

    def _subject(self, now: float) -> M.SubjectState | None:
        s = self.backend.subject_state()
        if s is not None:
            return s
        if self.subject_in is not None:
            newest = self.subject_in.latest()
            if newest is not None and newest.valid:
                self.subject, self.subject_rx_s = newest, now
        if self.subject is not None and now - self.subject_rx_s <= self.cfg.safety.subject_timeout_s:
            return self.subject
        return None

    def handle_commands(self, cmds: list[M.Command]) -> None:
        node, core, backend = self.node, self.core, self.backend
        for cmd in cmds:
            # guard: whatever one command trips over costs that command, not the loop
            with node.guard(self.cmd_in.key, "command"):
                args, why = core.command_args(cmd)
                if args is None:
                    node.reject(f"bridge command {cmd.action!r}: {why}")
                    continue
                action = core.on_command(cmd)
                log.info("command %s %s", cmd.action, cmd.args or "")
                if action and action != "hold" and not backend.command(action, args):
                    node.error(f"backend {backend.name} does not support command {action!r}", "command")
                elif action is None and cmd.action not in ("hold", "resume"):
                    node.reject(f"unknown bridge command {cmd.action!r}")

    def handle_setpoints(self, sps: list[M.Setpoint], now: float, clock_ns: int) -> None:
        """`now`: the control clock [s]; `clock_ns`: 'now' on the stamp clock (wall or simulation)."""
        subject = self._subject(now)
        for sp in sps:
            with self.node.guard(self.sp_in.key, "setpoint"):
                res = self.core.on_setpoint(sp, now, clock_ns=clock_ns, vehicle=self.vehicle, subject=subject)
                if res is not None and not res.accepted:
                    self.node.reject(f"setpoint #{sp.seq}: {res.reason}")

    def control(self, now: float, step_to: float | None = None) -> None:
        """Decide track/hold at `now`, drive the backend, advance it to `step_to` (default now)."""
        backend = self.backend
        self.link_up = bool(backend.connected)
        dec = self.core.tick(now, vehicle=self.vehicle, connected=self.link_up)
        if dec.hold:
            if dec.changed:
                log.info("holding: %s", dec.reason)
                backend.hold()
        else:
            if dec.changed:
                log.info("tracking setpoints")
            backend.apply(dec.setpoint)
        if dec.breach and dec.changed:
            log.warning("envelope breach at %s: flying back inside",
                        None if self.vehicle is None else self.vehicle.position_m)
        self.decision_hold, self.breach = dec.hold, dec.breach
        backend.step(now if step_to is None else step_to)
        self._refresh_vehicle()

    def _refresh_vehicle(self) -> None:
        vs = self.backend.vehicle_state()
        self.vehicle = dataclasses.replace(vs, holding=self.decision_hold, envelope_breach=self.breach,
                                           valid=bool(vs.valid and self.link_up))

    def publish_state(self, stamp_ns: int | None = None) -> None:
        """Vehicle (and simulated subject) state; `stamp_ns` restamps them with the clock tick."""
        if self.vehicle is None:
            self._refresh_vehicle()
        vs = self.vehicle
        if stamp_ns is not None:
            vs = dataclasses.replace(vs, stamp_ns=stamp_ns)
        if stamp_ns is not None or self.ticks % self.cfg.state_every_n == 0:
            self.state_pub.put(vs)
        if self.subject_pub is not None:
            subj = self.backend.subject_state()
            if subj is not None:
                self.subject_pub.put(subj if stamp_ns is None else dataclasses.replace(subj, stamp_ns=stamp_ns))

    def publish_frames(self) -> int:
        n = 0
        for frame in self.backend.frames():
            self.frame_pub.put(frame)
            n += 1
        if self.truth_pub is not None:
            for truth in self.backend.truths():
                self.truth_pub.put(truth)
        return n

    def update_health(self) -> None:
        counters = self.core.all_counters()
        extra = getattr(self.backend, "health_counters", None)
        if callable(extra):
            counters.update(extra())
        counters["connected"] = self.link_up
        self.node.counters.update(counters)
        self.node.healthy = bool(self.link_up and self.vehicle is not None and self.vehicle.valid
                                 and not self.breach)

    def guarded_tick(self) -> None:
        """`tick`, where an exception costs the tick (counted, logged), never the loop."""
        with self.node.guard("control", "control tick"):
            self.tick()

    def tick(self) -> None:
        """One real-time control step on the monotonic clock."""
        now = time.monotonic()
        # one Health report holds a whole tick or none of it (a rejection and its own counter together)
        with self.node.consistent():
            with self.node.timed():
                self.handle_commands(self.cmd_in.drain())
                self.handle_setpoints(self.sp_in.drain(), now, M.now_ns())
                self.control(now)
                self.publish_state()
                self.publish_frames()
            self.ticks += 1
            self.update_health()


def main(argv: list[str]) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        cfg = config_from_args(args)
    except ConfigError as e:
        return report_config_error(e, "cinetransfer autopilot_bridge")
    node = node_from_args(NODE_NAME, args, config=cfg)
    sim_time = cfg.backend == "sim" and cfg.sim_clock == "lockstep"
    try:
        backend = make_backend(cfg)
    except ModuleNotFoundError as e:
        log.error("backend %r is not available in this build: %s", cfg.backend, e)
        return 2
    with node:
        try:
            backend.start()
        except (ConnectionError, OSError) as e:
            log.error("backend %s failed to start: %s", cfg.backend, e)
            return 1
        try:
            bridge = Bridge(node, cfg, backend, lossless_frames=sim_time)
            if sim_time:
                from cinetransfer.services.autopilot_bridge.lockstep import SimClockLoop

                loop = SimClockLoop(node, cfg, bridge)
                node.ready()
                loop.run()
            else:
                node.ready()
                call_periodically(1.0 / cfg.rate_hz, node, bridge.guarded_tick)
        finally:
            backend.hold()
            backend.close()
    return 0
