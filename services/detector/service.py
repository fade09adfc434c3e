"""`cinetransfer detector --rig R`: the detector node.

Inputs (`--input`):
- `source` (default): the source clip's frames on `ct/{rig}/source/frame` (from `cinetransfer
  source`). Every frame is measured, in order: none is skipped (the source only sends as many as
  the detector has credit for). When the source's StreamEnd arrives on `ct/{rig}/source/end`,
  the detector finishes the frames it holds and publishes its own StreamEnd on
  `ct/{rig}/detector/end` (the smoother then publishes the whole-sequence instructions).
  Output: one Measurement per frame on `ct/{rig}/detector/measurement`.
- `camera`: the drone's own camera on `ct/{rig}/camera/frame`, for a live view of the output's
  style; measurements go to `ct/{rig}/output/measurement` and never feed the smoother or the
  planner. Frames arrive in a small drop-oldest queue (`--queue`, default 2): when processing is
  slower than the camera the newest frame is taken and the older ones skipped, every skip
  counted (`frames_skipped`, Health.dropped); gaps in the incoming indices are counted as
  `frames_missing_upstream`.
- a file given with `--video PATH` / `--images DIR`: this process plays and measures it (its
  frames are also published on `ct/{rig}/source/frame` unless `--no-publish-frames`).
"""
from __future__ import annotations

import argparse
import collections
import logging
import sys
import time

from cinetransfer.services.detector.config import add_config_arguments, config_from_args
from cinetransfer.shared import keys, nodeconfig
from cinetransfer.shared import messages as M
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.node import add_node_arguments, node_from_args
from cinetransfer.shared.frame_sources import FrameSourceError, iter_frames

NAME = "detector"
log = logging.getLogger(f"cinetransfer.{NAME}")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cinetransfer detector", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_node_arguments(ap)
    nodeconfig.add_config_arguments(ap, NAME)
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--video", metavar="PATH", help="process this video file instead of subscribing to frames")
    src.add_argument("--images", metavar="DIR", help="process this folder of images instead of subscribing")
    ap.add_argument("--stop", type=int, default=None, help="(--video/--images) stop before this frame index")
    ap.add_argument("--realtime", action="store_true",
                    help="(--video/--images) pace frames at the source rate, skipping when behind")
    ap.add_argument("--no-publish-frames", action="store_true",
                    help="(--video/--images) do not publish the file's frames on the frame key")
    ap.add_argument("--wait-subscriber", type=float, default=3.0, metavar="S",
                    help="(--video/--images) wait up to S seconds for a measurement subscriber before "
                         "starting (default %(default)s)")
    ap.add_argument("--input", choices=("source", "camera"), default="source",
                    help="frames to measure: the source clip (default) or the drone's camera (live output view)")
    ap.add_argument("--queue", type=int, default=2,
                    help="(--input camera) frame queue length (drop-oldest, default %(default)s)")
    add_config_arguments(ap)
    return ap


class _Stats:
    def __init__(self) -> None:
        self.processed = 0
        self.skipped = 0
        self.errors = 0
        self.people = 0
        self.index_gaps = 0  # frames missing from the index sequence of one source
        self._last: dict[str, int] = {}
        self.t0 = time.monotonic()
        self.win: list[float] = []

    def note_frames(self, frames: list[M.Frame]) -> None:
        """Count index gaps per source: frames lost upstream (camera, network) are visible too."""
        for f in frames:
            last = self._last.get(f.source)
            if last is not None and f.index > last + 1:
                self.index_gaps += f.index - last - 1
            self._last[f.source] = f.index

    def fps(self) -> float:
        now = time.monotonic()
        self.win = [t for t in self.win if now - t < 5.0]
        span = (now - self.win[0]) if len(self.win) > 1 else 0.0
        return (len(self.win) - 1) / span if span > 0 else 0.0


def _process(node, det, pub, stats: _Stats, frame: M.Frame) -> bool:
    """Measure one frame and publish (True); a failure is counted and logged, never fatal."""
    t = time.perf_counter()
    try:
        m = det.process(frame.image, frame.index, frame.stamp_ns, source=frame.source, fps=frame.fps,
                        lens=frame.lens, valid=frame.valid)
    except (ValueError, RuntimeError, OSError) as e:
        _count_error(node, stats, frame.index, e)
        return False
    node.record_latency_ms((time.perf_counter() - t) * 1e3)
    _published(node, pub, stats, m)
    return True


