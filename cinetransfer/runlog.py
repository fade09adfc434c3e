"""Run recordings as MCAP (`run.mcap`): every message of the rig on its key, in forms that Foxglove,
Rerun and the `mcap` library read, and that `cinetransfer replay` turns back into the very
messages that were sent.

What goes where (`views`):

- a message of ours on key K -> channel K, JSON (`json`), with the JSON schema generated from
  shared/messages.py (`cinetransfer.<Type>`, shared/jsonmsg.py);
- a `Frame` on key K -> channel K as foxglove.CompressedVideo (H.264, one frame per message,
  no B-frames, a keyframe with SPS/PPS every second) in a recording, or foxglove.CompressedImage
  (JPEG) in the live view and for odd-sized images; its other fields (index, lens, stamps) on
  K/info (`cinetransfer.FrameInfo`); a frame with a known lens also gives K/calibration
  (foxglove.CameraCalibration, pinhole);
- vehicle, gimbal/camera and subject poses -> foxglove.FrameTransform on ct/RIG/tf/{drone,camera,
  subject} (frames `world` -> `drone`, `world` -> `camera` (optical: x right, y down, z forward),
  `world` -> `subject`), so the 3-D panel shows the drone, the camera frustum and the subject;
- a payload our codec cannot decode -> channel K with message encoding `cinetransfer-codec` and
  no schema, bytes as they travelled (a recording keeps even what the recorder could not read).

Derived channels (tf, calibration, info) carry the channel metadata `cinetransfer.role`; replay
skips tf and calibration and joins info with its image to rebuild the Frame.

Log time is the receive time (wall clock, as replay's timing wants); publish time is the message's
own `stamp_ns` (simulation time in lockstep). The writer closes a chunk at least every
`flush_s` wall seconds, so a run killed hard keeps everything but its last second; a run that
ends normally has the full summary and index.
"""
from __future__ import annotations

import contextlib
import io
import json
import logging
import math
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Collection, Iterator

import numpy as np

from cinetransfer import diskroom
from cinetransfer.shared import codec, jsonmsg, keys
from cinetransfer.shared import messages as M

log = logging.getLogger("cinetransfer.runlog")

FORMAT = "cinetransfer-run"
FORMAT_VERSION = 1
META_NAME = "cinetransfer"
RAW_ENCODING = "cinetransfer-codec"
ROLE = "cinetransfer.role"  # channel metadata: message, frame-video, frame-image, frame-info, derived, raw
#: JPEG quality of frames in the live view (and of odd-sized frames in a recording)
JPEG_QUALITY = 75
#: H.264 of recorded frames: x264 constant quality, a keyframe every KEYFRAME_S seconds (seeking)
VIDEO_CRF = 23
KEYFRAME_S = 1.0
#: x264 on top of veryfast for recorded frames: a diamond motion search and one sub-pixel refinement
#: (the report's comparison video's choice): output.mp4 of the README take ~23 % less encoding CPU,
#: 19-29 % more bytes at the same CRF, no lower PSNR (docs/transfer.md)
VIDEO_X264_PARAMS = "me=dia:subme=1"


class RunFormatError(ValueError):
    """Not a cinetransfer recording (not MCAP, a foreign MCAP), or a damaged one."""


@dataclass(frozen=True)
class View:
    """One record to log: a topic, how it is encoded, the bytes."""

    topic: str
    schema_name: str
    schema_encoding: str  # 'jsonschema' | 'protobuf' | '' (raw)
    schema_data: bytes
    message_encoding: str  # 'json' | 'protobuf' | RAW_ENCODING
    data: bytes
    role: str
    stamp_ns: int = 0


# --------------------------------------------------------------------------- translation
def _rig_of(key: str) -> str:
    parts = key.split("/")
    return parts[1] if len(parts) >= 2 else "rig"


def _json_view(topic: str, msg: Any, role: str = "message") -> View:
    cls = type(msg)
    return View(topic, jsonmsg.schema_name(cls), "jsonschema", _schema_bytes(cls), "json",
                json.dumps(jsonmsg.to_json(msg), separators=(",", ":"), allow_nan=False).encode(), role,
                int(getattr(msg, "stamp_ns", 0)))


