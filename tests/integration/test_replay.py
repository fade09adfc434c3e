"""Run logs and `cinetransfer replay` over a real Zenoh session."""
import threading

import pytest

from cinetransfer.shared import codec, zenoh_config
from cinetransfer.shared import messages as M
from cinetransfer.shared.recording import LogFormatError, LogWriter, read_log, read_meta
from conftest import connect_flags, spawn, wait_for


def test_log_round_trip_and_truncated_tail(tmp_path):
    path = tmp_path / "run.ctlog"
    msgs = [M.Command(seq=i, action="start") for i in range(5)]
    with LogWriter(path, {"description": "t"}) as w:
        for i, m in enumerate(msgs):
            w.write(f"ct/r/k{i}", codec.encode(m), t_ns=1000 + i)
    assert read_meta(path) == {"description": "t"}
    recs = list(read_log(path))
    assert [r[0] for r in recs] == [1000, 1001, 1002, 1003, 1004]
    assert [codec.decode(r[2]).seq for r in recs] == [0, 1, 2, 3, 4]
    # a crash mid-record keeps every complete record
    data = path.read_bytes()
    path.write_bytes(data[:-5])
    assert len(list(read_log(path))) == 4
    (tmp_path / "bad").write_bytes(b"nope")
    with pytest.raises(LogFormatError):
        list(read_log(tmp_path / "bad"))


def test_replay_republishes_under_new_rig(tmp_path, port, listener_opts):
    path = tmp_path / "run.ctlog"
    with LogWriter(path, {}) as w:
        for i in range(20):
            w.write("ct/live/vehicle/state", codec.encode(M.VehicleState(seq=i, backend="sim")), t_ns=i * 10_000_000)
    got: list[M.VehicleState] = []
    lock = threading.Lock()
    with zenoh_config.open_session(listener_opts) as s:
        def on(sample):
            with lock:
                got.append(codec.decode(sample.payload.to_bytes()))
        sub = s.declare_subscriber("ct/again/vehicle/state", on)
        proc = spawn("replay", str(path), "--rig", "again", "--speed", "4", *connect_flags(port))
        try:
            # the replay connects, then publishes; it may start before our subscription is known,
            # so wait for the tail of the stream rather than the head
            wait_for(lambda: any(m.seq == 19 for m in got), timeout=30, what="replayed messages")
        finally:
            assert proc.wait(30) == 0
        sub.undeclare()
    assert [m.seq for m in got] == sorted(m.seq for m in got)