def _count_error(node, stats: _Stats, index: int, e: BaseException) -> None:
    stats.errors += 1
    node.counters["errors"] = stats.errors
    node.error(f"frame #{index}: {type(e).__name__}: {e}", "process")


def _published(node, pub, stats: _Stats, m: M.Measurement) -> None:
    pub.put(m)
    stats.processed += 1
    stats.people += len(m.people)
    stats.win.append(time.monotonic())
    node.counters.update(frames_processed=stats.processed, frames_skipped=stats.skipped,
                         people_last=len(m.people), fps=round(stats.fps(), 2), last_frame=m.frame_index)


def _wait_matching(node, pub, timeout_s: float) -> None:
    if timeout_s <= 0:
        return
    deadline = time.monotonic() + timeout_s
    while node.running and time.monotonic() < deadline:
        try:
            if pub._pub.matching_status.matching:
                return
        except AttributeError:  # older zenoh without matching status: just proceed
            return
        node.sleep(0.02)
    log.info("no measurement subscriber after %.1f s; publishing anyway", timeout_s)


def run_file(node, det, args, stats: _Stats) -> int:
    path = args.video or args.images
    pub = node.publisher(keys.MEASUREMENT)
    fpub = None if args.no_publish_frames else node.publisher(keys.SOURCE_FRAME)
    node.ready()
    _wait_matching(node, pub, args.wait_subscriber)
    t_start = None
    try:
        for f in iter_frames(path, stop=args.stop):
            if not node.running:
                break
            if args.realtime:
                now = time.monotonic()
                if t_start is None:
                    t_start = now - f.stamp_ns * 1e-9
                lag = now - (t_start + f.stamp_ns * 1e-9)
                if lag > 1.5 / f.fps:  # behind by more than a frame: skip (counted)
                    stats.skipped += 1
                    node.counters["frames_skipped"] = stats.skipped
                    continue
                if lag < 0:
                    node.sleep(-lag)
            frame = M.Frame(stamp_ns=f.stamp_ns, source=str(path), index=f.index, fps=f.fps, image=f.image)
            if fpub is not None:
                fpub.put(frame)
            _process(node, det, pub, stats, frame)
    except FrameSourceError as e:
        log.error("cannot read %s: %s", path, e)
        return 1
    log.info("%s: processed %d frames (%d skipped, %d errors)", path, stats.processed, stats.skipped, stats.errors)
    return 0


def run_source(node, det, args, stats: _Stats) -> int:
    """Measure every source frame in order; close each stream with a StreamEnd of our own. Frames are
    streamed (`FrameStream`: a frame's tail beside the next frames' poses); what is in flight is
    handed out whenever no frame is waiting, so the source, which sends only as many frames as it
    has credit for, never waits on measurements held here."""
    from cinetransfer.services.detector.core import FrameStream

    frames = node.subscribe(keys.SOURCE_FRAME, policy="no-drop")
    ends = node.subscribe(keys.SOURCE_END)
    out = _Streamed(node, node.publisher(keys.MEASUREMENT, block=True), stats)
    end_pub = node.publisher(keys.DETECTOR_END)
    node.ready()
    with FrameStream(det) as stream:
        while node.running:
            node.wait(0.2)
            for frame in frames.drain():
                stats.note_frames([frame])
                with node.guard(frames.key, "frame"):  # anything unexpected costs the frame, not the loop
                    out.push(stream, frame)
            if stream.in_flight and not len(frames):  # nothing waiting: hand out what is held
                with node.guard(frames.key, "frame"):
                    out.publish(stream.flush())
            for end in ends.drain():
                with node.guard(ends.key, "end of stream"):
                    _finish_stream(node, frames, stream, out, end_pub, end)
    return 0


