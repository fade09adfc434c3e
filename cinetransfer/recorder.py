"""The recorder of a transfer: every message of the rig into the recording (run.mcap, see
cinetransfer/runlog.py), the take's frames into output.mp4 (H.264) and their ground truth into a list,
each frame in its slot.

The Zenoh callback only enqueues (key, payload, receive time); one worker thread writes the
recording, decodes what it needs and feeds a `TakeAssembler` that gives each camera frame its
slot; the truth of a slot is the truth of the frame it shows (joined at close, whatever order
they came in). Which recorded frame is slot k is set by `arm(Window)`: in simulation time by
the camera frame index within the takes, on the wall clock by the frame stamp.

A full disk (any write error, or less than LOW_SPACE_BYTES left) stops the recording at once:
`failure` says why, the worker closes run.mcap and output.mp4 so that they stay readable and
frees what is left of the reserve; the flight sees `failure` and ends. The reserve
(`RESERVE_BYTES`, set aside before any node starts) moves into the two files as they open: each
keeps room allocated past its end (RECORDING_ROOM, VIDEO_ROOM; cinetransfer/diskroom.py),
renewed as it grows, so that no write of theirs meets a full disk (a record cut in half would
damage the file) and closing has room however fast another writer fills the disk; a renewal
the disk cannot give is the full disk. Where the file system cannot hold room past a file's
end, the reserve stays a file of its own, freed on the failure.
"""
from __future__ import annotations

import contextlib
import dataclasses
import errno
import logging
import os
import queue
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from cinetransfer import diskroom
from cinetransfer.shared import codec, keys
from cinetransfer.shared import messages as M
from cinetransfer.runlog import KEYFRAME_S, VIDEO_X264_PARAMS, RunWriter
from cinetransfer.shared.video import H264Writer
from cinetransfer.take import Placed, TakeAssembler, TakeSummary
from cinetransfer.waiting import wait_while_moving

log = logging.getLogger("cinetransfer.recorder")
RESERVE_BYTES = 8 * 2**20  #: set aside at the start: room to close the files (see the module doc)
#: of the reserve, held past run.mcap's end: its next chunk (4 MB of messages at most) and its summary
RECORDING_ROOM = 6 * 2**20
#: of the reserve, held past output.mp4's end: its index (moov) and the shift that puts it first
VIDEO_ROOM = 1 * 2**20
#: less free space than this (beside the reserve) is a full disk: stop before a write is cut in half
LOW_SPACE_BYTES = 4 * 2**20
SPACE_LOOK_S = 0.2  #: how often the free space is looked at
RESERVE = ".reserve"
#: closing: the worker may take as long as it needs to drain its queue (a loaded machine encodes
#: slowly), but it must finish a message (handled and written) at least this often; longer, it hangs:
#: RecorderHang
CLOSE_STALL_S = 120.0


class RecorderHang(RuntimeError):
    """The recorder's worker finished no message for CLOSE_STALL_S while the recording was closing."""


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

    def index_of(self, slot: int) -> int | None:
        """The camera frame index that fills `slot` (exact mode; None: no such slot)."""
        for t in self.takes:
            if t.slot0 <= slot < t.slot0 + t.n:
                return t.first_index + slot - t.slot0
        return None