_SCHEMA_CACHE: dict[type, bytes] = {}


def _schema_bytes(cls: type) -> bytes:
    if cls not in _SCHEMA_CACHE:
        _SCHEMA_CACHE[cls] = json.dumps(jsonmsg.message_schema(cls)).encode()
    return _SCHEMA_CACHE[cls]


def _fox(topic: str, obj: Any, stamp_ns: int, role: str = "derived") -> View:
    s = type(obj).get_schema()
    return View(topic, s.name, s.encoding, bytes(s.data), "protobuf", obj.encode(), role, stamp_ns)


def _ts(stamp_ns: int) -> Any:
    from foxglove.messages import Timestamp

    return Timestamp(sec=int(stamp_ns // 10**9), nsec=int(stamp_ns % 10**9))


def _ypr_matrix(ypr: np.ndarray) -> np.ndarray:
    """Body (x forward, y left, z up) to world: yaw about z, pitch positive up, roll about x."""
    y, p, r = (float(v) for v in ypr)
    cy, sy, cp, sp, cr, sr = math.cos(y), math.sin(y), math.cos(-p), math.sin(-p), math.cos(r), math.sin(r)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


#: camera body (forward, left, up) -> optical (right, down, forward), as columns
_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _transform(parent: str, child: str, pos: np.ndarray, rot: np.ndarray, stamp_ns: int) -> Any:
    from foxglove.messages import FrameTransform, Quaternion, Vector3
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    p = [float(v) if math.isfinite(float(v)) else 0.0 for v in pos]
    return FrameTransform(timestamp=_ts(stamp_ns), parent_frame_id=parent, child_frame_id=child,
                          translation=Vector3(x=p[0], y=p[1], z=p[2]),
                          rotation=Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)))


def _finite(a: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(a), a, 0.0)


class H264Stream:
    """One topic's frames as an H.264 elementary stream (Annex B), one packet per frame, at once
    (x264 zerolatency: no lookahead, no B-frames; SPS/PPS repeated on every keyframe)."""

    def __init__(self, width: int, height: int, fps: float, crf: int = VIDEO_CRF) -> None:
        from fractions import Fraction

        import av

        self._av = av
        fps = fps if math.isfinite(fps) and fps > 0 else 24.0
        self.ctx = av.CodecContext.create("libx264", "w")
        self.ctx.width, self.ctx.height, self.ctx.pix_fmt = width, height, "yuv420p"
        self.ctx.time_base = Fraction(1, 1000)
        self.ctx.options = {"preset": "veryfast", "tune": "zerolatency", "crf": str(crf), "bf": "0",
                            "g": str(max(1, int(round(KEYFRAME_S * fps)))), "x264-params": VIDEO_X264_PARAMS}
        self.shape = (height, width)
        self.n = 0

    def encode(self, img: np.ndarray) -> bytes:
        f = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="bgr24")
        f.pts = self.n
        self.n += 1
        return b"".join(bytes(p) for p in self.ctx.encode(f))


