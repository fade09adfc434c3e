"""The camera-motion fit's batched parts against the plain loop they replace, and the detector's
grey frame handed to the tracker: the same values."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cinetransfer.services.detector.camera_motion import CameraMotionTracker
from cinetransfer.shared import camera_motion as cm

DATA = Path(__file__).parents[1] / "data" / "camera_motion"


def _loop_scores(p0, p1, f, inlier_px):
    """The direction search as a loop: each direction's rotation (trimmed), then its inliers in
    front of the camera."""
    mid, flow = 0.5 * (p0 + p1), p1 - p0
    basis = cm.rotation_zoom_basis(mid, f)[:, :, :3]
    use = np.ones(len(p0), dtype=bool)
    out = []
    for c in cm._DIRECTIONS:
        rot = cm.rotation_given_direction(p0, p1, f, c, use, inlier_px=inlier_px)
        out.append(cm._count_in_front(flow, basis, rot, c, cm._lines(mid, c, f), inlier_px))
    return np.array(out)


def _dolly_tracks():
    data = json.loads((DATA / "dolly_zoom_tracks.json").read_text())
    return np.array(data["earlier"]), np.array(data["now"]), data["focal_px"], data["inlier_px"]


def _truck_tracks(rng):
    """A truck right past points 4-30 m away with a little pan, 2 % of the tracks moving things."""
    f = 440.0
    x = np.column_stack([rng.uniform(-12, 12, 150), rng.uniform(-6, 6, 150), rng.uniform(4, 30, 150)])
    p0 = f * x[:, :2] / x[:, 2:]
    moved = x - np.array([0.3, 0.0, 0.0])
    p1 = f * moved[:, :2] / moved[:, 2:] + np.array([1.2, 0.0]) + rng.normal(0, 0.1, (150, 2))
    p1[:3] += 9.0
    return p0, p1, f, 0.6


@pytest.mark.parametrize("tracks", ["dolly_zoom", "truck"])
def test_the_batched_direction_search_counts_as_the_loop(tracks):
    p0, p1, f, tol = _dolly_tracks() if tracks == "dolly_zoom" else _truck_tracks(np.random.default_rng(3))
    mid, flow = 0.5 * (p0 + p1), p1 - p0
    got = cm._search_scores(mid, flow, cm.rotation_zoom_basis(mid, f)[:, :, :3], f, tol)
    want = _loop_scores(p0, p1, f, tol)
    assert want.max() > 0.5 * len(p0)  # the search has something to find
    np.testing.assert_array_equal(got, want)


def test_the_masked_least_squares_is_numpys_on_the_kept_rows():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(5, 40, 3)), rng.normal(size=(5, 40))
    use = rng.random((5, 40)) > 0.3
    a[4, :, 2] = a[4, :, 0]  # rank-deficient: the minimum-norm solution, as numpy's
    got = cm._masked_lstsq(a, b, use)
    for k in range(5):
        np.testing.assert_allclose(got[k], np.linalg.lstsq(a[k][use[k]], b[k][use[k]], rcond=None)[0],
                                   rtol=1e-9, atol=1e-12)


def test_the_tracker_given_the_grey_frame_measures_the_same():
    rng = np.random.default_rng(2)
    scene = cv2.GaussianBlur(rng.integers(0, 255, (400, 900, 3), dtype=np.uint8), (0, 0), 2.0)
    frames = [np.ascontiguousarray(scene[40:400, 10 + 3 * k:650 + 3 * k]) for k in range(4)]
    plain, handed = CameraMotionTracker(), CameraMotionTracker()
    outs = []
    for k, img in enumerate(frames):
        a = plain.update(img, [], source="s", frame_index=k)
        b = handed.update(img, [], source="s", frame_index=k, grey=cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
        outs.append((a, b))
    assert outs[0] == (None, None)
    for a, b in outs[1:]:
        assert a is not None and a.points >= cm.MIN_POINTS
        assert all(np.array_equal(np.asarray(getattr(a, n)), np.asarray(getattr(b, n)), equal_nan=True)
                   for n in ("rotation_rad", "log_zoom", "translation_dir", "focal_px", "points", "explained"))
