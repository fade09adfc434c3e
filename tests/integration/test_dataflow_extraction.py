"""Style extraction on the dataflow: the source, detector and smoother nodes as real processes over
Zenoh give the same style as the in-process `cinetransfer extract`, and no source frame is lost."""
import queue
import subprocess
import sys

import numpy as np
import pytest

from cinetransfer.shared.instructions import load_style
from cinetransfer.shared import codec, keys
from cinetransfer.shared import messages as M
from cinetransfer.shared.zenoh_config import open_session
from conftest import connect_flags, spawn, stop, wait_for

RIG = "flow"
N = 30


@pytest.mark.slow
def test_source_detector_smoother_give_the_extract_style(data, port, listener_opts, tmp_path):
    clip = data / "sam2_juggle_1280x720.mp4"
    got: queue.SimpleQueue = queue.SimpleQueue()
    alive: set[str] = set()
    procs = []
    with open_session(listener_opts) as session:
        subs = [session.declare_subscriber(t.key(RIG), lambda s, t=t: got.put((t, s.payload.to_bytes())))
                for t in (keys.INSTRUCTIONS, keys.SOURCE_END, keys.DETECTOR_END)]
        subs.append(session.liveliness().declare_subscriber(
            keys.all_alive(RIG), lambda s: alive.add(str(s.key_expr).rsplit("/", 1)[-1]), history=True))
        try:
            # the detector is slowed by a tiny credit window: the source must wait, never drop
            procs = [spawn("source", "--rig", RIG, "--window", "2", *connect_flags(port), log=tmp_path / "source.log"),
                     spawn("detector", "--rig", RIG, *connect_flags(port), log=tmp_path / "detector.log"),
                     spawn("smoother", "--rig", RIG, "--end-idle", "0", *connect_flags(port),
                           log=tmp_path / "smoother.log")]
            wait_for(lambda: {"source", "detector", "smoother"} <= alive, 120, what="nodes alive")
            session.put(keys.SOURCE_COMMAND.key(RIG), codec.encode(
                M.Command(action="play", args={"path": str(clip), "stop": N})))
            final, ends = None, {}
            while final is None:
                topic, payload = got.get(timeout=180)
                msg = codec.decode(payload, topic.msg_type)
                if topic is keys.INSTRUCTIONS and msg.final:
                    final = msg
                elif topic is not keys.INSTRUCTIONS:
                    ends[topic.topic + topic.service] = msg
        finally:
            for s in subs:
                s.undeclare()
            rcs = [stop(p) for p in procs]
    assert rcs == [0, 0, 0]
    # then every source frame was sent, measured and smoothed
    assert ends["endsource"].frames == N and ends["endsource"].valid and ends["endsource"].reason == "end of file"
    assert ends["enddetector"].frames == N and ends["enddetector"].valid
    assert final.image_targets.shape[0] == N and final.source.path == str(clip)
    # and the in-process path gives the same style (within float tolerance)
    out = tmp_path / "extract.json"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "extract", str(clip), "--stop", str(N), "-o", str(out),
                        "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    ref = load_style(out)
    assert ref.joint_names == final.joint_names and ref.fps == final.fps and ref.first_frame == final.first_frame
    assert ref.source.n_frames == final.source.n_frames and ref.source.sha256 == final.source.sha256
    np.testing.assert_allclose(final.image_targets, ref.image_targets, atol=1e-5, equal_nan=True)
    np.testing.assert_allclose(final.subject_box, ref.subject_box, atol=1e-5, equal_nan=True)
    np.testing.assert_allclose(final.focus_smoothed, ref.focus_smoothed, atol=1e-5, equal_nan=True)
    assert np.array_equal(final.focus_in, ref.focus_in) and np.array_equal(final.subject_visible, ref.subject_visible)
