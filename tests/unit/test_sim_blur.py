"""The one Gaussian blur both renderers use (sim/blur.py): wide sigmas on a downscaled copy, same width."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.sim.blur import gaussian_blur


def _second_moment_px(row: np.ndarray) -> float:
    x = np.arange(row.size)
    m = (row * x).sum() / row.sum()
    return math.sqrt((row * (x - m) ** 2).sum() / row.sum())


@pytest.mark.parametrize("max_sigma_px,border", [(1.5, cv2.BORDER_REFLECT), (6.0, cv2.BORDER_CONSTANT)])
@pytest.mark.parametrize("sigma", [1.0, 2.0, 5.0, 13.0, 30.0])
def test_an_impulse_spreads_to_the_asked_sigma_whether_or_not_it_is_downscaled(sigma, max_sigma_px, border):
    got = []
    for phase in range(16):  # where the impulse falls in a downscaled pixel changes the spread: average over it
        img = np.zeros((256, 640), np.float32)
        img[128, 300 + phase] = 1.0
        got.append(_second_moment_px(gaussian_blur(img, sigma, max_sigma_px=max_sigma_px, border=border).sum(axis=0)))
    assert np.mean(got) == pytest.approx(sigma, rel=0.015)


def test_a_narrow_blur_is_opencvs_own_and_the_input_is_left_alone():
    img = (np.random.default_rng(0).random((60, 80, 3)) * 255).astype(np.uint8)
    before = img.copy()
    out = gaussian_blur(img, 1.2, max_sigma_px=1.5, border=cv2.BORDER_REFLECT)
    assert np.array_equal(out, cv2.GaussianBlur(img, (0, 0), 1.2, borderType=cv2.BORDER_REFLECT))
    assert np.array_equal(img, before) and out.shape == img.shape and out.dtype == img.dtype
