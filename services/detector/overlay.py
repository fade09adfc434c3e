"""Draw a Measurement over its frame for a human to check: masks, boxes, skeletons, focus map."""
from __future__ import annotations

import cv2
import numpy as np

from cinetransfer.shared.messages import Measurement

# COCO-17 limbs (indices into COCO17_NAMES)
COCO17_EDGES: tuple[tuple[int, int], ...] = (
    (0, 1), (0, 2), (1, 3), (2, 4), (5, 6), (5, 7), (7, 9), (6, 8), (8, 10), (5, 11), (6, 12), (11, 12),
    (11, 13), (13, 15), (12, 14), (14, 16),
)
_COLOURS = ((66, 135, 245), (80, 200, 120), (245, 90, 66), (200, 80, 200), (40, 200, 220), (230, 200, 40))


def draw(image_bgr: np.ndarray, m: Measurement, *, joint_threshold: float = 0.5, focus_alpha: float = 0.35,
         inset: bool = True) -> np.ndarray:
    """A copy of the frame with the measurement drawn on it.

    Out-of-focus areas are tinted blue (stronger = more surely out of focus); each person's mask
    is tinted in its colour with its box, confidence and skeleton (joints below
    `joint_threshold` are drawn hollow); a small inset in the corner shows the raw focus map.
    """
    out = image_bgr.copy()
    h, w = out.shape[:2]
    if m.focus_map is not None and focus_alpha > 0:
        fm = cv2.resize(m.focus_map, (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float32) / 255.0
        a = (focus_alpha * (1.0 - fm))[..., None]
        tint = np.array((255, 60, 0), np.float32)
        out = (out.astype(np.float32) * (1 - a) + tint * a).astype(np.uint8)
    for i, p in enumerate(m.people):
        c = _COLOURS[i % len(_COLOURS)]
        mask = p.full_mask(w, h)
        if mask.any():
            out[mask] = (0.55 * out[mask] + 0.45 * np.array(c)).astype(np.uint8)
        x0, y0, x1, y1 = (int(round(v)) for v in p.box_xyxy)
        cv2.rectangle(out, (x0, y0), (x1 - 1, y1 - 1), c, 2)
        cv2.putText(out, f"{i}: {p.confidence:.2f}", (x0 + 2, max(12, y0 - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.5, c, 1,
                    cv2.LINE_AA)
    for s in m.skeletons:
        c = _COLOURS[s.person_index % len(_COLOURS)] if s.person_index >= 0 else (255, 255, 255)
        kp, q = s.keypoints_px, s.confidences
        for a_, b_ in COCO17_EDGES:
            if a_ < len(kp) and b_ < len(kp) and q[a_] >= joint_threshold and q[b_] >= joint_threshold:
                cv2.line(out, _pt(kp[a_]), _pt(kp[b_]), c, 2, cv2.LINE_AA)
        for j in range(len(kp)):
            if np.isfinite(kp[j]).all():
                cv2.circle(out, _pt(kp[j]), 3, (255, 255, 255), -1 if q[j] >= joint_threshold else 1, cv2.LINE_AA)
    if inset and m.focus_map is not None:
        iw = max(32, w // 6)
        ih = max(1, int(round(iw * m.focus_map.shape[0] / m.focus_map.shape[1])))
        small = cv2.cvtColor(cv2.resize(m.focus_map, (iw, ih), interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
        out[h - ih - 4:h - 4, w - iw - 4:w - 4] = small
        cv2.rectangle(out, (w - iw - 5, h - ih - 5), (w - 4, h - 4), (255, 255, 255), 1)
    cv2.putText(out, f"#{m.frame_index} people {len(m.people)}", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55,
                (255, 255, 255), 1, cv2.LINE_AA)
    return out


def _pt(p: np.ndarray) -> tuple[int, int]:
    return int(round(float(p[0]))), int(round(float(p[1])))


class OverlayWriter:
    """Writes overlay frames to a video (mp4v for .mp4, MJPG for .avi; no H.264 encoder here)."""

    def __init__(self, path: str, fps: float, width: int, height: int) -> None:
        fourcc = cv2.VideoWriter_fourcc(*("MJPG" if path.lower().endswith(".avi") else "mp4v"))
        self.path = path
        self._vw = cv2.VideoWriter(path, fourcc, float(fps if fps and np.isfinite(fps) else 24.0), (width, height))
        if not self._vw.isOpened():
            raise OSError(f"{path}: cannot open a video writer")
        self.size = (width, height)

    def write(self, image_bgr: np.ndarray, m: Measurement) -> None:
        frame = draw(image_bgr, m)
        if (frame.shape[1], frame.shape[0]) != self.size:
            frame = cv2.resize(frame, self.size)
        self._vw.write(frame)

    def close(self) -> None:
        self._vw.release()
