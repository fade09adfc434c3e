"""The camera's motion between consecutive frames: background corners tracked on a small grey
copy of the frame (people masked out), then fitted by shared/camera_motion.py.

Cost: about 4-5 ms of CPU per frame at 1280x720 (a 320 px wide grey copy, up to 200 corners
carried from frame to frame, pyramidal Lucas-Kanade forward and back, the fit), measured on a
loaded 2-core machine, and about 1 ms more for telling the tracks on edges (`edge_normals`); about
15 ms where a translation is fitted in most frames (the transfer's rendered output video, the
camera following its subject).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from cinetransfer.shared import camera_motion as cm
from cinetransfer.shared.messages import CameraMotion, LensState, PersonDetection

MAX_CORNERS = 200
#: search for fresh corners when fewer than this many of the tracked ones are left
MIN_KEPT = 120
#: people's masks are grown by this much [px at the work width]: their edges and shadows move too
MASK_MARGIN_PX = 4
#: a track whose backward track misses its start by more than this is dropped [px at the work width]
FB_ERROR_PX = 0.5
#: the parallax baseline: corners' positions are kept over this many frames (1/3 s at 24 fps)
SPAN_FRAMES = 8
#: least distance between corners [px at the work width]
MIN_DISTANCE_PX = 8
#: the parallax baseline needs this many corners tracked over it
BASELINE_POINTS = 40
#: a track is an edge when its window's structure tensor has its lesser eigenvalue under this share of
#: the greater in each of these windows [px at the work width]: the tracker's pyramid (3 levels of an
#: 11 px window) locates a track along a short edge from the coarser levels; along a long straight one
#: (the paving's lines) it slides (the aperture problem)
EDGE_RATIO = 0.1
EDGE_WINDOWS_PX = (11, 31)
#: a track lies on a line when that share is under this in each window: the paving's tracks between
#: 0.1 and 0.2 drift across their lines under a dolly as those under 0.1 do (rendered slow dolly, lower
#: third: +0.6 px over the baseline against +0.02 for those above 0.5), so they are left out of the
#: rotation given a dolly (cm.frame_motion's `lines`)
LINE_RATIO = 0.2


def _baseline_start(history: np.ndarray | None) -> int | None:
    """The oldest row of the history (frames, N, 2) that at least BASELINE_POINTS corners were
    tracked from; None when there is none before the newest."""
    if history is None or len(history) < 2:
        return None
    known = np.isfinite(history[:-1, :, 0]).sum(axis=1)
    rows = np.flatnonzero(known >= BASELINE_POINTS)
    return int(rows[0]) if len(rows) else None
_LK = dict(winSize=(11, 11), maxLevel=2, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.03))


class TensorScratch:
    """The images `edge_normals` reuses for one grey size: fresh ones each frame cost page faults
    (0.6-1.1 ms of system time a call, measured)."""

    def __init__(self) -> None:
        self.shape: tuple[int, ...] | None = None

    def fit(self, shape: tuple[int, ...]) -> TensorScratch:
        if self.shape != shape:
            pad = EDGE_WINDOWS_PX[-1] // 2
            h, w = shape[0] + 2 * pad, shape[1] + 2 * pad
            self.shape = shape
            self.gx, self.gy = np.empty(shape, np.int16), np.empty(shape, np.int16)
            self.px, self.py = np.empty((h, w), np.int16), np.empty((h, w), np.int16)
            self.product = np.empty((h, w), np.float32)
            self.table = np.empty((h + 1, w + 1), np.float64)
        return self


def _window_corners(xi: np.ndarray, yi: np.ndarray, stride: int) -> list[tuple[np.ndarray, ...]]:
    """For each of EDGE_WINDOWS_PX, the flat indices into a summed-area table (`stride` wide, of the
    image padded by the largest window's half) of the four corners of each point's window."""
    pad = EDGE_WINDOWS_PX[-1] // 2
    out = []
    for size in EDGE_WINDOWS_PX:
        first = (yi + pad - size // 2) * stride + (xi + pad - size // 2)
        out.append((first, first + size, first + size * stride, first + size * stride + size))
    return out


def tensor_sums(grey: np.ndarray, xi: np.ndarray, yi: np.ndarray, scratch: TensorScratch | None = None) -> list:
    """For each of EDGE_WINDOWS_PX, (N, 3) float32 the structure tensor's gx², gx gy, gy² of the 3x3
    Sobel gradients summed over the window round each pixel (xi, yi), the image's border reflected
    (BORDER_REFLECT_101): exactly cv2.boxFilter's sums (unnormalised) at those pixels. The products
    are whole numbers and a summed-area table in float64 holds their sums exactly, so the window's
    sum is exact before its one rounding to float32, as the box filter's double sums are; the table
    is read at the points only, not filtered over the whole image twice."""
    s = (scratch or TensorScratch()).fit(grey.shape)
    pad = EDGE_WINDOWS_PX[-1] // 2
    cv2.Sobel(grey, cv2.CV_16S, 1, 0, dst=s.gx, ksize=3)
    cv2.Sobel(grey, cv2.CV_16S, 0, 1, dst=s.gy, ksize=3)
    cv2.copyMakeBorder(s.gx, pad, pad, pad, pad, cv2.BORDER_REFLECT_101, dst=s.px)
    cv2.copyMakeBorder(s.gy, pad, pad, pad, pad, cv2.BORDER_REFLECT_101, dst=s.py)
    corners = _window_corners(xi, yi, s.table.shape[1])
    out = [np.empty((len(xi), 3), np.float32) for _ in EDGE_WINDOWS_PX]
    for j, (u, v) in enumerate(((s.px, s.px), (s.px, s.py), (s.py, s.py))):
        cv2.multiply(u, v, dst=s.product, dtype=cv2.CV_32F)
        cv2.integral(s.product, sum=s.table, sdepth=cv2.CV_64F)
        flat = s.table.reshape(-1)
        for k, (top_left, top_right, bottom_left, bottom_right) in enumerate(corners):
            out[k][:, j] = flat[bottom_right] - flat[top_right] - flat[bottom_left] + flat[top_left]
    return out


def edge_normals(grey: np.ndarray, pts: np.ndarray, scratch: TensorScratch | None = None) -> np.ndarray:
    """(N, 2) the unit normal of the edge each point (N, 2, work px) lies on, from the structure
    tensor of the grey image (uint8) summed over the EDGE_WINDOWS_PX windows round it (the normal
    from the first); zeros where any window holds a corner (or nothing): its lesser eigenvalue at
    least EDGE_RATIO of the greater. `scratch`: images kept from the previous call (saves page faults)."""
    return edges_and_lines(grey, pts, scratch)[0]


def edges_and_lines(grey: np.ndarray, pts: np.ndarray,
                    scratch: TensorScratch | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`edge_normals` (N, 2), and (N,) True for the points on a line: the lesser eigenvalue under
    LINE_RATIO of the greater in every window (one pass over the structure tensor for both)."""
    out = np.zeros((len(pts), 2))
    if not len(pts):
        return out, np.zeros(0, dtype=bool)
    h, w = grey.shape
    xi = np.clip(np.round(pts[:, 0]).astype(int), 0, w - 1)
    yi = np.clip(np.round(pts[:, 1]).astype(int), 0, h - 1)
    edge = np.ones(len(pts), dtype=bool)
    line = np.ones(len(pts), dtype=bool)
    for size, sums in zip(EDGE_WINDOWS_PX, tensor_sums(grey, xi, yi, scratch)):
        a, b, c = (sums[:, j].astype(float) for j in range(3))
        half, root = 0.5 * (a + c), np.sqrt((0.5 * (a - c)) ** 2 + b * b)
        edge &= (half + root > 0.0) & (half - root < EDGE_RATIO * (half + root))
        line &= (half + root > 0.0) & (half - root < LINE_RATIO * (half + root))
        if size == EDGE_WINDOWS_PX[0]:
            angle = 0.5 * np.arctan2(2.0 * b, a - c)  # the greater eigenvector: the gradient, across the edge
    out[edge] = np.column_stack([np.cos(angle), np.sin(angle)])[edge]
    return out, line


def background_mask(people: list[PersonDetection], width: int, height: int, size: tuple[int, int]) -> np.ndarray:
    """uint8 (h, w) at the work size `size` = (w, h): 255 where no person (nor its margin) is."""
    w, h = size
    sx, sy = w / width, h / height
    out = np.full((h, w), 255, np.uint8)
    for p in people:
        ox, oy = float(p.mask_origin_xy[0]), float(p.mask_origin_xy[1])
        mh, mw = p.mask.shape
        x0, y0 = int(math.floor(ox * sx)), int(math.floor(oy * sy))
        x1, y1 = int(math.ceil((ox + mw) * sx)), int(math.ceil((oy + mh) * sy))
        if mw and mh and x1 > x0 and y1 > y0:
            m = cv2.resize(p.mask.astype(np.uint8), (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST)
        else:  # no mask: the whole box
            b = p.box_xyxy
            x0, y0, x1, y1 = (int(math.floor(b[0] * sx)), int(math.floor(b[1] * sy)), int(math.ceil(b[2] * sx)),
                              int(math.ceil(b[3] * sy)))
            m = np.ones((max(y1 - y0, 0), max(x1 - x0, 0)), np.uint8)
        cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        if cx1 > cx0 and cy1 > cy0:
            out[cy0:cy1, cx0:cx1][m[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0] > 0] = 0
    if MASK_MARGIN_PX > 0 and (out == 0).any():
        out = cv2.erode(out, np.ones((2 * MASK_MARGIN_PX + 1,) * 2, np.uint8))
    return out


def frame_focal_px(lens: LensState | None, width: int, hfov_deg: float) -> float:
    """Focal length [px] of a frame `width` px wide: from its lens when known, else the assumed field of view."""
    if lens is not None and lens.focal_length_mm > 0 and lens.sensor_width_mm > 0:
        return float(lens.focal_length_mm / lens.sensor_width_mm * width)
    return cm.focal_px(width, hfov_deg)


class CameraMotionTracker:
    """Consecutive frames of one source in, the camera's motion between them out."""

    def __init__(self, hfov_deg: float = cm.ASSUMED_HFOV_DEG, work_width: int = cm.WORK_WIDTH,
                 edge_tracks: bool = False) -> None:
        self.hfov_deg = float(hfov_deg)
        self.work_width = int(work_width)
        # judge the tracks that slide along an edge across it only (edge_normals, cm.sliding_edges)
        self.edge_tracks = bool(edge_tracks)
        # source, index, grey, corners, their positions over the last frames (frames, N, 2)
        self._prev: tuple | None = None
        # the last frame's motion, whose dolly a frame showing no parallax carries on (cm.dolly_carried)
        self._motion: cm.FrameMotion | None = None
        self._scratch = TensorScratch()

    def reset(self) -> None:
        self._prev = None
        self._motion = None

    def update(self, image_bgr: np.ndarray, people: list[PersonDetection], *, source: str, frame_index: int,
               lens: LensState | None = None, grey: np.ndarray | None = None) -> CameraMotion | None:
        """The motion since the previous frame (None when this is not the next frame of one source).
        `grey`: the frame in grey at full size when the caller has it already (saves converting it)."""
        h, w = image_bgr.shape[:2]
        ww = min(self.work_width, w)
        size = (ww, max(int(round(h * ww / w)), 8))
        if grey is None:
            grey = image_bgr if image_bgr.ndim == 2 else cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        mask = background_mask(people, w, h, size)
        prev = self._prev
        out = None
        history = None
        f_work = frame_focal_px(lens, w, self.hfov_deg) * ww / w
        if prev is not None and prev[0] == source and prev[1] == int(frame_index) - 1:
            p0, p1, ok = self._track(prev[2], grey, prev[3], mask)
            # each kept corner's positions over the last SPAN_FRAMES frames (NaN before it was found):
            # the parallax baseline, the longest that enough of them were tracked over
            history = np.concatenate([prev[4][-SPAN_FRAMES:, ok], p1[None]]) if prev[4] is not None else None
            centre = np.array([(size[0] - 1) / 2.0, (size[1] - 1) / 2.0])
            start = _baseline_start(history)
            normals, lines = edges_and_lines(grey, p1, self._scratch) if self.edge_tracks else (None, None)
            fm = cm.frame_motion(p0 - centre, p1 - centre, f_work, inlier_px=cm.INLIER_PX * ww / cm.WORK_WIDTH,
                                 earlier=None if start is None else history[start] - centre,
                                 span=0 if start is None else len(history) - 1 - start,
                                 normals=normals, lines=lines)
            if start is None or len(history) - 1 - start < cm.MIN_SPAN:
                fm = cm.parallax_untested(fm)
            fm = cm.dolly_carried(fm, self._motion)
            self._motion = fm
            out = CameraMotion(rotation_rad=fm.rotation_rad.astype(float), log_zoom=float(fm.log_zoom),
                               translation_dir=fm.translation_dir.astype(float), focal_px=float(f_work * w / ww),
                               points=int(fm.points), explained=float(fm.explained))
        # the corners tracked into this frame go on to the next (saves the corner search, ~15 % of
        # the stage, and keeps the baseline); fresh ones away from them top up when too few are left
        if history is None or history.shape[1] < MIN_KEPT:
            history = self._top_up(grey, mask, history)
        corners = None if history is None else history[-1].reshape(-1, 1, 2).astype(np.float32)
        if out is None:
            self._motion = None
        self._prev = (source, int(frame_index), grey, corners, history)
        return out

    @staticmethod
    def _top_up(grey: np.ndarray, mask: np.ndarray, history: np.ndarray | None) -> np.ndarray | None:
        """The history (frames, N, 2) with fresh corners (off the people and the kept corners) added
        up to MAX_CORNERS, their earlier positions NaN; None when there are none at all."""
        kept = 0 if history is None else history.shape[1]
        free = mask.copy()
        for x, y in ([] if history is None else history[-1]):
            cv2.circle(free, (int(round(x)), int(round(y))), MIN_DISTANCE_PX, 0, -1)
        fresh = cv2.goodFeaturesToTrack(grey, MAX_CORNERS - kept, 0.01, MIN_DISTANCE_PX, mask=free, blockSize=5) \
            if MAX_CORNERS > kept else None
        if fresh is None or not len(fresh):
            return history if kept else None
        rows = 1 if history is None else history.shape[0]
        add = np.full((rows, len(fresh), 2), np.nan)
        add[-1] = fresh.reshape(-1, 2)
        return add if history is None else np.concatenate([history, add], axis=1)

    @staticmethod
    def _track(g0: np.ndarray, g1: np.ndarray, corners: np.ndarray | None,
               mask1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Corners of g0 tracked into g1, kept when the backward track returns and they land off
        the people of g1: (N, 2) each, work pixels, and which of the corners were kept (bool)."""
        if corners is None or len(corners) == 0:
            return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, dtype=bool)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(g0, g1, corners, None, **_LK)
        p0r, st_b, _ = cv2.calcOpticalFlowPyrLK(g1, g0, p1, None, **_LK)
        a, b = corners.reshape(-1, 2), p1.reshape(-1, 2)
        ok = (st.ravel() == 1) & (st_b.ravel() == 1) & (np.linalg.norm(p0r.reshape(-1, 2) - a, axis=1) < FB_ERROR_PX)
        hh, ww = mask1.shape
        xi, yi = np.clip(b[:, 0].round().astype(int), 0, ww - 1), np.clip(b[:, 1].round().astype(int), 0, hh - 1)
        inside = (b[:, 0] >= 0) & (b[:, 0] < ww) & (b[:, 1] >= 0) & (b[:, 1] < hh)
        ok &= inside & (mask1[yi, xi] > 0)
        return a[ok].astype(float), b[ok].astype(float), ok
