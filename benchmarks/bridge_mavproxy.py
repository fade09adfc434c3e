"""Check the MAVLink side against an independent peer: MAVProxy (ArduPilot's ground station).

MAVProxy is NOT a project dependency (its declared requirements pull a non-headless OpenCV);
install it in a scratch virtual environment (docs/mavlink.md):

    python3 -m venv /tmp/mavproxy-venv
    /tmp/mavproxy-venv/bin/pip install --no-deps MAVProxy
    /tmp/mavproxy-venv/bin/pip install pymavlink pyserial
    .venv/bin/python benchmarks/bridge_mavproxy.py --mavproxy /tmp/mavproxy-venv/bin/mavproxy.py

Part A: MAVProxy is the ground station of `cinetransfer sim-vehicle`. Commands are typed into
        its console (stdin); its telemetry log (mav.tlog) is then decoded to list every
        COMMAND_LONG it sent and the COMMAND_ACK it got back.
Part B: MAVProxy is a router between sim-vehicle and the bridge's MavlinkBackend
        (vehicle <-udp-> MAVProxy --out <-udp-> backend): the backend engages (arm + OFFBOARD),
        flies a setpoint and sets zoom/focus/aperture through it; MAVProxy's console must show
        the mode change and the arming.
Writes benchmarks/results/bridge_mavproxy.json.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

try:
    from harness import free_udp_port, stats, write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import free_udp_port, stats, write_result

REPO = Path(__file__).resolve().parents[1]


def vehicle(port: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cinetransfer", "sim-vehicle", "--mavlink",
                             f"udpin:127.0.0.1:{port}", "--start", "0,0,3"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def stop(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        proc.send_signal(2)
    try:
        out, _ = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return (out or b"").decode(errors="replace")


class MavProxy:
    """MAVProxy with its console on a pipe; the output is collected in a thread."""

    def __init__(self, exe: str, *args: str, workdir: str) -> None:
        self.proc = subprocess.Popen([exe, *args, f"--state-basedir={workdir}", "--nowait"], cwd=workdir,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.lines: list[str] = []
        self.t = threading.Thread(target=self._read, daemon=True)
        self.t.start()

    def _read(self) -> None:
        for raw in self.proc.stdout:
            self.lines.append(raw.decode(errors="replace").rstrip())

    def send(self, cmd: str, wait_s: float = 1.0) -> None:
        self.proc.stdin.write((cmd + "\n").encode())
        self.proc.stdin.flush()
        time.sleep(wait_s)

    def wait_for(self, text: str, timeout: float = 15.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in ln for ln in self.lines):
                return True
            time.sleep(0.05)
        return False

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def decode_tlog(path: Path) -> list[dict]:
    from cinetransfer.services.autopilot_bridge.mavlink import RESULT_NAMES, mavutil

    out = []
    m = mavutil.mavlink_connection(str(path))
    while True:
        msg = m.recv_match(type=["COMMAND_LONG", "COMMAND_ACK"])
        if msg is None:
            break
        if msg.get_type() == "COMMAND_LONG":
            out.append({"sent": int(msg.command), "params": [msg.param1, msg.param2, msg.param3]})
        else:
            out.append({"ack": int(msg.command), "result": RESULT_NAMES.get(int(msg.result), str(msg.result))})
    return out


def part_a(exe: str, work: Path) -> dict:
    port = free_udp_port()
    veh = vehicle(port)
    mp = MavProxy(exe, f"--master=udpout:127.0.0.1:{port}", workdir=str(work))
    try:
        online = mp.wait_for("online system 1", 20)
        mp.send("long DO_SET_MODE 1 6 0")  # OFFBOARD without a setpoint stream: PX4 refuses
        mp.send("arm throttle")
        mp.send("long SET_CAMERA_ZOOM 3 85")
        mp.send("long SET_CAMERA_FOCUS 3 12.5")
        mp.send("long DO_DIGICAM_CONFIGURE 0 0 2.8")
        mp.send("long SET_CAMERA_ZOOM 3 5000")  # outside the lens range: denied
        mp.send("status CAMERA_FOV_STATUS", 2.0)  # zoom has moved by now
        mp.send("status LOCAL_POSITION_NED")
        mp.send("status GIMBAL_DEVICE_ATTITUDE_STATUS")
    finally:
        mp.close()
        vlog = stop(veh)
    status = [ln for ln in mp.lines if "CAMERA_FOV_STATUS {" in ln or "LOCAL_POSITION_NED {" in ln
              or "GIMBAL_DEVICE_ATTITUDE_STATUS {" in ln or "HEARTBEAT {" in ln]
    return {"online": online, "console": [ln for ln in mp.lines if ln.strip()][-40:], "status_lines": status,
            "tlog_commands": decode_tlog(work / "mav.tlog"), "vehicle_log": vlog.splitlines()[-10:]}


def part_b(exe: str, work: Path) -> dict:
    from cinetransfer.services.autopilot_bridge.config import MavlinkConfig
    from cinetransfer.services.autopilot_bridge.mavlink import MavlinkBackend, mavlink
    from cinetransfer.shared import messages as M

    vport, bport = free_udp_port(), free_udp_port()
    veh = vehicle(vport)
    mp = MavProxy(exe, f"--master=udpout:127.0.0.1:{vport}", f"--out=udpout:127.0.0.1:{bport}", workdir=str(work))
    result: dict = {}
    try:
        result["mavproxy_online"] = mp.wait_for("online system 1", 20)
        be = MavlinkBackend(MavlinkConfig(url=f"udpin:127.0.0.1:{bport}", connect_timeout_s=20))
        be.start()
        be.command("engage", {})
        target = np.array([2.0, 1.0, 4.0])
        sp = M.Setpoint(position_m=target, camera_ypr_rad=np.array([0.5, -0.3, 0.0]),
                        lens=M.LensState(focal_length_mm=85.0, focus_distance_m=12.0, f_number=2.8))
        t0 = time.monotonic()
        st = be.vehicle_state()
        while time.monotonic() - t0 < 30:
            be.apply(sp)
            be.step(time.monotonic())
            st = be.vehicle_state()
            if np.linalg.norm(st.position_m - target) < 0.1 and abs(st.lens.focal_length_mm - 85) < 0.1:
                break
            time.sleep(0.02)
        result["reached_s"] = round(time.monotonic() - t0, 2)
        result["state"] = {"mode": st.mode, "armed": st.armed, "position_m": st.position_m.round(3).tolist(),
                           "camera_ypr_rad": st.camera_ypr_rad.round(3).tolist(),
                           "lens": [st.lens.focal_length_mm, st.lens.focus_distance_m, st.lens.f_number]}
        rtts = []
        for _ in range(20):
            be.send_command(mavlink.MAV_CMD_SET_CAMERA_FOCUS, mavlink.FOCUS_TYPE_METERS, 12.0)
            ack = be.wait_ack(mavlink.MAV_CMD_SET_CAMERA_FOCUS)
            if ack is not None:
                rtts.append(ack.rtt_ms)
        result["ack_rtt_ms_via_mavproxy"] = stats(rtts) if rtts else None
        result["backend_counters"] = be.health_counters()
        result["mavproxy_saw_offboard"] = mp.wait_for("OFFBOARD", 2)
        result["mavproxy_saw_armed"] = mp.wait_for("ARMED", 1)
        be.close()
    finally:
        mp.close()
        vlog = stop(veh)
    result["console"] = [ln for ln in mp.lines if ln.strip()][-25:]
    result["vehicle_log"] = vlog.splitlines()[-10:]
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mavproxy", default="/tmp/mavproxy-venv/bin/mavproxy.py")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "bridge_mavproxy.json"))
    args = ap.parse_args()
    if not Path(args.mavproxy).exists():
        print(f"MAVProxy not found at {args.mavproxy}; see the module docstring", file=sys.stderr)
        return 2
    ver = subprocess.run([str(Path(args.mavproxy).parent / "pip"), "show", "MAVProxy"], capture_output=True,
                         text=True).stdout
    with tempfile.TemporaryDirectory() as a, tempfile.TemporaryDirectory() as b:
        res = {"mavproxy": next((ln for ln in ver.splitlines() if ln.startswith("Version")), "?"),
               "part_a_gcs": part_a(args.mavproxy, Path(a)),
               "part_b_router": part_b(args.mavproxy, Path(b))}
    print(json.dumps(res, indent=1, default=str))
    print(f"wrote {write_result(args.out, res)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
