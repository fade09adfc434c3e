"""People, masks and COCO-17 skeletons from MediaPipe's multi-person PoseLandmarker (CPU, offline).

The `.task` bundle is built from the mediapipe wheel's own models (pose_bundle.py). MediaPipe
gives, per person, 33 BlazePose landmarks (normalised x, y, visibility, presence) and a
full-frame float segmentation mask, but no box and no score; we derive:

- keypoints: COCO-17 = BlazePose landmarks [0,2,5,7,8,11,12,13,14,15,16,23,24,25,26,27,28];
  joint confidence = visibility x presence, 0 for a joint outside the image;
- mask: segmentation > `mask_threshold`, cropped to its bounding box;
- box: the mask's bounding box (the landmarks' box, padded, when the mask is empty);
- confidence: mean presence of the 17 COCO joints (MediaPipe's own "is this a person" signal).

Small or far people (the detector is face-anchored and works on a 224x224 view of the frame):
`upscale_max_side_px` runs on an enlarged frame and `tiles` adds a pass over overlapping
vertical strips, each seen larger by the detector; results are merged by box overlap.
"""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
from typing import Any, Iterator

import cv2
import numpy as np

from cinetransfer.services.detector import dedupe
from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.services.detector.pose_bundle import bundle_path
from cinetransfer.shared.boxes import box_iou  # noqa: F401 - re-exported for the other backends
from cinetransfer.shared.messages import PersonDetection, Skeleton

log = logging.getLogger("cinetransfer.detector")

#: BlazePose landmark index of each COCO-17 joint (COCO17_NAMES order).
BLAZEPOSE_TO_COCO17: tuple[int, ...] = (0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)
_COCO = np.asarray(BLAZEPOSE_TO_COCO17)


def make_person(mask_full: np.ndarray | None, kp_px: np.ndarray, kp_conf: np.ndarray, confidence: float,
                width: int, height: int, *, pad_frac: float = 0.1) -> PersonDetection | None:
    """A PersonDetection from a full-frame boolean mask (or None) and the person's keypoints."""
    box = None
    crop = None
    if mask_full is not None and mask_full.any():
        ys = np.flatnonzero(mask_full.any(axis=1))
        xs = np.flatnonzero(mask_full.any(axis=0))
        x0, x1, y0, y1 = int(xs[0]), int(xs[-1]) + 1, int(ys[0]), int(ys[-1]) + 1
        crop = np.ascontiguousarray(mask_full[y0:y1, x0:x1])
        box = (x0, y0, x1, y1)
    if box is None:
        ok = np.isfinite(kp_px).all(axis=1) & (kp_conf > 0.3)
        if ok.sum() < 2:
            return None
        p = kp_px[ok]
        x0, y0 = p.min(axis=0)
        x1, y1 = p.max(axis=0)
        px, py = pad_frac * (x1 - x0 + 1), pad_frac * (y1 - y0 + 1)
        x0, x1 = int(max(0, np.floor(x0 - px))), int(min(width, np.ceil(x1 + px)))
        y0, y1 = int(max(0, np.floor(y0 - py))), int(min(height, np.ceil(y1 + py)))
        if x1 <= x0 or y1 <= y0:
            return None
        crop = np.zeros((y1 - y0, x1 - x0), dtype=bool)
        box = (x0, y0, x1, y1)
    return PersonDetection(box_xyxy=np.asarray(box, dtype=np.float32), confidence=float(np.clip(confidence, 0, 1)),
                           mask_origin_xy=np.asarray(box[:2], dtype=np.int32), mask=crop)


#: Start-up chatter that MediaPipe's C++ side writes straight to fd 2 (before absl logging is
#: initialised, so no flag or environment variable silences it). Harmless on a CPU-only host.
_NATIVE_NOISE = ("All log messages before absl::InitializeLog", "Created TensorFlow Lite XNNPACK delegate",
                 "inference_feedback_manager.cc", "GPU suport is not available", "gl_context_egl.cc",
                 "landmark_projection_calculator.cc")


