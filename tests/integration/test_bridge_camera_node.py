"""`cinetransfer camera` as a real process: a real clip published as Frames at its own rate, with
the lens state taken from the vehicle's state (or a static lens), ended by the file or by SIGINT."""
from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M
from conftest import connect_flags, spawn, stop, wait_for

pytestmark = pytest.mark.timeout(300)
RIG = "cam"


class Frames:
    def __init__(self, opts):
        self.session = zenoh_config.open_session(opts)
        self.lock = threading.Lock()
        self.got: list[tuple[float, M.Frame]] = []
        self.sub = self.session.declare_subscriber(keys.FRAME.key(RIG), self._on)
        self.state_pub = self.session.declare_publisher(keys.VEHICLE_STATE.key(RIG))

    def _on(self, s):
        f = codec.decode(s.payload.to_bytes(), M.Frame)
        with self.lock:
            self.got.append((time.monotonic(), f))

    def frames(self):
        with self.lock:
            return list(self.got)

    def close(self):
        self.sub.undeclare()
        self.state_pub.undeclare()
        self.session.close()


@pytest.fixture
def frames(listener_opts):
    f = Frames(listener_opts)
    yield f
    f.close()


def test_file_frames_at_source_rate_with_the_vehicle_lens(frames, port, data, tmp_path):
    clip = data / "tos_clip01_640x360.mp4"  # 24 fps
    stop_evt = threading.Event()
    lens = M.LensState(focal_length_mm=77.0, focus_distance_m=9.0, f_number=2.0)

    def publish_state():  # the bridge's role: VehicleState with the confirmed lens
        while not stop_evt.wait(0.05):
            frames.state_pub.put(codec.encode(M.VehicleState(stamp_ns=time.time_ns(), lens=lens)))

    th = threading.Thread(target=publish_state, daemon=True)
    th.start()
    log = tmp_path / "camera.log"
    proc = spawn("camera", "--rig", RIG, "--video", str(clip), "--max-frames", "48", *connect_flags(port), log=log)
    try:
        rc = proc.wait(240)  # the node ends by itself after 48 frames (a loaded machine may be slow)
    finally:
        stop_evt.set()
        th.join(2)
        if proc.poll() is None:
            stop(proc)
    assert rc == 0, log.read_text()
    got = frames.frames()
    # a real-time source skips the frames it could not send in time, and the link drops what it
    # cannot carry (a drop-oldest topic): how many arrive depends on load. Judged instead: the
    # node read the whole clip, counted what it skipped, and nothing came that it did not send
    done = re.search(r"done: (\d+) frames read, (\d+) dropped", log.read_text())
    assert done is not None, log.read_text()
    read, dropped = int(done[1]), int(done[2])
    assert read == 48 and 2 <= len(got) <= read - dropped, (read, dropped, len(got))
    idx = [f.index for _, f in got]
    assert idx == sorted(set(idx)) and idx[-1] <= 47  # in order, once each; the last ones may be lost on the link
    f = got[-1][1]
    assert f.image.shape == (360, 640, 3) and f.fps == pytest.approx(24.0, abs=0.1)
    assert f.lens is not None and f.lens.focal_length_mm == 77.0 and f.lens.f_number == 2.0
    # paced at the source rate (measured at the receiver): never faster than the clip; slower only
    # when the machine is (load may stretch the gaps, never shorten them)
    t = np.array([tt for tt, _ in got])
    rate = (len(t) - 1) / (t[-1] - t[0])
    assert rate < 28.0
    stamps = np.array([f.stamp_ns for _, f in got], dtype=float) * 1e-9
    assert np.all(np.diff(stamps) > 0)


def test_looping_file_with_static_lens_stops_cleanly_on_sigint(frames, port, data, tmp_path):
    log = tmp_path / "camera.log"
    proc = spawn("camera", "--rig", RIG, "--video", str(data / "tos_clip01_640x360.mp4"), "--loop", "--width", "320",
                 "--focal-length", "35", "--f-number", "4", "--jpeg", "80", *connect_flags(port), log=log)
    try:
        wait_for(lambda: len(frames.frames()) >= 10 or proc.poll() is not None, 30, what="frames")
    finally:
        rc = stop(proc)
    assert rc == 0, log.read_text()
    f = frames.frames()[-1][1]
    assert f.image.shape == (180, 320, 3)  # resized, JPEG on the wire
    assert f.lens.focal_length_mm == 35.0 and f.lens.f_number == 4.0 and np.isnan(f.lens.focus_distance_m)


def test_missing_source_fails_with_exit_code_1(port, tmp_path):
    proc = spawn("camera", "--video", str(tmp_path / "nope.mp4"), *connect_flags(port))
    assert proc.wait(30) == 1
