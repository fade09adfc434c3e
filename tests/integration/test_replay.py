"""Recordings (run.mcap) and `cinetransfer replay` over a real Zenoh session."""
import threading

import numpy as np

from cinetransfer.shared import codec, zenoh_config
from cinetransfer.shared import messages as M
from cinetransfer.runlog import RunWriter
from conftest import connect_flags, spawn, wait_for


def test_replay_republishes_under_new_rig(tmp_path, port, listener_opts):
    # given a recording of vehicle states and camera frames on rig 'live'
    path = tmp_path / "run.mcap"
    img = np.zeros((48, 64, 3), np.uint8)
    img[10:30, 20:40] = (0, 200, 255)
    with RunWriter(path, {"description": "t"}) as w:
        for i in range(20):
            w.write("ct/live/vehicle/state", codec.encode(M.VehicleState(seq=i, backend="sim")), t_ns=i * 10_000_000)
            w.write("ct/live/camera/frame", codec.encode(M.Frame(stamp_ns=i, seq=i, index=i, image=img)),
                    t_ns=i * 10_000_000 + 1)
    got: list = []
    lock = threading.Lock()
    with zenoh_config.open_session(listener_opts) as s:
        def on(sample):
            with lock:
                got.append(codec.decode(sample.payload.to_bytes()))
        subs = [s.declare_subscriber(k, on) for k in ("ct/again/vehicle/state", "ct/again/camera/frame")]
        # when it is replayed under rig 'again', four times as fast
        proc = spawn("replay", str(path), "--rig", "again", "--speed", "4", *connect_flags(port))
        try:
            # the replay connects, then publishes; it may start before our subscription is known,
            # so wait for the tail of the stream rather than the head
            wait_for(lambda: any(isinstance(m, M.Frame) and m.seq == 19 for m in got), timeout=30,
                     what="replayed messages")
        finally:
            assert proc.wait(30) == 0
        for sub in subs:
            sub.undeclare()
    # then the messages come back in order, as our own messages, frames with their image (JPEG-close)
    states = [m for m in got if isinstance(m, M.VehicleState)]
    frames = [m for m in got if isinstance(m, M.Frame)]
    assert [m.seq for m in states] == sorted(m.seq for m in states) and states[-1].seq == 19
    assert frames[-1].index == 19 and frames[-1].image.shape == img.shape
    assert float(np.abs(frames[-1].image.astype(int) - img).mean()) < 3.0


def test_replay_refuses_bad_input_with_a_clear_error(tmp_path):
    import subprocess
    import sys

    (tmp_path / "foreign.txt").write_bytes(b"CTLOG1\n{}\n")
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "replay", str(tmp_path / "foreign.txt"),
                        "--connect", "tcp/127.0.0.1:9"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "not an MCAP file" in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "replay", str(tmp_path / "missing.mcap")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "no such file" in r.stderr, r.stderr
