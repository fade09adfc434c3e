"""The edge tracks' structure tensor read from a summed-area table at the tracks: exactly the box
filter's sums over the whole image (the form it replaced), borders and reused scratch included."""
from __future__ import annotations

import cv2
import numpy as np

from cinetransfer.services.detector import camera_motion as dcm


def _box_filter_sums(grey: np.ndarray, xi: np.ndarray, yi: np.ndarray) -> list[np.ndarray]:
    """The reference: Sobel gradients, their products, box filters over the whole image, read at the pixels."""
    g = grey.astype(np.float32)
    gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    return [np.column_stack([cv2.boxFilter(m, -1, (size, size), normalize=False)[yi, xi]
                             for m in (gx * gx, gx * gy, gy * gy)]) for size in dcm.EDGE_WINDOWS_PX]


def test_tensor_sums_equal_the_box_filters_bit_for_bit_to_the_borders():
    rng = np.random.default_rng(3)
    scratch = dcm.TensorScratch()
    for shape in ((180, 320), (40, 52), (180, 320)):  # a size change and back: the scratch follows
        grey = rng.integers(0, 256, size=shape).astype(np.uint8)
        grey[::7] = 255  # the largest gradients: sums past float32's whole numbers, rounded once
        grey[:, ::5] = 0
        h, w = shape
        xi = np.concatenate([rng.integers(0, w, 300), [0, w - 1, 0, w - 1, 3, w - 4]])
        yi = np.concatenate([rng.integers(0, h, 300), [0, 0, h - 1, h - 1, h - 2, 1]])
        got = dcm.tensor_sums(grey, xi, yi, scratch)
        want = _box_filter_sums(grey, xi, yi)
        assert max(float(np.abs(s).max()) for s in want) > 2.0 ** 24  # rounding to float32 is exercised
        for g, r in zip(got, want):
            assert g.dtype == np.float32 and g.tobytes() == r.tobytes()


def test_edge_normals_equal_without_and_with_scratch():
    rng = np.random.default_rng(4)
    grey = cv2.GaussianBlur(rng.integers(0, 256, size=(90, 160)).astype(np.uint8), (0, 0), 2.0)
    grey[40:, :] //= 3  # a long level edge
    pts = np.column_stack([rng.uniform(-2, 162, 200), rng.uniform(-2, 92, 200)])
    first = dcm.edge_normals(grey, pts)
    again = dcm.edge_normals(grey, pts, dcm.TensorScratch())
    assert first.tobytes() == again.tobytes()
    assert (np.abs(first).sum(axis=1) > 0).any()  # some are edges
