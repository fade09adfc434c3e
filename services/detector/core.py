"""The detector's core: one frame in, one Measurement out (no Zenoh, no clock, no globals).

    det = Detector(DetectorConfig())
    m = det.process(image_bgr, frame_index=0, stamp_ns=0, source="clip.mp4", fps=24.0)
    det.close()

    for m in det.process_source("clip.mp4"):      # every frame of a file or image folder
        ...

Parallelism (2 cores): the focus estimator's expensive stage (edges and their defocus, pure
OpenCV/numpy that releases the GIL) runs in a worker thread while the pose backend (LiteRT or
MediaPipe C++, also GIL-free) runs in the caller's thread; the cheap second focus stage then uses
the people's masks so that the in-focus map does not bleed between a person and what is behind,
while the camera-motion stage (which masks the people out too) runs in the worker.
`process_frames` / `process_source` go further for a sequence: a frame's tail (mask refinement,
focus map, camera motion, Measurement: nothing the next frame's pose needs) runs in a thread of its own beside the
next frames' poses, with the same results; there the frame's focus edges and colour signature run in
that tail thread too, queued when its pose starts, so a stream keeps three busy threads (caller,
pose worker, tail) on the two cores rather than four. `process_source` also decodes the next frames
in a background thread.
"""
from __future__ import annotations

import collections
import concurrent.futures as cf
import dataclasses
import logging
import math
from typing import Iterable, Iterator, NamedTuple

import cv2
import numpy as np

from cinetransfer.services.detector import allocator, shots, subject_mask
from cinetransfer.services.detector.camera_motion import CameraMotionTracker
from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.services.detector.focus import FocusEstimator, FocusResult
from cinetransfer.shared.frame_sources import SourceFrame, iter_frames
from cinetransfer.shared.messages import LensState, Measurement, PersonDetection, Skeleton

log = logging.getLogger("cinetransfer.detector")


class DetectorError(RuntimeError):
    """The detector cannot run (backend missing, bad checkpoint, ...)."""


def make_backend(cfg: DetectorConfig):
    """The pose backend named by the config. When the box-first backend (the default) is not
    installed (npm was missing at setup), it says so once and MediaPipe's landmarker runs instead;
    that backend's `unavailable` attribute then holds the reason (Health counters, `detect` log)."""
    if cfg.backend == "box_first":
        from cinetransfer.services.detector.box_first import BoxFirstPose, BoxFirstUnavailable
        from cinetransfer.services.detector.box_models import FALLBACK_SUFFIX

        try:
            return BoxFirstPose(cfg)
        except BoxFirstUnavailable as e:
            log.warning("box_first backend unavailable (%s); running the mediapipe backend instead", e)
            be = make_backend(dataclasses.replace(cfg, backend="mediapipe"))
            be.unavailable = f"box_first: {e}"
            be.name = f"{be.name}{FALLBACK_SUFFIX}"
            return be
    if cfg.backend == "mediapipe":
        from cinetransfer.services.detector.pose_mediapipe import MediaPipePose

        try:
            return MediaPipePose(cfg)
        except ImportError as e:
            raise DetectorError(f"mediapipe backend unavailable: {e}") from e
    if cfg.backend == "torchvision":
        from cinetransfer.services.detector.torchvision_backend import TorchvisionPose

        return TorchvisionPose(cfg)
    raise DetectorError(f"unknown backend {cfg.backend!r}")


def _grey(image: np.ndarray) -> np.ndarray:
    """The frame in grey (as it is when it is grey already)."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


class _Head(NamedTuple):
    """A frame after its pose: what its tail needs."""

    image: np.ndarray
    people: list[PersonDetection]
    skeletons: list[Skeleton]
    edges: object  # the focus estimator's EdgeEvidence, or None
    signature: np.ndarray
    refined: bool  # the people's masks are refined already
    grey: np.ndarray | None = None  # the frame in grey at full size (the focus edges' and the camera motion's)
    side: cf.Future | None = None  # (edges, signature, grey) still being made: the tail waits for them


def people_mask(people: list[PersonDetection], width: int, height: int) -> np.ndarray | None:
    """Union of the people's masks (None when nobody has a mask pixel)."""
    if not people:
        return None
    out = np.zeros((height, width), dtype=bool)
    for p in people:
        out |= p.full_mask(width, height)
    return out if out.any() else None


