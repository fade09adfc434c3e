"""The depth of field's blur stack blended in bands of rows gives the bytes of blending the whole frame
at every level (sim/dof.py), and each band blends only the levels its sigmas straddle."""
from __future__ import annotations

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.sim import dof
from cinetransfer.services.autopilot_bridge.sim.blur import gaussian_blur


def whole_frame_cascade(img: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Every level up to the frame's widest sigma blended over the whole frame, one after the other."""
    out, top = img, float(sigma.max())
    for k in range(1, len(dof.SIGMA_LEVELS)):
        lo, hi = dof.SIGMA_LEVELS[k - 1], dof.SIGMA_LEVELS[k]
        if top <= lo:
            break
        a = np.clip((sigma - np.float32(lo)) / np.float32(hi - lo), 0.0, 1.0).astype(np.float32)
        level = gaussian_blur(img, hi, max_sigma_px=dof.MAX_SIGMA_PX, border=cv2.BORDER_REFLECT)
        out = cv2.blendLinear(out, level, 1.0 - a, a)
    return out


def test_banded_blending_gives_the_whole_frame_cascades_bytes():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (270, 180, 3), dtype=np.uint8)
    rows = np.linspace(0.0, 1.0, 270, dtype=np.float32)[:, None]
    cols = np.linspace(0.0, 1.0, 180, dtype=np.float32)[None, :]
    cases = {
        "sharp top, blurred bottom": 20.0 * rows ** 2 + 0 * cols,
        "a sharp person in blurred rows": np.where(np.abs(cols - 0.5) < 0.1, 0.0, 3.0 * rows + 0.6),
        "everything in one level": np.full((270, 180), 0.3, np.float32) + 0.1 * cols,
        "in focus": np.zeros((270, 180), np.float32),
    }
    for name, sigma in cases.items():
        sigma = np.ascontiguousarray(sigma, np.float32)
        assert np.array_equal(dof.apply_dof(img, sigma), whole_frame_cascade(img, sigma)), name


def test_a_band_blends_only_the_levels_its_sigmas_straddle():
    assert dof._plan(0.0, 0.3) == (0, (1,))  # sharp to 0.5
    assert dof._plan(0.6, 0.9) == (1, (2,))  # every pixel past level 1 (0.5): from there, towards 1.0
    assert dof._plan(0.0, 3.0) == (0, (1, 2, 3, 4))
    assert dof._plan(5.0, 5.0) == (4, (5,))
    assert dof._plan(0.0, 0.0) == (0, ())
    sigma = np.zeros((100, 10), np.float32)
    sigma[64:] = 5.0
    assert [(b[0].start, b[0].stop, b[1], b[2]) for b in dof._bands(sigma)] == [(0, 64, 0, ()), (64, 100, 4, (5,))]
