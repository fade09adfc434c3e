"""The report's side-by-side video: source | output, frame by frame, with the controlled joints and
the focus labels drawn, as H.264 (shared/video.py) that a browser plays.

Row i of the comparison shows source frame `first_frame + k[i]` on the left and output frame i on
the right. Rings: the source's targets for the controlled joints (on both halves: where the shot
should put them); dots: extraction on the output; crosses: the simulator's truth. Under each half,
the regions in focus (source: the instructions; output: truth, else extraction).
"""
from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from cinetransfer.report import fidelity as F
from cinetransfer.report.figures import _colour, _dark, _in_focus_text, hex_rgb

HEIGHT = 360  #: pixel height of each half
#: x264 on top of its veryfast preset: a diamond motion search and one sub-pixel refinement encode a
#: frame in ~3/4 of the CPU (README run: 10.4 -> 7.9 ms a 1280x360 frame) for ~5 % more bytes
X264_PARAMS = "me=dia:subme=1"


def _bgr(colour: str | tuple[float, float, float]) -> tuple[int, int, int]:
    """OpenCV's BGR of a '#rrggbb' colour or an RGB triple in [0, 1]."""
    r, g, b = hex_rgb(colour) if isinstance(colour, str) else colour
    return int(b * 255), int(g * 255), int(r * 255)


class _Reader:
    """Sequential frames of a video (exact on any codec); None past the end or when unreadable."""

    def __init__(self, path: str | Path | None) -> None:
        import cv2

        self.cap = cv2.VideoCapture(str(path)) if path and Path(path).is_file() else None
        self.i, self.last = 0, None

    def get(self, index: int) -> np.ndarray | None:
        if self.cap is None or index < self.i - 1:
            return None
        if index == self.i - 1:
            return self.last
        while self.i < index:
            if not self.cap.grab():
                return None
            self.i += 1
        ok, img = self.cap.read()
        if not ok:
            return None
        self.i += 1
        self.last = img
        return img

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()