class _Streamed:
    """Publishes the measurements a FrameStream hands back, paired with the frames pushed (in order);
    a failure is counted and logged, never fatal. `done`: measurements published per source path."""

    def __init__(self, node, pub, stats: _Stats) -> None:
        self.node, self.pub, self.stats = node, pub, stats
        self.held: collections.deque[tuple[int, float]] = collections.deque()  # (frame index, push time)
        self.done: dict[str, int] = {}

    def push(self, stream, frame: M.Frame) -> None:
        self.held.append((frame.index, time.perf_counter()))
        try:
            due = stream.push(frame.image, frame.index, frame.stamp_ns, source=frame.source, fps=frame.fps,
                              lens=frame.lens, valid=frame.valid)
        except (ValueError, RuntimeError, OSError) as e:
            self.held.pop()
            _count_error(self.node, self.stats, frame.index, e)
            return
        self.publish(due)

    def publish(self, due: list) -> None:
        for fut in due:
            index, t = self.held.popleft()
            try:
                m = fut.result()
            except Exception as e:  # noqa: BLE001 - a failed tail costs its frame, not the ones after it
                _count_error(self.node, self.stats, index, e)
                continue
            self.node.record_latency_ms((time.perf_counter() - t) * 1e3)
            _published(self.node, self.pub, self.stats, m)
            self.done[m.source] = self.done.get(m.source, 0) + 1


def _finish_stream(node, frames, stream, out: _Streamed, end_pub, end: M.StreamEnd) -> None:
    """The source ended: measure what is still queued (frames travel ahead of the end but on
    another key), then say how many measurements this stream produced."""
    path = end.source.path
    out.publish(stream.flush())
    deadline = time.monotonic() + 5.0
    while out.done.get(path, 0) + out.stats.errors < end.frames and time.monotonic() < deadline and node.running:
        for frame in frames.get_all(0.1):
            out.push(stream, frame)
        out.publish(stream.flush())
    n = out.done.pop(path, 0)
    end_pub.put(M.StreamEnd(stamp_ns=end.stamp_ns, valid=end.valid and n == end.frames, source=end.source,
                            frames=n, reason=end.reason if n == end.frames else
                            f"{end.reason}; {end.frames - n} of {end.frames} frames not measured"))
    node.log.info("end of %s: %d of %d frames measured (%s)", path, n, end.frames, end.reason)


def run_subscriber(node, det, args, stats: _Stats) -> int:
    inbox = node.subscribe(keys.FRAME, maxlen=max(1, args.queue), policy="drop-oldest")
    pub = node.publisher(keys.OUTPUT_MEASUREMENT)
    node.ready()
    while node.running:
        node.wait(0.2)
        frames = inbox.drain()
        if not frames:
            continue
        # newest wins: older queued frames are skipped (and counted) so we never fall behind
        stats.note_frames(frames)
        stats.skipped += len(frames) - 1
        # gaps not explained by our own queue's drops were lost before reaching us
        node.counters["frames_missing_upstream"] = max(0, stats.index_gaps - inbox.dropped)
        # guard: _process counts the errors it expects; anything else is a rejected frame, not an exit
        with node.guard(inbox.key, "frame"):
            _process(node, det, pub, stats, frames[-1])
        node.counters["frames_skipped"] = stats.skipped
    return 0


def main(argv: list[str]) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.queue < 1:
        ap.error("--queue must be >= 1")
    try:
        cfg = config_from_args(args)
    except ConfigError as e:
        return report_config_error(e, "cinetransfer detector")
    node = node_from_args(NAME, args, config=cfg)
    from cinetransfer.services.detector.core import Detector, DetectorError

    try:
        det = Detector(cfg)  # slow set-up (bundle, models) before announcing readiness
    except (DetectorError, OSError, RuntimeError) as e:
        log.error("detector cannot start: %s", e)
        return 1
    stats = _Stats()
    try:
        with node:
            node.counters.update(backend=det.name, frames_processed=0, frames_skipped=0, errors=0,
                                 frames_missing_upstream=0)
            if getattr(det.backend, "unavailable", ""):  # the configured backend is not installed
                node.counters["backend_unavailable"] = det.backend.unavailable
            if args.video or args.images:
                return run_file(node, det, args, stats)
            if args.input == "source":
                return run_source(node, det, args, stats)
            return run_subscriber(node, det, args, stats)
    finally:
        det.close()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
