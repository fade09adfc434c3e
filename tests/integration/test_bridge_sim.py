"""The autopilot_bridge service with the built-in simulator backend, as a real process over real
Zenoh: it publishes VehicleState, SubjectState, rendered Frames (JPEG here, --jpeg) with their lens
state and GroundTruth; a setpoint stream moves the simulated vehicle; the watchdog holds it when
the stream stops; SIGINT gives exit code 0."""
from __future__ import annotations

import threading

import numpy as np
import pytest
import zenoh

from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M
from conftest import connect_flags, spawn, stop, wait_for

pytestmark = pytest.mark.timeout(120)
RIG = "bs"


class Collector:
    def __init__(self, opts):
        self.session = zenoh_config.open_session(opts)
        self.lock = threading.Lock()
        self.msgs: dict[str, list] = {}
        self.alive: set[str] = set()
        self._decl = [self.session.declare_subscriber(f"ct/{RIG}/**", self._on),
                      self.session.liveliness().declare_subscriber(keys.all_alive(RIG), self._on_alive, history=True)]
        self.sp_pub = self.session.declare_publisher(keys.SETPOINT.key(RIG))

    def _on(self, s):
        key = str(s.key_expr)
        if key.startswith(f"ct/{RIG}/health/"):
            return
        msg = codec.decode(s.payload.to_bytes())
        with self.lock:
            lst = self.msgs.setdefault(key, [])
            lst.append(msg)
            del lst[:-50]  # keep memory small (frames)

    def _on_alive(self, s):
        with self.lock:
            name = str(s.key_expr).split("/")[-1]
            (self.alive.add if s.kind == zenoh.SampleKind.PUT else self.alive.discard)(name)

    def last(self, topic):
        with self.lock:
            lst = self.msgs.get(topic.key(RIG), [])
            return lst[-1] if lst else None

    def count(self, topic):
        with self.lock:
            return len(self.msgs.get(topic.key(RIG), []))

    def close(self):
        for d in self._decl:
            d.undeclare()
        self.sp_pub.undeclare()
        self.session.close()


def test_sim_backend_publishes_state_subject_frames_truth_and_tracks_setpoints(listener_opts, port, tmp_path):
    bus = Collector(listener_opts)
    log = tmp_path / "bridge.log"
    br = spawn("autopilot_bridge", "--rig", RIG, "--backend", "sim", "--scene", "lawn_juggler_25d", "--jpeg", "80",
               "--health-period", "0.2", *connect_flags(port), log=log)
    stop_stream = threading.Event()
    try:
        wait_for(lambda: "autopilot_bridge" in bus.alive or br.poll() is not None, 60, what="bridge liveliness")
        assert br.poll() is None, log.read_text()
        wait_for(lambda: bus.last(keys.VEHICLE_STATE) is not None, 20, what="vehicle state")
        s0 = bus.last(keys.VEHICLE_STATE)
        assert s0.backend == "sim" and s0.holding  # no setpoint yet
        target = s0.position_m + np.array([0.0, 0.0, 0.5])
        sp = M.Setpoint(position_m=target, camera_ypr_rad=s0.camera_ypr_rad.copy(), lens=M.LensState())

        def stream():
            # stamped on the bridge's simulation clock, as the planner does: under load simulated
            # time falls behind the wall clock, and a wall-stamped setpoint is then "from the future"
            while not stop_stream.wait(0.04):
                tick = bus.last(keys.SIM_CLOCK)
                if tick is not None:
                    bus.sp_pub.put(codec.encode(M.Setpoint(**{**sp.__dict__, "stamp_ns": tick.stamp_ns})))

        th = threading.Thread(target=stream, daemon=True)
        th.start()
        wait_for(lambda: np.linalg.norm(bus.last(keys.VEHICLE_STATE).position_m - target) < 0.1
                 and not bus.last(keys.VEHICLE_STATE).holding, 30, what="simulated vehicle at the setpoint")
        # frames (JPEG on the wire) with their lens state, truth and subject
        wait_for(lambda: bus.count(keys.FRAME) >= 3 and bus.count(keys.SIM_TRUTH) >= 3, 30, what="frames + truth")
        f = bus.last(keys.FRAME)
        assert f.image.ndim == 3 and f.image.shape[2] == 3 and f.image.shape[0] > 100
        assert f.lens is not None and f.lens.focal_length_mm > 0 and f.source.startswith("sim:")
        subj = bus.last(keys.SUBJECT_STATE)
        assert subj is not None and subj.joints_m.shape == (17, 3)
        # the stream stops: the watchdog holds the simulated vehicle
        stop_stream.set()
        th.join(2)
        wait_for(lambda: bus.last(keys.VEHICLE_STATE).holding, 30, what="watchdog hold")
    finally:
        stop_stream.set()
        rc = stop(br)
        bus.close()
    assert rc == 0, log.read_text()[-3000:]
