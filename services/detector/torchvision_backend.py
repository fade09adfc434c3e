"""The paper's kind of models behind the same interface: torchvision Mask R-CNN / Keypoint R-CNN
with user-supplied checkpoint files (no package ships their weights; nothing is downloaded).

    cinetransfer detect clip.mp4 -o m.msgpack --backend torchvision \\
        --mask-checkpoint maskrcnn_resnet50_fpn_coco.pth --keypoint-checkpoint keypointrcnn_coco.pth

Checkpoints: a `state_dict` saved with `torch.save(model.state_dict(), path)` (torchvision's own
released files are exactly that), or a dict holding it under 'model' or 'state_dict' (the
torchvision reference training scripts); a 'module.' prefix (DataParallel) is stripped. Files are
loaded with `weights_only=True` (no pickled code runs). The number of classes and keypoints are
read from the tensors' shapes.

Output mapping:
- Mask R-CNN: every detection of class `tv_person_label` scoring >= `tv_score_threshold` is a
  PersonDetection (box, score, mask > 0.5 cropped to the box);
- Keypoint R-CNN: skeletons (17 COCO keypoints; joint confidence = sigmoid of torchvision's
  keypoint heat-map score), matched to the Mask R-CNN people by box IoU; without a mask
  checkpoint its own boxes become the people, with an all-False mask (mask unknown).

Installing torchvision: it must match torch (torch 2.13 <-> torchvision 0.28; the optional extra
`pip install -e .[torchvision]`). On a CPU-only torch, PyPI's torchvision wheel cannot load its
compiled operators (they are built against CUDA torch); `ensure_torchvision()` then registers a
pure-torch `nms` (the only operator these models need that has no Python fallback; RoIAlign has
one) so that the models still run on CPU — slowly (seconds per frame). With a matching GPU build
everything is native.
"""
from __future__ import annotations

import importlib.util
import logging
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.services.detector.pose_mediapipe import box_iou, make_person
from cinetransfer.shared.messages import PersonDetection, Skeleton

log = logging.getLogger("cinetransfer.detector")

MASK_ARCHS = ("maskrcnn_resnet50_fpn", "maskrcnn_resnet50_fpn_v2")
KEYPOINT_ARCHS = ("keypointrcnn_resnet50_fpn",)
_FALLBACK_LIB: Any = None


class TorchvisionUnavailable(RuntimeError):
    """torchvision is not installed or cannot run with this torch."""


class CheckpointError(RuntimeError):
    """A checkpoint file is missing, unreadable or does not fit the architecture."""


def _nms_fallback(dets, scores, iou_threshold: float):
    """Greedy NMS in plain torch (loops once per kept box)."""
    import torch

    order = torch.argsort(scores, descending=True)
    b = dets[order]
    area = (b[:, 2] - b[:, 0]).clamp(min=0) * (b[:, 3] - b[:, 1]).clamp(min=0)
    keep = []
    idx = torch.arange(len(b))
    while idx.numel():
        i = idx[0]
        keep.append(int(i))
        rest = idx[1:]
        if not rest.numel():
            break
        iw = (torch.minimum(b[i, 2], b[rest, 2]) - torch.maximum(b[i, 0], b[rest, 0])).clamp(min=0)
        ih = (torch.minimum(b[i, 3], b[rest, 3]) - torch.maximum(b[i, 1], b[rest, 1])).clamp(min=0)
        inter = iw * ih
        iou = inter / (area[i] + area[rest] - inter).clamp(min=1e-12)
        idx = rest[iou <= iou_threshold]
    return order[torch.tensor(keep, dtype=torch.long)]


