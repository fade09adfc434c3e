"""Thin-lens depth of field from a depth buffer: a blur stack, blended per pixel by its blur circle.

Every pixel's blur-circle diameter comes from its depth with the lens model of shared/camera.py
(`blur_diameter_mm`, the same formula the planner and the truth use), as a Gaussian of sigma
d / 4 (`SIGMA_PER_DIAMETER`). The image is blurred at a few fixed sigmas (`SIGMA_LEVELS`, the
wide ones on a downscaled copy: cheap) and each pixel takes the two levels around its own sigma,
linearly blended. Deterministic: the same image and depths give the same bytes.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from cinetransfer.shared import camera as cam

#: the blur stack's sigmas [px of the output image]; a pixel's sigma beyond the last is clamped
SIGMA_LEVELS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


def sigma_px(depth_m: np.ndarray, focal_mm: float, f_number: float, focus_m: float, sensor_width_mm: float,
             width_px: int) -> np.ndarray:
    """Per-pixel defocus sigma [px] of an image `width_px` wide from depths [m] (inf = sky)."""
    f = focal_mm / 1000.0
    k = f * f / (f_number * max(focus_m - f, 1e-6)) * 1000.0  # blur_diameter_mm = k |d - s| / d
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(1.0 - focus_m / np.asarray(depth_m, np.float32))
    rel = np.where(np.isfinite(rel), rel, 1.0)  # the sky: |d - s| / d -> 1
    return (cam.SIGMA_PER_DIAMETER * k / sensor_width_mm * width_px * rel).astype(np.float32)


def _blurred(img: np.ndarray, sigma: float) -> np.ndarray:
    """`img` blurred by a Gaussian of `sigma` px; wide ones on a copy downscaled so that the blur
    left to do there is at most ~1.5 px (then upscaled: the result is smooth at that scale anyway)."""
    h, w = img.shape[:2]
    k = 1
    while sigma / k > 1.5 and min(h, w) // (2 * k) >= 8:
        k *= 2
    if k == 1:
        return cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    small = cv2.resize(img, (max(w // k, 1), max(h // k, 1)), interpolation=cv2.INTER_AREA)
    # INTER_AREA's box already blurs by about k/sqrt(12) px of the full image
    rest = math.sqrt(max((sigma / k) ** 2 - 1.0 / 12.0, 0.09))
    small = cv2.GaussianBlur(small, (0, 0), rest, borderType=cv2.BORDER_REFLECT)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def level_index(sigma: np.ndarray) -> np.ndarray:
    """Continuous index into SIGMA_LEVELS of each pixel's sigma (0 = sharp)."""
    return np.interp(sigma, SIGMA_LEVELS, np.arange(len(SIGMA_LEVELS), dtype=np.float32)).astype(np.float32)


def apply_dof(img: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """`img` (h, w, 3) uint8 with each pixel blurred by its own `sigma` [px] (h, w)."""
    t = level_index(sigma)
    top = float(t.max()) if t.size else 0.0
    out = img
    # acc_k = the image with every index clipped to [0, k]: acc_k = blend(acc_{k-1}, level k, clip(t - k + 1))
    for k in range(1, len(SIGMA_LEVELS)):
        if top <= k - 1:
            break
        a = np.clip(t - (k - 1), 0.0, 1.0)
        out = cv2.blendLinear(out, _blurred(img, SIGMA_LEVELS[k]), 1.0 - a, a)
    return out
