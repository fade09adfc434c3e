"""Camera and thin-lens model against hand-computed values (DESIGN §1.3)."""
import math

import numpy as np
import pytest

from cinetransfer.shared import camera as C


def test_hyperfocal_hand_computed():
    # given f = 50 mm, A = 2.8, c = 0.05 mm: H = 50^2 / (2.8 * 0.05) + 50 = 17907.14 mm
    assert C.hyperfocal_m(50.0, 2.8, 0.05) == pytest.approx(17.90714, rel=1e-5)


def test_dof_limits_hand_computed():
    # given f = 50 mm, A = 2.8, c = 0.05, s = 5 m, H = 17.90714 m, f = 0.05 m
    # D_n = 5 (17.85714) / (17.90714 + 5 - 0.1) = 89.2857 / 22.80714 = 3.91482
    # D_f = 5 (17.85714) / (17.90714 - 5) = 89.2857 / 12.90714 = 6.91753
    near, far = C.dof_limits_m(50.0, 2.8, 5.0, 0.05)
    assert near == pytest.approx(3.91482, rel=1e-4)
    assert far == pytest.approx(6.91753, rel=1e-4)


@pytest.mark.parametrize("s", [17.9072, 20.0, 100.0])
def test_far_limit_infinite_at_or_beyond_hyperfocal(s):
    near, far = C.dof_limits_m(50.0, 2.8, s, 0.05)
    assert far == math.inf
    assert 0 < near < s


def test_focus_at_hyperfocal_gives_half_H_near_limit():
    h = C.hyperfocal_m(35.0, 8.0)
    near, far = C.dof_limits_m(35.0, 8.0, h)
    # D_n = H (H - f) / (2H - 2f) = H / 2
    assert near == pytest.approx(h / 2, rel=1e-9)
    assert far == math.inf


def test_blur_equals_coc_at_dof_limits():
    f, a, s = 85.0, 2.0, 4.0
    near, far = C.dof_limits_m(f, a, s)
    assert C.blur_diameter_mm(near, f, a, s) == pytest.approx(C.COC_MM, rel=1e-9)
    assert C.blur_diameter_mm(far, f, a, s) == pytest.approx(C.COC_MM, rel=1e-9)
    assert C.blur_diameter_mm(s, f, a, s) == 0.0
    assert C.in_focus(s, f, a, s) and not C.in_focus(far * 1.5, f, a, s)


def test_projection_hand_computed():
    # given a camera at the origin looking along +x (yaw = pitch = roll = 0), f = 23.76 mm
    # (= sensor width), a point 10 m ahead, 1 m left, 0.5 m up:
    # u = 0.5 - 23.76 * 1 / (10 * 23.76) = 0.4; v = 0.5 - 23.76 * 0.5 / (10 * 13.365) = 0.41111
    uv = C.project_world(np.array([10.0, 1.0, 0.5]), np.zeros(3), np.zeros(3), 23.76)
    assert uv == pytest.approx([0.4, 0.5 - 11.88 / 133.65], abs=1e-9)


def test_projection_yaw_and_pitch():
    # yaw +90 deg looks along +y; a point on +y projects to the centre
    uv = C.project_world(np.array([0.0, 7.0, 0.0]), np.zeros(3), np.array([math.pi / 2, 0, 0]), 35.0)
    assert uv == pytest.approx([0.5, 0.5], abs=1e-12)
    # pitch +45 deg (looking up) sees a point at 45 deg elevation at the centre
    uv = C.project_world(np.array([3.0, 0.0, 3.0]), np.zeros(3), np.array([0.0, math.pi / 4, 0]), 35.0)
    assert uv == pytest.approx([0.5, 0.5], abs=1e-12)
    # with pitch 0 the same point is above the centre (v < 0.5)
    assert C.project_world(np.array([3.0, 0.0, 3.0]), np.zeros(3), np.zeros(3), 35.0)[1] < 0.5


def test_projection_behind_camera_is_nan():
    uv = C.project_world(np.array([[-1.0, 0, 0], [1.0, 0, 0]]), np.zeros(3), np.zeros(3), 35.0)
    assert np.isnan(uv[0]).all() and np.isfinite(uv[1]).all()


def test_rotation_is_orthonormal():
    r = C.rotation_ypr(0.3, -0.2, 0.1)
    assert r @ r.T == pytest.approx(np.eye(3), abs=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize("flags,expect", [
    ((True, False, False), (0.0, 4.0)),          # foreground only: D_n* = 0, D_f* = d - mu
    ((False, True, False), (4.0, 6.0)),          # subject: d -/+ mu
    ((False, False, True), (6.0, math.inf)),     # background: d + mu .. inf
    ((True, True, True), (0.0, math.inf)),       # everything
    ((False, False, False), (math.inf, -math.inf)),  # nothing controlled
    ((True, False, True), (6.0, math.inf)),      # fg and bg sharp, subject soft: no one interval; as background
])
def test_desired_dof_limits_table(flags, expect):
    assert C.desired_dof_limits(*flags, distance_m=5.0, mu_m=1.0) == expect


def test_nothing_in_focus_can_ask_for_defocus():
    # DESIGN's table leaves it uncontrolled; the option puts the far limit mu before the subject
    assert C.desired_dof_limits(False, False, False, 5.0, 1.0, defocus_when_none=True) == (math.inf, 4.0)
    assert C.desired_dof_limits(False, True, False, 5.0, 1.0, defocus_when_none=True) == (4.0, 6.0)


def test_realisable_labels_drop_only_the_foreground_of_the_impossible_combination():
    # one depth of field is one interval: sharp in front and behind with the subject soft between cannot be;
    # the foreground gives way (the report's order: subject, background, foreground)
    assert C.realisable_labels(True, False, True) == (False, False, True)
    for flags in [(a, b, c) for a in (False, True) for b in (False, True) for c in (False, True)]:
        if flags != (True, False, True):
            assert C.realisable_labels(*flags) == flags