def ensure_torchvision():
    """Import torchvision, making its detection models runnable on a CPU-only torch if needed."""
    global _FALLBACK_LIB
    spec = importlib.util.find_spec("torchvision")
    if spec is None:
        raise TorchvisionUnavailable(
            "the torchvision backend needs torchvision, which is not installed: install the build that "
            "matches torch (torch 2.13 -> torchvision 0.28, e.g. `pip install -e .[torchvision]`)")
    import torch

    if _FALLBACK_LIB is None and spec.submodule_search_locations:
        folder = Path(list(spec.submodule_search_locations)[0])
        libs = sorted(folder.glob("_C*.so")) + sorted(folder.glob("_C*.pyd"))
        native = False
        for lib in libs:
            try:
                torch.ops.load_library(str(lib))
                native = True
                break
            except (OSError, RuntimeError):
                continue
        if not native and not hasattr(torch.ops.torchvision, "nms"):
            log.warning("torchvision's compiled operators do not load with this torch (%s); using a pure-torch "
                        "NMS fallback (CPU, slow)", torch.__version__)
            lib = torch.library.Library("torchvision", "DEF")
            lib.define("nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
            lib.impl("nms", _nms_fallback, "CPU")
            lib.define("qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
            _FALLBACK_LIB = lib
    try:
        import torchvision
        import torchvision.ops.boxes as box_ops
    except (ImportError, RuntimeError, OSError) as e:
        raise TorchvisionUnavailable(f"torchvision is installed but cannot be imported with torch "
                                     f"{torch.__version__}: {e}") from e
    if _FALLBACK_LIB is not None:
        box_ops._assert_has_ops = lambda: None  # our registered nms stands in for the compiled one
    return torchvision


def load_state_dict(path: str | os.PathLike) -> dict[str, Any]:
    import torch

    p = Path(path)
    if not p.is_file():
        raise CheckpointError(f"{p}: no such checkpoint file")
    try:
        obj = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for a bad file (pickle, zip, runtime)
        raise CheckpointError(f"{p}: not a readable torch checkpoint ({type(e).__name__}: {e})") from None
    if isinstance(obj, dict):
        for k in ("model", "state_dict"):
            if k in obj and isinstance(obj[k], dict):
                obj = obj[k]
                break
    if not isinstance(obj, dict) or not obj or not all(hasattr(v, "shape") for v in obj.values()):
        raise CheckpointError(f"{p}: does not hold a state_dict of tensors")
    return {(k[7:] if k.startswith("module.") else k): v for k, v in obj.items()}


def build_model(arch: str, state: dict[str, Any], cfg: DetectorConfig, *, path: str = "?", **overrides: Any):
    """A torchvision detection model of `arch` with the checkpoint's weights, in eval mode."""
    tv = ensure_torchvision()
    det = tv.models.detection
    if arch not in MASK_ARCHS + KEYPOINT_ARCHS:
        raise CheckpointError(f"architecture {arch!r} is not one of {', '.join(MASK_ARCHS + KEYPOINT_ARCHS)}")
    kw: dict[str, Any] = dict(weights=None, weights_backbone=None, min_size=cfg.tv_min_size_px,
                              max_size=cfg.tv_max_size_px, box_score_thresh=cfg.tv_score_threshold)
    cls_w = state.get("roi_heads.box_predictor.cls_score.weight")
    if cls_w is None:
        raise CheckpointError(f"{path}: no 'roi_heads.box_predictor.cls_score.weight': not a {arch} checkpoint")
    kw["num_classes"] = int(cls_w.shape[0])
    if arch in KEYPOINT_ARCHS:
        kp_w = state.get("roi_heads.keypoint_predictor.kps_score_lowres.weight")
        if kp_w is None:
            raise CheckpointError(f"{path}: no keypoint predictor weights: not a {arch} checkpoint")
        kw["num_keypoints"] = int(kp_w.shape[1])
    kw.update(overrides)
    model = getattr(det, arch)(**kw)
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise CheckpointError(f"{path}: does not fit {arch}: {str(e)[:400]}") from None
    return model.eval()


class TorchvisionPose:
    """Pose backend from user checkpoints: `detect(image_bgr, stamp_ns) -> (people, skeletons)`."""

    name = "torchvision"

    def __init__(self, cfg: DetectorConfig, **model_overrides: Any) -> None:
        import torch

        self.cfg = cfg
        self._torch = torch
        self.device = torch.device(cfg.tv_device)
        self.mask_model = self.kp_model = None
        if cfg.tv_mask_checkpoint:
            st = load_state_dict(cfg.tv_mask_checkpoint)
            self.mask_model = build_model(cfg.tv_mask_arch, st, cfg, path=cfg.tv_mask_checkpoint,
                                          **model_overrides).to(self.device)
        if cfg.tv_keypoint_checkpoint:
            st = load_state_dict(cfg.tv_keypoint_checkpoint)
            self.kp_model = build_model(cfg.tv_keypoint_arch, st, cfg, path=cfg.tv_keypoint_checkpoint,
                                        **model_overrides).to(self.device)
        if self.mask_model is None and self.kp_model is None:
            raise CheckpointError("the torchvision backend needs --mask-checkpoint and/or --keypoint-checkpoint")

    def close(self) -> None:
        self.mask_model = self.kp_model = None

    def _tensor(self, image_bgr: np.ndarray):
        t = self._torch.from_numpy(np.ascontiguousarray(image_bgr[..., ::-1])).to(self.device)
        return t.permute(2, 0, 1).float().div_(255.0)

    def detect(self, image_bgr: np.ndarray, stamp_ns: int) -> tuple[list[PersonDetection], list[Skeleton]]:
        cfg = self.cfg
        h, w = image_bgr.shape[:2]
        x = self._tensor(image_bgr)
        people: list[PersonDetection] = []
        skels: list[Skeleton] = []
        with self._torch.inference_mode():
            if self.mask_model is not None:
                out = self._run(self.mask_model, x)
                keep = (out["labels"] == cfg.tv_person_label) & (out["scores"] >= cfg.tv_score_threshold)
                boxes = out["boxes"][keep].cpu().numpy()
                scores = out["scores"][keep].cpu().numpy()
                masks = (out["masks"][keep, 0] > 0.5).cpu().numpy() if "masks" in out else None
                for i in range(len(boxes)):
                    p = self._person(boxes[i], float(scores[i]), masks[i] if masks is not None else None, w, h)
                    if p is not None:
                        people.append(p)
            if self.kp_model is not None:
                out = self._run(self.kp_model, x)
                keep = (out["labels"] == cfg.tv_person_label) & (out["scores"] >= cfg.tv_score_threshold)
                kps = out["keypoints"][keep].cpu().numpy()
                ksc = out["keypoints_scores"][keep].cpu().numpy()
                kboxes = out["boxes"][keep].cpu().numpy()
                kscores = out["scores"][keep].cpu().numpy()
                for i in range(len(kps)):
                    xy = kps[i, :, :2].astype(np.float32)
                    conf = (1.0 / (1.0 + np.exp(-np.clip(ksc[i], -30, 30)))).astype(np.float32)
                    inside = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
                    conf = np.where(inside, conf, 0.0).astype(np.float32)
                    if self.mask_model is None:
                        p = self._person(kboxes[i], float(kscores[i]), None, w, h)
                        if p is None:
                            continue
                        people.append(p)
                        idx = len(people) - 1
                    else:
                        ious = [box_iou(kboxes[i], p.box_xyxy) for p in people]
                        idx = int(np.argmax(ious)) if ious and max(ious) >= 0.3 else -1
                    skels.append(Skeleton(keypoints_px=xy, confidences=conf,
                                          keypoint_set="coco17" if len(xy) == 17 else f"keypoints{len(xy)}",
                                          person_index=idx))
        return people, skels

    @staticmethod
    def _run(model, x) -> dict:
        # The first call torch.compiles torchvision's Python RoIAlign (when its compiled operators are
        # unavailable); torch's compile machinery emits DeprecationWarnings of its own on the way.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            return model([x])[0]

    @staticmethod
    def _person(box: np.ndarray, score: float, mask: np.ndarray | None, w: int, h: int) -> PersonDetection | None:
        x0, y0 = int(max(0, np.floor(box[0]))), int(max(0, np.floor(box[1])))
        x1, y1 = int(min(w, np.ceil(box[2]))), int(min(h, np.ceil(box[3])))
        if x1 <= x0 or y1 <= y0:
            return None
        if mask is not None and mask.any():
            return make_person(mask, np.zeros((0, 2), np.float32), np.zeros(0, np.float32), score, w, h)
        return PersonDetection(box_xyxy=np.array([x0, y0, x1, y1], np.float32), confidence=float(np.clip(score, 0, 1)),
                               mask_origin_xy=np.array([x0, y0], np.int32),
                               mask=np.zeros((y1 - y0, x1 - x0), dtype=bool))
