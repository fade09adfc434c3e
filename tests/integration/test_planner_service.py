"""The planner as a real process over real Zenoh: instructions and states in, setpoints out."""
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from cinetransfer.services.planner.kinematic_sim import KinematicSim
from cinetransfer.services.planner.scenarios import reference_instructions, standing_shot, wrong_start_scene
from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M
from conftest import connect_flags, spawn, stop, wait_for

RIG = "t"


class Peer:
    """The test's own session: publishes states/instructions/commands and the simulation clock,
    collects setpoints and health."""

    def __init__(self, opts):
        import zenoh

        self.session = zenoh_config.open_session(opts)
        self.lock = threading.Lock()
        self.setpoints: list[M.Setpoint] = []
        self.health: list[M.Health] = []
        self.alive: set[str] = set()
        self._decl = [
            self.session.declare_subscriber(keys.SETPOINT.key(RIG), self._on_sp),
            self.session.declare_subscriber(keys.health(RIG, "planner"), self._on_health),
            self.session.liveliness().declare_subscriber(keys.all_alive(RIG), self._on_alive, history=True),
        ]
        self.pubs = {t: self.session.declare_publisher(t.key(RIG)) for t in
                     (keys.INSTRUCTIONS, keys.VEHICLE_STATE, keys.SUBJECT_STATE, keys.PLANNER_COMMAND,
                      keys.SIM_CLOCK)}
        self._zenoh = zenoh

    def _on_sp(self, s):
        msg = codec.decode(s.payload.to_bytes(), M.Setpoint)
        with self.lock:
            self.setpoints.append(msg)

    def _on_health(self, s):
        with self.lock:
            self.health.append(codec.decode(s.payload.to_bytes(), M.Health))

    def _on_alive(self, s):
        name = str(s.key_expr).split("/")[-1]
        with self.lock:
            (self.alive.add if s.kind == self._zenoh.SampleKind.PUT else self.alive.discard)(name)

    def setpoint_at(self, stamp_ns):
        with self.lock:
            return next((s for s in self.setpoints if s.stamp_ns == stamp_ns), None)

    def health_where(self, pred):
        with self.lock:
            return any(pred(h.counters) for h in self.health)

    def health_since(self, stamp_ns, state):
        """A Health taken at or after simulation time `stamp_ns` in planner state `state`, or None."""
        with self.lock:
            return next((h for h in self.health if h.stamp_ns >= stamp_ns and h.counters.get("state") == state), None)

    def put(self, topic, msg):
        self.pubs[topic].put(codec.encode(msg))

    def close(self):
        for d in [*self._decl, *self.pubs.values()]:
            d.undeclare()
        self.session.close()


@pytest.fixture
def peer(listener_opts):
    p = Peer(listener_opts)
    yield p
    p.close()


#: the test owns simulation time, as the simulator bridge does (services/autopilot_bridge/lockstep.py)
PERIOD_NS = 50_000_000
EPOCH_NS = 1_000_000_000_000


