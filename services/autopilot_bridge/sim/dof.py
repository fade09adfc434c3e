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
#: the frame is blended in strips of this many rows, each with only the levels its own sigmas need (a
#: sigma changes slowly down a frame: most strips straddle one or two levels, not all up to the frame's widest)
STRIP_ROWS = 32


def sigma_px(depth_m: np.ndarray, focal_mm: float, f_number: float, focus_m: float, sensor_width_mm: float,
             width_px: int) -> np.ndarray:
    """Per-pixel defocus sigma [px] of an image `width_px` wide from depths [m] (inf = sky)."""
    f = focal_mm / 1000.0
    k = f * f / (f_number * max(focus_m - f, 1e-6)) * 1000.0  # blur_diameter_mm = k |d - s| / d
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.divide(np.float32(focus_m), np.asarray(depth_m, np.float32))  # the sky (inf): 0, so |d - s| / d = 1
        np.subtract(np.float32(1.0), rel, out=rel)
        np.abs(rel, out=rel)
    rel[~np.isfinite(rel)] = 1.0  # no depth (0 or NaN): as far as the sky
    rel *= np.float32(cam.SIGMA_PER_DIAMETER * k / sensor_width_mm * width_px)
    return rel


def apply_dof(img: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """`img` (h, w, 3) uint8 with each pixel blurred by its own `sigma` [px] (h, w).

    acc_k = blend(acc_{k-1}, level k, a_k), a_k the pixel's share of the way from level k-1 to k
    (piecewise linear in sigma: no per-pixel table look-up). Where a_k is 0 for every pixel of a band of
    rows acc_k is acc_{k-1} there, where it is 1 the level itself: each band blends only the levels its
    sigmas straddle (per pixel the same bytes as blending the whole frame at every level)."""
    sigma = np.asarray(sigma, np.float32)
    top = float(sigma.max()) if sigma.size else 0.0
    levels = {k: gaussian_blur(img, SIGMA_LEVELS[k], max_sigma_px=MAX_SIGMA_PX, border=cv2.BORDER_REFLECT)
              for k in range(1, len(SIGMA_LEVELS)) if top > SIGMA_LEVELS[k - 1]}
    out = np.empty_like(img)
    for rows, start, blends in _bands(sigma):
        acc = levels[start][rows] if start else img[rows]
        if not blends:
            np.copyto(out[rows], acc)
        for n, k in enumerate(blends):
            lo, hi = SIGMA_LEVELS[k - 1], SIGMA_LEVELS[k]
            a = sigma[rows] - np.float32(lo)
            a *= np.float32(1.0 / (hi - lo))
            np.clip(a, 0.0, 1.0, out=a)
            acc = cv2.blendLinear(acc, levels[k][rows], 1.0 - a, a, dst=out[rows] if n == len(blends) - 1 else None)
    return out


def _plan(lo_sigma: float, hi_sigma: float) -> tuple[int, tuple[int, ...]]:
    """(the level every pixel has fully reached (0 = the sharp image), the levels to blend) for sigmas in
    [lo_sigma, hi_sigma]."""
    start, blends = 0, []
    for k in range(1, len(SIGMA_LEVELS)):
        lo, hi = SIGMA_LEVELS[k - 1], SIGMA_LEVELS[k]
        if hi_sigma <= lo:
            break
        if lo_sigma >= hi:
            start = k
        else:
            blends.append(k)
    return start, tuple(blends)


def _bands(sigma: np.ndarray) -> list[tuple[slice, int, tuple[int, ...]]]:
    """The frame's rows cut into strips of STRIP_ROWS, consecutive strips with the same plan joined."""
    bands: list[tuple[slice, int, tuple[int, ...]]] = []
    for r0 in range(0, sigma.shape[0], STRIP_ROWS):
        strip = sigma[r0:r0 + STRIP_ROWS]
        plan = _plan(float(strip.min()), float(strip.max()))
        if bands and bands[-1][1:] == plan:
            bands[-1] = (slice(bands[-1][0].start, r0 + len(strip)), *plan)
        else:
            bands.append((slice(r0, r0 + len(strip)), *plan))
    return bands
