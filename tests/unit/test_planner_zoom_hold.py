"""The zoom's hold along the axis gives way while the framing is off (services/planner/zoom_hold.py)."""
import math

import numpy as np
import pytest

from cinetransfer.services.planner.zoom_hold import (HOLD_FULL_ERROR, HOLD_OFF_ERROR, framing_error_now,
                                                       settled_hold_share)


def test_framing_error_is_the_weighted_mean_distance():
    seen = np.array([[0.5, 0.5], [0.6, 0.5], [0.2, 0.2]])
    targets = np.array([[0.53, 0.54], [0.6, 0.45], [0.9, 0.9]])  # distances 0.05, 0.05, far
    weights = np.array([1.0, 3.0, 0.0])  # the far joint is not controlled
    assert framing_error_now(seen, targets, weights) == pytest.approx(0.05)
    weights = np.array([1.0, 1.0, 0.0])
    targets[1] = [0.6, 0.49]  # distance 0.01: mean (0.05 + 0.01) / 2
    assert framing_error_now(seen, targets, weights) == pytest.approx(0.03)


def test_joints_behind_the_camera_do_not_count_and_none_seen_is_unknown():
    seen = np.array([[np.nan, np.nan], [0.5, 0.5]])
    targets = np.array([[0.1, 0.1], [0.5, 0.52]])
    assert framing_error_now(seen, targets, np.ones(2)) == pytest.approx(0.02)
    assert math.isnan(framing_error_now(seen[:1], targets[:1], np.ones(1)))


def test_hold_share_is_full_when_settled_and_off_when_the_framing_is_off():
    assert settled_hold_share(0.0) == 1.0
    assert settled_hold_share(HOLD_FULL_ERROR) == 1.0
    assert settled_hold_share(0.015, full=0.010, off=0.020) == pytest.approx(0.5)
    assert settled_hold_share(0.018, full=0.010, off=0.020) == pytest.approx(0.2)
    assert settled_hold_share(HOLD_OFF_ERROR) == 0.0
    assert settled_hold_share(0.1) == 0.0
    assert settled_hold_share(math.nan) == 0.0
