"""The recorder of a transfer: every message of the rig into the recording (run.mcap, see
cinetransfer/runlog.py), the take's frames into output.mp4 (H.264) and their ground truth into a list,
each frame in its slot.

The Zenoh callback only enqueues (key, payload, receive time); one worker thread writes the
recording, decodes what it needs and feeds a `TakeAssembler` that gives each camera frame its
slot; the truth of a slot is the truth of the frame it shows (joined at close, whatever order
they came in). Which recorded frame is slot k is set by `arm(Window)`: in simulation time by
the camera frame index within the takes, on the wall clock by the frame stamp.
"""
from __future__ import annotations

import dataclasses
import logging
import queue
import threading
from pathlib import Path
from typing import Any

import numpy as np

from cinetransfer.shared import codec, keys
from cinetransfer.shared import messages as M
from cinetransfer.runlog import RunWriter
from cinetransfer.shared.video import H264Writer
from cinetransfer.take import Placed, TakeAssembler, TakeSummary

log = logging.getLogger("cinetransfer.recorder")


@dataclasses.dataclass(frozen=True)
class Take:
    """One take of simulation time: camera frames first_index.. are instruction rows slot0.."""

    first_index: int
    slot0: int
    n: int


@dataclasses.dataclass(frozen=True)
class Window:
    """Which frames make the recording: exact -> by camera frame index within the takes (stamps
    >= epoch; frames between takes, e.g. settling, are not recorded); real time -> by stamp
    from `t0_ns` at `fps`."""

    exact: bool
    n_slots: int
    fps: float
    epoch_ns: int = 0
    takes: tuple[Take, ...] = ()
    t0_ns: int = 0

    def slot(self, stamp_ns: int, index: int) -> int | None:
        if self.exact:
            if stamp_ns < self.epoch_ns:
                return None
            for t in self.takes:
                if t.first_index <= index < t.first_index + t.n:
                    return t.slot0 + index - t.first_index
            return None
        if stamp_ns < self.t0_ns:
            return None
        return int(round((stamp_ns - self.t0_ns) * 1e-9 * self.fps))


class Recorder:
    """Subscribes to everything of the rig (see the module doc)."""

    def __init__(self, session: Any, rig: str, outdir: Path, meta: dict) -> None:
        self.outdir = outdir
        self.log = RunWriter(outdir / "run.mcap", meta)
        self.frame_key, self.truth_key = keys.FRAME.key(rig), keys.SIM_TRUTH.key(rig)
        self.clock_key = keys.SIM_CLOCK.key(rig)
        self.health: dict[str, M.Health] = {}
        self.last_clock: M.SimClock | None = None
        #: the truth of each recorded slot: the truth of the very frame the video shows there (a
        #: repeated slot shows, and is scored as, the frame before it); filled by close()
        self.truths: list[M.GroundTruth] = []
        #: truth of every camera frame since the recording was armed, by frame index (settling included)
        self.timeline_truths: dict[int, M.GroundTruth] = {}
        self._shown: list[int] = []  # frame index shown in each written slot
        self.undecodable = 0
        self.interrupted = False
        self._window: Window | None = None
        self._frames: TakeAssembler | None = None
        self._video = None
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._progress = threading.Condition()
        self._worker = threading.Thread(target=self._work, name="recorder", daemon=True)
        self._worker.start()
        self._sub = session.declare_subscriber(keys.everything(rig), self._on)

    # ------------------------------------------------------------------ Zenoh thread
    def _on(self, sample: Any) -> None:
        self._q.put((str(sample.key_expr), sample.payload.to_bytes()))

    # ------------------------------------------------------------------ worker thread
    def _work(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            key, payload = item
            self.log.write(key, payload)
            try:
                self._handle(key, payload)
            except codec.DecodeError:
                self.undecodable += 1
            except Exception:  # noqa: BLE001 - a bad message must not end the recording
                log.exception("recorder: could not handle a message on %s", key)
                self.undecodable += 1

    def _handle(self, key: str, payload: bytes) -> None:
        if "/health/" in key:
            h = codec.decode(payload, M.Health)
            with self._progress:
                self.health[h.node] = h
                self._progress.notify_all()
        elif key == self.clock_key:
            clk = codec.decode(payload, M.SimClock)
            with self._progress:
                self.last_clock = clk
                self._progress.notify_all()
        elif key in (self.frame_key, self.truth_key) and self._window is not None:
            msg = codec.decode(payload)
            if isinstance(msg, M.Frame):
                self._place_frame(msg)
            elif isinstance(msg, M.GroundTruth):
                start = self._window.epoch_ns if self._window.exact else self._window.t0_ns
                if msg.stamp_ns >= start - 10**9:  # (real time: the frame shown first may be a bit older)
                    self.timeline_truths[int(msg.frame_index)] = msg

    def _place_frame(self, frame: M.Frame) -> None:
        slot = self._window.slot(frame.stamp_ns, frame.index) if self._window else None
        if self._frames is None or slot is None:
            return
        placed = self._frames.add(slot, frame)
        for p in placed:
            self._write_frame(p)
        if placed:
            with self._progress:
                self._progress.notify_all()

    def _write_frame(self, p: Placed) -> None:
        if self._video is None:
            self._video = H264Writer(self.outdir / "output.mp4", self._window.fps)
        self._video.write(np.asarray(p.item.image))
        self._shown.append(int(p.item.index))

    # ------------------------------------------------------------------ control (main thread)
    def arm(self, window: Window) -> None:
        """Record the take defined by `window` from now on."""
        self._frames = TakeAssembler(window.n_slots, exact=window.exact)
        self._window = window

    @property
    def frames_written(self) -> int:
        return 0 if self._frames is None else self._frames.summary.written

    def wait(self, predicate: Any, timeout: float) -> bool:
        """Wait until `predicate()` is true (re-checked on every recorded frame, clock or health)."""
        with self._progress:
            return self._progress.wait_for(predicate, timeout)

    def close(self) -> tuple[TakeSummary | None, TakeSummary | None]:
        """Stop, drain what was received, close the files; returns the (frames, truths) summaries
        without judging them (the caller decides whether a gap is an error)."""
        self._sub.undeclare()
        self._q.put(None)
        self._worker.join()
        if self._video is not None:
            self._video.close()
        self.log.close()
        if self._frames is None:
            return None, None
        return self._frames.finish(), self._truth_summary()

    def _truth_summary(self) -> TakeSummary:
        """Give each written slot the truth of the frame it shows; slots without one are missing."""
        summary = TakeSummary(self._frames.summary.n_slots)
        self.truths = []
        for slot, index in enumerate(self._shown):
            truth = self.timeline_truths.get(index)
            if truth is None:
                summary.missing_slots.append(slot)
                continue
            self.truths.append(dataclasses.replace(truth, frame_index=slot))
        summary.written = len(self.truths)
        summary.missing_slots += list(range(len(self._shown), summary.n_slots))
        return summary
