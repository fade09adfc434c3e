"""Simulation time through real processes: the simulator bridge owns the clock, a step completes
only once the real planner's setpoint for it has arrived, every camera frame slot is rendered and
published, and the watchdog counts simulated seconds, whatever the wall clock does."""
import dataclasses
import os
import signal
import threading
import time

import numpy as np
import pytest

from cinetransfer.services.planner.core import instructions_from_arrays
from cinetransfer.shared import codec, keys
from cinetransfer.shared import messages as M
from cinetransfer.shared.zenoh_config import open_session
from conftest import connect_flags, spawn, stop, wait_for

RIG = "clk"


class Tape:
    """Everything of the rig, in arrival order (the callback only appends)."""

    def __init__(self, session):
        self.items: list[tuple[str, object]] = []
        self.lock = threading.Lock()
        self.alive: set[str] = set()
        self._subs = [session.declare_subscriber(keys.everything(RIG), self._on),
                      session.liveliness().declare_subscriber(keys.all_alive(RIG), self._on_alive, history=True)]

    def _on(self, s):
        key = str(s.key_expr)
        if "/health/" in key:
            return
        with self.lock:
            self.items.append((key, codec.decode(s.payload.to_bytes())))

    def _on_alive(self, s):
        import zenoh

        name = str(s.key_expr).rsplit("/", 1)[-1]
        (self.alive.add if s.kind == zenoh.SampleKind.PUT else self.alive.discard)(name)

    def of(self, topic) -> list:
        with self.lock:
            return [m for k, m in self.items if k == topic.key(RIG)]

    def snapshot(self) -> list[tuple[str, object]]:
        with self.lock:
            return list(self.items)

    def close(self):
        for s in self._subs:
            s.undeclare()


@pytest.fixture
def tape(listener_opts):
    with open_session(listener_opts) as session:
        t = Tape(session)
        t.session = session
        yield t
        t.close()


def bridge(port, tmp_path, *flags):
    return spawn("autopilot_bridge", "--rig", RIG, "--backend", "sim", "--scene", "lawn_juggler_25d",
                 *flags, *connect_flags(port), log=tmp_path / "bridge.log")


@pytest.mark.slow
def test_steps_wait_for_the_planner_and_no_frame_is_skipped(tape, port, tmp_path):
    br = bridge(port, tmp_path, "--pace", "0")
    pl = spawn("planner", "--rig", RIG, *connect_flags(port), log=tmp_path / "planner.log")
    try:
        wait_for(lambda: {"planner", "autopilot_bridge"} <= tape.alive, 120, what="nodes alive")
        ins = instructions_from_arrays(targets=np.full((240, 1, 2), 0.5), joint_names=["nose"], fps=24.0)
        tape.session.put(keys.INSTRUCTIONS.key(RIG), codec.encode(dataclasses.replace(ins, final=True)))
        tape.session.put(keys.PLANNER_COMMAND.key(RIG), codec.encode(M.Command(action="start")))
        wait_for(lambda: len([t for t in tape.of(keys.SIM_CLOCK) if t.lockstep]) > 60, 120,
                 what="60 lockstep clock ticks")
        # when the planner is frozen (alive, but answering nothing), the clock stops with it
        os.kill(pl.pid, signal.SIGSTOP)
        try:
            time.sleep(0.3)  # let the step in flight finish
            n_frozen = len(tape.of(keys.SIM_CLOCK))
            time.sleep(1.5)
            assert len(tape.of(keys.SIM_CLOCK)) <= n_frozen + 1
        finally:
            os.kill(pl.pid, signal.SIGCONT)
        # and it goes on when the planner does
        wait_for(lambda: len(tape.of(keys.SIM_CLOCK)) > n_frozen + 40, 120, what="clock resumes")
    finally:
        assert stop(pl) == 0
        assert stop(br) == 0
    items = tape.snapshot()
    ticks = [m for k, m in items if k == keys.SIM_CLOCK.key(RIG)]
    lock = [t for t in ticks if t.lockstep]
    assert len(lock) > 80
    # then each lockstep tick is answered by a setpoint stamped with it, and the bridge never went on
    # without one (a timed-out wait is logged). The observer's arrival order is not used: the planner
    # and the bridge reach it over separate links, so a setpoint may arrive after the next tick.
    answered = {m.stamp_ns for k, m in items if k == keys.SETPOINT.key(RIG)}
    for a, b in zip(lock, lock[1:]):
        assert a.stamp_ns in answered, f"step {a.step}: no setpoint stamped with its tick"
        assert b.stamp_ns - a.stamp_ns == int(round(a.period_s * 1e9))
    assert "no setpoint for simulation step" not in (tmp_path / "bridge.log").read_text()
    # and every camera frame slot up to the last tick was rendered and published, in order
    frames = [m for k, m in items if k == keys.FRAME.key(RIG)]
    idx = [f.index for f in frames]
    assert idx == list(range(idx[0], idx[0] + len(idx)))
    sim_s = (ticks[-1].stamp_ns - ticks[-1].epoch_ns) * 1e-9
    assert idx[-1] >= int(sim_s * 24) - 2
    # each frame stamped at its own slot time
    for f in frames:
        assert f.stamp_ns == ticks[-1].epoch_ns + int(round(f.index / 24 * 1e9))


