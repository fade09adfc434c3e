"""`cinetransfer camera`: publish frames from a video device, a stream URL or a file on keys.FRAME.

    cinetransfer camera --device 0                      # /dev/video0
    cinetransfer camera --url rtsp://192.168.1.10:8554/cam --jpeg 85
    cinetransfer camera --video ../shared/data/tos_clip01_640x360.mp4 --loop

With the `mavlink` backend the frames come from here, not from the simulator. A reader thread
pulls frames with OpenCV at the source's own rate (a file is paced at its nominal fps unless
--as-fast-as-possible) into a bounded drop-oldest queue; the node publishes the newest frame, so
a slow network never makes the camera lag behind (drops are counted in Health).

Each Frame carries the lens state it was taken with: the newest VehicleState's lens (the bridge
reports what the vehicle's camera confirmed), unless a static lens is given with --focal-length
/--focus/--f-number (a camera without lens control). A file ends the node (exit 0) unless --loop;
a device or URL that stops delivering is reopened with backoff.
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import logging
import math
import threading
import time
from typing import Any

import numpy as np

from cinetransfer.shared import keys, nodeconfig
from cinetransfer.shared.nodeconfig import setting
from cinetransfer.shared import messages as M
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.node import add_node_arguments, node_from_args

log = logging.getLogger("cinetransfer.camera")
NODE_NAME = "camera"
LENS_MAX_AGE_S = 1.0


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """The camera node."""

    source: str = ""  #: device index ('0'), URL or file path
    kind: str = "video"  #: 'device', 'url' or 'video'
    loop: bool = setting(False, flag="--loop", help="restart a file at its end")
    realtime: bool = setting(True, flag="--as-fast-as-possible",
                             help="do not pace a file at its fps (frames may then be dropped)")
    fps: float = setting(0.0, flag="--fps", unit="Hz", help="override the nominal frame rate; 0 = the source's")
    max_frames: int = setting(0, flag="--max-frames", help="stop after N frames (0 = no limit)")
    queue_len: int = setting(2, flag="--queue", help="reader queue length (drop-oldest)")
    jpeg_quality: int = setting(0, flag="--jpeg", metavar="QUALITY",
                                help="publish JPEG of this quality (radio links); 0 = raw frames (one host)")
    width: int = setting(0, flag="--width", unit="px", help="resize to this width (0 = as captured)")
    #: a static lens (NaN = take the lens from VehicleState)
    focal_length_mm: float = setting(math.nan, flag="--focal-length", unit="mm", help="static lens: focal length")
    focus_distance_m: float = setting(math.nan, flag="--focus", unit="m", help="static lens: focus distance")
    f_number: float = setting(math.nan, flag="--f-number", help="static lens: f-number")

    def __post_init__(self) -> None:
        if self.kind not in ("device", "url", "video") or not self.source:
            raise ConfigError("camera: give exactly one source: --device, --url or --video (settings: "
                              "device, url or video)")
        if not (0 <= self.jpeg_quality <= 100):
            raise ConfigError(f"camera.jpeg_quality (--jpeg): must be 0 (raw) or 1..100, got {self.jpeg_quality}")
        if self.fps < 0 or not math.isfinite(self.fps):
            raise ConfigError(f"camera.fps (--fps): must be a finite number >= 0, got {self.fps}")
        for name, low in (("queue_len", 1), ("max_frames", 0), ("width", 0)):
            if getattr(self, name) < low:
                raise ConfigError(f"camera.{name}: must be >= {low}, got {getattr(self, name)}")
        for name in ("focal_length_mm", "focus_distance_m", "f_number"):
            v = getattr(self, name)
            if not math.isnan(v) and not (math.isfinite(v) and v > 0):
                raise ConfigError(f"camera.{name}: must be a number > 0 (or unset), got {v}")


_SOURCES = ("device", "url", "video")


def config_from_args(args: argparse.Namespace, settings: dict[str, Any]) -> CameraConfig:
    """The node's settings, then the flags that were given: the source is one of device/url/video
    (a source flag replaces the file's), the other fields are the config idiom's
    (shared/nodeconfig.py)."""
    settings = dict(settings)
    allowed = sorted({*_SOURCES, *(f.name for f in dataclasses.fields(CameraConfig))} - {"kind", "source"})
    unknown = sorted(set(settings) - set(allowed))
    if unknown:  # before the source check: a misspelt 'video' is named as such
        raise ConfigError(f"camera config: unknown field(s) {unknown}; allowed: {allowed}")
    given = [k for k in _SOURCES if settings.get(k) is not None]
    if len(given) > 1:
        raise ConfigError(f"camera config: give one source, not {given}")
    kind, source = (given[0], str(settings[given[0]])) if given else ("video", "")
    for k in _SOURCES:
        settings.pop(k, None)
    flag_source = [k for k in _SOURCES if getattr(args, k, None) is not None]
    if flag_source:
        kind, source = flag_source[0], str(getattr(args, flag_source[0]))
    return nodeconfig.config_from_args(CameraConfig, args, NODE_NAME, base=CameraConfig(source=source, kind=kind),
                                       section=settings)


class FrameReader:
    """Reads frames in a thread into a bounded drop-oldest queue."""

    def __init__(self, cfg: CameraConfig) -> None:
        self.cfg = cfg
        self.q: collections.deque[tuple[int, int, np.ndarray]] = collections.deque(maxlen=cfg.queue_len)
        self.cond = threading.Condition()
        self.stop_evt = threading.Event()
        self.done = False  # the source ended (file without --loop) or failed for good
        self.read = 0
        self.dropped = 0
        self.reopens = 0
        self.fps = math.nan
        self.error = ""
        self.thread: threading.Thread | None = None

    def _open(self) -> Any:
        import cv2

        src: Any = int(self.cfg.source) if self.cfg.kind == "device" else self.cfg.source
        cap = cv2.VideoCapture(src)
        if not cap.isOpened():
            raise OSError(f"cannot open {self.cfg.kind} {self.cfg.source!r}")
        fps = self.cfg.fps or float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if fps > 0 and math.isfinite(fps) else math.nan
        return cap

    def start(self) -> None:
        cap = self._open()  # fail early (before announcing readiness)
        self.thread = threading.Thread(target=self._run, args=(cap,), name="camera-reader", daemon=True)
        self.thread.start()

    def _put(self, item: tuple[int, int, np.ndarray]) -> None:
        with self.cond:
            if len(self.q) == self.q.maxlen:
                self.dropped += 1
            self.q.append(item)
            self.read += 1
            self.cond.notify_all()

    def _run(self, cap: Any) -> None:
        import cv2

        index = 0
        t_start = time.monotonic()
        backoff = 0.5
        try:
            while not self.stop_evt.is_set():
                if self.cfg.max_frames and index >= self.cfg.max_frames:
                    break
                ok, img = cap.read()
                if not ok or img is None:
                    if self.cfg.kind == "video":
                        if not self.cfg.loop or index == 0:
                            break
                        cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                        continue
                    # a device / stream that stopped: reopen with backoff
                    self.error = f"{self.cfg.source}: no frame, reopening"
                    cap.release()
                    if self.stop_evt.wait(backoff):
                        break
                    backoff = min(backoff * 2, 5.0)
                    try:
                        cap = self._open()
                        self.reopens += 1
                    except OSError as e:
                        self.error = str(e)
                    continue
                backoff = 0.5
                if self.cfg.width and img.shape[1] != self.cfg.width:
                    h = max(1, round(img.shape[0] * self.cfg.width / img.shape[1]))
                    img = cv2.resize(img, (self.cfg.width, h), interpolation=cv2.INTER_AREA)
                if self.cfg.kind == "video" and self.cfg.realtime and math.isfinite(self.fps):
                    due = t_start + index / self.fps
                    if self.stop_evt.wait(max(0.0, due - time.monotonic())):
                        break
                self._put((index, M.now_ns(), np.ascontiguousarray(img)))
                index += 1
        finally:
            cap.release()
            with self.cond:
                self.done = True
                self.cond.notify_all()

    def get(self, timeout: float) -> tuple[int, int, np.ndarray] | None:
        """The newest frame (older ones are dropped), or None after `timeout` / at the end."""
        with self.cond:
            if not self.q and not self.done:
                self.cond.wait(timeout)
            if not self.q:
                return None
            item = self.q.pop()
            self.dropped += len(self.q)
            self.q.clear()
            return item

    def stop(self) -> None:
        self.stop_evt.set()
        if self.thread is not None and self.thread.is_alive():
            self.thread.join(2.0)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cinetransfer camera", description="publish camera frames on Zenoh")
    nodeconfig.add_config_arguments(ap, NODE_NAME)
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--device", help="video device index (e.g. 0)")
    src.add_argument("--url", help="stream URL (rtsp://, http://, udp://; anything OpenCV/FFmpeg reads)")
    src.add_argument("--video", help="video file")
    nodeconfig.add_settings_arguments(ap, CameraConfig, "camera")
    add_node_arguments(ap)
    return ap


def main(argv: list[str]) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        cfg = config_from_args(args, nodeconfig.args_section(args, NODE_NAME))
    except ConfigError as e:
        return report_config_error(e, "cinetransfer camera")
    kind = cfg.kind
    node = node_from_args(NODE_NAME, args, config=cfg)
    reader = FrameReader(cfg)
    static = any(math.isfinite(v) for v in (cfg.focal_length_mm, cfg.focus_distance_m, cfg.f_number))
    static_lens = M.LensState(focal_length_mm=cfg.focal_length_mm, focus_distance_m=cfg.focus_distance_m,
                              f_number=cfg.f_number)
    with node:
        try:
            reader.start()
        except OSError as e:
            log.error("%s", e)
            return 1
        pub = node.publisher(keys.FRAME, jpeg_quality=cfg.jpeg_quality or None)
        states = None if static else node.subscribe(keys.VEHICLE_STATE, maxlen=1)
        lens: M.LensState | None = static_lens if static else None
        lens_rx = -math.inf
        node.ready()
        log.info("publishing %s %s at %.2f fps", kind, cfg.source, reader.fps)
        try:
            while node.running:
                item = reader.get(0.1)
                if item is None:
                    if reader.done:
                        break
                    continue
                index, stamp, img = item
                if states is not None:
                    vs = states.latest()
                    if vs is not None:
                        lens, lens_rx = vs.lens, time.monotonic()
                    elif time.monotonic() - lens_rx > LENS_MAX_AGE_S:
                        lens = None  # unknown: the vehicle's state is stale
                with node.timed():
                    pub.put(M.Frame(stamp_ns=stamp, valid=True, source=cfg.source, index=index, fps=reader.fps,
                                    image=img, lens=lens))
                node.counters.update(frames_read=reader.read, frames_dropped=reader.dropped, reopens=reader.reopens,
                                     source_error=reader.error)
        finally:
            reader.stop()
    log.info("done: %d frames read, %d dropped", reader.read, reader.dropped)
    return 0
