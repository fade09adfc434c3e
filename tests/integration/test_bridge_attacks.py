"""The hostile-input attacks replayed at a real autopilot_bridge process over real Zenoh, flying a real
`cinetransfer sim-vehicle` over MAVLink/UDP: each one now fails safely, visibly (Health,
VehicleState) and without ending the bridge. Synchronised on received samples and on the
vehicle's own log, never on sleeps."""
from __future__ import annotations

import time

import numpy as np
import pytest

from attacks import deep_args_command
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M
from conftest import cpu_seconds, wait_for
from test_bridge_service import Bus, Streamer, logs, start_pair, stop_pair

pytestmark = pytest.mark.timeout(150)
#: how long a wait for a service's answer may take: a ceiling for a hang, not a measure of speed (a
#: service process at load 50 on 2 cores gets a few % of a core; the wait ends as soon as it answers)
WAIT_S = 30.0


@pytest.fixture
def bus(listener_opts):
    b = Bus(listener_opts)
    yield b
    b.close()


def engaged(bus, br, tmp_path):
    wait_for(lambda: "autopilot_bridge" in bus.alive or br.poll() is not None, what="bridge liveliness",
             progress=lambda: cpu_seconds(br))
    assert br.poll() is None, logs(tmp_path)
    wait_for(lambda: (s := bus.state()) is not None and s.armed and s.mode == "OFFBOARD", 20, what="engaged")


def n_states(bus) -> int:
    with bus.lock:
        return len(bus.states)


def command(bus, action, **args):
    bus.cmd_pub.put(codec.encode(M.Command(stamp_ns=time.time_ns(), action=action, args=args)))


def test_deep_args_command_and_bad_takeoff_arguments_are_rejected_and_the_bridge_flies_on(bus, port, tmp_path):
    veh, br = start_pair(tmp_path, port)
    try:
        engaged(bus, br, tmp_path)
        wait_for(lambda: bus.health is not None, WAIT_S, what="first Health")
        rejected0 = bus.health.rejected
        # 1. the 576-byte Command, three times (it used to end the loop with RecursionError)
        for _ in range(3):
            bus.cmd_pub.put(deep_args_command())
        wait_for(lambda: bus.health.rejected >= rejected0 + 3, WAIT_S, what="deep Commands counted as rejected")
        assert "deeper than" in bus.health.last_error
        seen = n_states(bus)
        wait_for(lambda: n_states(bus) >= seen + 20, WAIT_S, what="vehicle state still flowing")
        assert br.poll() is None, logs(tmp_path)
        # 2. take-off arguments: out of the altitude band (climbed past 73 m) and not a number
        #    (ValueError ended the bridge); then a good one, which the vehicle logs when it gets it
        command(bus, "takeoff", altitude_m=10000.0)
        command(bus, "takeoff", altitude_m="abc")
        command(bus, "takeoff", altitude_m=4.0)
        vlog = tmp_path / "vehicle.log"
        wait_for(lambda: "take-off to 4.0 m" in vlog.read_text(), WAIT_S, what="the good take-off reached the vehicle")
        assert "take-off to 10000" not in vlog.read_text()  # commands are handled in order: never sent
        # one Health report with both counts (a report can be taken between the two increments)
        wait_for(lambda: (h := bus.health).rejected >= rejected0 + 5 and h.counters.get("commands_bad_args", 0) >= 2,
                 WAIT_S, what="bad arguments counted as rejected")
        assert bus.counters()["commands_bad_args"] == 2
        assert br.poll() is None, logs(tmp_path)
        assert max(s.position_m[2] for s in bus.states_since(0)) < 40.0
    finally:
        stop_pair(veh, br, tmp_path)


def test_a_future_stamped_setpoint_no_longer_locks_out_the_planner(bus, port, tmp_path):
    veh, br = start_pair(tmp_path, port)
    streamer = Streamer(bus)
    try:
        engaged(bus, br, tmp_path)
        wait_for(lambda: bus.health is not None, WAIT_S, what="first Health")
        rejected0 = bus.health.rejected
        forged = M.Setpoint(stamp_ns=time.time_ns() + 3600 * 10**9, position_m=np.array([9.0, 9.0, 9.0]))
        bus.sp_pub.put(codec.encode(forged))
        wait_for(lambda: (h := bus.health).rejected >= rejected0 + 1 and h.counters.get("sp_future_stamp", 0) >= 1,
                 WAIT_S, what="future stamp counted as rejected")
        assert bus.counters()["sp_future_stamp"] == 1
        target = np.array([2.0, 1.0, 4.0])
        streamer.pos = target  # the honest planner, stamping with its own clock
        wait_for(lambda: np.linalg.norm(bus.state().position_m - target) < 0.2 and not bus.state().holding, 30,
                 what="honest setpoints tracked")
        assert bus.counters()["sp_out_of_order"] == 0
    finally:
        streamer.stop()
        stop_pair(veh, br, tmp_path)


def test_a_vehicle_outside_the_envelope_is_flagged_and_flown_back_inside(bus, port, tmp_path):
    """The vehicle starts 8 m from home with a 5 m fence and above the 6 m ceiling, while a
    planner keeps asking for a point far outside: VehicleState and Health show the breach, the
    bridge flies it back inside, and the flag clears."""
    veh, br = start_pair(tmp_path, port, "--geofence-radius", "5", "--alt-max", "6", start="8,0,7")
    streamer = Streamer(bus)
    try:
        wait_for(lambda: "autopilot_bridge" in bus.alive or br.poll() is not None, what="bridge liveliness",
                 progress=lambda: cpu_seconds(br))
        wait_for(lambda: (s := bus.state()) is not None and s.envelope_breach, 20, what="breach flag in VehicleState")
        wait_for(lambda: bus.counters().get("envelope_breach") is True and not bus.health.valid, WAIT_S,
                 what="breach flag in Health, Health invalid")
        assert bus.counters()["breaches"] >= 1
        streamer.pos = np.array([50.0, 0.0, 20.0])
        wait_for(lambda: not bus.state().envelope_breach, 30, what="back inside")
        s = bus.state()
        assert np.hypot(*s.position_m[:2]) <= 5.0 and s.position_m[2] <= 6.0
        wait_for(lambda: bus.health.valid and bus.counters().get("envelope_breach") is False, WAIT_S,
                 what="Health valid again")
        t_back = time.monotonic()
        wait_for(lambda: len(bus.states_since(t_back)) >= 25, WAIT_S, what="more states inside")
        assert max(np.hypot(*m.position_m[:2]) for m in bus.states_since(t_back)) <= 5.0 + 0.25
    finally:
        streamer.stop()
        stop_pair(veh, br, tmp_path)