def _frame_views(key: str, frame: M.Frame, jpeg_quality: int, streams: dict[str, H264Stream] | None = None,
                 packet: bytes | None = None) -> list[View]:
    import cv2
    from foxglove.messages import CameraCalibration, CompressedImage, CompressedVideo

    img = np.asarray(frame.image)
    frame_id = "camera" if key.endswith("/camera/frame") else key.split("/")[2]
    h, w = img.shape[:2]
    if streams is not None and h % 2 == 0 and w % 2 == 0 and h and w:
        data = packet if packet is not None else _encoded(streams, key, img, frame.fps)
        if packet is not None:  # the stream is another encoder's now: an own one must start afresh (keyframe)
            streams.pop(key, None)
        image = _fox(key, CompressedVideo(timestamp=_ts(frame.stamp_ns), frame_id=frame_id, data=data,
                                          format="h264"), frame.stamp_ns, role="frame-video")
    else:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise codec.EncodeError("JPEG encoding failed")
        image = _fox(key, CompressedImage(timestamp=_ts(frame.stamp_ns), frame_id=frame_id, data=buf.tobytes(),
                                          format="jpeg"), frame.stamp_ns, role="frame-image")
    out = [image, _json_view(key + "/info", frame, role="frame-info")]
    lens = frame.lens
    if lens is not None and img.ndim == 3 and all(math.isfinite(v) and v > 0 for v in (
            lens.focal_length_mm, lens.sensor_width_mm)):
        h, w = img.shape[:2]
        fx = lens.focal_length_mm / lens.sensor_width_mm * w
        fy = lens.focal_length_mm / lens.sensor_height_mm * h if math.isfinite(lens.sensor_height_mm) and \
            lens.sensor_height_mm > 0 else fx
        cx, cy = w / 2.0, h / 2.0
        cal = CameraCalibration(timestamp=_ts(frame.stamp_ns), frame_id=frame_id, width=w, height=h,
                                distortion_model="plumb_bob", D=[0.0] * 5,
                                K=[fx, 0, cx, 0, fy, cy, 0, 0, 1], R=[1, 0, 0, 0, 1, 0, 0, 0, 1],
                                P=[fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0])
        out.append(_fox(key + "/calibration", cal, frame.stamp_ns))
    return out


def _encoded(streams: dict[str, H264Stream], key: str, img: np.ndarray, fps: float) -> bytes:
    st = streams.get(key)
    if st is None or st.shape != img.shape[:2]:
        st = streams[key] = H264Stream(img.shape[1], img.shape[0], fps)
    return st.encode(img)


def views(key: str, payload: bytes, *, jpeg_quality: int = JPEG_QUALITY,
          video: dict[str, H264Stream] | None = None, packet: bytes | None = None, msg: Any = None) -> list[View]:
    """What one message of the rig becomes in a recording or the live view (see the module doc).
    `video`: the H.264 streams of the frame topics (a recording's; None = JPEG frames); `packet`:
    this frame's H.264, encoded already by the caller as the next frame of the topic's stream;
    `msg`: the payload decoded already by the caller (None: decoded here)."""
    if msg is None:
        try:
            msg = codec.decode(payload)
        except codec.DecodeError:
            return [View(key, "", "", b"", RAW_ENCODING, bytes(payload), "raw")]
    rig = _rig_of(key)
    tf = f"{keys.ROOT}/{rig}/tf"
    if isinstance(msg, M.Frame):
        return _frame_views(key, msg, jpeg_quality, video, packet)
    out = [_json_view(key, msg)]
    if isinstance(msg, M.VehicleState):
        pos = _finite(msg.position_m)
        out.append(_fox(f"{tf}/drone", _transform("world", "drone", pos, _ypr_matrix(_finite(msg.attitude_ypr_rad)),
                                                  msg.stamp_ns), msg.stamp_ns))
        out.append(_fox(f"{tf}/camera", _transform("world", "camera", pos,
                                                   _ypr_matrix(_finite(msg.camera_ypr_rad)) @ _OPTICAL,
                                                   msg.stamp_ns), msg.stamp_ns))
    elif isinstance(msg, M.SubjectState) and msg.joints_m.size:
        good = np.isfinite(msg.joints_m).all(axis=1)
        if good.any():
            centre = msg.joints_m[good].mean(axis=0)
            out.append(_fox(f"{tf}/subject", _transform("world", "subject", centre, np.eye(3), msg.stamp_ns),
                            msg.stamp_ns))
    return out


