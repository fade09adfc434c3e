"""Gaussian blur of any width at the cost of a narrow one: wide sigmas are done on a downscaled copy.

Both renderers blur with it: the 2.5-D compositor each plane (sim/renderer.py), the 3-D world's
depth of field each level of its blur stack (sim/dof.py).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

#: the variance [px² of the downscaled copy] that the INTER_AREA downscale and the INTER_LINEAR
#: upscale add between them; measured: an impulse blurred at sigma 2-30 px then has a second moment
#: within 1 % of sigma (1/12, the box alone, gave 4 % too much; 1/4 gave up to 4 % too little)
RESAMPLE_VAR = 1.0 / 6.0


def gaussian_blur(img: np.ndarray, sigma: float, *, max_sigma_px: float, border: int) -> np.ndarray:
    """`img` blurred by a Gaussian of `sigma` px. When `sigma` exceeds `max_sigma_px` the blur is done
    on a copy downscaled by a power of two until what is left there is at most `max_sigma_px`, then
    upscaled (the result is smooth at that scale anyway). `border`: an OpenCV border mode."""
    h, w = img.shape[:2]
    k = 1
    while sigma / k > max_sigma_px and min(h, w) // (2 * k) >= 8:
        k *= 2
    if k == 1:
        return cv2.GaussianBlur(img, (0, 0), sigma, borderType=border)
    small = cv2.resize(img, (max(w // k, 1), max(h // k, 1)), interpolation=cv2.INTER_AREA)
    rest = math.sqrt(max((sigma / k) ** 2 - RESAMPLE_VAR, 0.09))
    small = cv2.GaussianBlur(small, (0, 0), rest, borderType=border)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
