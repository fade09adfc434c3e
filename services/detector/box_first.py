"""Box-first pose backend: person boxes from an SSD, then landmarks and a mask per box (CPU, offline).

Stage 1, boxes: MediaPipe's `object_detection_ssd_mobilenetv2_oidv4_fp16.tflite` (SSD MobileNetV2
trained on Open Images, 24 classes, Person = 4) on the whole frame stretched to 300x300 RGB in
[-1, 1]. Its 1917 raw box encodings (y, x, h, w) are decoded against MediaPipe's SSD anchors
(6 layers, strides 16..512, scales 0.2..0.95, aspect ratios 1, 2, 0.5, 3, 1/3 plus an interpolated
square one; the lowest layer has 3 boxes) with scales 10/10/5/5; class scores are sigmoids.
Boxes of Person scoring >= `bf_score_threshold` (0.35: the scores are compressed, MediaPipe's own
0.5 finds only about a third of the people) go through NMS at `bf_nms_iou`.

Stage 2, per box: `pose_landmark_full.tflite` (or heavy) on a square crop of 1.25x the box's long
side, 256x256 RGB in [0, 1]: 39 landmarks (x, y, z, visibility, presence logits), a pose flag
and a 256x256 segmentation logit map. COCO-17 joints are BlazePose landmarks
[0,2,5,7,8,11,12,13,14,15,16,23,24,25,26,27,28] with confidence visibility x presence (0 for a
joint outside the frame); the mask is segmentation > `mask_threshold` inside the crop.

The person's confidence is sqrt(box certainty x pose flag), the box certainty being the SSD score
spread over [0.3, 1] (`box_certainty`); the pose flag is the second opinion that drops static
objects the SSD takes for people (`bf_min_pose_flag`). The reported box is the mask's bounding box
where it agrees with the SSD box (IoU >= `bf_mask_box_min_iou`), else the SSD box; the second look
(`second_look`: one more upright crop around the previous frame's largest person, when its box was
changing and the last look gained something) widens the box it agrees with to its own mask's box.

Video mode (`running_mode`, the default) follows people as MediaPipe does: each person of the
previous frame is looked for in the crop its auxiliary landmarks (33 mid-hip, 34 body scale) give,
rotated upright, so twirling or tumbling bodies stay aligned (this runs beside the SSD, on the
other thread when `threads` = 2). An SSD box overlapping a person found so (IoU >= `bf_track_iou`)
confirms it; the other boxes get upright crops of their own; a person the SSD loses is kept on its
landmarks alone for up to `bf_max_coast_frames` while the pose flag stays >= `bf_track_min_pose_flag`.
`track_id` goes by motion: each box to the previous person whose box, moved by its velocity, it
overlaps most (the crop that found it counts a little); a person not seen (hidden, or merged into
one box with another) is remembered on its motion for `ghost_frames` and gets its id back.
`reset()`, image mode and time going backwards forget it all.
"""
from __future__ import annotations

import concurrent.futures as cf
import logging
import math
import threading

import cv2
import numpy as np

from cinetransfer.services.detector import box_models, dedupe
from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.shared.boxes import box_iou
from cinetransfer.shared.messages import PersonDetection, Skeleton

log = logging.getLogger("cinetransfer.detector")

PERSON_CLASS = 4  # line 5 of the 24-line Open Images labelmap ('???' is 0)
SSD_INPUT = 300
LANDMARK_INPUT = 256
BLAZEPOSE_TO_COCO17 = np.asarray((0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28))


class BoxFirstUnavailable(RuntimeError):
    """The box-first backend's models (npm) or runtime (ai-edge-litert) are not installed."""