# --------------------------------------------------------------------------- writing
class RunWriter:
    """Writes run.mcap; `write` takes a key and the payload as it travelled. Not thread-safe:
    the recorder's worker thread is its only user."""

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None, *, jpeg_quality: int = JPEG_QUALITY,
                 flush_s: float = 1.0, chunk_size: int = 4 << 20, video: bool = True, hold_bytes: int = 0) -> None:
        """`hold_bytes`: disk room kept allocated past the file's end (cinetransfer/diskroom.py), renewed
        after every chunk, for the next chunk and the summary: writing never runs into a full disk,
        a renewal that cannot be had raises OSError (ENOSPC) with the file intact and closable."""
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        self._w = Writer(self._f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile="", library="cinetransfer")
        self._w.add_metadata(META_NAME, {"format": FORMAT, "version": str(FORMAT_VERSION),
                                         "meta": json.dumps(meta or {}, default=str)})
        self._f.flush()
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self._seq: dict[int, int] = {}
        self.jpeg_quality = jpeg_quality
        self._video: dict[str, H264Stream] | None = {} if video else None
        self.flush_s = flush_s
        self._last_flush = time.monotonic()
        self.count = 0  #: messages of the rig written (each may have several views)
        self.errors = 0  #: messages kept as raw bytes because they could not be translated
        self.closed = False
        self.hold_bytes = hold_bytes
        try:
            #: room is held past the end (False: none asked, or this file system cannot)
            self.holding = bool(hold_bytes) and diskroom.hold(self._f.fileno(), hold_bytes, at=self._f.tell(),
                                                              name=str(self.path))
        except OSError:
            self._f.close()
            raise
        self._held_at = self._f.tell()

    def _channel(self, v: View) -> int:
        ck = (v.topic, v.schema_name, v.message_encoding)
        cid = self._channels.get(ck)
        if cid is None:
            sid = 0
            if v.schema_encoding:
                sk = (v.schema_name, v.schema_encoding)
                sid = self._schemas.get(sk) or self._w.register_schema(v.schema_name, v.schema_encoding, v.schema_data)
                self._schemas[sk] = sid
            cid = self._w.register_channel(v.topic, v.message_encoding, sid, {ROLE: v.role})
            self._channels[ck] = cid
        return cid

    def write(self, key: str, payload: bytes, t_ns: int | None = None, *, video_packet: bytes | None = None,
              msg: Any = None) -> None:
        """`video_packet`: a frame's H.264 from the caller's encoder (the recorder's output.mp4, one
        encode for both), the next packet of that encoder's stream: a stream that switches encoder
        must begin again at a keyframe, which the caller sees to. `msg`: `payload` decoded already
        by the caller (the recorder decodes the take's frames and truths: not twice)."""
        t = time.time_ns() if t_ns is None else t_ns
        try:
            vs = views(key, payload, jpeg_quality=self.jpeg_quality, video=self._video, packet=video_packet, msg=msg)
        except Exception as e:  # noqa: BLE001 - a message we cannot translate is still kept, as it travelled
            self.errors += 1
            if self.errors <= 5 or self.errors % 1000 == 0:
                log.warning("recording %s as raw bytes (%d so far): %s: %s", key, self.errors, type(e).__name__, e)
            vs = [View(key, "", "", b"", RAW_ENCODING, bytes(payload), "raw")]
        for v in vs:
            cid = self._channel(v)
            seq = self._seq.get(cid, 0)
            self._seq[cid] = seq + 1
            self._w.add_message(channel_id=cid, log_time=t, data=v.data, publish_time=v.stamp_ns, sequence=seq)
        self.count += 1
        now = time.monotonic()
        if now - self._last_flush >= self.flush_s:
            self.flush()
        self._renew_hold()

    def _renew_hold(self) -> None:
        """Room ahead of the file again once a chunk has gone out (the file only grows by chunks)."""
        end = self._f.tell()
        if self.holding and end != self._held_at:
            diskroom.hold(self._f.fileno(), self.hold_bytes, at=end, name=str(self.path))
            self._held_at = end

    def flush(self) -> None:
        """Close the chunk in progress and push it to the file (an interruption keeps it)."""
        self._w.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._w.finish()
            self._f.flush()
        finally:
            if self.holding:
                with contextlib.suppress(OSError):
                    diskroom.release(self._f.fileno())
            self._f.close()

    def __enter__(self) -> "RunWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------- reading