@pytest.mark.slow
def test_watchdog_counts_simulated_seconds(tape, port, tmp_path):
    # given a simulator bridge with no planner (the clock free-runs, paced at real time)
    br = bridge(port, tmp_path, "--watchdog", "0.5")
    try:
        wait_for(lambda: len(tape.of(keys.SIM_CLOCK)) > 5, 120, what="clock ticks")
        now = tape.of(keys.SIM_CLOCK)[-1].stamp_ns
        state = tape.of(keys.VEHICLE_STATE)[-1]
        # when one setpoint arrives (stamped with the simulation clock) and then no more
        sp = M.Setpoint(stamp_ns=now, position_m=state.position_m + np.array([0.5, 0, 0]),
                        camera_ypr_rad=state.camera_ypr_rad, lens=state.lens, horizon_t_s=np.zeros(1),
                        horizon_position_m=np.zeros((1, 3)), horizon_camera_ypr_rad=np.zeros((1, 3)),
                        horizon_lens=np.array([[35.0, 5.0, 4.0]]))
        tape.session.put(keys.SETPOINT.key(RIG), codec.encode(sp))
        wait_for(lambda: any(not s.holding for s in tape.of(keys.VEHICLE_STATE)), 30, what="tracking")
        wait_for(lambda: tape.of(keys.VEHICLE_STATE)[-1].holding
                 and any(not s.holding for s in tape.of(keys.VEHICLE_STATE)), 30, what="watchdog hold")
    finally:
        assert stop(br) == 0
    states = tape.of(keys.VEHICLE_STATE)
    first_track = next(i for i, s in enumerate(states) if not s.holding)
    back_to_hold = next(i for i in range(first_track, len(states)) if states[i].holding)
    tracked_s = (states[back_to_hold].stamp_ns - states[first_track].stamp_ns) * 1e-9
    # then the vehicle tracked for the watchdog's 0.5 s of simulated time (to within a step)
    assert 0.45 <= tracked_s <= 0.6, tracked_s


@pytest.mark.slow
def test_a_clock_tick_600_s_back_resets_the_planners_warm_start_and_the_take_goes_on(tape, port, tmp_path):
    health: dict[str, M.Health] = {}
    sub = tape.session.declare_subscriber(keys.health(RIG, "planner"),
                                          lambda s: health.update(planner=codec.decode(s.payload.to_bytes())))
    br = bridge(port, tmp_path, "--pace", "0")
    pl = spawn("planner", "--rig", RIG, "--health-period", "0.2", *connect_flags(port),
               log=tmp_path / "planner.log")
    try:
        wait_for(lambda: {"planner", "autopilot_bridge"} <= tape.alive, 120, what="nodes alive")
        ins = instructions_from_arrays(targets=np.full((2400, 1, 2), 0.5), joint_names=["nose"], fps=24.0)
        tape.session.put(keys.INSTRUCTIONS.key(RIG), codec.encode(dataclasses.replace(ins, final=True)))
        tape.session.put(keys.PLANNER_COMMAND.key(RIG), codec.encode(M.Command(action="start")))
        wait_for(lambda: health.get("planner") is not None and health["planner"].counters.get("solves", 0) > 20, 120,
                 what="the planner tracking")
        resets = int(health["planner"].counters.get("warm_start_resets", 0))
        # when one clock tick arrives 600 s back (what a restarted bridge publishes) ...
        last = tape.of(keys.SIM_CLOCK)[-1]
        back = dataclasses.replace(last, stamp_ns=last.stamp_ns - 600 * 10**9)
        tape.session.put(keys.SIM_CLOCK.key(RIG), codec.encode(back))
        # ... then the planner resets its warm start (and again when the clock is back where it was)
        wait_for(lambda: int(health["planner"].counters.get("warm_start_resets", 0)) > resets, 60,
                 what="warm start reset")
        n = len(tape.of(keys.SIM_CLOCK))
        # and the take goes on: the lockstep clock, which waits for the planner's setpoints, still runs
        wait_for(lambda: len(tape.of(keys.SIM_CLOCK)) > n + 40, 120, what="clock ticks after the jump")
        assert pl.poll() is None and br.poll() is None
    finally:
        sub.undeclare()
        rc_pl, rc_br = stop(pl), stop(br)
    log = (tmp_path / "planner.log").read_text()
    assert rc_pl == 0 and rc_br == 0, log[-3000:]
    assert "Traceback" not in log and "warm start reset" in log, log[-3000:]


@pytest.mark.slow
def test_a_command_wakes_a_slowly_paced_bridge_at_once(tape, port, tmp_path):
    # given a bridge paced so slowly that its next step would come 500 s after the first one
    br = bridge(port, tmp_path, "--pace", "0.0001", "--no-frames-before-reset")
    try:
        wait_for(lambda: "autopilot_bridge" in tape.alive, 120, what="bridge alive")
        wait_for(lambda: tape.of(keys.SIM_CLOCK), 120, what="the first clock tick")
        n = len(tape.of(keys.SIM_CLOCK))

        def ask(action, **args):  # (again each time: the first put may come before its subscription)
            tape.session.put(keys.BRIDGE_COMMAND.key(RIG), codec.encode(M.Command(action=action, args=args)))
            return False

        # when a 'clock' command without a pace arrives, then the bridge steps at once: a new tick
        wait_for(lambda: len(tape.of(keys.SIM_CLOCK)) > n or ask("clock"), 120, interval=2.0, what="a woken tick")
        ticks = tape.of(keys.SIM_CLOCK)
        assert ticks[-1].pace == pytest.approx(0.0001)  # the pace is kept
        # and a reset is handled at once too: ticks of the new time zero, at its pace (as fast as possible)
        epoch = ticks[-1].stamp_ns + 600 * 10**9
        wait_for(lambda: any(t.epoch_ns == epoch for t in tape.of(keys.SIM_CLOCK))
                 or ask("reset", epoch_ns=epoch, pace=0.0, pictures=[]), 120, interval=2.0, what="the reset's tick")
        wait_for(lambda: sum(t.epoch_ns == epoch for t in tape.of(keys.SIM_CLOCK)) > 20, 120, what="20 ticks at pace 0")
    finally:
        assert stop(br) == 0