def half_covered(canvas: np.ndarray, k: int) -> np.ndarray:
    """Whether each k x k block of a boolean image (both sides whole multiples of k) has at least half
    of its pixels True, from exact counts. A bool is one byte holding 0 or 1, so the set bits of eight
    of them read as one 64-bit word are their count (`np.bitwise_count`, numpy >= 2): ~10x faster
    than summing the booleans block by block, the same counts."""
    h, w = canvas.shape
    if k % 8 == 0 and canvas.flags.c_contiguous and hasattr(np, "bitwise_count"):
        per8 = np.bitwise_count(canvas.view(np.uint64))  # (h, w / 8): the True pixels of each 8
        counts = per8.reshape(h // k, k, w // k, k // 8).sum(axis=(1, 3), dtype=np.int64)
    else:
        counts = canvas.reshape(h // k, k, w // k, k).sum(axis=(1, 3))
    return 2 * counts >= k * k


def people_mask_at(people: list[PersonDetection], width: int, height: int,
                   size: tuple[int, int]) -> np.ndarray | None:
    """The people's mask as the focus propagation takes it (None when nobody has a mask pixel): the
    union at the frame's resolution, or, when the frame is a whole multiple of the grid `size` = (w,
    h) (1280x720 -> 160x90), straight at the grid's: the cells whose own block of frame pixels is at
    least half covered. The propagation keeps only that (an area resize, then >= 0.5), and block
    counts are exact, so the result is the same; only the blocks round the people are looked at."""
    mw, mh = size
    k = width // mw
    if k < 1 or k * mw != width or k * mh != height:
        return people_mask(people, width, height)
    rects = []
    for p in people:
        ox, oy = int(p.mask_origin_xy[0]), int(p.mask_origin_xy[1])
        h, w = p.mask.shape
        x0, y0, x1, y1 = max(ox, 0), max(oy, 0), min(ox + w, width), min(oy + h, height)
        if x1 > x0 and y1 > y0:
            rects.append((p, ox, oy, x0, y0, x1, y1))
    if not rects:
        return None
    bx0, by0 = min(r[3] for r in rects) // k * k, min(r[4] for r in rects) // k * k
    bx1, by1 = -(-max(r[5] for r in rects) // k) * k, -(-max(r[6] for r in rects) // k) * k
    canvas = np.zeros((by1 - by0, bx1 - bx0), dtype=bool)
    for p, ox, oy, x0, y0, x1, y1 in rects:
        canvas[y0 - by0:y1 - by0, x0 - bx0:x1 - bx0] |= p.mask[y0 - oy:y1 - oy, x0 - ox:x1 - ox]
    if not canvas.any():
        return None
    half = half_covered(canvas, k)
    if not half.any():  # people too small to cover half a cell: the propagation sees the full mask
        return people_mask(people, width, height)
    out = np.zeros((mh, mw), dtype=bool)
    out[by0 // k:by1 // k, bx0 // k:bx1 // k] = half
    return out


def _centre_inside(a: PersonDetection, b: PersonDetection) -> bool:
    """Is the centre of box a inside box b?"""
    cx, cy = (a.box_xyxy[0] + a.box_xyxy[2]) / 2, (a.box_xyxy[1] + a.box_xyxy[3]) / 2
    return bool(b.box_xyxy[0] <= cx <= b.box_xyxy[2] and b.box_xyxy[1] <= cy <= b.box_xyxy[3])


class Detector:
    """People, skeletons and an in-focus map per frame. Not thread-safe: one caller at a time."""

    def __init__(self, cfg: DetectorConfig | None = None, *, backend=None) -> None:
        self.cfg = (cfg or DetectorConfig()).validate()
        if self.cfg.cv_threads > 0:
            cv2.setNumThreads(self.cfg.cv_threads)
        if self.cfg.keep_freed_memory:
            allocator.keep_freed_memory()
        self.backend = backend if backend is not None else make_backend(self.cfg)
        self.focus = FocusEstimator(self.cfg) if self.cfg.focus else None
        self.fallback = None
        if self.cfg.person_fallback == "hog":
            from cinetransfer.services.detector.hog_people import HogPeople

            self.fallback = HogPeople(self.cfg)
        self._prev_shot: tuple[str, int, np.ndarray] | None = None  # (source, frame index, signature)
        self.motion = (CameraMotionTracker(self.cfg.camera_hfov_deg, edge_tracks=self.cfg.camera_motion_edge_tracks)
                       if self.cfg.camera_motion else None)
        self._pool = (cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="focus")
                      if self.cfg.threads > 1 else None)

    @property
    def name(self) -> str:
        return getattr(self.backend, "name", "?")

    @property
    def unavailable(self) -> str:
        """Why the configured backend is not the one running ('' when it is: no fallback)."""
        return str(getattr(self.backend, "unavailable", "") or "")

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        close = getattr(self.backend, "close", None)
        if close is not None:
            close()

    def __enter__(self) -> "Detector":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reset(self) -> None:
        """Forget temporal state (tracking) before an unrelated sequence."""
        self._prev_shot = None
        if self.motion is not None:
            self.motion.reset()
        reset = getattr(self.backend, "reset", None)
        if reset is not None:
            reset()

    # ------------------------------------------------------------------ one frame
    def analyse(self, image_bgr: np.ndarray, stamp_ns: int) -> tuple[list[PersonDetection], list[Skeleton],
                                                                    FocusResult | None]:
        """People, skeletons and focus of one BGR frame."""
        head = self._head(image_bgr, stamp_ns, refine=True)
        return head.people, head.skeletons, self._focus_of(head)

    def _head(self, image_bgr: np.ndarray, stamp_ns: int, *, refine: bool,
              side_pool: cf.Executor | None = None) -> "_Head":
        """The part of a frame that the next frame's pose depends on (the pose backend's tracking), with
        what needs no pose: people, skeletons, the focus map's edge evidence, the colour signature.

        The focus map's edge stage and the colour signature start at once in the worker thread (or
        `side_pool`: a stream's tail thread) beside the pose backend. `refine`: the caller
        refines the people's masks meanwhile too and waits for that side work; else the tail does both
        (`_settled`), so the next frame's pose need not wait for this one's edges. The fallback detector,
        when there is one, starts first (it is the longest job)."""
        if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
            raise ValueError(f"expected a BGR uint8 image (H, W, 3), got {image_bgr.dtype} {image_bgr.shape}")

        def fallback_work():
            return self.fallback.detect(image_bgr) if self.fallback is not None else []

        def side_work():  # everything that does not need the pose result (runs in another thread)
            # one grey frame for the focus edges and the camera motion (~0.6 ms at 1280x720)
            grey = _grey(image_bgr) if self.focus is not None or self.motion is not None else None
            ev = self.focus.measure_edges(grey) if self.focus is not None else None
            return ev, shots.colour_signature(image_bgr), grey

        pool = self._pool
        extra_fut = pool.submit(fallback_work) if pool is not None and self.fallback is not None else None
        side_pool = side_pool if side_pool is not None else pool
        side_fut = side_pool.submit(side_work) if side_pool is not None else None
        try:
            people, skeletons = self.backend.detect(image_bgr, stamp_ns)
            if refine and self.cfg.mask_refine_radius_px > 0:
                people = subject_mask.refine_people(image_bgr, people, skeletons,
                                                    radius=self.cfg.mask_refine_radius_px)
        finally:
            extra = extra_fut.result() if extra_fut is not None else fallback_work()
        if extra:
            people = self._merge_fallback(people, extra)
        if side_fut is not None and not refine:
            return _Head(image_bgr, people, skeletons, None, None, refine, None, side_fut)
        ev, sig, grey = side_fut.result() if side_fut is not None else side_work()
        return _Head(image_bgr, people, skeletons, ev, sig, refine, grey)

    @staticmethod
    def _settled(head: "_Head") -> "_Head":
        """The head with its side work (edges, signature, grey) done."""
        if head.side is None:
            return head
        ev, sig, grey = head.side.result()
        return head._replace(edges=ev, signature=sig, grey=grey, side=None)

    def _refined(self, head: "_Head") -> "_Head":
        """The head with its people's masks refined (snapped to the image's edges, cut to their own
        body). No later frame's pose reads them, so this is tail work; a fallback person has no mask
        and stays as it is."""
        if head.refined or self.cfg.mask_refine_radius_px <= 0:
            return head
        people = subject_mask.refine_people(head.image, head.people, head.skeletons,
                                            radius=self.cfg.mask_refine_radius_px, grey=head.grey)
        return head._replace(people=people, refined=True)

    def _focus_of(self, head: "_Head") -> FocusResult | None:
        """The focus map spread from the edges, inside and outside the people's masks apart."""
        if self.focus is None or head.edges is None:
            return None
        h, w = head.image.shape[:2]
        # at the map's own resolution: the propagation keeps apart whole map pixels
        return self.focus.propagate(head.edges, people_mask_at(head.people, w, h, self.focus.map_size(w, h)))

    def _tail(self, head: "_Head", frame_index: int, stamp_ns: int, source: str, fps: float,
              lens: LensState | None, valid: bool, *, overlap: bool) -> Measurement:
        """The rest of a frame, which no later frame's pose needs: the people's masks refined, the focus
        map, the camera motion (it masks the people out), the shot change, the Measurement. Camera
        motion and shot change depend on the previous frame's tail: tails run in frame order.
        `overlap`: the camera motion runs in the worker thread while this one spreads the focus map."""
        head = self._refined(self._settled(head))

        def motion_of():
            if self.motion is None:
                return None
            return self.motion.update(head.image, head.people, source=source, frame_index=int(frame_index),
                                      lens=lens, grey=head.grey)

        pool = self._pool if overlap else None
        motion_fut = pool.submit(motion_of) if pool is not None else None
        try:
            focus = self._focus_of(head)
        finally:
            motion = motion_fut.result() if motion_fut is not None else motion_of()
        h, w = head.image.shape[:2]
        prev = self._prev_shot
        # Only consecutive frames of one source are compared: after a gap nothing is known.
        change = (shots.shot_change(prev[2], head.signature) if prev is not None and prev[0] == source
                  and prev[1] == int(frame_index) - 1 else float("nan"))
        self._prev_shot = (source, int(frame_index), head.signature)
        return Measurement(shot_change=change, camera_motion=motion, stamp_ns=int(stamp_ns), valid=valid, source=source,
                           frame_index=int(frame_index),
                           fps=float(fps) if fps is not None and math.isfinite(fps) else float("nan"),
                           width=w, height=h, people=head.people, skeletons=head.skeletons,
                           focus_map=focus.as_uint8() if focus is not None else None, lens=lens,
                           detector=self.name)

    def _merge_fallback(self, people: list[PersonDetection], extra: list[PersonDetection]) -> list[PersonDetection]:
        """Add fallback (box-only) people that no pose person already covers; skeleton indices stay valid
        because the additions go after the pose people."""
        from cinetransfer.services.detector.pose_mediapipe import box_iou

        out = list(people)
        for e in sorted(extra, key=lambda p: -p.confidence):
            if e.confidence < self.cfg.min_person_confidence:
                continue
            if all(box_iou(e.box_xyxy, p.box_xyxy) < self.cfg.fallback_overlap and not _centre_inside(p, e)
                   for p in out):
                out.append(e)
        return out

    def process(self, image_bgr: np.ndarray, frame_index: int = 0, stamp_ns: int = 0, *, source: str = "",
                fps: float = float("nan"), lens: LensState | None = None, valid: bool = True) -> Measurement:
        """One Measurement for one BGR frame (an empty one, not an error, when nobody is there)."""
        head = self._head(image_bgr, stamp_ns, refine=True)
        return self._tail(head, frame_index, stamp_ns, source, fps, lens, valid, overlap=True)

    #: tails queued or running at once when streaming (`FrameStream`): with two, the tail thread has the
    #: next one ready when it finishes one, and a frame's pose never waits for the tail before the last
    TAILS_IN_FLIGHT = 2

    def process_frames(self, frames: Iterable[SourceFrame], *, source: str | None = None) -> Iterator[Measurement]:
        """Measurements of a sequence of frames, in order: the same as `process` on each, but frame k's
        tail (mask refinement, focus map, camera motion, Measurement) runs in a thread of its own while
        the next frames' poses run, so both cores stay busy across frames (a frame's pose and tail alone
        leave one idle much of the time); see `FrameStream`. `source` overrides each frame's own source
        name."""
        with FrameStream(self) as stream:
            for f in frames:
                for due in stream.push(f.image, f.index, f.stamp_ns, source=f.source if source is None else source,
                                       fps=f.fps):
                    yield due.result()
            for due in stream.flush():
                yield due.result()

    def process_source(self, path: str, *, start: int = 0, stop: int | None = None,
                       fps: float | None = None) -> Iterator[Measurement]:
        """Measurements of every frame of a video file or image folder (FrameSourceError if unreadable)."""
        yield from self.process_frames(iter_frames(path, start=start, stop=stop, fps=fps), source=str(path))

    def focus_map_scale(self, width: int, height: int) -> float:
        if self.focus is None:
            return float("nan")
        return self.focus.map_size(width, height)[0] / width


class FrameStream:
    """Frames pushed one at a time, in order; their measurements handed back in order, as futures.

    With `threads` 2, frame k's tail (mask refinement, focus map, camera motion, shot change, the
    Measurement: nothing a later pose needs) runs in a thread of its own while the next frames'
    poses run; the frame's focus edges and colour signature run in that thread too, queued when its
    pose starts (before its tail), and no pose waits for them. Tails run one at a time, in frame order (they share the
    camera-motion and shot-change state), so the measurements are those `Detector.process` gives.
    `push` returns the futures now due (finished, or held back `Detector.TAILS_IN_FLIGHT` frames),
    oldest first; `flush` the rest. A frame whose pose fails raises from `push`; a failed tail (or
    focus edge stage) raises from its future's `result()`.
    With `threads` 1 each push measures its frame at once."""

    def __init__(self, det: Detector) -> None:
        self.det = det
        self._tails = (cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="tail")
                       if det._pool is not None else None)
        self._pending: collections.deque[cf.Future] = collections.deque()

    def __enter__(self) -> "FrameStream":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def in_flight(self) -> int:
        return len(self._pending)

    def push(self, image_bgr: np.ndarray, frame_index: int, stamp_ns: int, *, source: str, fps: float,
             lens: LensState | None = None, valid: bool = True) -> list[cf.Future]:
        if self._tails is None:
            done: cf.Future = cf.Future()
            done.set_result(self.det.process(image_bgr, frame_index, stamp_ns, source=source, fps=fps, lens=lens,
                                             valid=valid))
            return [done]
        # the frame's edges and signature go to the tail thread, ahead of its tail: a fourth busy thread
        # on two cores cost ~2.5 ms CPU a frame more (measured) and slowed the caller's crop
        head = self.det._head(image_bgr, stamp_ns, refine=False, side_pool=self._tails)
        due = []
        while self._pending and (self._pending[0].done() or len(self._pending) >= Detector.TAILS_IN_FLIGHT):
            due.append(self._pending.popleft())
            due[-1].exception()  # waits for it: at most TAILS_IN_FLIGHT tails queued or running
        self._pending.append(self._tails.submit(self.det._tail, head, frame_index, stamp_ns, source, fps, lens, valid,
                                                overlap=False))
        return due

    def flush(self) -> list[cf.Future]:
        """The futures of every frame pushed and not yet handed back, finished."""
        due = list(self._pending)
        self._pending.clear()
        cf.wait(due)
        return due

    def close(self) -> None:
        self._pending.clear()
        if self._tails is not None:
            self._tails.shutdown(wait=True)
            self._tails = None
