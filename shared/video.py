"""Videos people watch: H.264 (yuv420p) MP4 with the index up front (`movflags=faststart`), so a
browser plays it and knows its duration before the whole file has arrived. Written with PyAV
(libx264 is in its wheels); OpenCV's own writer has no H.264 encoder (DESIGN §5).

Frame k is shown at k/fps exactly (time base 1/fps). Odd widths or heights are padded by one
black pixel (yuv420p needs even sizes).

`H264Writer(..., stream_keyframe_s=S)` also hands back each frame's H.264 as it is encoded, an
Annex B packet that decodes on its own terms (x264 zerolatency: no lookahead, no B-frames, so the
packet of frame k comes out with frame k; a keyframe every S seconds, with the SPS/PPS in front
of it): what a recording keeps of a frame stream (cinetransfer/runlog.py), so that a frame
written to both is encoded once.
"""
from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np


class H264Writer:
    """`write(bgr)` frame by frame, then `close()` (also as a context manager)."""

    def __init__(self, path: str | Path, fps: float, *, crf: int = 20, preset: str = "veryfast",
                 stream_keyframe_s: float | None = None, x264_params: str = "") -> None:
        import av

        if not (fps > 0):
            raise ValueError(f"fps must be > 0, got {fps}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fps = Fraction(fps).limit_denominator(1001)
        self._av = av
        self._container = av.open(str(self.path), mode="w", format="mp4", options={"movflags": "+faststart"})
        self._stream: Any = None
        self._crf, self._preset, self._x264_params = crf, preset, x264_params
        self._keyframe_s = stream_keyframe_s
        self._size: tuple[int, int] | None = None
        self.frames = 0

    def _open_stream(self, h: int, w: int) -> None:
        s = self._container.add_stream("libx264", rate=self.fps)
        s.width, s.height = w + (w % 2), h + (h % 2)
        s.pix_fmt = "yuv420p"
        s.time_base = 1 / self.fps
        s.codec_context.time_base = 1 / self.fps
        # no B-frames: each frame is decodable once its packet arrives (also what Foxglove wants)
        s.options = {"crf": str(self._crf), "preset": self._preset, "bf": "0"}
        if self._x264_params:  # libx264's own key=value:... settings on top of the preset
            s.options = {**s.options, "x264-params": self._x264_params}
        if self._keyframe_s is not None:
            s.options = {**s.options, "tune": "zerolatency", "g": str(max(1, int(round(self._keyframe_s * self.fps))))}
        self._stream, self._size = s, (h, w)

    def write(self, bgr: np.ndarray) -> bytes:
        """Encode one frame; with `stream_keyframe_s`, its Annex B packet (see the module doc), else b""."""
        img = np.asarray(bgr)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise ValueError(f"expected a (H, W, 3) uint8 BGR image, got {img.shape} {img.dtype}")
        h, w = img.shape[:2]
        if self._stream is None:
            self._open_stream(h, w)
        if (h, w) != self._size:
            raise ValueError(f"frame {self.frames} is {w}x{h}; the video is {self._size[1]}x{self._size[0]}")
        if h % 2 or w % 2:
            img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)))
        # the frame wraps the array's memory (no copy into a freshly allocated picture, ~1.3 ms a 960x540
        # frame): encode() converts it to yuv420p before it returns, so nothing holds on to the array
        frame = self._av.VideoFrame.from_numpy_buffer(np.ascontiguousarray(img), format="bgr24")
        frame.pts = self.frames
        frame.time_base = 1 / self.fps
        out = []
        for pkt in self._stream.encode(frame):
            if self._keyframe_s is not None:
                out.append(self._annex_b(pkt))
            self._container.mux(pkt)
        self.frames += 1
        return b"".join(out)

    def _annex_b(self, pkt: Any) -> bytes:
        """The packet as a stream decoder wants it: the mp4 keeps SPS/PPS once in its header
        (extradata, Annex B from libx264), a stream repeats them before every keyframe."""
        data = bytes(pkt)
        return bytes(self._stream.codec_context.extradata or b"") + data if pkt.is_keyframe else data

    def close(self) -> None:
        if self._container is None:
            return
        try:
            if self._stream is not None:
                for pkt in self._stream.encode(None):
                    self._container.mux(pkt)
        finally:
            self._container.close()
            self._container = None

    def __enter__(self) -> "H264Writer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def probe(path: str | Path) -> dict[str, Any]:
    """Codec, size, frame count, duration and whether the index comes first (faststart)."""
    import av

    with av.open(str(path)) as c:
        v = c.streams.video[0]
        n = sum(1 for _ in c.demux(v) if _.size)
        info = {"codec": v.codec_context.name, "width": v.codec_context.width, "height": v.codec_context.height,
                "pix_fmt": v.codec_context.pix_fmt, "frames": n, "fps": float(v.average_rate or 0),
                "duration_s": float(v.duration * v.time_base) if v.duration else None}
    boxes = top_level_boxes(path)
    info["faststart"] = "moov" in boxes and "mdat" in boxes and boxes.index("moov") < boxes.index("mdat")
    return info


def top_level_boxes(path: str | Path) -> list[str]:
    """The types of an MP4's top-level boxes, in file order (faststart: moov before mdat)."""
    import struct

    out = []
    with open(path, "rb") as f:
        size = Path(path).stat().st_size
        pos = 0
        while pos + 8 <= size:
            f.seek(pos)
            n, kind = struct.unpack(">I4s", f.read(8))
            if n == 1:
                n = struct.unpack(">Q", f.read(8))[0]
            elif n == 0:
                n = size - pos
            out.append(kind.decode("latin-1"))
            if n < 8:
                break
            pos += n
    return out
