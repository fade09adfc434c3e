"""Another local process claims to be the vehicle (tests/mav_spoofer.py: system 1, component 1,
HEARTBEAT 'armed, POSCTL' and LOCAL_POSITION_NED 150 m away, 50 Hz, real MAVLink 2 bytes over
UDP on 127.0.0.1) while the backend flies `cinetransfer sim-vehicle` (a real process).

- udpin: the backend locks to the address the vehicle's first HEARTBEAT came from; the spoofer's
  datagrams are dropped and counted, nothing is sent back to it, the state stays the vehicle's.
- udpout + MAVLink 2 signing (the key `deploy certs` writes): unsigned and wrongly signed
  messages are dropped and counted; a backend without the key cannot command the signed vehicle.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.config import MavlinkConfig
from cinetransfer.services.autopilot_bridge.mavlink import MavlinkBackend, mavlink
from cinetransfer.shared import messages as M
from cinetransfer.shared.signing_key import write_signing_key

pytestmark = pytest.mark.timeout(180)
SPOOFER = Path(__file__).resolve().parents[1] / "mav_spoofer.py"


def free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def spawn(*args: str) -> subprocess.Popen:
    # a generous offboard failsafe: these tests are about spoofing, and a loaded machine can stall
    # the test's setpoint stream past the default 0.5 s (the vehicle then leaves OFFBOARD, rightly)
    return subprocess.Popen([sys.executable, "-m", "cinetransfer", "sim-vehicle", "--offboard-timeout", "5", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def stop(proc: subprocess.Popen) -> str:
    proc.send_signal(2)
    out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, out.decode(errors="replace")
    return out.decode(errors="replace")


def run_spoofer(addr: str, seconds: float, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(SPOOFER), addr, str(seconds), *extra], stdout=subprocess.PIPE)


def fly_while(backend: MavlinkBackend, proc: subprocess.Popen, target) -> list[M.VehicleState]:
    """Step the backend (holding at `target`) until the spoofer process ends; the states seen."""
    states = []
    sp = M.Setpoint(position_m=np.array(target, float), camera_ypr_rad=np.zeros(3))
    deadline = time.monotonic() + 60
    while proc.poll() is None and time.monotonic() < deadline:
        backend.apply(sp)
        backend.step(time.monotonic())
        states.append(backend.vehicle_state())
        time.sleep(0.01)
    return states


def drain(backend: MavlinkBackend, done) -> None:
    """Step the backend until `done(health)` (what is still in its socket gets read), 20 s at most."""
    deadline = time.monotonic() + 20
    while not done(backend.health_counters()) and time.monotonic() < deadline:
        backend.step(time.monotonic())
        time.sleep(0.01)


def engage_at(backend: MavlinkBackend, target) -> None:
    backend.command("engage", {})
    sp = M.Setpoint(position_m=np.array(target, float), camera_ypr_rad=np.zeros(3))
    deadline = time.monotonic() + 60
    while not (backend.engaged and np.linalg.norm(backend.vehicle_state().position_m - target) < 0.3):
        assert time.monotonic() < deadline, backend.health_counters()
        backend.apply(sp)
        backend.step(time.monotonic())
        time.sleep(0.01)


def test_udpin_locks_to_the_vehicles_address_and_ignores_a_local_spoofer():
    port = free_udp_port()
    backend = MavlinkBackend(MavlinkConfig(url=f"udpin:127.0.0.1:{port}", connect_timeout_s=30.0))
    veh = spawn("--mavlink", f"udpout:127.0.0.1:{port}", "--start", "0,0,3")
    try:
        backend.start()
        target = np.array([1.0, 2.0, 4.0])
        engage_at(backend, target)
        spoofer = run_spoofer(f"127.0.0.1:{port}", 3.0)
        states = fly_while(backend, spoofer, target)
        report = json.loads(spoofer.communicate(timeout=20)[0])
        drain(backend, lambda h: h["mav_foreign_address"] >= report["sent"])
        h = backend.health_counters()
    finally:
        backend.close()
        out = stop(veh)
    assert report["sent"] > 100 and report["received"] == 0  # nothing was sent to the spoofer
    # every spoofed datagram that reached the socket is dropped and counted (on a loaded machine the
    # kernel may drop a few from a full receive buffer before the backend reads them)
    assert 0.9 * report["sent"] <= h["mav_foreign_address"] <= report["sent"]
    assert h["mav_mode_lost"] == 0 and h["mav_owner"] == "engaged" and h["mav_mode"] == "OFFBOARD"
    worst = max(float(np.linalg.norm(s.position_m - target)) for s in states)
    assert worst < 0.3, f"a state moved {worst:.1f} m towards the spoofed position"
    assert "vehicle left" not in out


def test_signed_link_drops_unsigned_and_wrongly_signed_messages(tmp_path):
    (tmp_path / "good").mkdir()
    (tmp_path / "bad").mkdir()
    key, wrong = write_signing_key(tmp_path / "good"), write_signing_key(tmp_path / "bad")
    assert key.stat().st_mode & 0o777 == 0o600
    port = free_udp_port()
    veh = spawn("--mavlink", f"udpin:127.0.0.1:{port}", "--start", "0,0,3", "--signing-key", str(key))
    backend = MavlinkBackend(MavlinkConfig(url=f"udpout:127.0.0.1:{port}", connect_timeout_s=30.0,
                                           signing_key_file=str(key)))
    intruder = MavlinkBackend(MavlinkConfig(url=f"udpout:127.0.0.1:{port}", connect_timeout_s=30.0,
                                            source_system=246))
    try:
        backend.start()
        target = np.array([-1.0, 1.0, 4.0])
        engage_at(backend, target)
        # the spoofers write straight to the backend's own socket
        here = "127.0.0.1:%d" % backend.conn.port.getsockname()[1]
        unsigned, badly_signed = run_spoofer(here, 3.0), run_spoofer(here, 3.0, "--key", str(wrong))
        states = fly_while(backend, unsigned, target) + fly_while(backend, badly_signed, target)
        sent = sum(json.loads(p.communicate(timeout=20)[0])["sent"] for p in (unsigned, badly_signed))
        drain(backend, lambda h: h["mav_signature_rejected"] >= sent)
        h = backend.health_counters()
        # a peer without the key hears the vehicle (signatures are checked by receivers) but is not obeyed
        intruder.start()
        intruder.send_command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3, 0)
        assert intruder.wait_ack(mavlink.MAV_CMD_DO_SET_MODE, timeout_s=3.0) is None
        backend.step(time.monotonic())
        still = backend.vehicle_state()
    finally:
        intruder.close()
        backend.close()
        out = stop(veh)
    assert h["mav_signing"] and 0.9 * sent <= h["mav_signature_rejected"] <= sent  # (as above)
    assert h["mav_mode_lost"] == 0 and h["mav_owner"] == "engaged"
    assert max(float(np.linalg.norm(s.position_m - target)) for s in states) < 0.3
    # (the backend was not stepped while the intruder waited: the vehicle left OFFBOARD for its hold)
    assert still.mode != "POSCTL" and "-> POSCTL" not in out
    assert "MAVLink 2 signed" in out
