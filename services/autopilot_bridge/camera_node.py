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
    loop: bool = False  #: restart a file at its end
    realtime: bool = True  #: pace a file at its nominal fps
    fps: float = 0.0  #: override the nominal rate [Hz]; 0 = the source's
    max_frames: int = 0  #: stop after this many frames; 0 = no limit
    queue_len: int = 2  #: reader -> publisher queue (drop-oldest)
    jpeg_quality: int = 0  #: 0 = raw frames (one host), 1..100 = JPEG (radio links)
    width: int = 0  #: resize to this width [px] (height keeps the aspect); 0 = as captured
    focal_length_mm: float = math.nan  #: static lens (NaN = take the lens from VehicleState)
    focus_distance_m: float = math.nan
    f_number: float = math.nan

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
#: flag dest -> CameraConfig field (a flag that was given overrides the node's settings)
_FLAG_FIELDS = {"loop": "loop", "fps": "fps", "max_frames": "max_frames", "queue": "queue_len",
                "jpeg": "jpeg_quality", "width": "width", "focal_length": "focal_length_mm",
                "focus": "focus_distance_m", "f_number": "f_number"}
_FIELD_TYPES = {"loop": bool, "realtime": bool, "fps": float, "max_frames": int, "queue_len": int,
                "jpeg_quality": int, "width": int, "focal_length_mm": float, "focus_distance_m": float,
                "f_number": float}


def settings_fields(d: dict[str, Any]) -> dict[str, Any]:
    """CameraConfig fields from the node's settings (shared/nodeconfig.py): one of device/url/video
    as the source, the other fields by name; unknown keys and values of the wrong kind are refused."""
    unknown = sorted(set(d) - set(_SOURCES) - set(_FIELD_TYPES))
    if unknown:
        allowed = sorted(_SOURCES + tuple(_FIELD_TYPES))
        raise ConfigError(f"camera config: unknown field(s) {unknown}; allowed: {allowed}")
    out: dict[str, Any] = {}
    given = [k for k in _SOURCES if d.get(k) is not None]
    if len(given) > 1:
        raise ConfigError(f"camera config: give one source, not {given}")
    if given:
        out["kind"], out["source"] = given[0], str(d[given[0]])
    for k, t in _FIELD_TYPES.items():
        if k in d:
            out[k] = _typed(k, d[k], t)
    return out


def _typed(name: str, v: Any, t: type) -> Any:
    if t is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"camera.{name}: must be true or false, got {v!r}")
        return v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (t is int and v != int(v)):
        raise ConfigError(f"camera.{name}: must be {'an integer' if t is int else 'a number'}, got {v!r}")
    return t(v)


def config_from_args(args: argparse.Namespace, settings: dict[str, Any]) -> CameraConfig:
    """The node's settings, then the flags that were given."""
    f = settings_fields(settings)
    flag_source = [k for k in _SOURCES if getattr(args, k, None) is not None]
    if flag_source:
        f["kind"], f["source"] = flag_source[0], str(getattr(args, flag_source[0]))
    f.update({field: getattr(args, dest) for dest, field in _FLAG_FIELDS.items() if getattr(args, dest) is not None})
    if args.as_fast_as_possible:
        f["realtime"] = False
    return CameraConfig(**f)


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
    ap.add_argument("--loop", action="store_true", default=None, help="restart a file at its end")
    ap.add_argument("--as-fast-as-possible", action="store_true",
                    help="do not pace a file at its fps (frames may then be dropped)")
    ap.add_argument("--fps", type=float, default=None, help="override the nominal frame rate [Hz]")
    ap.add_argument("--max-frames", type=int, default=None, help="stop after N frames (0 = no limit)")
    ap.add_argument("--queue", type=int, default=None, help="reader queue length (drop-oldest)")
    ap.add_argument("--jpeg", type=int, default=None, metavar="QUALITY", help="publish JPEG of this quality (radio)")
    ap.add_argument("--width", type=int, default=None, help="resize to this width [px]")
    ap.add_argument("--focal-length", type=float, default=None, metavar="MM", help="static lens: focal length")
    ap.add_argument("--focus", type=float, default=None, metavar="M", help="static lens: focus distance")
    ap.add_argument("--f-number", type=float, default=None, help="static lens: f-number")
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