def test_planner_service_tracks_and_exits_cleanly(port, peer, tmp_path):
    # solve budgets of 1 ms, which no solve meets on the wall clock: on the simulation clock the
    # planner lifts them (a loaded machine may solve slower, never differently) and counts the misses
    log, settings = tmp_path / "planner.log", tmp_path / "planner.yaml"
    settings.write_text("planner:\n  max_solve_time_s: 0.001\n  max_cold_solve_time_s: 0.001\n")
    proc = spawn("planner", "--rig", RIG, "--config", str(settings), "--health-period", "0.2",
                 *connect_flags(port), log=log)
    try:
        wait_for(lambda: "planner" in peer.alive or proc.poll() is not None, timeout=60, what="planner liveliness")
        assert proc.poll() is None, log.read_text()
        scene = wrong_start_scene()
        ins = reference_instructions(scene, standing_shot(), duration_s=10.0)
        sim = KinematicSim(scene)

        states: dict[int, tuple[M.VehicleState, M.SubjectState]] = {}

        def send(step):
            """States at the step's time, then its clock tick (the bridge's order)."""
            t = EPOCH_NS + step * PERIOD_NS
            veh, sub = states.setdefault(step, (sim.vehicle_state(t), sim.subject_state(t)))
            peer.put(keys.VEHICLE_STATE, veh)
            peer.put(keys.SUBJECT_STATE, sub)
            peer.put(keys.SIM_CLOCK, M.SimClock(stamp_ns=t, epoch_ns=EPOCH_NS, step=step, period_s=PERIOD_NS * 1e-9))

        def tick(step):
            send(step)
            t = EPOCH_NS + step * PERIOD_NS
            return wait_for(lambda: peer.setpoint_at(t), timeout=60, interval=0.005,
                            what=f"the setpoint of clock tick {step}")  # a hang ceiling, not a speed

        def deliver(cmd, step):
            """Put a command scheduled for a later tick, and repeat tick `step` until Health shows it
            scheduled: the planner reads commands at ticks, and nothing orders one key's samples
            against another's, so a command put before a tick may still come after it."""
            peer.put(keys.PLANNER_COMMAND, cmd)
            deadline = time.monotonic() + 60  # a hang ceiling, not a speed
            while not peer.health_where(lambda c: c.get("scheduled_at_ns") == cmd.args["at_ns"]):
                assert time.monotonic() < deadline, f"{cmd.action!r} never scheduled\n" + log.read_text()
                send(step)
                time.sleep(0.2)

        # the first tick is repeated until answered (a sample sent before the routes are up may be lost)
        deadline = time.monotonic() + 30
        while peer.setpoint_at(EPOCH_NS) is None:
            assert time.monotonic() < deadline, "no setpoint stamped with the first tick\n" + log.read_text()
            peer.put(keys.INSTRUCTIONS, ins)
            send(0)
            time.sleep(0.1)
        assert peer.setpoint_at(EPOCH_NS).mode == "hold"  # not started yet
        # given instructions and a 'start' at the next tick, when the simulator flies 3 s of its
        # time in lockstep (one setpoint per tick, stamped with it)
        peer.put(keys.INSTRUCTIONS, ins)
        deliver(M.Command(stamp_ns=EPOCH_NS, action="start", args={"at_ns": EPOCH_NS + PERIOD_NS}), 0)
        n = 60
        got = []
        for step in range(1, n + 1):
            sp = tick(step)
            got.append(sp)
            sim.apply(sp)
            sim.step(PERIOD_NS * 1e-9)
        # then every setpoint tracks, valid, finite, with the horizon
        assert [s.stamp_ns for s in got] == [EPOCH_NS + k * PERIOD_NS for k in range(1, n + 1)]
        assert [s.seq for s in got] == list(range(got[0].seq, got[0].seq + n))
        tracking = [s for s in got if s.mode == "track" and s.valid]
        assert len(tracking) == n, [(s.mode, s.solver_status) for s in got if s not in tracking][:5]
        # (no solve cut short by the wall clock: the first, cold one converges in as many iterations as it needs)
        assert got[0].solver_status == "Solve_Succeeded", got[0].solver_status
        sp = tracking[-1]
        assert sp.horizon_position_m.shape == (16, 3) and sp.horizon_lens.shape == (16, 3)
        assert all(np.all(np.isfinite(a)) for a in (sp.position_m, sp.camera_ypr_rad, sp.horizon_lens))
        assert sp.instruction_frame > 0
        # and the camera got closer to the shot it was asked for (the loop closes over Zenoh)
        err = np.linalg.norm(sim.image_points(ins.joint_names) - ins.image_targets[sp.instruction_frame], axis=1)
        assert np.max(err) < 0.3
        # when a 'hold' command arrives for the next tick, that tick's setpoint holds
        t_hold = EPOCH_NS + (n + 1) * PERIOD_NS
        deliver(M.Command(stamp_ns=t_hold, action="hold", args={"at_ns": t_hold}), n)
        assert tick(n + 1).mode == "hold"
        # and Health shows the state, the clock followed, and the solver figures (every solve over
        # the 1 ms budget counted, none failed for it)
        health = wait_for(lambda: peer.health_since(t_hold, "holding"), timeout=30, what="health of the hold")
        c = health.counters
        assert c["sim_time"] is True and c["solves"] >= len(tracking) and c["over_budget"] >= 1
        assert isinstance(c["solve_ms"], float)
    finally:
        rc = stop(proc)
    # then SIGINT exits 0
    assert rc == 0, log.read_text()


def test_planner_config_error_refuses_to_start(tmp_path):
    bad = tmp_path / "p.yaml"
    bad.write_text("planner:\n  bounds:\n    focal_length_min_mm: 900\n")
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "planner", "--config", str(bad)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "focal_length_min_mm" in r.stderr
