"""Bridge figures: safety-layer compute time, MAVLink command round trip over UDP loopback,
setpoint stream rate and regularity at the vehicle, link-loss detection time.

    .venv/bin/python benchmarks/bridge.py [--samples 200]

- safety: BridgeCore.on_setpoint + tick per setpoint (in-process), microseconds;
- command RTT: MavlinkBackend -> `cinetransfer sim-vehicle` (its own process) over UDP on
  127.0.0.1, MAV_CMD_SET_CAMERA_FOCUS -> COMMAND_ACK, milliseconds;
- stream: SET_POSITION_TARGET_LOCAL_NED as received by the vehicle while the backend is driven
  at the service's 50 Hz loop (rate, interval p95/max; PX4 needs > 2 Hz);
- link loss: the vehicle process is frozen (SIGSTOP); time until `connected` goes False
  (link_timeout_s = 1.5 s by default, so ~1.5 s is the expected figure).
Writes benchmarks/results/bridge.json (commit, machine, config).
"""
from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from cinetransfer.services.autopilot_bridge.config import MavlinkConfig, SafetyConfig
from cinetransfer.services.autopilot_bridge.core import BridgeCore
from cinetransfer.services.autopilot_bridge.mavlink import MavlinkBackend, mavlink
from cinetransfer.services.autopilot_bridge.sim_vehicle import SimVehicle
from cinetransfer.shared import messages as M

try:
    from harness import free_udp_port, stats, write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import free_udp_port, stats, write_result

REPO = Path(__file__).resolve().parents[1]


def bench_safety(n: int) -> dict:
    core = BridgeCore(SafetyConfig())
    vs = M.VehicleState(position_m=np.array([0.0, 0.0, 5.0]))
    subj = M.SubjectState(joints_m=np.random.default_rng(0).normal(size=(17, 3)) + [5.0, 0.0, 1.0])
    out = []
    for k in range(n + 50):
        sp = M.Setpoint(stamp_ns=k + 1, position_m=np.array([1.0 + 0.01 * k, 2.0, 5.0]),
                        velocity_mps=np.array([0.5, 0.0, 0.0]), lens=M.LensState(focal_length_mm=50.0))
        t = time.perf_counter()
        core.on_setpoint(sp, k * 0.02, clock_ns=sp.stamp_ns, vehicle=vs, subject=subj)
        core.tick(k * 0.02 + 0.01, vehicle=vs)
        if k >= 50:
            out.append((time.perf_counter() - t) * 1e6)
    return {"us_per_setpoint": stats(out)}


def bench_rtt(n: int) -> dict:
    port = free_udp_port()
    proc = subprocess.Popen([sys.executable, "-m", "cinetransfer", "sim-vehicle", "--mavlink",
                             f"udpin:127.0.0.1:{port}", "--start", "0,0,3"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    be = MavlinkBackend(MavlinkConfig(url=f"udpout:127.0.0.1:{port}", connect_timeout_s=20))
    try:
        be.start()
        rtts = []
        for k in range(n + 10):
            time.sleep(0.005)
            be._poll(time.monotonic())  # drain: no stale ack may match
            be.send_command(mavlink.MAV_CMD_SET_CAMERA_FOCUS, mavlink.FOCUS_TYPE_METERS, 5.0 + k % 10)
            ack = be.wait_ack(mavlink.MAV_CMD_SET_CAMERA_FOCUS, 2.0)
            if ack is None or not ack.accepted:
                raise RuntimeError(f"no/failed ack: {ack}")
            if k >= 10:
                rtts.append(ack.rtt_ms)
        # link loss detection: freeze the vehicle process
        for _ in range(20):
            be.step(time.monotonic())
            time.sleep(0.02)
        proc.send_signal(signal.SIGSTOP)
        t0 = time.monotonic()
        while be.connected and time.monotonic() - t0 < 10:
            be.step(time.monotonic())
            time.sleep(0.005)
        detect = time.monotonic() - t0
        proc.send_signal(signal.SIGCONT)
        t1 = time.monotonic()
        while not be.connected and time.monotonic() - t1 < 10:
            be.step(time.monotonic())
            time.sleep(0.005)
        back = time.monotonic() - t1
    finally:
        be.close()
        proc.send_signal(signal.SIGCONT)
        proc.send_signal(signal.SIGINT)
        proc.wait(10)
    return {"command_rtt_ms": stats(rtts), "link_loss_detect_s": detect, "link_back_s": back,
            "link_timeout_s": be.cfg.link_timeout_s}


def bench_stream(duration_s: float) -> dict:
    port = free_udp_port()
    veh = SimVehicle(f"udpin:127.0.0.1:{port}", start_enu=(0.0, 0.0, 3.0))
    stop = threading.Event()
    th = threading.Thread(target=veh.run, args=(stop,), daemon=True)
    th.start()
    be = MavlinkBackend(MavlinkConfig(url=f"udpout:127.0.0.1:{port}", connect_timeout_s=20))
    try:
        be.start()
        sp = M.Setpoint(position_m=np.array([1.0, 1.0, 4.0]), lens=M.LensState())
        period, nxt = 1.0 / 50.0, time.monotonic()
        t_end = nxt + duration_s
        while time.monotonic() < t_end:  # the service loop: apply + step at 50 Hz
            be.apply(sp)
            be.step(time.monotonic())
            nxt += period
            time.sleep(max(0.0, nxt - time.monotonic()))
        times = np.array(veh.sp_times)
    finally:
        be.close()
        stop.set()
        th.join(2)
        veh.close()
    times = times[times > times[-1] - duration_s + 0.5]
    gaps = np.diff(times) * 1e3
    return {"configured_hz": be.cfg.setpoint_rate_hz, "received_hz": float((len(times) - 1) / (times[-1] - times[0])),
            "interval_ms": stats(gaps)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--stream-seconds", type=float, default=10.0)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "bridge.json"))
    args = ap.parse_args()
    res = {"safety": bench_safety(args.samples * 10), "mavlink_udp": bench_rtt(args.samples),
           "setpoint_stream": bench_stream(args.stream_seconds)}
    print(json.dumps(res, indent=1))
    print(f"wrote {write_result(args.out, res)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
