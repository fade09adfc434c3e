"""Bus benchmark: one-way latency of a small message and 1280x720 raw-frame throughput
between two processes over real Zenoh sessions on 127.0.0.1, through the project's codec.

    python benchmarks/bus.py [--samples 5000] [--frames 600]

Latency: the sender stamps CLOCK_MONOTONIC (shared by all processes on Linux) into the
message; the receiver decodes and subtracts. Paced at 1 kHz so that queueing does not count.
Throughput: the sender publishes encoded raw frames as fast as the link takes them
(congestion control BLOCK); the receiver decodes each (zero-copy view) and counts.
Goals: small-message p99 < 1 ms; 720p frames >= 200/s.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from cinetransfer.shared import codec, zenoh_config
from cinetransfer.shared import messages as M

try:
    from harness import stats, write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import stats, write_result


def receiver(port: int, kind: str, n: int, shm: bool) -> None:
    """Child process: listen, receive n messages, print the measurements as JSON."""
    opts = zenoh_config.ZenohOptions(listen=(f"tcp/127.0.0.1:{port}",), shared_memory=shm)
    lat_us: list[float] = []
    t_first = t_last = None
    count = 0
    done = threading.Event()

    def on(sample: zenoh.Sample) -> None:
        nonlocal t_first, t_last, count
        now = time.monotonic_ns()
        msg = codec.decode(sample.payload.to_bytes())
        if msg.stamp_ns == 0:  # warm-up marker
            return
        count += 1
        if kind == "small":
            lat_us.append((now - msg.stamp_ns) / 1e3)
        else:
            assert msg.image.shape == (720, 1280, 3)
            t_first = t_first or now
            t_last = now
        if count >= n:
            done.set()

    with zenoh_config.open_session(opts) as s:
        sub = s.declare_subscriber("bench/**", on)
        tok = s.liveliness().declare_token("bench/ready")
        done.wait(120)
        tok.undeclare()
        sub.undeclare()
    out = {"count": count}
    if kind == "small":
        out["lat_us"] = lat_us
    else:
        out["fps"] = (count - 1) / ((t_last - t_first) / 1e9) if count > 1 else 0.0
    print(json.dumps(out), flush=True)


def run(kind: str, n: int, shm: bool) -> dict:
    port = zenoh_config.free_tcp_port()
    child = subprocess.Popen([sys.executable, __file__, "--role", "rx", "--port", str(port), "--kind", kind,
                              "--n", str(n)] + (["--shm"] if shm else []), stdout=subprocess.PIPE, text=True)
    opts = zenoh_config.ZenohOptions(connect=(f"tcp/127.0.0.1:{port}",), shared_memory=shm)
    with zenoh_config.open_session(opts) as s:
        deadline = time.monotonic() + 30
        while not list(s.liveliness().get("bench/ready", timeout=0.5)) and time.monotonic() < deadline:
            time.sleep(0.05)
        pub = s.declare_publisher("bench/x", congestion_control=zenoh.CongestionControl.BLOCK, express=kind == "small")
        if kind == "small":
            msg = M.Command(action="start", args={"take": "bench", "t": 1.5})
            for _ in range(200):  # warm-up (stamp 0 is ignored by the receiver)
                pub.put(codec.encode(msg))
                time.sleep(0.0005)
            size = len(codec.encode(msg))
            for i in range(n):
                pub.put(codec.encode(M.Command(stamp_ns=time.monotonic_ns(), seq=i, action="start",
                                               args={"take": "bench", "t": 1.5})))
                time.sleep(0.001)
        else:
            img = np.random.default_rng(0).integers(0, 255, (720, 1280, 3), dtype=np.uint8)
            for _ in range(10):
                pub.put(codec.encode(M.Frame(image=img)))
            size = len(codec.encode(M.Frame(image=img)))
            for i in range(n):
                pub.put(codec.encode(M.Frame(stamp_ns=time.monotonic_ns(), index=i, image=img)))
        out = json.loads(child.stdout.readline())
        pub.undeclare()
    child.wait(30)
    out["size"] = size
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--role", default="main", choices=["main", "rx"])
    p.add_argument("--port", type=int)
    p.add_argument("--kind", default="small")
    p.add_argument("--n", type=int)
    p.add_argument("--shm", action="store_true")
    p.add_argument("--samples", type=int, default=5000)
    p.add_argument("--frames", type=int, default=600)
    p.add_argument("--out", default=str(Path(__file__).parent / "results" / "bus.json"))
    a = p.parse_args()
    if a.role == "rx":
        receiver(a.port, a.kind, a.n, a.shm)
        return 0
    results: dict = {}
    small = run("small", a.samples, shm=False)
    lat = stats(small["lat_us"])
    results["small"] = {"bytes": small["size"], "latency_us": lat}
    print(f"small message ({small['size']} B, peer-to-peer, encode+send+receive+decode), n={lat['n']}: "
          f"median {lat['median']:.0f} us, p95 {lat['p95']:.0f} us, p99 {lat['p99']:.0f} us, max {lat['max']:.0f} us "
          f"-> goal p99 < 1000 us: {'MET' if lat['p99'] < 1000 else 'MISSED'}")
    for shm in (False, True):
        r = run("frame", a.frames, shm=shm)
        name = "frames_shm" if shm else "frames_tcp"
        results[name] = {"bytes": r["size"], "n": r["count"], "fps": r["fps"]}
        print(f"1280x720 raw frames over {'shared memory' if shm else 'TCP loopback'} ({r['size'] / 1e6:.2f} MB each), "
              f"n={r['count']}: {r['fps']:.0f} frames/s -> goal >= 200/s: {'MET' if r['fps'] >= 200 else 'MISSED'}")
    print(f"wrote {write_result(a.out, results)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
