"""Hostile inputs at the planner and the smoother as real processes over real Zenoh:
the 576-byte deep-args Command, which used to end both loops, is counted in Health.rejected and
each keeps working (the planner keeps publishing setpoints; the smoother still answers 'end' with
the final instructions); instructions nothing can fly are refused by the planner. SIGINT then
gives exit code 0."""
from __future__ import annotations

import threading

import pytest
import zenoh

from attacks import deep_args_command
from cinetransfer.services.smoother.synthetic import walking_sequence
from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M
from conftest import connect_flags, spawn, stop, wait_for

pytestmark = pytest.mark.timeout(150)
#: how long a wait for a service's answer may take: a ceiling for a hang, not a measure of speed (a
#: service process at load 50 on 2 cores gets a few % of a core; the wait ends as soon as it answers)
WAIT_S = 30.0
RIG = "dm"


class Peer:
    def __init__(self, opts, node: str, out_key: str):
        self.session = zenoh_config.open_session(opts)
        self.lock = threading.Lock()
        self.health: M.Health | None = None
        self.outputs = 0
        self.alive: set[str] = set()
        self._decl = [
            self.session.declare_subscriber(keys.health(RIG, node), self._on_health),
            self.session.declare_subscriber(out_key, self._on_out),
            self.session.liveliness().declare_subscriber(keys.all_alive(RIG), self._on_alive, history=True),
        ]

    def _on_health(self, s):
        msg = codec.decode(s.payload.to_bytes(), M.Health)
        with self.lock:
            self.health = msg

    def _on_out(self, s):
        with self.lock:
            self.outputs += 1

    def _on_alive(self, s):
        with self.lock:
            name = str(s.key_expr).split("/")[-1]
            (self.alive.add if s.kind == zenoh.SampleKind.PUT else self.alive.discard)(name)

    def counters(self) -> dict:
        with self.lock:
            return dict(self.health.counters) if self.health else {}

    def rejected(self) -> int:
        with self.lock:
            return self.health.rejected if self.health else -1

    def close(self):
        for d in self._decl:
            d.undeclare()
        self.session.close()


def test_the_planner_survives_the_deep_command(port, listener_opts, tmp_path):
    log = tmp_path / "planner.log"
    peer = Peer(listener_opts, "planner", keys.SETPOINT.key(RIG))
    proc = spawn("planner", "--rig", RIG, "--health-period", "0.2", "--max-solve-time", "0.2", *connect_flags(port),
                 log=log)
    try:
        wait_for(lambda: "planner" in peer.alive or proc.poll() is not None, timeout=60, what="planner liveliness")
        wait_for(lambda: peer.rejected() >= 0, WAIT_S, what="first Health")
        pub = peer.session.declare_publisher(keys.PLANNER_COMMAND.key(RIG))
        for _ in range(3):
            pub.put(deep_args_command())
        wait_for(lambda: peer.rejected() >= 3, WAIT_S, what="deep Commands counted as rejected")
        seen = peer.outputs
        wait_for(lambda: peer.outputs >= seen + 5, WAIT_S, what="setpoints still published")
        assert proc.poll() is None, log.read_text()
        pub.undeclare()
    finally:
        rc = stop(proc)
        peer.close()
    assert rc == 0, log.read_text()


def test_the_smoother_survives_the_deep_command(port, listener_opts, tmp_path):
    log = tmp_path / "smoother.log"
    peer = Peer(listener_opts, "smoother", keys.INSTRUCTIONS.key(RIG))
    proc = spawn("smoother", "--rig", RIG, "--end-idle", "0", "--publish-period", "0.2", "--health-period", "0.2",
                 *connect_flags(port), log=log)
    try:
        wait_for(lambda: "smoother" in peer.alive or proc.poll() is not None, timeout=60, what="smoother liveliness")
        wait_for(lambda: peer.rejected() >= 0, WAIT_S, what="first Health")
        cc = zenoh.CongestionControl.BLOCK
        cmd = peer.session.declare_publisher(keys.SMOOTHER_COMMAND.key(RIG), congestion_control=cc)
        meas = peer.session.declare_publisher(keys.MEASUREMENT.key(RIG), congestion_control=cc)
        cmd.put(deep_args_command())
        wait_for(lambda: peer.rejected() >= 1, WAIT_S, what="deep Command counted as rejected")
        for m in walking_sequence(24):
            meas.put(codec.encode(m))
        n0 = peer.outputs
        cmd.put(codec.encode(M.Command(action="end")))
        wait_for(lambda: peer.outputs > n0, 20, what="final instructions after the deep Command")
        assert proc.poll() is None, log.read_text()
        cmd.undeclare()
        meas.undeclare()
    finally:
        rc = stop(proc)
        peer.close()
    assert rc == 0, log.read_text()


def test_the_planner_refuses_instructions_nothing_can_fly(port, listener_opts, tmp_path):
    """All-NaN or ±1e6 image targets used to be flown in 'track' mode: now each set is a counted
    rejection (Health.rejected, counter instructions_refused) and never becomes the plan."""
    import numpy as np

    from cinetransfer.services.planner.core import instructions_from_arrays

    log = tmp_path / "planner.log"
    peer = Peer(listener_opts, "planner", keys.SETPOINT.key(RIG))
    proc = spawn("planner", "--rig", RIG, "--health-period", "0.2", "--max-solve-time", "0.2", "--autostart",
                 *connect_flags(port), log=log)
    try:
        wait_for(lambda: "planner" in peer.alive or proc.poll() is not None, timeout=60, what="planner liveliness")
        wait_for(lambda: peer.rejected() >= 0, WAIT_S, what="first Health")
        pub = peer.session.declare_publisher(keys.INSTRUCTIONS.key(RIG),
                                             congestion_control=zenoh.CongestionControl.BLOCK)
        for value in (np.nan, 1e6, -1e6):
            ins = instructions_from_arrays(targets=np.full((24, 2, 2), value), joint_names=["nose", "left_hip"])
            pub.put(codec.encode(ins))
        # the service's Health may carry the rejection before the planner's counters catch up: wait
        # for a report that has both
        wait_for(lambda: peer.rejected() >= 3 and "instructions_refused" in peer.counters(), WAIT_S,
                 what="unusable instructions counted as rejected")
        counters = peer.counters()
        assert counters["instructions_refused"] == 3
        assert counters["state"] != "recording"  # --autostart never started on them
        pub.undeclare()
    finally:
        rc = stop(proc)
        peer.close()
    assert rc == 0, log.read_text()