class Recorder:
    """Subscribes to everything of the rig (see the module doc)."""

    def __init__(self, session: Any, rig: str, outdir: Path, meta: dict, on_frame: Any = None) -> None:
        self.outdir = outdir
        #: called with (slot, image) for every frame written to the take, in slot order (the
        #: output measured while filming, cinetransfer/live_output.py); None: nobody
        self.on_frame = on_frame
        make_reserve(outdir)  # (made by the transfer before its nodes start; OSError: no room even for that)
        self.log = _held(outdir, RECORDING_ROOM, lambda: RunWriter(outdir / "run.mcap", meta,
                                                                   hold_bytes=RECORDING_ROOM))
        #: the write error that stopped the recording (None: none)
        self.failure: OSError | None = None
        self.closed_cleanly = True  #: False: a file could not be closed after `failure`
        self._space_seen = -1e9
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
        #: exact mode: (slot, frame index) of a camera frame that never came although a later frame
        #: or its own truth did (see `_look_for_gap`); None: no frame lost
        self.lost: tuple[int, int] | None = None
        self._seen_index = -1  # the highest frame index of a frame or truth received in the take
        self._window: Window | None = None
        self._frames: TakeAssembler | None = None
        self._video = None
        self._video_fd: int | None = None  #: output.mp4 opened to hold its room (None: not held)
        self._video_held: bool | None = None  #: whether output.mp4 holds room (None: not tried yet)
        #: output.mp4's encoder makes run.mcap's camera stream too (one encode a frame) for as long as
        #: both streams hold the same frames in the same order; `_packet`: the frame in hand's H.264
        self._shared = True
        self._packet: bytes | None = None
        self._msg: Any = None  #: the message in hand, when decoded already (run.mcap's views need it too)
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._finished = 0  # messages the worker handled and wrote: its progress while the recording closes
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
            keep = True
            self._packet = self._msg = None
            try:
                keep = self._handle(key, payload)
            except codec.DecodeError:
                self.undecodable += 1
            except OSError as e:  # writing output.mp4: the disk is full
                self._fail(e)
            except Exception:  # noqa: BLE001 - a bad message must not end the recording
                log.exception("recorder: could not handle a message on %s", key)
                self.undecodable += 1
            if keep:
                self._write(key, payload)
            self._finished += 1  # counted once written: a write that hangs is no progress

    def _write(self, key: str, payload: bytes) -> None:
        if self.failure is not None:
            return
        packet = self._packet if self._shared else None
        if key == self.frame_key and packet is None and self._video is not None and self._video.frames:
            self._shared = False  # run.mcap gets a frame output.mp4's stream has not: the streams part here
        try:
            self._check_space()
            self.log.write(key, payload, video_packet=packet, msg=self._msg)
        except OSError as e:
            self._fail(e)

    def _check_space(self) -> None:
        """ENOSPC before the disk is really full: a chunk cut by a real ENOSPC would damage the file."""
        now = time.monotonic()
        if now - self._space_seen < SPACE_LOOK_S:
            return
        self._space_seen = now
        st = os.statvfs(self.outdir)
        if st.f_bavail * st.f_frsize < LOW_SPACE_BYTES:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.outdir))

    def _fail(self, e: OSError) -> None:
        """Stop recording at the first write error: free the reserve, close the files readable."""
        log.error("recording stopped: %s", e)
        self.failure = e
        with contextlib.suppress(OSError):  # what is left of it (all of it where the files hold no room)
            os.unlink(self.outdir / RESERVE)
        for name, close in (("output.mp4", self._close_video), ("run.mcap", self.log.close)):
            try:
                close()
            except Exception as ce:  # noqa: BLE001 - closing is best effort once the disk is full
                self.closed_cleanly = False
                log.error("could not close %s after the write error: %s", name, ce)
        with self._progress:
            self._progress.notify_all()

    def _handle(self, key: str, payload: bytes) -> bool:
        """Take one message in; False for a camera frame or truth from before the flight's time zero
        (the free-running simulation before its reset), which the recording leaves out."""
        if key in (self.frame_key, self.truth_key):
            return self.failure is None and self._handle_take(key, payload)
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
        return True

    def _handle_take(self, key: str, payload: bytes) -> bool:
        if self._window is None:
            return False  # not armed: no take yet
        msg = self._msg = codec.decode(payload)  # kept for run.mcap's views: decoded once
        # (real time: the frame shown first may be a bit older than the window)
        start = self._window.epoch_ns if self._window.exact else self._window.t0_ns - 10**9
        if not isinstance(msg, (M.Frame, M.GroundTruth)) or msg.stamp_ns < start:
            return False
        if isinstance(msg, M.Frame):
            self._place_frame(msg)
        else:
            self.timeline_truths[int(msg.frame_index)] = msg
        self._look_for_gap(int(msg.index if isinstance(msg, M.Frame) else msg.frame_index))
        return True

    def _look_for_gap(self, index: int) -> None:
        """Simulation time: the bridge publishes its frames in index order, each frame before its
        truth, on one session whose messages arrive in order; so once a later frame, or the truth
        of the very frame the take waits for, has arrived, that frame was lost on the way and the
        take would wait for it forever (the bridge does not wait for the recorder)."""
        self._seen_index = max(self._seen_index, index)
        w, frames = self._window, self._frames
        if self.lost is not None or not w.exact or frames is None or frames.done:
            return
        want = w.index_of(frames.next_slot)
        if want is not None and want <= self._seen_index:
            self.lost = (frames.next_slot, want)
            log.error("camera frame %d (slot %d) never arrived, frame or truth %d did", want, frames.next_slot,
                      self._seen_index)
            with self._progress:
                self._progress.notify_all()

    def _place_frame(self, frame: M.Frame) -> None:
        slot = self._window.slot(frame.stamp_ns, frame.index) if self._window else None
        if self._frames is None or slot is None:
            return
        self._check_space()  # before the frame is counted: a full disk must not count a frame it never wrote
        placed = self._frames.add(slot, frame)
        packets = [self._write_frame(p) for p in placed]
        if len(placed) == 1 and placed[0].item is frame:
            self._packet = packets[0]
        elif placed:  # a repeated or held-back frame: output.mp4's stream is not run.mcap's any more
            self._shared = False
        if placed:
            with self._progress:
                self._progress.notify_all()

    def _write_frame(self, p: Placed) -> bytes:
        """Encode a placed frame into output.mp4; its H.264 packet (for run.mcap)."""
        if self._video is None:
            self._video = H264Writer(self.outdir / "output.mp4", self._window.fps, stream_keyframe_s=KEYFRAME_S,
                                     x264_params=VIDEO_X264_PARAMS)
        packet = self._video.write(np.asarray(p.item.image))
        self._shown.append(int(p.item.index))
        if self.on_frame is not None:
            self.on_frame(p.slot, p.item.image)
        self._hold_video_room()  # (OSError: the disk is full; the frame is in, and counted)
        return packet

    def _hold_video_room(self) -> None:
        """Room ahead of output.mp4's end again, taken from the reserve the first time the file is
        there (the encoder makes it with its header, at its first packet)."""
        path = self.outdir / "output.mp4"
        if self._video_fd is not None:
            diskroom.hold(self._video_fd, VIDEO_ROOM, name=str(path))
            return
        if self._video_held is not None or not path.is_file():
            return
        fd = os.open(path, os.O_WRONLY)  # the encoder's own descriptor is out of reach; the room is the file's
        try:
            self._video_held = _held(self.outdir, VIDEO_ROOM, lambda: diskroom.hold(fd, VIDEO_ROOM, name=str(path)))
        except OSError:
            self._video_held = False
            os.close(fd)
            raise
        if self._video_held:
            self._video_fd = fd
        else:
            os.close(fd)

    def _close_video(self) -> None:
        """Close output.mp4 (its index written, put first) and give back the room it held."""
        video, fd, self._video, self._video_fd = self._video, self._video_fd, None, None
        try:
            if video is not None:
                video.close()
        finally:
            if fd is not None:
                with contextlib.suppress(OSError):
                    diskroom.release(fd)
                os.close(fd)

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
        self._join_worker()
        if self.failure is None:
            self._close_video()
            self.log.close()
        with contextlib.suppress(OSError):
            os.unlink(self.outdir / RESERVE)
        if self._frames is None:
            return None, None
        frames = self._frames.finish()
        if frames.written > len(self._shown):  # a write failed mid-batch: count what output.mp4 holds
            frames.written = len(self._shown)
            frames.missing_slots = list(range(len(self._shown), frames.n_slots))
        return frames, self._truth_summary()

    def _join_worker(self) -> None:
        """Wait for the worker to drain its queue, however long that takes while it makes progress;
        RecorderHang when it finished no message for CLOSE_STALL_S (the files are left as they are: the
        worker may be inside a write)."""
        stall_s = CLOSE_STALL_S
        if not wait_while_moving(lambda: not self._worker.is_alive(), lambda: self._finished, stall_s,
                                 wait=self._worker.join):
            raise RecorderHang(f"the recorder finished no message for {stall_s:.0f} s while closing, with "
                               f"{self._q.qsize()} still queued; run.mcap and output.mp4 may be incomplete")

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


