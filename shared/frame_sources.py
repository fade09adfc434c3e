"""Frame sources: a video file (anything OpenCV decodes) or a folder of images.

(The third source, the `ct/{rig}/camera/frame` topic, lives in service.py: it needs Zenoh.)

    for f in iter_frames("clip.mp4"):       # SourceFrame(index, stamp_ns, image BGR, fps, source)
        ...

A file that cannot be opened or yields no frame raises `FrameSourceError` with a clear message.
A video that breaks off part-way (truncated or corrupt tail) ends the iteration after the last
decodable frame and logs how many frames were expected; what was decoded is kept.
Stamps of file frames are media time: stamp_ns = round(index * 1e9 / fps).
"""
from __future__ import annotations

import hashlib
import logging
import os
import queue
import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from cinetransfer.shared.messages import SourceInfo

log = logging.getLogger("cinetransfer.detector")

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm")
DEFAULT_IMAGE_FPS = 24.0


class FrameSourceError(RuntimeError):
    """A frame source cannot be opened or decoded."""


@dataclass(frozen=True, eq=False)
class SourceFrame:
    index: int  # frame index within the source (0-based)
    stamp_ns: int  # media time of the frame [ns] (index / fps)
    image: np.ndarray  # BGR uint8 (H, W, 3)
    fps: float  # nominal frame rate of the source [Hz]
    source: str  # path of the source


def _natural_key(p: Path) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]


def list_images(folder: str | os.PathLike) -> list[Path]:
    d = Path(folder)
    return sorted((p for p in d.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()),
                  key=_natural_key)


def _open_video(path: Path) -> cv2.VideoCapture:
    if not path.exists():
        raise FrameSourceError(f"{path}: no such file")
    if not path.is_file():
        raise FrameSourceError(f"{path}: not a regular file")
    if not os.access(path, os.R_OK):
        raise FrameSourceError(f"{path}: permission denied")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise FrameSourceError(f"{path}: OpenCV cannot open it as a video (unknown or corrupt format)")
    return cap


def _fps_of(cap: cv2.VideoCapture) -> float:
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    return fps if np.isfinite(fps) and 0.5 <= fps <= 1000.0 else DEFAULT_IMAGE_FPS


def probe(path: str | os.PathLike, *, hash_file: bool = False, fps: float | None = None) -> SourceInfo:
    """Width, height, fps and frame count of a video file or image folder (raises FrameSourceError)."""
    p = Path(path)
    sha = ""
    if p.is_dir():
        files = list_images(p)
        if not files:
            raise FrameSourceError(f"{p}: folder holds no images ({', '.join(IMAGE_EXTENSIONS)})")
        img = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
        if img is None:
            raise FrameSourceError(f"{files[0]}: unreadable image")
        return SourceInfo(path=str(p), width=img.shape[1], height=img.shape[0],
                          fps=float(fps or DEFAULT_IMAGE_FPS), n_frames=len(files), sha256="")
    cap = _open_video(p)
    try:
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        f = float(fps) if fps else _fps_of(cap)
        if w <= 0 or h <= 0:
            ok, img = cap.read()
            if not ok or img is None:
                raise FrameSourceError(f"{p}: no decodable frame")
            h, w = img.shape[:2]
    finally:
        cap.release()
    if hash_file:
        hh = hashlib.sha256()
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                hh.update(chunk)
        sha = hh.hexdigest()
    return SourceInfo(path=str(p), width=w, height=h, fps=f, n_frames=max(n, 0), sha256=sha)


def _iter_video(p: Path, start: int, stop: int | None, fps_override: float | None) -> Iterator[SourceFrame]:
    cap = _open_video(p)
    try:
        fps = float(fps_override) if fps_override else _fps_of(cap)
        expected = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        if start > 0:
            cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        i = start
        while stop is None or i < stop:
            ok, img = cap.read()
            if not ok or img is None:
                break
            yield SourceFrame(i, int(round(i * 1e9 / fps)), img, fps, str(p))
            i += 1
        if i == start:
            raise FrameSourceError(f"{p}: no decodable frame (corrupt or empty video)")
        if stop is None and expected > 0 and i < expected - 1:
            log.warning("%s: decoding stopped after %d of %d frames (truncated or corrupt); keeping what "
                        "was decoded", p, i, expected)
    finally:
        cap.release()


def _iter_images(p: Path, start: int, stop: int | None, fps_override: float | None) -> Iterator[SourceFrame]:
    files = list_images(p)
    if not files:
        raise FrameSourceError(f"{p}: folder holds no images ({', '.join(IMAGE_EXTENSIONS)})")
    fps = float(fps_override or DEFAULT_IMAGE_FPS)
    n_ok = 0
    for i, f in enumerate(files[start:stop], start=start):
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None:
            log.warning("%s: unreadable image, skipped", f)
            continue
        n_ok += 1
        yield SourceFrame(i, int(round(i * 1e9 / fps)), img, fps, str(f))
    if n_ok == 0:
        raise FrameSourceError(f"{p}: none of its images could be read")


def iter_frames(path: str | os.PathLike, *, start: int = 0, stop: int | None = None, fps: float | None = None,
                prefetch: int = 4) -> Iterator[SourceFrame]:
    """Frames of a video file or image folder, in order. `prefetch` > 0 decodes in a background
    thread (OpenCV releases the GIL), overlapping decoding with processing."""
    p = Path(path)
    if not p.exists():
        raise FrameSourceError(f"{p}: no such file or folder")
    gen = _iter_images(p, start, stop, fps) if p.is_dir() else _iter_video(p, start, stop, fps)
    if prefetch <= 0:
        yield from gen
        return
    # Fail fast (in the caller's thread) on a source that cannot be opened.
    first = next(gen)
    yield from _prefetched(first, gen, prefetch)


_END = object()


class _Prefetcher:
    """Reads frames ahead in a thread of its own into a bounded queue; a decoder failure is handed
    to the consumer, and closing stops and unblocks the reader."""

    def __init__(self, gen: Iterator[SourceFrame], depth: int) -> None:
        self.q: queue.Queue = queue.Queue(maxsize=depth)
        self.stop = threading.Event()
        self.gen = gen
        self.thread = threading.Thread(target=self._work, name="frame-reader", daemon=True)

    def _put(self, item: object) -> bool:
        while not self.stop.is_set():
            try:
                self.q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _work(self) -> None:
        try:
            for item in self.gen:
                if not self._put(item):
                    break
            else:
                self._put(_END)
        except Exception as e:  # hand any decoder failure to the consumer
            self._put(e)
        finally:
            self.gen.close()

    def items(self) -> Iterator[SourceFrame]:
        while True:
            item = self.q.get()
            if item is _END:
                return
            if isinstance(item, Exception):
                raise item
            yield item

    def close(self) -> None:
        self.stop.set()
        while True:  # unblock the reader so it can exit
            try:
                self.q.get_nowait()
            except queue.Empty:
                break
        self.thread.join(timeout=2.0)


def _prefetched(first: SourceFrame, gen: Iterator[SourceFrame], depth: int) -> Iterator[SourceFrame]:
    reader = _Prefetcher(gen, depth)
    yield first
    reader.thread.start()
    try:
        yield from reader.items()
    finally:
        reader.close()
