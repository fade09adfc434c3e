"""The recorder of a transfer: every message of the rig into the recording (run.mcap, see
shared/runlog.py), the take's frames into output.mp4 (H.264) and their ground truth into a list,
each frame in its slot.

The Zenoh callback only enqueues (key, payload, receive time); one worker thread writes the
recording, decodes what it needs and feeds two `TakeAssembler`s (frames, truths). Which recorded
frame is slot k of the take is set by `arm_exact` (simulation time: the camera frame index
since the simulation reset) or `arm_realtime` (wall clock: the frame stamp).
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
from cinetransfer.shared.runlog import RunWriter
from cinetransfer.shared.video import H264Writer
from cinetransfer.take import Placed, TakeAssembler, TakeSummary

log = logging.getLogger("cinetransfer.recorder")


@dataclasses.dataclass(frozen=True)
class Window:
    """Which frames make the take: exact -> by frame index from `first_index` (stamps >= epoch);
    real time -> by stamp from `t0_ns` at `fps`."""

    exact: bool
    n_slots: int
    fps: float
    epoch_ns: int = 0
    first_index: int = 0
    t0_ns: int = 0

    def slot(self, stamp_ns: int, index: int) -> int | None:
        if self.exact:
            return None if stamp_ns < self.epoch_ns else index - self.first_index
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
        self.truths: list[M.GroundTruth] = []
        self.undecodable = 0
        self.interrupted = False
        self._window: Window | None = None
        self._frames: TakeAssembler | None = None
        self._truth_asm: TakeAssembler | None = None
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
                self._place(self._frames, msg.stamp_ns, msg.index, msg, self._write_frame)
            elif isinstance(msg, M.GroundTruth):
                self._place(self._truth_asm, msg.stamp_ns, msg.frame_index, msg, self._add_truth)

    def _place(self, asm: TakeAssembler | None, stamp_ns: int, index: int, msg: Any, sink: Any) -> None:
        slot = self._window.slot(stamp_ns, index) if self._window else None
        if asm is None or slot is None:
            return
        placed = asm.add(slot, msg)
        for p in placed:
            sink(p)
        if placed:
            with self._progress:
                self._progress.notify_all()

    def _write_frame(self, p: Placed) -> None:
        if self._video is None:
            self._video = H264Writer(self.outdir / "output.mp4", self._window.fps)
        self._video.write(np.asarray(p.item.image))

    def _add_truth(self, p: Placed) -> None:
        self.truths.append(dataclasses.replace(p.item, frame_index=p.slot))

    # ------------------------------------------------------------------ control (main thread)
    def arm(self, window: Window) -> None:
        """Record the take defined by `window` from now on."""
        self._frames = TakeAssembler(window.n_slots, exact=window.exact)
        self._truth_asm = TakeAssembler(window.n_slots, exact=window.exact)
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
        if self._frames is None or self._truth_asm is None:
            return None, None
        return self._frames.finish(), self._truth_asm.finish()