@dataclass
class RunInfo:
    """What a recording holds (read by `scan`)."""

    path: Path
    meta: dict[str, Any] = field(default_factory=dict)
    complete: bool = True  #: False: no footer (the run was interrupted); messages up to the cut are there
    messages: int = 0
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)  #: topic -> {schema, encoding, count, role}
    bytes: int = 0
    frame_stamps: list[int] = field(default_factory=list)  #: stamps of the camera frames (ct/RIG/camera/frame)
    start_ns: int = 0  #: log time of the first message (0: none)
    end_ns: int = 0  #: log time of the last message

    def duration_s(self) -> float:
        """Wall seconds from the first message to the last (log times)."""
        return (self.end_ns - self.start_ns) / 1e9 if self.messages else 0.0

    @property
    def frames(self) -> int:
        return len(self.frame_stamps)

    def flight_s(self) -> float:
        """Seconds of flight the recording covers: camera frames x their period (the median step
        between consecutive stamps, simulation time in lockstep). Not the span of the stamps: a
        take's simulation restarts at a time zero far ahead of the clock that ran before it."""
        st = np.asarray(self.frame_stamps, np.int64)
        steps = np.diff(st)
        steps = steps[steps > 0]
        return float(len(st) * np.median(steps) / 1e9) if steps.size else 0.0


class _Tell(io.RawIOBase):
    """A file reader that knows how far it has read (to tell a clean end from a cut record)."""

    def __init__(self, f: Any) -> None:
        self.f, self.pos = f, 0

    def readable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        n = self.f.readinto(b)
        self.pos += n or 0
        return n


def _records(path: Path, salvage: bool) -> Iterator[Any]:
    """MCAP records in file order, chunks opened. A file that stops at a record boundary without a
    footer (interrupted run) ends quietly; one cut inside a record raises RunFormatError, unless
    `salvage` (then everything before the cut is yielded and a warning logged)."""
    from mcap.records import Chunk, Footer
    from mcap.stream_reader import StreamReader, breakup_chunk

    size = path.stat().st_size
    with open(path, "rb", buffering=0) as raw:
        t = _Tell(raw)
        reader = StreamReader(io.BufferedReader(t, buffer_size=1), emit_chunks=True, record_size_limit=1 << 31)
        boundary = 0
        it = reader.records
        while True:
            try:
                rec = next(it)
            except StopIteration:
                return
            except Exception as e:  # noqa: BLE001 - judged by _end_of_stream: zstd and friends raise their own types
                _end_of_stream(e, path, salvage, boundary=boundary, size=size, pos=t.pos)
                return
            boundary = t.pos
            if isinstance(rec, Chunk):
                try:
                    yield from breakup_chunk(rec)
                except Exception as e:  # noqa: BLE001
                    _damaged(e, path, salvage, "damaged chunk")
                    return
            else:
                yield rec
            if isinstance(rec, Footer):
                return


def _end_of_stream(e: Exception, path: Path, salvage: bool, *, boundary: int, size: int, pos: int) -> None:
    """The next record could not be read: return if the records end there (an interrupted run
    cut at a record boundary, or `salvage`), else RunFormatError saying where and why."""
    from mcap.exceptions import EndOfFile, InvalidMagic, McapError

    if isinstance(e, InvalidMagic):
        raise RunFormatError(f"{path}: not an MCAP file (bad magic)") from None
    if not isinstance(e, (EndOfFile, McapError, struct.error, ValueError, EOFError)):
        _damaged(e, path, salvage, "damaged MCAP")
        return
    if boundary and boundary >= size:
        return  # interrupted cleanly: no summary, every record complete
    if pos <= 8:
        raise RunFormatError(f"{path}: not an MCAP file ({type(e).__name__})") from None
    msg = (f"{path}: truncated or damaged MCAP: a record is cut at byte {boundary} of {size} "
           f"({type(e).__name__}{': ' + str(e) if str(e) else ''})")
    if not salvage:
        raise RunFormatError(msg + "; `--salvage` keeps the messages before the cut") from None
    log.warning("%s; keeping the messages before it", msg)


