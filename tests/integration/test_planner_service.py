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
    """The test's own session: publishes states/instructions/commands, collects setpoints and health."""

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
                     (keys.INSTRUCTIONS, keys.VEHICLE_STATE, keys.SUBJECT_STATE, keys.PLANNER_COMMAND)}
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


def test_planner_service_tracks_and_exits_cleanly(port, peer, tmp_path):
    log = tmp_path / "planner.log"
    proc = spawn("planner", "--rig", RIG, "--health-period", "0.2", "--max-solve-time", "0.2", *connect_flags(port),
                 log=log)
    try:
        wait_for(lambda: "planner" in peer.alive or proc.poll() is not None, timeout=60, what="planner liveliness")
        assert proc.poll() is None, log.read_text()
        scene = wrong_start_scene()
        ins = reference_instructions(scene, standing_shot(), duration_s=10.0)
        sim = KinematicSim(scene)

        def feed():
            now = M.now_ns()
            peer.put(keys.VEHICLE_STATE, sim.vehicle_state(now))
            peer.put(keys.SUBJECT_STATE, sim.subject_state(now))

        # given instructions, states and a 'start' command (repeated until the planner reports
        # it is recording: a sample sent before the routes are up may be lost)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            peer.put(keys.INSTRUCTIONS, ins)
            peer.put(keys.PLANNER_COMMAND, M.Command(stamp_ns=M.now_ns(), action="start"))
            feed()
            time.sleep(0.1)
            with peer.lock:
                if any(h.counters.get("state") == "recording" for h in peer.health):
                    break
        else:
            raise AssertionError("planner never reported state=recording\n" + log.read_text())
        # when the simulator flies the setpoints it receives for at least 3 s of its time and 20 setpoints
        # (counted, not timed: a loaded machine may solve slower, never differently)
        with peer.lock:
            n0 = len(peer.setpoints)
        steps, deadline = 0, time.monotonic() + 120
        while time.monotonic() < deadline:
            with peer.lock:
                sp = peer.setpoints[-1] if peer.setpoints else None
                fresh = len(peer.setpoints) - n0
            if steps >= 60 and fresh >= 20:
                break
            if sp is not None:
                sim.apply(sp)
            sim.step(0.05)
            steps += 1
            feed()
            time.sleep(0.05)
        # then setpoints arrive at about the configured rate, tracking, valid, finite, with the horizon
        with peer.lock:
            got = peer.setpoints[n0:]
            health = peer.health[-1]
        assert len(got) >= 20, f"{len(got)} setpoints in {steps} steps"
        tracking = [s for s in got if s.mode == "track" and s.valid]
        assert len(tracking) >= 0.8 * len(got), [s.solver_status for s in got[:5]]
        sp = tracking[-1]
        assert sp.horizon_position_m.shape == (16, 3) and sp.horizon_lens.shape == (16, 3)
        assert all(np.all(np.isfinite(a)) for a in (sp.position_m, sp.camera_ypr_rad, sp.horizon_lens))
        assert sp.instruction_frame > 0
        assert [s.seq for s in got] == list(range(got[0].seq, got[0].seq + len(got)))
        # and the camera got closer to the shot it was asked for (the loop closes over Zenoh)
        err = np.linalg.norm(sim.image_points(ins.joint_names) - ins.image_targets[sp.instruction_frame], axis=1)
        assert np.max(err) < 0.3
        # and Health shows the recording state and solver figures
        assert health.counters["state"] == "recording" and health.counters["solves"] > 10
        assert isinstance(health.counters["solve_ms"], float)
        # when a 'hold' command arrives, the setpoints become holds
        peer.put(keys.PLANNER_COMMAND, M.Command(stamp_ns=M.now_ns(), action="hold"))

        def holding():
            feed()
            with peer.lock:
                return peer.setpoints and peer.setpoints[-1].mode == "hold"
        wait_for(holding, timeout=30, interval=0.05, what="hold setpoints")  # a hang ceiling, not a speed
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
