"""The torchvision (Mask R-CNN / Keypoint R-CNN) backend with checkpoints the test writes itself."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from cinetransfer.services.detector import torchvision_backend as tvb
from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.services.detector.core import Detector
from cinetransfer.shared import codec
from cinetransfer.shared.messages import Measurement

HAVE_TV = importlib.util.find_spec("torchvision") is not None
needs_tv = pytest.mark.skipif(not HAVE_TV, reason="torchvision not installed (optional extra)")


def test_missing_torchvision_is_a_clear_error(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "torchvision" else real(n, *a))
    with pytest.raises(tvb.TorchvisionUnavailable, match="torchvision 0.28"):
        tvb.ensure_torchvision()


def test_bad_checkpoint_files(tmp_path):
    with pytest.raises(tvb.CheckpointError, match="no such checkpoint"):
        tvb.load_state_dict(tmp_path / "missing.pth")
    bad = tmp_path / "bad.pth"
    bad.write_bytes(b"not a torch file")
    with pytest.raises(tvb.CheckpointError, match="not a readable torch checkpoint"):
        tvb.load_state_dict(bad)
    import torch

    torch.save({"epoch": 3}, tmp_path / "nodict.pth")
    with pytest.raises(tvb.CheckpointError, match="state_dict"):
        tvb.load_state_dict(tmp_path / "nodict.pth")


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """Randomly initialised Mask R-CNN and Keypoint R-CNN (2 classes: background, person)."""
    import torch

    tv = tvb.ensure_torchvision()
    d = tmp_path_factory.mktemp("ckpt")
    torch.manual_seed(0)
    det = tv.models.detection
    m = det.maskrcnn_resnet50_fpn(weights=None, weights_backbone=None, num_classes=2)
    torch.save(m.state_dict(), d / "mask.pth")
    k = det.keypointrcnn_resnet50_fpn(weights=None, weights_backbone=None, num_classes=2)
    torch.save({"model": {f"module.{n}": v for n, v in k.state_dict().items()}}, d / "kp.pth")  # DDP-style
    return d / "mask.pth", d / "kp.pth"


@needs_tv
@pytest.mark.slow
def test_random_checkpoints_run_behind_the_detector_interface(checkpoints):
    mask_ckpt, kp_ckpt = checkpoints
    cfg = DetectorConfig(backend="torchvision", tv_mask_checkpoint=str(mask_ckpt),
                         tv_keypoint_checkpoint=str(kp_ckpt), tv_score_threshold=0.0, tv_min_size_px=96,
                         tv_max_size_px=160, threads=1)
    backend = tvb.TorchvisionPose(cfg, rpn_pre_nms_top_n_test=100, rpn_post_nms_top_n_test=30,
                                  box_detections_per_img=4)
    img = (np.random.default_rng(1).random((90, 120, 3)) * 255).astype(np.uint8)
    with Detector(cfg, backend=backend) as det:
        m = det.process(img, 5, 7, source="noise", fps=10.0)
    assert m.detector == "torchvision" and m.frame_index == 5
    # random weights: whatever it finds must still be a well-formed measurement
    assert len(m.people) <= 4 and len(m.skeletons) <= 4
    for p in m.people:
        x0, y0, x1, y1 = p.box_xyxy
        assert 0 <= x0 < x1 <= 120 and 0 <= y0 < y1 <= 90 and 0 <= p.confidence <= 1
        assert p.mask.shape == (int(y1) - int(y0), int(x1) - int(x0)) or p.mask.any()
    for s in m.skeletons:
        assert s.keypoints_px.shape == (17, 2) and s.keypoint_set == "coco17"
        assert ((s.confidences >= 0) & (s.confidences <= 1)).all()
        assert -1 <= s.person_index < len(m.people)
    assert isinstance(codec.decode(codec.encode(m), Measurement), Measurement)


@needs_tv
@pytest.mark.slow
def test_checkpoint_that_does_not_fit_the_architecture(checkpoints):
    _, kp_ckpt = checkpoints
    cfg = DetectorConfig(backend="torchvision", tv_mask_checkpoint=str(kp_ckpt))
    with pytest.raises(tvb.CheckpointError, match="does not fit maskrcnn_resnet50_fpn"):
        tvb.TorchvisionPose(cfg)