def _damaged(e: Exception, path: Path, salvage: bool, what: str) -> None:
    """Garbage inside the file: with `salvage` the records end here (logged), else RunFormatError."""
    if not salvage:
        raise RunFormatError(f"{path}: {what} ({type(e).__name__}: {e})") from None
    log.warning("%s: damaged chunk (%s); keeping the messages before it", path, e)


@dataclass
class _ReadState:
    """What RunReader keeps while it reads (messages, typed, records): schemas and channels so far,
    halves of frames waiting for the other half, protobuf classes and H.264 decoders per topic."""

    schemas: dict[int, Any] = field(default_factory=dict)
    chans: dict[int, Any] = field(default_factory=dict)
    pending_img: dict[tuple[str, int], tuple[int, np.ndarray]] = field(default_factory=dict)
    pending_info: dict[tuple[str, int], M.Frame] = field(default_factory=dict)
    pb_classes: dict[str, Any] = field(default_factory=dict)
    decoders: dict[str, Any] = field(default_factory=dict)
    types_by_schema: dict[str, type] = field(
        default_factory=lambda: {jsonmsg.schema_name(c): c for c in M.MESSAGE_TYPES.values()})


def _wanted(topic: str, role: str, only: Collection[str] | None) -> bool:
    """Whether a channel carries one of the keys `only` (None: every key); a frame's info channel
    is K/info of the frame's key K."""
    if only is None:
        return True
    return (topic[: -len("/info")] if role == "frame-info" else topic) in only