def ssd_anchors(*, input_size: int = SSD_INPUT, strides=(16, 32, 64, 128, 256, 512), min_scale: float = 0.2,
                max_scale: float = 0.95, aspect_ratios=(1.0, 2.0, 0.5, 3.0, 0.3333),
                interpolated_ratio: float = 1.0) -> np.ndarray:
    """MediaPipe's SsdAnchorsCalculator (reduce_boxes_in_lowest_layer): (N, 4) anchors (cx, cy, w, h),
    normalised, in the order the model's outputs use."""
    n = len(strides)

    def scale(i: int) -> float:
        return min_scale + (max_scale - min_scale) * i / (n - 1)

    out = []
    for layer, stride in enumerate(strides):
        if layer == 0:
            ars, scs = [1.0, 2.0, 0.5], [0.1, scale(0), scale(0)]
        else:
            ars = list(aspect_ratios) + [interpolated_ratio]
            nxt = 1.0 if layer == n - 1 else scale(layer + 1)
            scs = [scale(layer)] * len(aspect_ratios) + [math.sqrt(scale(layer) * nxt)]
        wh = [(s * math.sqrt(a), s / math.sqrt(a)) for a, s in zip(ars, scs)]
        fm = int(math.ceil(input_size / stride))
        for y in range(fm):
            for x in range(fm):
                for w, h in wh:
                    out.append(((x + 0.5) / fm, (y + 0.5) / fm, w, h))
    return np.asarray(out, dtype=np.float32)


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> list[int]:
    """Greedy non-maximum suppression: indices kept, best first."""
    order = list(np.argsort(-scores))
    keep: list[int] = []
    for i in order:
        if all(box_iou(boxes[i], boxes[k]) <= iou for k in keep):
            keep.append(int(i))
    return keep


def _sigmoid(x: np.ndarray) -> np.ndarray:
    """1 / (1 + exp(-clip(x, -60, 60))), in x's float type, into one fresh array (x is left as it is)."""
    y = np.clip(x, -60, 60)
    np.negative(y, out=y)
    np.exp(y, out=y)
    y += 1.0
    return np.divide(1.0, y, out=y)


def _interpreter(path, threads: int):
    from ai_edge_litert.interpreter import Interpreter

    from cinetransfer.services.detector.pose_mediapipe import _filtered_native_stderr

    with _filtered_native_stderr():  # LiteRT announces its XNNPACK delegate on fd 2
        it = Interpreter(model_path=str(path), num_threads=threads)
        it.allocate_tensors()
    return it


def _area(b: np.ndarray) -> float:
    return float(max(0.0, b[2] - b[0]) * max(0.0, b[3] - b[1]))