@contextlib.contextmanager
def _filtered_native_stderr() -> Iterator[None]:
    """Capture fd 2 while MediaPipe starts, then write back every line that is not known
    start-up noise (so a real native error is still seen, just after the call)."""
    fd = 2  # native code writes to the descriptor, whatever Python's sys.stderr is
    try:
        sys.stderr.flush()
        saved = os.dup(fd)
    except OSError:  # no descriptor 2 at all: nothing to filter
        yield
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            keep = [ln for ln in tmp.read().decode(errors="replace").splitlines(keepends=True)
                    if ln.strip() and not any(n in ln for n in _NATIVE_NOISE)]
            if keep:
                os.write(fd, "".join(keep).encode())


class MediaPipePose:
    """Pose backend: `detect(image_bgr, stamp_ns) -> (people, skeletons)`."""

    name = "mediapipe"

    def __init__(self, cfg: DetectorConfig) -> None:
        self.cfg = cfg
        from mediapipe.tasks.python import BaseOptions, vision  # heavy import: only when used

        self._vision = vision
        self._base = BaseOptions
        self._task = str(bundle_path())
        self._video = cfg.running_mode == "video"
        self._quiet_next_run = True  # inference prints start-up noise too, until a pose is first found
        with _filtered_native_stderr():
            self._lm = self._make(self._video, cfg.num_poses)
        self._tile_lm: Any = None
        self._last_ts_ms = -1

    def _make(self, video: bool, num_poses: int) -> Any:
        v = self._vision
        opts = v.PoseLandmarkerOptions(
            base_options=self._base(model_asset_path=self._task),
            running_mode=v.RunningMode.VIDEO if video else v.RunningMode.IMAGE,
            num_poses=num_poses,
            min_pose_detection_confidence=self.cfg.min_detection_confidence,
            min_pose_presence_confidence=self.cfg.min_presence_confidence,
            min_tracking_confidence=self.cfg.min_tracking_confidence,
            output_segmentation_masks=True,
        )
        return v.PoseLandmarker.create_from_options(opts)

    def close(self) -> None:
        for lm in (self._lm, self._tile_lm):
            if lm is not None:
                lm.close()
        self._lm = self._tile_lm = None

    def reset(self) -> None:
        """Forget tracking state (e.g. when the source changes or time goes backwards)."""
        if self._video:
            self._lm.close()
            self._lm = self._make(True, self.cfg.num_poses)
            self._last_ts_ms = -1

    # ------------------------------------------------------------------ one pass
    def _run(self, lm: Any, rgb: np.ndarray, video: bool, ts_ms: int) -> list[tuple[np.ndarray, np.ndarray]]:
        import mediapipe as mp

        img = mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb))
        if self._quiet_next_run:
            with _filtered_native_stderr():
                res = lm.detect_for_video(img, ts_ms) if video else lm.detect(img)
            self._quiet_next_run = not res.pose_landmarks  # the landmark stage speaks once, when it first runs
        else:
            res = lm.detect_for_video(img, ts_ms) if video else lm.detect(img)
        out = []
        masks = res.segmentation_masks or []
        for i, pose in enumerate(res.pose_landmarks):
            a = np.array([(p.x, p.y, p.visibility if p.visibility is not None else 0.0,
                           p.presence if p.presence is not None else 0.0) for p in pose], dtype=np.float32)
            m = masks[i].numpy_view() if i < len(masks) else None
            out.append((a, m))
        return out

    def _to_frame(self, lms: np.ndarray, mask: np.ndarray | None, *, x0: int, y0: int, w: int, h: int,
                  width: int, height: int) -> tuple[PersonDetection | None, np.ndarray, np.ndarray]:
        """Landmarks/mask of a view (x0, y0, w, h) of the frame -> frame coordinates."""
        sel = lms[_COCO]
        kp = np.empty((17, 2), dtype=np.float32)
        kp[:, 0] = x0 + sel[:, 0] * w
        kp[:, 1] = y0 + sel[:, 1] * h
        conf = np.clip(sel[:, 2], 0, 1) * np.clip(sel[:, 3], 0, 1)
        inside = (kp[:, 0] >= 0) & (kp[:, 0] < width) & (kp[:, 1] >= 0) & (kp[:, 1] < height)
        conf = np.where(inside, conf, 0.0).astype(np.float32)
        score = float(np.mean(np.clip(sel[:, 3], 0, 1)))
        full = None
        if mask is not None:
            mb = mask
            if mb.shape != (h, w):
                mb = cv2.resize(mb, (w, h), interpolation=cv2.INTER_LINEAR)
            mb = mb > self.cfg.mask_threshold
            if (x0, y0, w, h) == (0, 0, width, height):
                full = mb
            else:
                full = np.zeros((height, width), dtype=bool)
                full[y0:y0 + h, x0:x0 + w] = mb
        person = make_person(full, kp, conf, score, width, height)
        return person, kp, conf

    # ------------------------------------------------------------------ per frame
    def detect(self, image_bgr: np.ndarray, stamp_ns: int) -> tuple[list[PersonDetection], list[Skeleton]]:
        height, width = image_bgr.shape[:2]
        cfg = self.cfg
        view = image_bgr
        up = cfg.upscale_max_side_px
        if up and max(width, height) < up:
            s = up / max(width, height)
            view = cv2.resize(image_bgr, (round(width * s), round(height * s)), interpolation=cv2.INTER_LINEAR)
        rgb = cv2.cvtColor(view, cv2.COLOR_BGR2RGB)
        ts = int(stamp_ns // 1_000_000)
        if self._video and ts <= self._last_ts_ms:
            if ts < self._last_ts_ms - 1000:  # time went backwards (new source): start tracking afresh
                self.reset()
            ts = max(ts, self._last_ts_ms + 1)
        self._last_ts_ms = ts
        cands: list[tuple[PersonDetection, np.ndarray, np.ndarray]] = []
        for lms, mask in self._run(self._lm, rgb, self._video, ts):
            p, kp, conf = self._to_frame(lms, mask, x0=0, y0=0, w=width, h=height, width=width, height=height)
            if p is not None:
                cands.append((p, kp, conf))
        if cfg.tiles:
            cands.extend(self._tiles(image_bgr))
        return self._select(cands, height)

    def _tiles(self, image_bgr: np.ndarray) -> list[tuple[PersonDetection, np.ndarray, np.ndarray]]:
        """Overlapping vertical strips, each shown to the (IMAGE-mode) landmarker on its own."""
        if self._tile_lm is None:
            with _filtered_native_stderr():
                self._tile_lm = self._make(False, max(2, self.cfg.num_poses // 2))
        height, width = image_bgr.shape[:2]
        n = self.cfg.tiles + 1  # strips
        tw = min(width, int(np.ceil(width / n * 1.5)))  # 50 % overlap
        out = []
        for k in range(n):
            x0 = int(round(k * (width - tw) / max(1, n - 1)))
            crop = image_bgr[:, x0:x0 + tw]
            rgb = cv2.cvtColor(crop, cv2.COLOR_BGR2RGB)
            for lms, mask in self._run(self._tile_lm, rgb, False, 0):
                p, kp, conf = self._to_frame(lms, mask, x0=x0, y0=0, w=tw, h=height, width=width, height=height)
                if p is not None:
                    out.append((p, kp, conf))
        return out

    def _select(self, cands: list[tuple[PersonDetection, np.ndarray, np.ndarray]],
                height: int) -> tuple[list[PersonDetection], list[Skeleton]]:
        cfg = self.cfg
        cands = [c for c in cands if c[0].confidence >= cfg.min_person_confidence
                 and (c[0].box_xyxy[3] - c[0].box_xyxy[1]) >= cfg.min_box_height_px]
        cands.sort(key=lambda c: -c[0].confidence)
        seen = [dedupe.Seen(c[0].box_xyxy, c[1], c[2], c[0].mask, tuple(int(v) for v in c[0].mask_origin_xy))
                for c in cands]
        keep = [cands[i] for i in dedupe.keep_distinct(seen, cfg, cfg.num_poses)]
        people = [c[0] for c in keep]
        skels = [Skeleton(keypoints_px=c[1], confidences=c[2], keypoint_set="coco17", person_index=i)
                 for i, c in enumerate(keep)]
        return people, skels