class RunReader:
    """Reads a recording back: `messages()` gives (log_time_ns, key, codec payload) of every
    message of the rig, as replay republishes them. Raises RunFormatError on a file that is not
    a cinetransfer recording or is cut inside a record (unless `salvage`)."""

    def __init__(self, path: str | Path, *, salvage: bool = False) -> None:
        self.path = Path(path)
        self.salvage = salvage
        if not self.path.is_file():
            raise RunFormatError(f"{self.path}: no such file")
        self.info = RunInfo(self.path, bytes=self.path.stat().st_size)
        self.skipped = 0  #: messages left out by messages() because they did not fit their schema
        self._scan()

    def _scan(self) -> None:
        from mcap.records import Channel, Footer, Message, Metadata, Schema

        schemas: dict[int, Schema] = {}
        chans: dict[int, Channel] = {}
        seen_meta = False
        self.info.complete = False
        for rec in _records(self.path, self.salvage):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                chans[rec.id] = rec
                s = schemas.get(rec.schema_id)
                self.info.channels.setdefault(rec.topic, {
                    "schema": s.name if s else "", "encoding": rec.message_encoding,
                    "schema_encoding": s.encoding if s else "", "role": rec.metadata.get(ROLE, ""), "count": 0,
                    "first_ns": 0, "last_ns": 0})
            elif isinstance(rec, Metadata) and rec.name == META_NAME:
                seen_meta = True
                if rec.metadata.get("format") != FORMAT:
                    raise RunFormatError(f"{self.path}: metadata says format {rec.metadata.get('format')!r}, "
                                         f"not {FORMAT!r}")
                try:
                    self.info.meta = json.loads(rec.metadata.get("meta", "{}"))
                except json.JSONDecodeError:
                    self.info.meta = {}
            elif isinstance(rec, Message):
                ch = chans.get(rec.channel_id)
                if ch is None:
                    raise RunFormatError(f"{self.path}: message on unknown channel {rec.channel_id}")
                self._count(self.info.channels[ch.topic], rec.log_time)
                if ch.metadata.get(ROLE) in ("frame-image", "frame-video") and ch.topic.endswith("/camera/frame"):
                    self.info.frame_stamps.append(rec.publish_time)
            elif isinstance(rec, Footer):
                self.info.complete = True
        if not seen_meta:
            names = sorted({c["schema"] for c in self.info.channels.values()})[:5]
            raise RunFormatError(f"{self.path}: an MCAP file, but not a cinetransfer recording (no "
                                 f"'{META_NAME}' metadata; schemas: {', '.join(names) or 'none'})")

    def _count(self, ch: dict[str, Any], t_ns: int) -> None:
        ch["first_ns"] = t_ns if ch["count"] == 0 else min(ch["first_ns"], t_ns)
        ch["last_ns"] = t_ns if ch["count"] == 0 else max(ch["last_ns"], t_ns)
        ch["count"] += 1
        self.info.start_ns = t_ns if self.info.messages == 0 else min(self.info.start_ns, t_ns)
        self.info.end_ns = t_ns if self.info.messages == 0 else max(self.info.end_ns, t_ns)
        self.info.messages += 1

    @property
    def meta(self) -> dict[str, Any]:
        return self.info.meta

    def records(self) -> Iterator[tuple[Any, Any, Any]]:
        """(message record, its channel record, its schema record or None) of every message as
        stored, derived channels included (for tools that show the recording as it is)."""
        st = _ReadState()
        for rec, ch in self._stored(st):
            yield rec, ch, st.schemas.get(ch.schema_id)

    def messages(self, key_prefix: str = "", *,
                 only: Collection[str] | None = None) -> Iterator[tuple[int, str, bytes]]:
        """(log_time_ns, key, payload): our codec bytes for every message of the rig, frames rebuilt
        from their JPEG and info (the image is lossy: JPEG), raw channels as they travelled.
        `only`: just these keys (the others are not decoded: a reader of a few small keys does not
        pay for rebuilding every camera frame)."""
        st = _ReadState()
        for rec, ch in self._stored(st):
            role = ch.metadata.get(ROLE, "")
            if role == "derived" or not ch.topic.startswith(key_prefix) or not _wanted(ch.topic, role, only):
                continue
            out = self._message(st, rec, ch, role)
            if out is not None:
                yield out

    def typed(self, only: Collection[str]) -> Iterator[tuple[int, str, Any]]:
        """(log_time_ns, key, message) of the typed messages of the keys `only`, as message objects:
        a reader that wants the objects skips the codec's encode and decode of each (`messages`
        hands codec bytes, as replay publishes them). Frames and raw channels are not among them."""
        st = _ReadState()
        for rec, ch in self._stored(st):
            if ch.metadata.get(ROLE, "") != "message" or ch.topic not in only or not ch.schema_id:
                continue
            cls = st.types_by_schema.get(st.schemas[ch.schema_id].name)
            try:
                if cls is not None:
                    yield rec.log_time, ch.topic, jsonmsg.from_json(cls, self._json(rec.data, ch.topic), ch.topic)
            except (RunFormatError, jsonmsg.JsonMessageError) as e:
                self._skip(e)

    def _stored(self, st: _ReadState) -> Iterator[tuple[Any, Any]]:
        """(message record, its channel record) in file order, `st` filled with the schemas and
        channels met so far."""
        from mcap.records import Channel, Message, Schema

        for rec in _records(self.path, self.salvage):
            if isinstance(rec, Schema):
                st.schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                st.chans[rec.id] = rec
            elif isinstance(rec, Message):
                yield rec, st.chans[rec.channel_id]

    def _message(self, st: _ReadState, rec: Any, ch: Any, role: str) -> tuple[int, str, bytes] | None:
        """One recorded message as (log_time_ns, key, payload), or None: left out, or half of a
        frame (image and info are joined by stamp, whichever comes first waits for the other)."""
        topic = ch.topic
        if role == "raw":
            return rec.log_time, topic, rec.data
        if role == "message":
            cls = st.types_by_schema.get(st.schemas[ch.schema_id].name) if ch.schema_id else None
            if cls is None:
                return None
            try:
                return rec.log_time, topic, self._encode(cls, rec.data, topic)
            except RunFormatError as e:
                self._skip(e)
                return None
        if role == "frame-info":
            return self._frame_info(st, rec, topic)
        if role in ("frame-image", "frame-video"):
            return self._frame_image(st, rec, ch, role)
        return None

    def _frame_info(self, st: _ReadState, rec: Any, topic: str) -> tuple[int, str, bytes] | None:
        key = topic[: -len("/info")]
        try:
            info = jsonmsg.from_json(M.Frame, self._json(rec.data, topic), topic)
        except (RunFormatError, jsonmsg.JsonMessageError) as e:
            self._skip(e)
            return None
        img = st.pending_img.pop((key, info.stamp_ns), None)
        if img is None:
            st.pending_info[(key, info.stamp_ns)] = info
            return None
        return img[0], key, self._frame(info, img[1])

    def _frame_image(self, st: _ReadState, rec: Any, ch: Any, role: str) -> tuple[int, str, bytes] | None:
        topic = ch.topic
        schema = st.schemas[ch.schema_id]
        if schema.name not in st.pb_classes:
            st.pb_classes[schema.name] = _protobuf_class(schema)
        ci = st.pb_classes[schema.name].FromString(rec.data)
        stamp = ci.timestamp.seconds * 10**9 + ci.timestamp.nanos
        img = self._jpeg(ci.data, stamp) if role == "frame-image" else self._h264(st.decoders, topic, ci.data, stamp)
        if img is None:
            return None
        info = st.pending_info.pop((topic, stamp), None)
        if info is None:
            st.pending_img[(topic, stamp)] = (rec.log_time, img)
            return None
        return rec.log_time, topic, self._frame(info, img)

    def _skip(self, e: Exception) -> None:
        """One message that does not fit its schema is left out (counted, logged), not the run."""
        self.skipped += 1
        if self.skipped <= 5:
            log.warning("skipping a message: %s", e)

    def _json(self, data: bytes, topic: str) -> Any:
        try:
            return json.loads(data)
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise RunFormatError(f"{self.path}: bad JSON on {topic}: {e}") from None

    def _encode(self, cls: type, data: bytes, topic: str) -> bytes:
        try:
            return codec.encode(jsonmsg.from_json(cls, self._json(data, topic), topic))
        except (jsonmsg.JsonMessageError, codec.CodecError) as e:
            raise RunFormatError(f"{self.path}: message on {topic} does not fit {cls.__name__}: {e}") from None

    def _jpeg(self, data: bytes, stamp: int) -> np.ndarray:
        import cv2

        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise RunFormatError(f"{self.path}: corrupt JPEG frame (stamp {stamp})")
        return img

    def _h264(self, decoders: dict[str, Any], topic: str, data: bytes, stamp: int) -> np.ndarray | None:
        """The frame of one H.264 packet (the stream is decoded in order; one frame per packet)."""
        import av

        dec = decoders.get(topic)
        if dec is None:
            dec = decoders[topic] = av.CodecContext.create("h264", "r")
        try:
            frames = dec.decode(av.Packet(data))
        except av.FFmpegError as e:
            raise RunFormatError(f"{self.path}: corrupt H.264 frame on {topic} (stamp {stamp}): {e}") from None
        return frames[-1].to_ndarray(format="bgr24") if frames else None

    def _frame(self, info: M.Frame, img: np.ndarray) -> bytes:
        from dataclasses import replace

        return codec.encode(replace(info, image=img))


def _protobuf_class(schema: Any) -> Any:
    """The protobuf message class of an MCAP protobuf schema (a FileDescriptorSet)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def read_run(path: str | Path, key_prefix: str = "", *, salvage: bool = False,
             only: Collection[str] | None = None) -> Iterator[tuple[int, str, bytes]]:
    """(log_time_ns, key, payload) of every message of the rig in a recording (see RunReader), or
    of the keys in `only`."""
    return RunReader(path, salvage=salvage).messages(key_prefix, only=only)


def size_report(info: RunInfo) -> dict[str, Any]:
    """Size of a recording per second of flight (the stamps' span), for the benchmark and report."""
    fl = info.flight_s()
    return {"bytes": info.bytes, "flight_s": round(fl, 3), "messages": info.messages,
            "mb_per_flight_s": round(info.bytes / 1e6 / fl, 3) if fl > 0 else None,
            "complete": info.complete, "channels": len(info.channels), "camera_frames": info.frames}

