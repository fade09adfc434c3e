"""A camera frame lost between the bridge and the transfer stops the take at once, naming the
frame, and keeps what was recorded: the real recorder on a real Zenoh session, fed by a second
real session that publishes a take's frames in order (as the bridge does) and skips one."""
import numpy as np
import pytest
import zenoh

from cinetransfer.flight import _progress
from cinetransfer.job import TransferError, await_subscriber
from cinetransfer.recorder import Recorder, Take, Window
from cinetransfer.transfer import recorded_files
from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M
from cinetransfer.shared.zenoh_config import ZenohOptions

EPOCH = 10**18
FPS = 10.0
FIRST = 5  # the take's first camera frame index (after a pre-roll of 5 frames)
N = 8


def _frame(index: int) -> M.Frame:
    return M.Frame(stamp_ns=EPOCH + int(index / FPS * 1e9), seq=index, source="sim:test", index=index, fps=FPS,
                   image=np.full((48, 64, 3), 10 * index, np.uint8))


def _truth(index: int) -> M.GroundTruth:
    return M.GroundTruth(stamp_ns=EPOCH + int(index / FPS * 1e9), seq=index, frame_index=index,
                         joints_norm=np.zeros((17, 2), np.float32), joints_visible=np.zeros(17, bool),
                         region_present=np.ones(3, bool), region_in_focus=np.ones(3, bool),
                         region_focus_fraction=np.ones(3, np.float32))


@pytest.fixture
def rig(port, listener_opts, tmp_path):
    """(recorder armed for one take of N frames, publish(frame or truth)) on two real sessions."""
    rx = zenoh_config.open_session(listener_opts)
    tx = zenoh_config.open_session(ZenohOptions(mode="peer", connect=(f"tcp/127.0.0.1:{port}",)))
    rec = Recorder(rx, "gap", tmp_path, {"test": "frame gap"})
    rec.arm(Window(exact=True, n_slots=N, fps=FPS, epoch_ns=EPOCH, takes=(Take(FIRST, 0, N),)))
    # block, as the bridge's publishers do in simulation time: only the test's skip loses a frame
    pubs = {k: tx.declare_publisher(k.key("gap"), congestion_control=zenoh.CongestionControl.BLOCK)
            for k in (keys.FRAME, keys.SIM_TRUTH)}
    assert all(await_subscriber(p, 60.0) for p in pubs.values())

    def publish(msg):
        pubs[keys.FRAME if isinstance(msg, M.Frame) else keys.SIM_TRUTH].put(codec.encode(msg))

    yield rec, publish
    if not getattr(rec, "summaries", None):
        rec.close()
    for p in pubs.values():
        p.undeclare()
    tx.close()
    rx.close()


def _fly(publish, indices_with_frames, truth_indices):
    for i in range(FIRST, FIRST + N):
        if i in indices_with_frames:
            publish(_frame(i))
        if i in truth_indices:
            publish(_truth(i))


def test_a_skipped_frame_stops_the_take_at_once_naming_it(rig, tmp_path):
    rec, publish = rig
    lost = FIRST + 3
    _fly(publish, set(range(FIRST, FIRST + N)) - {lost}, set(range(FIRST, FIRST + N)))
    # no wall-clock limit decides: the stall timeout is far longer than any loaded machine needs
    with pytest.raises(TransferError) as e:
        _progress(rec, N, 3600.0, what="simulation")
    assert f"camera frame {lost} (slot 3 of {N}) was lost" in str(e.value)
    assert rec.lost == (3, lost)
    rec.summaries = rec.close()
    frames, _ = rec.summaries
    # what came before the gap is kept: 3 frames in output.mp4, a complete run.mcap with every message
    assert frames.written == 3 and frames.missing_slots == [3]  # (the frames after it arrived, held back)
    # (as meta.json "files" states it, read back from the disk)
    assert recorded_files(tmp_path, N) == {"output.mp4": f"partial: 3 of {N} frames", "run.mcap": "complete"}


def test_the_last_frame_lost_is_seen_by_its_truth(rig):
    rec, publish = rig
    last = FIRST + N - 1
    # the bridge publishes each frame before its truth; the last frame has no later frame to tell
    _fly(publish, set(range(FIRST, last)), set(range(FIRST, FIRST + N)))
    with pytest.raises(TransferError, match=f"camera frame {last} \\(slot {N - 1} of {N}\\) was lost"):
        _progress(rec, N, 3600.0, what="simulation")
    assert rec.frames_written == N - 1


def test_a_take_without_a_gap_is_not_stopped(rig):
    rec, publish = rig
    # frames and truths of the settle phase before the take (indices < FIRST) are no evidence of a loss
    for i in range(FIRST):
        publish(_truth(i))
    _fly(publish, set(range(FIRST, FIRST + N)), set(range(FIRST, FIRST + N)))
    _progress(rec, N, 3600.0, what="simulation")
    assert rec.lost is None and rec.frames_written == N


def test_a_recorder_whose_worker_hangs_fails_to_close_in_one_line(port, listener_opts, tmp_path, monkeypatch):
    import threading

    from cinetransfer import recorder

    entered, release = threading.Event(), threading.Event()

    def hang(_slot, _image):  # the worker is stuck in a frame's hand-over: it makes no progress at all
        entered.set()
        release.wait()

    rx = zenoh_config.open_session(listener_opts)
    rec = Recorder(rx, "hang", tmp_path, {"test": "hang"}, on_frame=hang)
    rec.arm(Window(exact=True, n_slots=N, fps=FPS, epoch_ns=EPOCH, takes=(Take(FIRST, 0, N),)))
    pub = rx.declare_publisher(keys.FRAME.key("hang"))
    try:
        pub.put(codec.encode(_frame(FIRST)))
        assert entered.wait(600.0)
        # only the stall limit is short here: the worker is blocked, it can never catch up
        monkeypatch.setattr(recorder, "CLOSE_STALL_S", 0.5)
        with pytest.raises(recorder.RecorderHang, match="finished no message for .* while closing"):
            rec.close()
    finally:
        release.set()
        rec._worker.join()
        for f in (rec._video, rec.log):  # (what close() leaves open when it gives up)
            if f is not None:
                f.close()
        pub.undeclare()
        rx.close()