def make_reserve(outdir: Path) -> None:
    """Set RESERVE_BYTES of disk aside in `outdir` (really allocated, not a sparse file); a reserve
    already there is kept as it is. OSError (ENOSPC) when the disk has not that much room."""
    path = outdir / RESERVE
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        os.posix_fallocate(fd, 0, RESERVE_BYTES)
    except OSError:
        os.close(fd)
        os.unlink(path)
        raise
    os.close(fd)


def _held(outdir: Path, nbytes: int, make: Any) -> Any:
    """`make()` a file that holds `nbytes` of room past its end, the room taken from the reserve
    (shrunk first: a disk with no room besides has it all the same); where the file system cannot
    hold room (`make()` false, or a writer whose `holding` is false) the reserve is made whole again."""
    path = outdir / RESERVE
    with contextlib.suppress(OSError):
        os.truncate(path, max(0, path.stat().st_size - nbytes))
    try:
        made = make()
    except OSError:
        with contextlib.suppress(OSError):
            make_reserve(outdir)
        raise
    if not getattr(made, "holding", made):
        make_reserve(outdir)
    return made


def drop_reserve(outdir: Path) -> None:
    """Give the reserve back (a run that ends before its recording closed it)."""
    with contextlib.suppress(OSError):
        os.unlink(outdir / RESERVE)