def _half(img: np.ndarray | None, width: int, text: str) -> np.ndarray:
    import cv2

    if img is None:
        out = np.full((HEIGHT, width, 3), 200, np.uint8)
        cv2.putText(out, text, (10, HEIGHT // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (80, 80, 80), 1, cv2.LINE_AA)
        return out
    return cv2.resize(img, (width, HEIGHT), interpolation=_interpolation(img.shape[0]))


def _interpolation(height: int) -> int:
    """Pixel-area averaging where a half shrinks by a whole factor (OpenCV's fast path, 0.9 ms a
    1280x720 frame); bilinear otherwise, where area averaging costs 4x (3.8 against 0.8 ms a
    960x540 frame) for a picture that differs only in the finest texture."""
    import cv2

    return cv2.INTER_AREA if height % HEIGHT == 0 else cv2.INTER_LINEAR


def _keep(wanted: dict[int, Any], index: int, img: np.ndarray | None) -> None:
    import cv2

    if img is not None and index in wanted and wanted[index] is None:
        wanted[index] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _label(img: np.ndarray, text: str, y: int) -> None:
    import cv2

    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
    cv2.rectangle(img, (4, y - th - 6), (12 + tw, y + 4), (0, 0, 0), -1)
    cv2.putText(img, text, (8, y - 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)


#: frames the reading thread may be ahead of the drawing and encoding (~5 MB a row)
READ_AHEAD = 8


def _width(img: np.ndarray | None) -> int:
    """A half's width: the frame's aspect at HEIGHT, even (640 for a missing video)."""
    return 640 if img is None else int(round(img.shape[1] * HEIGHT / img.shape[0] / 2) * 2)


def _rows(source_video: str | Path | None, output_video: str | Path | None, source_rows: list[int]) -> Iterator[tuple]:
    """(source frame, output frame, left half, right half) of each row i (source frame
    source_rows[i], output frame i), decoded and shrunk by a thread of their own up to READ_AHEAD
    rows ahead: OpenCV decodes and resizes without the GIL, so this runs beside the drawing and
    x264 instead of before them (the same frames and halves, in the same order)."""
    q: queue.Queue = queue.Queue(maxsize=READ_AHEAD)
    stop = threading.Event()

    def put(item: Any) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def read() -> None:
        srd, ord_ = _Reader(source_video), _Reader(output_video)
        widths: tuple[int, int] | None = None
        try:
            for i, row in enumerate(source_rows):
                a, b = srd.get(row), ord_.get(i)
                widths = widths or (_width(a), _width(b))
                if not put((a, b, _half(a, widths[0], "source frame not readable"),
                            _half(b, widths[1], "no output frame"))):
                    return
        except BaseException as e:  # noqa: BLE001 - handed over: the caller raises it
            put(e)
        finally:
            srd.close()
            ord_.close()

    reader = threading.Thread(target=read, name="report-video-read", daemon=True)
    reader.start()
    try:
        for _ in source_rows:
            item = q.get()
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        reader.join()


def side_by_side(path: Path, series: dict[str, Any], *, source_video: str | Path | None,
                 output_video: str | Path | None, fps: float,
                 keep: tuple[dict[int, Any], dict[int, Any]] | None = None) -> dict[str, Any]:
    """Write the comparison video to `path`; returns what it holds (frames, fps, duration).
    `keep`: ({source frame index: None}, {output frame index: None}) to fill with those frames
    (RGB) as they are decoded, so that the figures need not decode the videos a second time."""
    import cv2

    from cinetransfer.shared.video import H264Writer

    t, k = series["t_s"], series["k"]
    src: F.Track = series["source"]
    ext: F.Track = series["extraction"]
    tru: F.Track = series["truth"]
    first = int(series.get("source_first_frame", 0))
    n, n_joints = len(t), len(series["joint_names"])
    if n == 0:
        raise ValueError("no frames to compare")
    colours = [(_bgr(_colour(e)), _bgr(_dark(_colour(e)))) for e in range(n_joints)]  # the figures' colours, once
    widths: tuple[int, int] | None = None
    with H264Writer(path, fps, crf=23, x264_params=X264_PARAMS) as w:
        for i, (a, b, left, right) in enumerate(_rows(source_video, output_video, [first + int(x) for x in k[:n]])):
            if keep is not None:
                _keep(keep[0], first + int(k[i]), a)
                _keep(keep[1], i, b)
            widths = widths or (left.shape[1], right.shape[1])
            for e in range(n_joints):
                col, dark = colours[e]
                if src.ok[i, e]:
                    for half, wd in ((left, widths[0]), (right, widths[1])):
                        x, y = src.xy[i, e]
                        cv2.circle(half, (int(x * wd), int(y * HEIGHT)), 9, col, 2, cv2.LINE_AA)
                if ext.ok[i, e]:
                    x, y = ext.xy[i, e]
                    cv2.circle(right, (int(x * widths[1]), int(y * HEIGHT)), 4, dark, -1, cv2.LINE_AA)
                if tru.ok[i, e]:
                    x, y = tru.xy[i, e]
                    cv2.drawMarker(right, (int(x * widths[1]), int(y * HEIGHT)), (255, 255, 255),
                                   cv2.MARKER_TILTED_CROSS, 10, 2, cv2.LINE_AA)
            _label(left, f"source  k={int(k[i])}  t={t[i]:.2f}s", 20)
            _label(right, f"output  frame {i}", 20)
            _label(left, _in_focus_text(src, i), HEIGHT - 10)
            which = tru if tru.available[i] else ext
            _label(right, _in_focus_text(which, i) + (" (truth)" if tru.available[i] else " (extraction)"),
                   HEIGHT - 10)
            w.write(np.hstack([left, right]))
    return {"file": path.name, "frames": n, "fps": fps, "duration_s": round(n / fps, 6),
            "width": sum(widths), "height": HEIGHT, "bytes": path.stat().st_size}
