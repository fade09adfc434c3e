"""The output's style, measured while the take is filmed instead of in a second pass afterwards.

The recorder hands over every frame it places in the take, in slot order (`feed`); a worker
thread streams them through the same detector that `cinetransfer extract` runs, the same way (a
frame's tail beside the next frame's pose: `FrameStream`), and keeps the smoother's features of
each frame; `finish` smooths them into OUTDIR/output_style.json with the takes' first rows as
the shots, exactly as `extract output.mp4 --cuts ...` would. What differs is the pixels: these are
the camera's frames as the simulator rendered them, before output.mp4's H.264 compression.

Why not the dataflow's `output_detector` node: it is a live view (a drop-oldest queue, newest frame
wins) of every camera frame, the pre-roll and settle phases included, while the evaluation needs
each frame of the takes exactly once, in slot order; only the recorder knows which camera frame
is which slot. The measuring overlaps the flight, whose lockstep leaves CPU time idle (the bridge
waits for the planner, the planner for the bridge).

The frames wait in a queue (a frame is 1.5 MB at 960x540; on a quiet machine the detector
measures ~25 frames/s, faster than the flight films them): the recorder's thread never blocks on
it. A machine so loaded that MAX_BACKLOG frames wait gives up the live measuring (memory), and the
output is measured from output.mp4 after the flight instead.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cinetransfer.waiting import wait_while_moving

if TYPE_CHECKING:
    from cinetransfer.services.detector.core import Detector, FrameStream

log = logging.getLogger("cinetransfer.transfer")
#: frames waiting to be measured beyond which the measuring stops (~450 MB of 960x540 frames)
MAX_BACKLOG = 300


class LiveOutputStyle:
    """Measures the take's frames as they are recorded (see the module doc). Not reusable."""

    def __init__(self, video_path: Path, fps: float) -> None:
        from fractions import Fraction

        self.video_path = Path(video_path)
        # the rate output.mp4 declares (shared/video.py), which a second pass would read back
        self.fps = float(Fraction(float(fps)).limit_denominator(1001))
        self.error: str | None = None  #: why the measuring stopped early (None: it did not)
        self.busy_s = 0.0  #: wall time the worker spent measuring
        self.detector: dict | None = None  #: its detector's backend (cinetransfer/detector_backend.py)
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._feats: list[Any] = []
        self._next_slot = 0
        self._ended = False  # the take has ended (`finish`): the backlog is measured with every thread
        self._worker = threading.Thread(target=self._work, name="output-style", daemon=True)
        self._worker.start()

    def feed(self, slot: int, image: np.ndarray) -> None:
        """The recorder placed `image` in `slot` (called from its thread, in slot order)."""
        if self.error is not None:
            return
        if self._q.qsize() >= MAX_BACKLOG:
            self.error = f"{MAX_BACKLOG} frames waited to be measured (the machine is too busy)"
            return
        self._q.put((int(slot), image))

    def _work(self) -> None:
        det = None
        try:
            from cinetransfer.services.detector.config import DetectorConfig
            from cinetransfer.services.detector.core import Detector, FrameStream
            from cinetransfer.services.smoother.config import SmootherConfig
            from cinetransfer.services.smoother.core import feature_options

            # the settings `cinetransfer extract` measures output.mp4 with (the code defaults), but the pose
            # model's worker thread until the take ends (`finish`): the same measurements, and beside the
            # flight, which keeps both cores busy, the SSD and a second crop cost less CPU after the
            # caller's crop than beside it; the backlog left after the flight has the cores to itself
            det = Detector(DetectorConfig(bf_pose_worker=False))
            from cinetransfer.detector_backend import of_detector

            self.detector = of_detector(det)
            with FrameStream(det) as stream:
                self._measure(stream, feature_options(SmootherConfig()))
        except Exception as e:  # noqa: BLE001 - the evaluation falls back to measuring output.mp4
            self.error = f"{type(e).__name__}: {e}"
            log.warning("measuring the output while filming failed (%s); it is measured from output.mp4 instead",
                        self.error)
        finally:
            if det is not None:
                det.close()

    def _measure(self, stream: FrameStream, opts: dict[str, float]) -> None:
        """Push the queued frames through the detector's stream (a frame's tail overlaps the next
        frame's pose, as in `cinetransfer extract`: the same measurements) until the end marker."""
        while True:
            item = self._q.get()
            if item is None:
                break
            if self.error is not None:
                continue  # drain: the evaluation falls back to the second pass
            slot, image = item
            if self._ended:
                _use_pose_worker(stream.det)
            if slot != self._next_slot:
                self.error = f"frame for slot {slot} arrived where slot {self._next_slot} was due"
                continue
            t = time.monotonic()
            stamp = int(round(slot * 1e9 / self.fps))
            self._keep(stream.push(np.ascontiguousarray(image), slot, stamp, source=str(self.video_path),
                                   fps=self.fps), opts)
            self._next_slot += 1
            self.busy_s += time.monotonic() - t
        if self.error is None:
            t = time.monotonic()
            self._keep(stream.flush(), opts)
            self.busy_s += time.monotonic() - t

    def _keep(self, due: list, opts: dict[str, float]) -> None:
        from cinetransfer.services.smoother.features import frame_features

        for fut in due:  # oldest first: the features stay in slot order
            self._feats.append(frame_features(fut.result(), **opts))

    def cancel(self) -> None:
        """Nothing will be evaluated (an interrupted or failed take): stop measuring."""
        self.error = self.error or "cancelled"
        self._q.put(None)

    def finish(self, out_style: Path, *, n_frames: int, cuts: list[int] | None, timeout_s: float = 600.0) -> bool:
        """Wait for the queued frames, then smooth them into `out_style`. False (nothing written)
        when the measuring failed or holds another number of frames than the video."""
        self._ended = True
        self._q.put(None)
        # as long as it takes while frames get measured (a loaded machine is slow), not past
        # `timeout_s` without one: the detector hangs
        if not wait_while_moving(lambda: not self._worker.is_alive(), lambda: len(self._feats), timeout_s,
                                 wait=self._worker.join):
            self.error = f"no frame measured for {timeout_s:.0f} s ({len(self._feats)} measured)"
        elif self.error is None and len(self._feats) != n_frames:
            self.error = f"{len(self._feats)} frames measured, the video has {n_frames}"
        if self.error is not None:
            log.warning("output measured while filming is not usable (%s): measuring output.mp4 instead", self.error)
            return False
        from cinetransfer.services.smoother.cli import write_result
        from cinetransfer.services.smoother.config import SmootherConfig
        from cinetransfer.services.smoother.core import smooth_sequence
        from cinetransfer.shared.frame_sources import probe

        source = probe(self.video_path, hash_file=True)
        result = smooth_sequence(self._feats, SmootherConfig(), source=source, known_cuts=cuts)
        write_result(result, out_style, None, diagnostics=True)
        log.info("output style from the frames measured while filming (%d frames, %.1f s of measuring)",
                 n_frames, self.busy_s)
        return True


def _use_pose_worker(det: Detector) -> None:
    """The detector's pose backend with its worker thread (a backend without one is left as it is)."""
    use = getattr(det.backend, "use_worker", None)
    if use is not None:
        use(True)
