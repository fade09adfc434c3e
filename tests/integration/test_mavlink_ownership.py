"""Mode ownership against `cinetransfer sim-vehicle` (a real process, real UDP on 127.0.0.1): after
a land, or a mode change by the pilot, the bridge never switches the vehicle back to OFFBOARD on
its own, however long it keeps streaming (mav_ownership.py)."""
from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge import enu_ned as F
from cinetransfer.services.autopilot_bridge.config import MavlinkConfig
from cinetransfer.services.autopilot_bridge.mavlink import MavlinkBackend, connect, mavlink
from cinetransfer.shared import messages as M

pytestmark = pytest.mark.timeout(180)


def free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def fly(backend: MavlinkBackend, target, until, timeout_s: float) -> None:
    sp = M.Setpoint(position_m=np.array(target, float), camera_ypr_rad=np.zeros(3))
    deadline = time.monotonic() + timeout_s
    while not until():
        assert time.monotonic() < deadline, f"timed out: {backend.health_counters()}"
        backend.apply(sp)
        backend.step(time.monotonic())
        time.sleep(0.01)


def fly_for(backend: MavlinkBackend, target, seconds: float) -> list[str]:
    """Keep streaming `target` for `seconds`; the vehicle modes seen."""
    t_end = time.monotonic() + seconds
    modes = []

    def done() -> bool:
        modes.append(backend.vehicle_state().mode)
        return time.monotonic() > t_end

    fly(backend, target, done, seconds + 30)
    return modes


def commands_sent_from_now(backend: MavlinkBackend) -> list[int]:
    """The COMMAND_LONG ids the backend puts on the wire from now on (each still sent)."""
    sent: list[int] = []
    send = backend._send_command_long

    def recorded(command, params, component, confirmation):  # noqa: ANN001, ANN202
        sent.append(int(command))
        return send(command, params, component, confirmation)

    backend._send_command_long = backend.retries.send_raw = recorded  # direct sends, and resent ones
    return sent


@pytest.fixture
def vehicle_and_backend():
    port = free_udp_port()
    proc = subprocess.Popen([sys.executable, "-m", "cinetransfer", "sim-vehicle", "--mavlink",
                             f"udpin:127.0.0.1:{port}", "--start", "0,0,3"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    backend = MavlinkBackend(MavlinkConfig(url=f"udpout:127.0.0.1:{port}", connect_timeout_s=30.0))
    out: list[str] = []
    try:
        backend.start()
        backend.command("engage", {})
        fly(backend, (1.0, 1.0, 4.0), lambda: backend.engaged, 30)
        yield port, backend, out
    finally:
        backend.close()
        proc.send_signal(2)
        out.append(proc.communicate(timeout=20)[0].decode(errors="replace"))
        assert proc.returncode == 0, out[-1]


def test_after_a_land_the_vehicle_is_never_switched_back_to_offboard(vehicle_and_backend):
    _, backend, out = vehicle_and_backend
    sent = backend.health_counters()["mav_commands_sent"]
    after_land = commands_sent_from_now(backend)
    where = backend.vehicle_state().position_m[:2].copy()
    assert backend.command("land", {})
    fly(backend, (3.0, 3.0, 6.0), lambda: backend.health_counters()["mav_land"] == "landing", 30)
    assert backend.acks[mavlink.MAV_CMD_NAV_LAND].accepted  # the sim-vehicle takes NAV_LAND
    # the plan goes on asking for (3, 3, 6): the bridge holds, the vehicle lands and disarms
    modes = fly_for(backend, (3.0, 3.0, 6.0), 3.0)
    fly(backend, (3.0, 3.0, 6.0), lambda: not backend.vehicle_state().armed, 60)
    h = backend.health_counters()
    assert set(modes) == {"LAND"} and h["mav_owner"] == "landing"
    # the NAV_LAND (resent while its ack is late: a loaded machine), nothing else after it
    assert after_land and set(after_land) == {mavlink.MAV_CMD_NAV_LAND}
    assert h["mav_commands_sent"] == sent + len(after_land)
    assert backend.vehicle_state().position_m[2] < 0.1
    assert np.linalg.norm(backend.vehicle_state().position_m[:2] - where) < 0.3  # landed where it was


def test_after_the_pilot_takes_over_the_bridge_keeps_its_hands_off(vehicle_and_backend):
    port, backend, out = vehicle_and_backend
    pilot = connect(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        posctl = F.px4_custom_mode(F.PX4_MAIN["POSCTL"])
        deadline = time.monotonic() + 30
        while backend.vehicle_state().mode != "POSCTL":  # a ground station's SET_MODE, resent until seen
            assert time.monotonic() < deadline
            pilot.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            pilot.mav.set_mode_send(1, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, posctl)
            fly_for(backend, (2.0, 2.0, 4.0), 0.3)
        modes = fly_for(backend, (2.0, 2.0, 4.0), 4.0)
    finally:
        pilot.close()
    h = backend.health_counters()
    assert set(modes) == {"POSCTL"} and h["mav_owner"] == "released" and h["mav_mode_lost"] == 1
    assert "vehicle left OFFBOARD" in h["mav_owner_reason"]
