"""Fallback person detector: OpenCV's built-in HOG + linear SVM pedestrian model (Dalal & Triggs).

MediaPipe's pose detector is face-anchored: back views, profiles and people in a crowd are
often missed. The HOG people detector (compiled into OpenCV < 5, no download) finds upright
pedestrians whatever their facing direction. Its windows are padded (a 64x128 window holds a
~48x96 person), so boxes are shrunk about their centre by `hog_box_shrink_xy` (calibrated on
TUD-Stadtmitte: 0.5 x 0.8). People found only by HOG have a box and a score but no skeleton and
an all-False mask (mask unknown).
"""
from __future__ import annotations

import cv2
import numpy as np

from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.shared.messages import PersonDetection


class HogPeople:
    """`detect(image_bgr) -> list[PersonDetection]` (thread-safe: one HOG object per instance)."""

    def __init__(self, cfg: DetectorConfig) -> None:
        self.cfg = cfg
        self.hog = cv2.HOGDescriptor()
        self.hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())

    def detect(self, image_bgr: np.ndarray) -> list[PersonDetection]:
        cfg = self.cfg
        h, w = image_bgr.shape[:2]
        s = min(1.0, cfg.hog_work_height_px / h)
        img = cv2.resize(image_bgr, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA) if s < 1 else image_bgr
        rects, weights = self.hog.detectMultiScale(img, hitThreshold=0.0, winStride=(8, 8), padding=(8, 8),
                                                   scale=1.05)
        out = []
        sx, sy = cfg.hog_box_shrink_xy
        for (x, y, bw, bh), score in zip(rects, np.ravel(weights) if len(rects) else []):
            if score < cfg.hog_min_score:
                continue
            cx, cy = (x + bw / 2) / s, (y + bh / 2) / s
            bw, bh = bw / s * sx, bh / s * sy
            x0, y0 = int(max(0, round(cx - bw / 2))), int(max(0, round(cy - bh / 2)))
            x1, y1 = int(min(w, round(cx + bw / 2))), int(min(h, round(cy + bh / 2)))
            if x1 <= x0 or y1 <= y0:
                continue
            conf = float(1.0 / (1.0 + np.exp(-(score - 0.5))))  # SVM margin -> (0, 1)
            out.append(PersonDetection(box_xyxy=np.array([x0, y0, x1, y1], np.float32), confidence=conf,
                                       mask_origin_xy=np.array([x0, y0], np.int32),
                                       mask=np.zeros((y1 - y0, x1 - x0), bool)))
        return out