class BoxFirstPose:
    """Pose backend: `detect(image_bgr, stamp_ns) -> (people, skeletons)`."""

    name = "box_first"
    # Second look: one more landmark pass per frame (~12 ms of CPU, beside the SSD) on an upright crop
    # around the previous frame's largest person; its mask's box widens the box it agrees with.
    # DAVIS dance-twirl box IoU 0.910 -> 0.92, parkour unchanged (benchmarks/eval_detector.py).
    second_look = True
    look_min_change = 0.05
    # A look that barely moved the box (less than `look_min_gain` of its IoU) rests the looks for
    # `look_rest_frames` frames, however much the box changes: a rendered dancer's box changes by ~10 %
    # a frame, and its looks then widened it by a median 1 px, a landmark pass for nothing.
    look_min_gain = 0.01
    look_rest_frames = 4
    ghost_frames = 15  # frames a person not seen is remembered for (its id given back when it reappears)
    provenance_bonus = 0.2  # association score bonus for the track whose landmark crop found the box

    def __init__(self, cfg: DetectorConfig) -> None:
        self.cfg = cfg
        ok, why = box_models.available(landmark_model=cfg.bf_landmark_model)
        if not ok:
            raise BoxFirstUnavailable(why)
        self._ssd = _interpreter(box_models.model_path(box_models.SSD_MODEL), cfg.bf_threads)
        lmk_path = box_models.model_path(box_models.LANDMARK_MODELS[cfg.bf_landmark_model])
        self._lmk = _interpreter(lmk_path, cfg.bf_threads)
        labels = box_models.model_path(box_models.LABELMAP).read_text().splitlines()
        if len(labels) <= PERSON_CLASS or labels[PERSON_CLASS].strip() != "Person":
            raise BoxFirstUnavailable(f"unexpected labelmap: line {PERSON_CLASS} is not 'Person'")
        self._anchors = ssd_anchors()
        self._ssd_in = self._ssd.get_input_details()[0]["index"]
        outs = self._ssd.get_output_details()
        # outputs: (1, 1917, 4) box encodings and (1, 1917, 24) class logits
        self._ssd_boxes = next(o["index"] for o in outs if o["shape"][-1] == 4)
        self._ssd_scores = next(o["index"] for o in outs if o["shape"][-1] != 4)
        self._lmk_in = self._lmk.get_input_details()[0]["index"]
        self._lmk_out = {}
        for o in self._lmk.get_output_details():
            shape = tuple(o["shape"])
            if shape == (1, 195):
                self._lmk_out["landmarks"] = o["index"]
            elif shape == (1, 1):
                self._lmk_out["flag"] = o["index"]
            elif len(shape) == 4 and shape[1:3] == (LANDMARK_INPUT, LANDMARK_INPUT):
                self._lmk_out["seg"] = o["index"]
        if set(self._lmk_out) != {"landmarks", "flag", "seg"}:
            raise BoxFirstUnavailable(f"unexpected landmark model outputs: {self._lmk.get_output_details()}")
        self._lmk_path = lmk_path
        self._lmk2, self._pool = None, None
        self.use_worker(cfg.bf_pose_worker)
        self._prev: list[dict] = []  # the last frame's people: box, track id, tracking crop, frames coasted
        self._ghosts: list[dict] = []  # people not seen lately: last box, velocity, id (see _emit)
        self._next_id = 0
        self._last_stamp: int | None = None
        self._since_ssd = 0  # frames since the SSD last ran (bf_ssd_every)
        self._look_gain, self._since_look = math.inf, 0  # the last second look's gain, frames since it

    def use_worker(self, on: bool) -> None:
        """With threads 2, run the SSD and a second landmark interpreter in a worker thread beside the
        caller's crop (LiteRT releases the GIL while it computes), or (off) everything in the caller's
        thread: the same measurements. Call it between frames, from the thread that calls `detect`."""
        on = bool(on) and self.cfg.threads > 1
        if on and self._pool is None:
            self._lmk2 = _interpreter(self._lmk_path, self.cfg.bf_threads)
            self._pool = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="box_first")
        elif not on and self._pool is not None:
            self._pool.shutdown(wait=True)
            self._lmk2, self._pool = None, None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        self._ssd = self._lmk = self._lmk2 = None

    def reset(self) -> None:
        self._prev = []
        self._ghosts = []
        self._last_stamp = None
        self._since_ssd = 0
        self._look_gain, self._since_look = math.inf, 0

    # ------------------------------------------------------------------ stage 1
    def boxes(self, image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Person boxes (N, 4) xyxy [px] and scores (N,), after threshold and NMS, best first."""
        h, w = image_bgr.shape[:2]
        x = cv2.resize(image_bgr, (SSD_INPUT, SSD_INPUT), interpolation=cv2.INTER_AREA)
        x = cv2.cvtColor(x, cv2.COLOR_BGR2RGB).astype(np.float32)
        x = x * (2.0 / 255.0) - 1.0
        self._ssd.set_tensor(self._ssd_in, x[None])
        self._ssd.invoke()
        raw = self._ssd.get_tensor(self._ssd_boxes)[0]
        logit = self._ssd.get_tensor(self._ssd_scores)[0][:, PERSON_CLASS]
        cand = np.flatnonzero(logit >= math.log(self.cfg.bf_score_threshold / (1 - self.cfg.bf_score_threshold)))
        if cand.size == 0:
            return np.zeros((0, 4), np.float32), np.zeros(0, np.float32)
        a, r = self._anchors[cand], raw[cand]
        cx = r[:, 1] / 10.0 * a[:, 2] + a[:, 0]
        cy = r[:, 0] / 10.0 * a[:, 3] + a[:, 1]
        bw = np.exp(np.clip(r[:, 3] / 5.0, -10, 10)) * a[:, 2]
        bh = np.exp(np.clip(r[:, 2] / 5.0, -10, 10)) * a[:, 3]
        boxes = np.stack([(cx - bw / 2) * w, (cy - bh / 2) * h, (cx + bw / 2) * w, (cy + bh / 2) * h], axis=1)
        boxes[:, 0::2] = np.clip(boxes[:, 0::2], 0, w)
        boxes[:, 1::2] = np.clip(boxes[:, 1::2], 0, h)
        scores = _sigmoid(logit[cand]).astype(np.float32)
        ok = (boxes[:, 2] - boxes[:, 0] >= 2) & (boxes[:, 3] - boxes[:, 1] >= max(2, self.cfg.min_box_height_px))
        boxes, scores = boxes[ok].astype(np.float32), scores[ok]
        keep = nms(boxes, scores, self.cfg.bf_nms_iou)[: self.cfg.bf_max_people * 2]
        return boxes[keep], scores[keep]

    # ------------------------------------------------------------------ stage 2
    def box_roi(self, box: np.ndarray) -> tuple[float, float, float, float, float]:
        """Upright square crop of `bf_crop_scale` x the box's long side: (cx, cy, side, cos, sin)."""
        cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
        side = max(float(max(box[2] - box[0], box[3] - box[1])) * self.cfg.bf_crop_scale, 8.0)
        return float(cx), float(cy), side, 1.0, 0.0

    @staticmethod
    def landmark_roi(lm: np.ndarray) -> tuple[float, float, float, float, float] | None:
        """MediaPipe's tracking crop from the auxiliary landmarks: centred on landmark 33 (mid-hip),
        side 2.5 x its distance to landmark 34, rotated so that 33 -> 34 points up in the crop."""
        c, e = lm[33, :2].astype(np.float64), lm[34, :2].astype(np.float64)
        d = e - c
        r = float(np.hypot(*d))
        if not np.isfinite(r) or r < 2.0:
            return None
        return float(c[0]), float(c[1]), 2.5 * r, float(-d[1] / r), float(d[0] / r)

    def landmarks(self, image_bgr: np.ndarray, roi: tuple, lmk=None) -> tuple[np.ndarray, float, np.ndarray]:
        """Landmarks (39, 5: x, y [frame px], z, visibility, presence [0,1]), pose flag and segmentation
        probability (256, 256) of one crop `roi` = (cx, cy, side, cos, sin)."""
        a, t = self._crop_matrix(roi)
        crop = cv2.warpAffine(image_bgr, np.hstack([a, t[:, None]]), (LANDMARK_INPUT, LANDMARK_INPUT),
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        it = lmk if lmk is not None else self._lmk
        # RGB in [0, 1] written straight into the model's input (no float image, no copy of it); the
        # view into the interpreter's buffer is let go before it runs
        np.multiply(cv2.cvtColor(crop, cv2.COLOR_BGR2RGB), np.float32(1.0 / 255.0), dtype=np.float32,
                    out=it.tensor(self._lmk_in)()[0])
        it.invoke()
        lm = it.get_tensor(self._lmk_out["landmarks"]).reshape(39, 5).astype(np.float64)
        flag = float(np.ravel(it.get_tensor(self._lmk_out["flag"]))[0])
        seg = it.get_tensor(self._lmk_out["seg"])[0, :, :, 0]  # get_tensor copies: nothing else holds it
        cx, cy, side, co, si = roi
        q = (lm[:, :2] - LANDMARK_INPUT / 2) * (side / LANDMARK_INPUT)  # crop offsets [frame px], crop axes
        lm[:, 0] = cx + co * q[:, 0] - si * q[:, 1]
        lm[:, 1] = cy + si * q[:, 0] + co * q[:, 1]
        lm[:, 3:5] = _sigmoid(lm[:, 3:5])
        return lm, flag, _sigmoid(seg)

    @staticmethod
    def _crop_matrix(roi: tuple, offset=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Affine map frame pixel index (+ offset) -> crop pixel index (pixel centres at +0.5)."""
        cx, cy, side, co, si = roi
        s = LANDMARK_INPUT / side
        a = s * np.array([[co, si], [-si, co]])  # S R^T
        t = a @ (np.array([offset[0] + 0.5 - cx, offset[1] + 0.5 - cy])) + (LANDMARK_INPUT / 2 - 0.5)
        return a, t

    def _mask(self, seg: np.ndarray, roi: tuple, width: int, height: int) -> tuple[np.ndarray, tuple] | None:
        """The crop's segmentation, thresholded, in frame pixels: (mask, (x0, y0)) clipped to the frame."""
        on = seg > self.cfg.mask_threshold
        rows, cols = np.flatnonzero(on.any(axis=1)), np.flatnonzero(on.any(axis=0))
        if rows.size == 0:
            return None
        # A frame pixel's bilinear value exceeds the threshold only if one of its four crop neighbours
        # does: only the frame rectangle round those crop pixels (one pixel wider) needs the warp.
        cx, cy, side, co, si = roi
        u = np.array([cols[0] - 1.0, cols[-1] + 2.0, cols[-1] + 2.0, cols[0] - 1.0]) - LANDMARK_INPUT / 2
        v = np.array([rows[0] - 1.0, rows[0] - 1.0, rows[-1] + 2.0, rows[-1] + 2.0]) - LANDMARK_INPUT / 2
        k = side / LANDMARK_INPUT
        xs, ys = cx + k * (co * u - si * v), cy + k * (si * u + co * v)
        fx0, fy0 = max(0, int(math.floor(xs.min())) - 1), max(0, int(math.floor(ys.min())) - 1)
        fx1, fy1 = min(width, int(math.ceil(xs.max())) + 1), min(height, int(math.ceil(ys.max())) + 1)
        if fx1 <= fx0 or fy1 <= fy0:
            return None
        a, t = self._crop_matrix(roi, (fx0, fy0))
        prob = cv2.warpAffine(seg, np.hstack([a, t[:, None]]), (fx1 - fx0, fy1 - fy0),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=0.0)
        return prob > self.cfg.mask_threshold, (fx0, fy0)

    # ------------------------------------------------------------------ per frame
    def box_certainty(self, score: float) -> float:
        """The SSD's Person score spread over [0.3, 1]: its scores are compressed (on TUD, true people
        score 0.41-0.54 (10-90 %), false ones 0.35-0.43), so `bf_score_threshold` maps to 0.3 and
        `bf_score_full` and above to 1."""
        t, full = self.cfg.bf_score_threshold, self.cfg.bf_score_full
        return 0.3 + 0.7 * float(np.clip((score - t) / max(1e-6, full - t), 0.0, 1.0))

    def _candidate(self, raw: tuple, box: np.ndarray | None, score: float, width: int, height: int):
        """One candidate from one crop's landmark result `raw` = (lm, flag, seg, roi), with its detector
        box and score (box None: followed by landmarks alone):
        (confidence, box, mask box, mask origin, mask, keypoints, joint conf, lm) or None."""
        cfg = self.cfg
        lm, flag, seg, roi = raw
        if flag < (cfg.bf_min_pose_flag if box is not None else cfg.bf_track_min_pose_flag):
            return None
        conf = math.sqrt(self.box_certainty(score) * flag) if box is not None else cfg.bf_track_confidence * flag
        sel = lm[BLAZEPOSE_TO_COCO17]
        kp = sel[:, :2].astype(np.float32)
        jc = (sel[:, 3] * sel[:, 4]).astype(np.float32)
        inside = (kp[:, 0] >= 0) & (kp[:, 0] < width) & (kp[:, 1] >= 0) & (kp[:, 1] < height)
        jc = np.where(inside, jc, 0.0).astype(np.float32)
        mb = mask_crop = None
        mk = self._mask(seg, roi, width, height)
        if mk is not None and mk[0].any():
            full, (ox, oy) = mk
            ys = np.flatnonzero(full.any(axis=1))
            xs = np.flatnonzero(full.any(axis=0))
            mb = np.array([ox + xs[0], oy + ys[0], ox + xs[-1] + 1, oy + ys[-1] + 1], dtype=np.float32)
            mask_crop = np.ascontiguousarray(full[ys[0]:ys[-1] + 1, xs[0]:xs[-1] + 1])
        if box is None:  # tracked without a detector box: the mask's box, else the confident joints'
            if mb is None:
                ok = jc > 0.3
                if ok.sum() < 3:
                    return None
                p = kp[ok]
                mb = np.array([*p.min(axis=0), *p.max(axis=0)], dtype=np.float32)
            box = mb
        if mask_crop is None:
            x0, y0, x1, y1 = (int(v) for v in np.round(box))
            mask_crop = np.zeros((max(1, y1 - y0), max(1, x1 - x0)), dtype=bool)
            origin = (x0, y0)
        else:
            origin = (int(mb[0]), int(mb[1]))
        return conf, box.astype(np.float32), mb, origin, mask_crop, kp, jc, lm

    def _final_box(self, box: np.ndarray, mb: np.ndarray | None) -> np.ndarray:
        """The reported box: the mask's box where it agrees with the detector's box (IoU >=
        bf_mask_box_min_iou; it is then the tighter of the two), else the detector's box (a mask that
        disagrees has lost hidden or thin parts of the person, or taken in a neighbour)."""
        cfg = self.cfg
        if mb is None or box_iou(mb, box) < cfg.bf_mask_box_min_iou:
            return box
        w = cfg.bf_mask_box_weight
        return (w * mb + (1 - w) * box).astype(np.float32)

    def _look_roi(self) -> tuple | None:
        """The second look's crop: upright, around the previous frame's largest person's box, if that
        box was changing (1 - IoU with the one before >= `look_min_change`: moving, turning, limbs or
        clothes flying) and the looks are not resting (`_look_rests`); a steady person's box is
        already settled."""
        self._since_look += 1
        if not self._prev or self._look_rests():
            return None
        t = max(self._prev, key=lambda t: _area(t["box"]))
        if t["moved"] < self.look_min_change:
            return None
        self._since_look = 0
        return self.box_roi(t["box"])

    def _look_rests(self) -> bool:
        """Whether the last look widened its box by less than `look_min_gain` (1 - IoU of the box
        before and after; 0 when it agreed with no box) within the last `look_rest_frames` frames."""
        return self._look_gain < self.look_min_gain and self._since_look < self.look_rest_frames

    def _look_box(self, raw: tuple, width: int, height: int) -> np.ndarray | None:
        """The box of the second look's mask (None if empty). One crop's mask loses parts another
        crop keeps (a twirling dancer's flying scarf, an arm at the crop's edge); the box of the
        union of two masks is the union of their boxes. The reported mask stays the first crop's.
        The crop is upright, so the box is found in crop pixels and scaled (no warp to the frame)."""
        _, _, seg, (cx, cy, side, _, _) = raw
        on = seg > self.cfg.mask_threshold
        ys = np.flatnonzero(on.any(axis=1))
        xs = np.flatnonzero(on.any(axis=0))
        if xs.size == 0:
            return None
        s = side / LANDMARK_INPUT
        box = np.array([cx + (xs[0] - LANDMARK_INPUT / 2) * s, cy + (ys[0] - LANDMARK_INPUT / 2) * s,
                        cx + (xs[-1] + 1 - LANDMARK_INPUT / 2) * s, cy + (ys[-1] + 1 - LANDMARK_INPUT / 2) * s])
        return np.clip(box, 0, [width, height, width, height]).astype(np.float32)

    def _run_crops(self, image_bgr: np.ndarray, rois: list[tuple], *, with_ssd: bool):
        """Landmarks of every crop (and, if asked, the SSD boxes), split over the caller's thread and the
        worker thread when there is one: ([(lm, flag, seg, roi)], (boxes, scores) or None)."""
        out: list = [None] * len(rois)
        if self._pool is None:
            ssd = self.boxes(image_bgr) if with_ssd else None
            for k, roi in enumerate(rois):
                out[k] = (*self.landmarks(image_bgr, roi), roi)
            return out, ssd
        lock = threading.Lock()
        todo = iter(range(len(rois)))

        def drain(lmk) -> None:
            while True:
                with lock:
                    k = next(todo, None)
                if k is None:
                    return
                out[k] = (*self.landmarks(image_bgr, rois[k], lmk), rois[k])

        def worker():
            ssd = self.boxes(image_bgr) if with_ssd else None
            drain(self._lmk2)
            return ssd

        fut = self._pool.submit(worker)
        try:
            drain(self._lmk)
        finally:
            ssd = fut.result()
        return out, ssd

    def detect(self, image_bgr: np.ndarray, stamp_ns: int) -> tuple[list[PersonDetection], list[Skeleton]]:
        cfg = self.cfg
        height, width = image_bgr.shape[:2]
        backwards = self._last_stamp is not None and stamp_ns < self._last_stamp - 1_000_000_000
        if cfg.running_mode == "image" or backwards:
            self.reset()  # frames are unrelated (image mode), or time went backwards (a new source)
        self._last_stamp = int(stamp_ns)
        # 1. the people of the last frame, looked for where their landmarks put them (as MediaPipe does in
        #    video mode: the crop follows the body's rotation), while the SSD looks at the whole frame
        tracks = [j for j, t in enumerate(self._prev) if t["roi"] is not None and t["coast"] < cfg.bf_max_coast_frames]
        look = self._look_roi() if self.second_look else None
        rois = [self._prev[j]["roi"] for j in tracks] + ([look] if look is not None else [])
        skip = self._may_skip_ssd(tracks)
        raws, ssd = self._run_crops(image_bgr, rois, with_ssd=not skip)
        second = self._look_box(raws.pop(), width, height) if look is not None else None
        followed = {j: (raw, self._candidate(raw, None, 0.0, width, height)) for j, raw in zip(tracks, raws)}
        followed = {j: v for j, v in followed.items() if v[1] is not None}
        if skip:
            cands = self._carried(followed, len(tracks), width, height)
            if cands is not None:
                self._since_ssd += 1
                return self._emit(cands, second)
            ssd = self.boxes(image_bgr)  # someone was not found again by the landmarks: the SSD looks after all
        self._since_ssd = 0
        return self._emit(self._confirmed(image_bgr, followed, *ssd, width, height), second)

    def _may_skip_ssd(self, tracks: list[int]) -> bool:
        """Whether this frame may go without the SSD: within `bf_ssd_every` frames of its last run, and
        at most `bf_ssd_skip_max_people` people (in a crowd people come and go), every person of the last
        frame was confirmed by a detector box, is followed by a landmark crop and no one is missing (a
        person not seen is looked for by the SSD on every frame)."""
        if self.cfg.bf_ssd_every <= 1 or self._since_ssd + 1 >= self.cfg.bf_ssd_every:
            return False
        return (0 < len(self._prev) <= self.cfg.bf_ssd_skip_max_people and not self._ghosts
                and len(tracks) == len(self._prev)
                and all(t["coast"] == 0 and t["ssd"] is not None for t in self._prev))

    def _carried(self, followed: dict, n_tracks: int, width: int, height: int) -> list | None:
        """The candidates of a frame without the SSD: each person followed by its landmarks again gets
        the box of its mask moved by the offset the detector's box had from its mask when last run, and
        that box's score. None when someone was not found again (pose flag low, or no mask)."""
        if len(followed) < n_tracks or any(c[2] is None for _, c in followed.values()):
            return None
        cands = []
        for j, (raw, c) in followed.items():
            score, offset = self._prev[j]["ssd"]
            box = np.clip(c[2] + offset, 0, [width, height, width, height]).astype(np.float32)
            conf = math.sqrt(self.box_certainty(score) * raw[1])
            cands.append(((conf, box, *c[2:]), j, 0, (score, offset)))
        return cands

    @staticmethod
    def _ssd_memo(score: float, box: np.ndarray, mask_box: np.ndarray | None) -> tuple | None:
        """What a frame without the SSD needs of this one's detector box: (score, box - mask box)."""
        return None if mask_box is None else (float(score), (box - mask_box).astype(np.float32))

    def _confirmed(self, image_bgr: np.ndarray, followed: dict, boxes: np.ndarray, scores: np.ndarray,
                   width: int, height: int) -> list:
        """The candidates of a frame with the SSD's boxes: (candidate, previous person index or -1, frames
        without a detector box, SSD memo)."""
        # a detector box on a followed person confirms it (its score, its box); the other boxes get
        # an upright crop of their own
        fj = list(followed)
        match = self._match(list(boxes), [followed[j][1][1] for j in fj])
        cands = []
        for i, k in match.items():
            raw, c = followed[fj[k]]
            conf = math.sqrt(self.box_certainty(float(scores[i])) * raw[1])
            cands.append(((conf, boxes[i].astype(np.float32), *c[2:]), fj[k], 0,
                          self._ssd_memo(scores[i], boxes[i], c[2])))
        rest = [i for i in range(len(boxes)) if i not in match]
        raws, _ = self._run_crops(image_bgr, [self.box_roi(boxes[i]) for i in rest], with_ssd=False)
        idmatch = self._match([boxes[i] for i in rest], [t["box"] for t in self._prev])  # ids only
        used = {fj[k] for k in match.values()}
        for n, (i, raw) in enumerate(zip(rest, raws)):
            c = self._candidate(raw, boxes[i], float(scores[i]), width, height)
            j = idmatch.get(n, -1)
            if c is not None:
                cands.append((c, j if j not in used else -1, 0, self._ssd_memo(scores[i], boxes[i], c[2])))
        for j in fj:  # people the detector lost this frame: followed by their landmarks alone
            if j not in used:
                cands.append((followed[j][1], j, self._prev[j]["coast"] + 1, None))
        return cands

    def _emit(self, cands: list, second: np.ndarray | None) -> tuple[list[PersonDetection], list[Skeleton]]:
        """The frame's people from its candidates (candidate, previous person index or -1, frames
        without a detector box, SSD memo): duplicates dropped, boxes final (widened by the second look's mask box
        `second`), track ids kept or new."""
        cfg = self.cfg
        cands.sort(key=lambda c: -c[0][0])
        # two crops on one person: keep the surer one (dedupe.py: overlapping boxes, or nested ones on one body)
        seen = [dedupe.Seen(c[0][1], c[0][5], c[0][6], c[0][4], c[0][3]) for c in cands]
        keep = [cands[i] for i in dedupe.keep_distinct(seen, cfg, cfg.bf_max_people)]
        finals = [self._final_box(c[0][1], c[0][2]) for c in keep]
        if second is not None:
            self._widen(finals, second)
        tracks = self._prev + self._ghosts
        owner = self._assign(finals, [c[1] for c in keep], tracks)
        self._prev, people, skels = [], [], []
        for i, ((conf, _, _, origin, mask, kp, jc, lm), _, coast, memo) in enumerate(keep):
            box, t = finals[i], owner[i]
            if t >= 0:
                tid, last, vel = tracks[t]["id"], tracks[t]["box"], tracks[t]["vel"]
                vel = 0.5 * vel + 0.5 * (box - last)
            else:
                tid, self._next_id = self._next_id, self._next_id + 1
                last, vel = box, np.zeros(4, np.float32)
            moved = 1.0 - box_iou(box, last) if t >= 0 else 1.0  # box change since the last frame
            self._prev.append({"box": box, "id": tid, "roi": self.landmark_roi(lm), "coast": coast, "moved": moved,
                               "vel": vel, "unseen": 0, "ssd": memo})
            people.append(PersonDetection(box_xyxy=box, confidence=float(np.clip(conf, 0, 1)),
                                          mask_origin_xy=np.asarray(origin, dtype=np.int32), mask=mask, track_id=tid))
            skels.append(Skeleton(keypoints_px=kp, confidences=jc, keypoint_set="coco17", person_index=i))
        # People not seen this frame (hidden behind another, or merged into one box with them) are
        # remembered on their last motion for a while, so they get their id back when they reappear.
        claimed = set(owner)
        self._ghosts = [{**t, "box": t["box"] + t["vel"], "unseen": t["unseen"] + 1, "roi": None}
                        for k, t in enumerate(tracks) if k not in claimed and t["unseen"] < self.ghost_frames]
        return people, skels

    def _widen(self, finals: list[np.ndarray], second: np.ndarray) -> None:
        """Widen the box the second look's box agrees with (IoU >= bf_mask_box_min_iou: the same
        person) to the union of the two, in place, and keep what the look gained (`_look_rests`)."""
        self._look_gain = 0.0
        if not finals:
            return
        k = max(range(len(finals)), key=lambda i: box_iou(finals[i], second))
        if box_iou(finals[k], second) < self.cfg.bf_mask_box_min_iou:
            return
        wide = np.concatenate([np.minimum(finals[k][:2], second[:2]), np.maximum(finals[k][2:], second[2:])])
        self._look_gain = 1.0 - box_iou(finals[k], wide)
        finals[k] = wide.astype(np.float32)

    def _assign(self, boxes: list[np.ndarray], came_from: list[int], tracks: list[dict]) -> list[int]:
        """Track of each box (-1 = new person): greedy by IoU with where each track's motion puts it
        this frame, plus `provenance_bonus` for the track whose landmark crop found the box. Motion,
        not the crop alone, decides: when two people cross, a crop can slide onto the other one."""
        n_prev = len(self._prev)
        pairs = []
        for i, b in enumerate(boxes):
            for k, t in enumerate(tracks):
                score = box_iou(b, t["box"] + t["vel"]) + (self.provenance_bonus if k < n_prev and k == came_from[i]
                                                           else 0.0)
                if score >= self.cfg.bf_track_iou:
                    pairs.append((score, i, k))
        owner, used = [-1] * len(boxes), set()
        for _, i, k in sorted(pairs, reverse=True):
            if owner[i] < 0 and k not in used:
                owner[i] = k
                used.add(k)
        return owner

    def _match(self, boxes: list[np.ndarray], prev: list[np.ndarray]) -> dict[int, int]:
        """Greedy IoU association {box index: previous index}."""
        pairs = sorted(((box_iou(b, pb), i, j) for i, b in enumerate(boxes) for j, pb in enumerate(prev)),
                       reverse=True)
        out: dict[int, int] = {}
        used = set()
        for iou, i, j in pairs:
            if iou < self.cfg.bf_track_iou:
                break
            if i not in out and j not in used:
                out[i] = j
                used.add(j)
        return out
