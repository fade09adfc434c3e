"""Thin-lens depth of field from a depth buffer: a blur stack, blended per pixel by its blur circle.

Every pixel's blur-circle diameter comes from its depth with the lens model of shared/camera.py
(`blur_diameter_mm`, the same formula the planner and the truth use), as a Gaussian of sigma
d / 4 (`SIGMA_PER_DIAMETER`). The image is blurred at a few fixed sigmas (`SIGMA_LEVELS`, the
wide ones on a downscaled copy: cheap) and each pixel takes the two levels around its own sigma,
linearly blended. Deterministic: the same image and depths give the same bytes.
"""
from __future__ import annotations

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.sim.blur import gaussian_blur
from cinetransfer.shared import camera as cam

#: the blur stack's sigmas [px of the output image]; a pixel's sigma beyond the last is clamped
SIGMA_LEVELS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
#: the widest blur done at full size; wider ones on a downscaled copy (sim/blur.py): a whole frame per level
MAX_SIGMA_PX = 1.5


def sigma_px(depth_m: np.ndarray, focal_mm: float, f_number: float, focus_m: float, sensor_width_mm: float,
             width_px: int) -> np.ndarray:
    """Per-pixel defocus sigma [px] of an image `width_px` wide from depths [m] (inf = sky)."""
    f = focal_mm / 1000.0
    k = f * f / (f_number * max(focus_m - f, 1e-6)) * 1000.0  # blur_diameter_mm = k |d - s| / d
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(1.0 - focus_m / np.asarray(depth_m, np.float32))
    rel = np.where(np.isfinite(rel), rel, 1.0)  # the sky: |d - s| / d -> 1
    return (cam.SIGMA_PER_DIAMETER * k / sensor_width_mm * width_px * rel).astype(np.float32)


def apply_dof(img: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """`img` (h, w, 3) uint8 with each pixel blurred by its own `sigma` [px] (h, w)."""
    sigma = np.asarray(sigma, np.float32)
    top = float(sigma.max()) if sigma.size else 0.0
    out = img
    # acc_k = the image with every sigma clipped to level k: acc_k = blend(acc_{k-1}, level k, a_k), a_k the
    # pixel's share of the way from level k-1 to k (piecewise linear in sigma: no per-pixel table look-up)
    for k in range(1, len(SIGMA_LEVELS)):
        lo, hi = SIGMA_LEVELS[k - 1], SIGMA_LEVELS[k]
        if top <= lo:
            break
        a = sigma - np.float32(lo)
        a *= np.float32(1.0 / (hi - lo))
        np.clip(a, 0.0, 1.0, out=a)
        level = gaussian_blur(img, hi, max_sigma_px=MAX_SIGMA_PX, border=cv2.BORDER_REFLECT)
        out = cv2.blendLinear(out, level, 1.0 - a, a)
    return out
