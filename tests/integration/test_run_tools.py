"""The recording tools: `record` a live rig over a real Zenoh session with the transfer's writer,
then `info`, `echo` and a `replay --start/--end` window on a recording whose log times are known,
each read back with the `mcap` library or our reader."""
import json
import subprocess
import sys
import threading
import time

import numpy as np

from cinetransfer.shared import codec, zenoh_config
from cinetransfer.shared import messages as M
from cinetransfer.runlog import RunReader, RunWriter
from conftest import connect_flags, spawn, stop, wait_for

S = 1_000_000_000


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cinetransfer", *args], capture_output=True, text=True, timeout=120)


def _state(i: int) -> M.VehicleState:
    return M.VehicleState(stamp_ns=i, seq=i, position_m=np.array([float(i), 2.0, 3.0]), backend="sim")


def _timed_run(path):
    """Vehicle states every 0.5 s from t=0 to t=6 s (seq = half-seconds), a take from 1 s to 5 s."""
    with RunWriter(path, {"started": "test"}) as w:
        for i in range(13):
            w.write("ct/t/vehicle/state", codec.encode(_state(i)), t_ns=i * S // 2)
        w.write("ct/t/planner/command", codec.encode(M.Command(action="start", args={
            "start_frame": 0, "end_frame": 48, "preroll_s": 2.0})), t_ns=1 * S)
        w.write("ct/t/planner/command", codec.encode(M.Command(action="stop")), t_ns=5 * S)


def test_info_lists_channels_rates_duration_and_takes(tmp_path):
    _timed_run(tmp_path / "run.mcap")
    r = _cli("info", str(tmp_path / "run.mcap"), "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    state = s["channels"]["ct/t/vehicle/state"]
    assert state == {"schema": "cinetransfer.VehicleState", "encoding": "json", "count": 13, "rate_hz": 2.0}
    # a VehicleState also gives two FrameTransforms (tf/drone, tf/camera)
    assert s["channels"]["ct/t/tf/drone"]["schema"] == "foxglove.FrameTransform"
    assert s["duration_s"] == 6.0 and s["complete"] and s["messages"] == 13 * 3 + 2
    assert s["takes"] == [{"start_s": 1.0, "end_s": 5.0, "first_frame": 0, "end_frame": 48, "preroll_s": 2.0}]
    table = _cli("info", str(tmp_path / "run.mcap")).stdout
    assert "take 1: 1.00 s to 5.00 s, instruction frames 0..48" in table and "ct/t/vehicle/state" in table


def test_echo_prints_a_window_of_one_channel_as_json_lines(tmp_path):
    _timed_run(tmp_path / "run.mcap")
    r = _cli("echo", str(tmp_path / "run.mcap"), "ct/t/vehicle/state", "--start", "2", "--end", "3")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [(x["t"], x["msg"]["seq"]) for x in lines] == [(2.0, 4), (2.5, 5), (3.0, 6)]
    assert lines[0]["msg"]["position_m"] == [4.0, 2.0, 3.0]
    # a key expression, and a protobuf channel shown as JSON
    tf_lines = _cli("echo", str(tmp_path / "run.mcap"), "ct/*/tf/*", "--limit", "2").stdout.splitlines()
    tf = [json.loads(x) for x in tf_lines]
    assert [x["key"] for x in tf] == ["ct/t/tf/drone", "ct/t/tf/camera"]
    assert tf[0]["msg"]["translation"] == {"y": 2.0, "z": 3.0}  # protobuf JSON leaves zeros out
    bad = _cli("echo", str(tmp_path / "run.mcap"), "ct/none/**")
    assert bad.returncode == 2 and "no channel" in bad.stderr and "Traceback" not in bad.stderr


def test_replay_plays_only_the_window(tmp_path, port, listener_opts):
    _timed_run(tmp_path / "run.mcap")
    got: list[int] = []
    at: list[float] = []
    lock = threading.Lock()
    with zenoh_config.open_session(listener_opts) as s:
        def on(sample):
            with lock:
                got.append(codec.decode(sample.payload.to_bytes()).seq)
                at.append(time.monotonic())
        sub = s.declare_subscriber("ct/w/vehicle/state", on)
        proc = spawn("replay", str(tmp_path / "run.mcap"), "--rig", "w", "--start", "2", "--end", "3", "--loop",
                     *connect_flags(port), log=tmp_path / "replay.log")
        try:
            # looping, every message of the window comes round again, whenever the subscription got known
            wait_for(lambda: _one_whole_pass(got) >= 0, timeout=90, interval=0.1, what="one whole pass of the window")
        finally:
            rc = stop(proc)
            sub.undeclare()
    assert rc == 0, (tmp_path / "replay.log").read_text()[-2000:]
    assert set(got) == {4, 5, 6}, got
    # at its recorded pace: the window spans 1 s from its own first message (a loaded machine only
    # stretches it), however long reading up to the window took
    i = _one_whole_pass(got)
    assert at[i + 2] - at[i] >= 0.9, at[i:i + 3]


def _one_whole_pass(seqs: list[int]) -> int:
    """Index where 4, 5, 6 arrive in a row, or -1."""
    return next((i for i in range(len(seqs) - 2) if seqs[i:i + 3] == [4, 5, 6]), -1)


def test_record_writes_a_live_rig_with_the_transfers_writer(tmp_path, port, listener_opts):
    out = tmp_path / "live.mcap"
    done = threading.Event()
    with zenoh_config.open_session(listener_opts) as s:
        def publish():
            pub = s.declare_publisher("ct/rec/vehicle/state")
            i = 0
            while not done.wait(0.02):
                pub.put(codec.encode(_state(i)))
                i += 1
            pub.undeclare()
        t = threading.Thread(target=publish, daemon=True)
        t.start()
        proc = spawn("record", "ct/rec/**", "-o", str(out), "--count", "30", *connect_flags(port),
                     log=tmp_path / "record.log")
        try:
            rc = proc.wait(120)
        finally:
            done.set()
            t.join()
            stop(proc)
    log = (tmp_path / "record.log").read_text()
    assert rc == 0, log[-2000:]
    assert "recorded" in log
    run = RunReader(out)
    assert run.info.complete and run.meta["keyexpr"] == "ct/rec/**"
    assert run.info.channels["ct/rec/vehicle/state"]["schema"] == "cinetransfer.VehicleState"
    states = [codec.decode(p) for _, k, p in run.messages() if k == "ct/rec/vehicle/state"]
    assert len(states) >= 30
    seqs = [m.seq for m in states]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # nothing lost in between
    assert all(float(m.position_m[0]) == m.seq for m in states)
    # and the mcap library reads it too
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        topics = {ch.topic for _, ch, _ in make_reader(f).iter_messages()}
    assert {"ct/rec/vehicle/state", "ct/rec/tf/drone"} <= topics
