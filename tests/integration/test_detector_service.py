"""The detector node over real Zenoh: frames in, measurements out, drops visible, clean exit."""
from __future__ import annotations

import threading

import zenoh

from attacks import jpeg_bomb_frame
from cinetransfer.shared.frame_sources import iter_frames
from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M
from conftest import connect_flags, spawn, stop, wait_for

#: how long a wait for a service's answer may take: a ceiling for a hang, not a measure of speed (a
#: service process at load 50 on 2 cores gets a few % of a core; the wait ends as soon as it answers)
WAIT_S = 30.0


class Bus:
    """The test's own session: collects measurements, frames, health and liveliness of a rig."""

    def __init__(self, opts, rig: str):
        self.rig = rig
        self.session = zenoh_config.open_session(opts)
        self.lock = threading.Lock()
        self.measurements: list[M.Measurement] = []
        self.frames: list[M.Frame] = []
        self.health: list[M.Health] = []
        self.alive: set[str] = set()
        self._decl = [
            self.session.declare_subscriber(keys.MEASUREMENT.key(rig), self._on_m),
            self.session.declare_subscriber(keys.OUTPUT_MEASUREMENT.key(rig), self._on_m),
            self.session.declare_subscriber(keys.SOURCE_FRAME.key(rig), self._on_f),
            self.session.declare_subscriber(keys.health(rig, "detector"), self._on_h),
            self.session.liveliness().declare_subscriber(keys.all_alive(rig), self._on_alive, history=True),
        ]
        # BLOCK: no frame is lost in transport, so the node's own accounting can be checked exactly
        self.frame_pub = self.session.declare_publisher(keys.FRAME.key(rig),
                                                        congestion_control=zenoh.CongestionControl.BLOCK)

    def _on_m(self, s: zenoh.Sample) -> None:
        with self.lock:
            self.measurements.append(codec.decode(s.payload.to_bytes(), M.Measurement))

    def _on_f(self, s: zenoh.Sample) -> None:
        try:  # the test itself puts garbage on this key
            f = codec.decode(s.payload.to_bytes(), M.Frame)
        except codec.DecodeError:
            return
        with self.lock:
            self.frames.append(f)

    def _on_h(self, s: zenoh.Sample) -> None:
        with self.lock:
            self.health.append(codec.decode(s.payload.to_bytes(), M.Health))

    def _on_alive(self, s: zenoh.Sample) -> None:
        name = str(s.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            (self.alive.add if s.kind == zenoh.SampleKind.PUT else self.alive.discard)(name)

    def close(self) -> None:
        for d in self._decl:
            d.undeclare()
        self.frame_pub.undeclare()
        self.session.close()


def test_service_measures_frames_and_drops_visibly(tmp_path, data, port, listener_opts):
    rig = "det1"
    bus = Bus(listener_opts, rig)
    proc = spawn("detector", "--rig", rig, "--input", "camera", *connect_flags(port), "--health-period", "0.3",
                 log=tmp_path / "detector.log")
    try:
        wait_for(lambda: "detector" in bus.alive, 60, what="detector liveliness")
        frames = [f for f in iter_frames(data / "sam2_juggle_1280x720.mp4", stop=40)]
        # one frame at a time, waiting for its measurement: every frame is measured
        # (frames 3-5 never reach the node: a gap upstream, which it must count)
        for k, f in enumerate(frames[:3] + frames[6:7]):
            frame = M.Frame(stamp_ns=f.stamp_ns, seq=k, source="cam", index=f.index, fps=24.0, image=f.image,
                            lens=M.LensState(focal_length_mm=35.0))
            bus.frame_pub.put(codec.encode(frame))
            wait_for(lambda: len(bus.measurements) > k, 30, what=f"measurement of frame {f.index}")
        with bus.lock:
            ms = list(bus.measurements)
        assert [m.frame_index for m in ms] == [0, 1, 2, 6]
        for m in ms:
            assert m.width == 1280 and m.height == 720 and m.source == "cam"
            assert len(m.people) == 1 and m.people[0].confidence > 0.8  # the juggler
            assert m.focus_map is not None and m.lens.focal_length_mm == 35.0
        assert ms[1].stamp_ns == frames[1].stamp_ns
        # a garbage payload is rejected and counted; the node carries on
        bus.frame_pub.put(b"not a frame at all")
        wait_for(lambda: any(h.rejected >= 1 for h in bus.health), WAIT_S, what="rejection in Health")
        # so is a 761-byte frame declaring a 30000x30000 JPEG (it once cost 28 s and 5.4 GB): refused unread
        bus.frame_pub.put(jpeg_bomb_frame())
        wait_for(lambda: any(h.rejected >= 2 for h in bus.health), WAIT_S, what="the JPEG bomb rejected in Health")
        # a burst faster than it can measure: the backlog stays bounded, the skipped frames are counted
        n0 = len(bus.measurements)
        burst = frames[7:40]
        for f in burst:
            bus.frame_pub.put(codec.encode(M.Frame(stamp_ns=f.stamp_ns, index=f.index, fps=24.0, image=f.image)))
        last = burst[-1].index
        wait_for(lambda: any(m.frame_index == last for m in bus.measurements), 30, what="last burst frame")

        def accounted():
            with bus.lock:
                h = bus.health[-1] if bus.health else None
            if h is None:
                return False
            done = h.counters.get("frames_processed", 0) - 4
            skipped = h.counters.get("frames_skipped", 0)
            return done + skipped + h.dropped >= len(burst) and h
        h = wait_for(accounted, WAIT_S, what="burst accounted for in Health")
        measured = len(bus.measurements) - n0
        assert measured < len(burst), "a 33-frame burst of 720p cannot all be measured in real time here"
        assert h.counters["frames_skipped"] + h.dropped > 0
        assert h.counters["backend"] in ("box_first", "mediapipe (box_first unavailable)")
        assert ("backend_unavailable" in h.counters) == (h.counters["backend"] != "box_first")
        assert h.counters["frames_missing_upstream"] == 3  # frames 3, 4, 5; queue drops are not counted here
    finally:
        rc = stop(proc)
        bus.close()
    assert rc == 0, (tmp_path / "detector.log").read_text()[-3000:]


def test_service_processes_a_video_file(tmp_path, data, port, listener_opts):
    rig = "det2"
    bus = Bus(listener_opts, rig)
    try:
        proc = spawn("detector", "--rig", rig, *connect_flags(port), "--video",
                     str(data / "tud_stadtmitte_640x480.mp4"), "--stop", "6", "--wait-subscriber", "20",
                     log=tmp_path / "detector.log")
        rc = proc.wait(120)
        assert rc == 0, (tmp_path / "detector.log").read_text()[-3000:]
        wait_for(lambda: len(bus.measurements) == 6, WAIT_S, what="6 measurements")
        assert [m.frame_index for m in bus.measurements] == list(range(6))
        assert all(m.fps == 25.0 and m.width == 640 for m in bus.measurements)
        assert sum(len(m.people) for m in bus.measurements) >= 1  # pedestrians
        wait_for(lambda: len(bus.frames) == 6, WAIT_S, what="6 republished frames")
        assert bus.frames[0].image.shape == (480, 640, 3)
    finally:
        bus.close()
    # an unreadable file: clear message, non-zero exit
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"junk" * 100)
    proc = spawn("detector", "--rig", rig, "--listen", "tcp/127.0.0.1:0", "--video", str(bad),
                 "--wait-subscriber", "0", log=tmp_path / "bad.log")
    assert proc.wait(60) == 1
    assert "bad.mp4" in (tmp_path / "bad.log").read_text()
