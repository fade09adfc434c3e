"""Camera motion: the motion-field fit against hand-computed values and exact homographies, the
classes, the rates from poses, the smoother's per-shot style and the style file's fields."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cinetransfer.services.smoother.camera_motion import motion_style
from cinetransfer.shared import camera_motion as cm
from cinetransfer.shared import instructions as I
from cinetransfer.shared import messages as M

F = 500.0


def _rot(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def _grid(n: int = 12, half_w: float = 300.0, half_h: float = 170.0) -> np.ndarray:
    xs, ys = np.meshgrid(np.linspace(-half_w, half_w, n), np.linspace(-half_h, half_h, n))
    return np.column_stack([xs.ravel(), ys.ravel()])


def _through_homography(p: np.ndarray, r: np.ndarray, f0: float, f1: float) -> np.ndarray:
    """Points seen by a camera of focal length f0, then by the same camera turned by r (camera
    axes x right, y down, z forward) with focal length f1: x1 ~ K1 r^T K0^-1 x0."""
    d = np.column_stack([p / f0, np.ones(len(p))]) @ r  # rows: r^T d
    return f1 * d[:, :2] / d[:, 2:3]


def test_motion_field_of_unit_moves_by_hand():
    b = cm.rotation_zoom_basis(np.array([[100.0, 50.0]]), F)[0]
    # pan: u = f + x^2/f = 520, v = x y / f = 10; tilt: u = 10, v = f + y^2/f = 505
    np.testing.assert_allclose(b[:, 0], [520.0, 10.0])
    np.testing.assert_allclose(b[:, 1], [10.0, 505.0])
    # roll (clockwise): u = y, v = -x; zoom: u = x, v = y
    np.testing.assert_allclose(b[:, 2], [50.0, -100.0])
    np.testing.assert_allclose(b[:, 3], [100.0, 50.0])


@pytest.mark.parametrize("axis, deg, zoom, want", [
    ((0, -1, 0), 1.0, 0.0, (1.0, 0.0, 0.0, 0.0)),     # turning left = about the up axis (-y)
    ((0, 1, 0), 0.5, 0.0, (-0.5, 0.0, 0.0, 0.0)),
    ((1, 0, 0), 0.8, 0.0, (0.0, 0.8, 0.0, 0.0)),      # looking up
    ((0, 0, 1), 2.0, 0.0, (0.0, 0.0, 2.0, 0.0)),      # clockwise as the camera sees it
    ((0, -1, 0), 0.0, 0.02, (0.0, 0.0, 0.0, 0.02)),   # zoom in: f * e^0.02
    ((0, -1, 0), 1.2, -0.015, (1.2, 0.0, 0.0, -0.015)),
])
def test_a_homography_of_known_pan_and_zoom_gives_back_the_rates(axis, deg, zoom, want):
    p0 = _grid()
    p1 = _through_homography(p0, _rot(axis, math.radians(deg)), F, F * math.exp(zoom))
    m = cm.frame_motion(p0, p1, F)
    np.testing.assert_allclose(np.degrees(m.rotation_rad), want[:3], atol=0.01)
    assert m.log_zoom == pytest.approx(want[3], abs=2e-4)
    assert not m.translation_dir.any() and m.explained == 1.0


def test_outliers_moving_things_do_not_move_the_fit():
    p0 = _grid(14)
    p1 = _through_homography(p0, _rot((0, -1, 0), math.radians(1.0)), F, F)
    p1[:40] += np.array([7.0, -3.0])  # a third of the points on something that moves by itself
    m = cm.frame_motion(p0, p1, F)
    assert math.degrees(m.rotation_rad[0]) == pytest.approx(1.0, abs=0.01)


def test_too_few_points_is_unknown():
    m = cm.frame_motion(np.zeros((5, 2)), np.zeros((5, 2)), F)
    assert np.isnan(m.rotation_rad).all() and math.isnan(m.log_zoom) and m.points == 5


@pytest.mark.parametrize("t, want", [((0.3, 0.0, 0.0), (1, 0, 0)), ((0.0, 0.0, 0.5), (0, 0, 1)),
                                     ((0.0, 0.0, -0.5), (0, 0, -1)), ((0.0, -0.2, 0.0), (0, -1, 0))])
def test_parallax_gives_the_translation_direction(t, want):
    rng = np.random.default_rng(3)
    x = np.column_stack([rng.uniform(-10, 10, 400), rng.uniform(-3, 3, 400), rng.uniform(4, 40, 400)])
    p0 = F * x[:, :2] / x[:, 2:3]
    x1 = x - np.asarray(t)  # the camera moved by t: the points moved by -t in its frame
    p1 = F * x1[:, :2] / x1[:, 2:3]
    keep = (np.abs(p0[:, 0]) < 320) & (np.abs(p0[:, 1]) < 180)
    m = cm.frame_motion(p0[keep], p1[keep], F)
    np.testing.assert_allclose(m.translation_dir, want, atol=0.02)
    np.testing.assert_allclose(m.rotation_rad, 0.0, atol=1e-3)


def test_a_dolly_read_as_a_zoom_in_one_frame_shows_over_the_baseline():
    """A dolly whose parallax per frame is mostly within the inlier distance reads as a zoom from
    one frame; the same points eight frames apart show the translation."""
    rng = np.random.default_rng(5)
    x = np.column_stack([rng.uniform(-8, 8, 500), rng.uniform(-2, 2, 500), rng.uniform(3, 30, 500)])
    step = np.array([0.0, 0.0, 0.06])  # 1.44 m/s at 24 frames/s
    proj = [F * (x - k * step)[:, :2] / (x - k * step)[:, 2:3] for k in range(9)]
    keep = (np.abs(proj[0][:, 0]) < 320) & (np.abs(proj[0][:, 1]) < 180)
    earlier, p0, p1 = proj[0][keep], proj[7][keep], proj[8][keep]
    one = cm.frame_motion(p0, p1, F)
    assert not one.translation_dir.any() and one.log_zoom > 0  # one frame: a zoom
    m = cm.frame_motion(p0, p1, F, earlier=earlier, span=8)
    np.testing.assert_allclose(m.translation_dir, (0, 0, 1), atol=0.02)
    np.testing.assert_allclose(m.rotation_rad, 0.0, atol=1e-4)
    assert m.log_zoom == 0.0
    # too short a baseline is not used: the frame is judged alone
    short = cm.frame_motion(p0, p1, F, earlier=proj[6][keep], span=2)
    assert not short.translation_dir.any()


def test_a_swaying_camera_that_does_not_move_shows_no_parallax_over_the_baseline():
    """A hovering camera turns a little differently every frame: the baseline's rotation is the sum
    of its frames', not the last frame's times the span. Judged by the last frame's rate the
    baseline is unexplained and the translation fit reads the points as parallax."""
    rng = np.random.default_rng(7)
    x = np.column_stack([rng.uniform(-10, 10, 300), rng.uniform(-3, 3, 300), rng.uniform(4, 40, 300)])
    pans = [0.0, 0.004, -0.002, 0.003, -0.003, 0.001, 0.004, -0.001, 0.005]  # attitude per frame [rad]
    views = [F * (x @ _rot((0, 1, 0), a))[:, :2] / (x @ _rot((0, 1, 0), a))[:, 2:3] for a in pans]
    keep = np.all([(np.abs(v[:, 0]) < 320) & (np.abs(v[:, 1]) < 180) for v in views], axis=0)
    earlier, p0, p1 = views[0][keep], views[7][keep], views[8][keep]
    m = cm.frame_motion(p0, p1, F, earlier=earlier, span=8)
    assert not m.translation_dir.any()
    # the frame's own rotation: 0.006 rad of pan (turning right: negative), no zoom
    np.testing.assert_allclose(m.rotation_rad, (-0.006, 0.0, 0.0), atol=2e-4)
    assert abs(m.log_zoom) < 1e-4
    # the last frame's rate over 8 frames mispredicts the baseline by ~20 px; its own fit explains all
    q = cm.fit_rotation_zoom(p0, p1, F, inlier_px=cm.INLIER_PX)[0]
    assert cm.explained_share(earlier, p1, F, q * 8, inlier_px=2 * cm.INLIER_PX) > 0.95


def test_tracks_drifting_across_a_pedestal_do_not_set_its_rotation():
    """Straight up past pillars and a wall: the tilt moves points along the vertical lines the
    pedestal allows, so it is seen only through the little it moves them sideways: a third of the
    tracks low on the right drifting 3 px sideways (the paving sliding under the tracker) set a
    tilt of over 1 deg/s in plain least squares, and none once the fit is repeated on its inliers."""
    rng = np.random.default_rng(11)
    x = np.column_stack([rng.uniform(-8, 8, 400), rng.uniform(-3, 3, 400), rng.uniform(6, 25, 400)])
    step = np.array([0.0, -0.2, 0.0])  # 0.6 m/s up over 8 frames at 24 frames/s
    p0, p1 = F * x[:, :2] / x[:, 2:3], F * (x - step)[:, :2] / (x - step)[:, 2:3]
    keep = (np.abs(p0[:, 0]) < 320) & (np.abs(p0[:, 1]) < 180)
    p0, p1 = p0[keep], p1[keep]
    drift = (np.arange(len(p0)) % 3 == 0) & (p0[:, 0] > 0) & (p0[:, 1] > 0)
    p1[drift, 0] += 3.0
    t, use = np.array([0.0, -1.0, 0.0]), np.ones(len(p0), dtype=bool)
    plain = cm.rotation_given_direction(p0, p1, F, t, use)
    trimmed = cm.rotation_given_direction(p0, p1, F, t, use, inlier_px=0.6)
    assert np.degrees(plain[1]) * 3 > 1.0  # deg/s: 8 frames at 24 frames/s
    np.testing.assert_allclose(trimmed, 0.0, atol=1e-4)


def _ground_points(rng: np.random.Generator) -> np.ndarray:
    """A camera 1.6 m above flat ground looking level, a wall 25 m ahead: points (N, 3) in the camera
    frame (x right, y down, z forward); the lower in the image, the nearer."""
    z_ground = rng.uniform(4.0, 25.0, 300)
    ground = np.column_stack([rng.uniform(-0.35, 0.35, 300) * z_ground, np.full(300, 1.6), z_ground])
    wall = np.column_stack([rng.uniform(-8, 8, 200), rng.uniform(-5, 1.5, 200), np.full(200, 25.0)])
    return np.vstack([ground, wall])


def test_a_cluster_of_tracks_sliding_one_way_is_no_dolly():
    """16 tracks at the lower left slide right (+7, -1 px) and 2 at the right too: a dolly out whose
    focus of expansion is (0, 0.1 F) explains the left ones in front of the camera (they move towards
    it) but puts the right ones behind it (16/18 = 0.89 in front, under 0.9), and they all lie to one
    side of it. A dolly seen all round its focus of expansion is one."""
    t = np.array([0.0, -0.1, -1.0]) / math.hypot(0.1, 1.0)
    left = np.column_stack([np.linspace(-150.0, -60.0, 16), np.linspace(45.0, 75.0, 16)])
    right = np.array([[25.0, 60.0], [35.0, 55.0]])
    p0 = np.vstack([left, right])
    p1 = p0 + np.array([7.0, -1.0])
    use = np.ones(len(p0), dtype=bool)
    assert cm.sliding_tracks(p0, p1, F, np.zeros(3), t, use, 1.2)
    # the same dolly out past points all round its focus of expansion, each moving towards it
    rng = np.random.default_rng(3)
    ring = rng.uniform(-200.0, 200.0, (40, 2))
    e = F * t[:2] / t[2]
    q1 = ring - 0.03 * (ring - e)
    assert not cm.sliding_tracks(ring, q1, F, np.zeros(3), t, np.ones(40, dtype=bool), 1.2)
    # a truck is not judged so (its lines are parallel, there is no focus of expansion in view)
    assert not cm.sliding_tracks(p0, p1, F, np.zeros(3), np.array([1.0, 0.0, 0.0]), use, 1.2)


def test_a_dolly_zoom_whose_zoom_outweighs_the_dolly_is_backed_by_the_ground():
    """In by 0.05 m while zooming out by e^-0.02: even the nearest ground (4 m) shrinks (-0.02 + 0.05/4
    < 0), so the translation fit's dolly is the zoom's way (out), which the ground denies (its nearer
    points shrink less); below the horizon the lower points grow more the other way, which backs the
    dolly in. A zoom out alone, its tracks jittered by 0.05 px, shows no such ground."""
    x = _ground_points(np.random.default_rng(7))
    p0 = F * x[:, :2] / x[:, 2:3]
    x1 = x - np.array([0.0, 0.0, 0.05])
    p1 = np.exp(-0.02) * F * x1[:, :2] / x1[:, 2:3]
    keep = (np.abs(p0[:, 0]) < 320) & (np.abs(p0[:, 1]) < 180)
    p0, p1 = p0[keep], p1[keep]
    use = np.ones(len(p0), dtype=bool)
    dolly_in, dolly_out = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    assert cm.ground_denies_dolly(p0, p1, F, np.zeros(3), dolly_out, use)
    assert cm.ground_backs_mirror(p0, p1, F, np.zeros(3), dolly_in, use)
    # the zoom it then reads is the ground's, against the dolly: -0.02 (within 1 %: read at the midpoints)
    assert cm.zoom_against_dolly(p0, p1, F, np.zeros(3), dolly_in, use) == pytest.approx(-0.02, rel=0.01)
    zoomed = np.exp(-0.02) * p0 + np.random.default_rng(1).normal(0.0, 0.05, p0.shape)
    assert not cm.ground_backs_mirror(p0, zoomed, F, np.zeros(3), dolly_in, use)


@pytest.mark.parametrize("step, zoom", [(0.05, -0.004), (-0.05, 0.004)])
def test_a_dolly_zoom_takes_its_sign_from_the_ground(step, zoom):
    """In while zooming out and out while zooming in fit every point with positive depths, mirror
    images of each other; the ground (lower = nearer) tells them apart, whichever sign is given."""
    x = _ground_points(np.random.default_rng(7))
    p0 = F * x[:, :2] / x[:, 2:3]
    x1 = x - np.array([0.0, 0.0, step])
    p1 = np.exp(zoom) * F * x1[:, :2] / x1[:, 2:3]
    keep = (np.abs(p0[:, 0]) < 320) & (np.abs(p0[:, 1]) < 180)
    p0, p1 = p0[keep], p1[keep]
    use = np.ones(len(p0), dtype=bool)
    want = np.array([0.0, 0.0, np.sign(step)])
    for given in (want, -want):
        np.testing.assert_array_equal(cm.dolly_sign(p0, p1, F, np.zeros(3), given, use), want)
    # the zoom then comes from the farthest points, against the dolly
    assert np.sign(cm.zoom_against_dolly(p0, p1, F, np.zeros(3), want, use)) == np.sign(zoom)


def test_the_zoom_at_the_horizon_is_the_ground_lines_by_hand():
    """Flow along u = (p - e) / |p - e| = s (p . u) + beta (y - horizon) |p - e| on the ground, across u
    s (p x u); a pillar (nearer than the ground behind it) lies above that line and points above the
    horizon are not used."""
    s, beta, horizon = -0.04, 2e-4, -30.0
    e = np.array([0.0, horizon])
    ground = np.array([[x, y] for x in (-140.0, -60.0, 20.0, 110.0) for y in (10.0, 40.0, 70.0, 85.0)])
    pillar = np.array([[130.0, y] for y in (-70.0, -20.0, 15.0, 50.0)])
    sky = np.array([[x, -60.0] for x in (-100.0, 0.0, 100.0)])
    mid = np.vstack([ground, pillar, sky])
    w = np.concatenate([beta * (ground[:, 1] - horizon), np.full(4, 0.04), np.full(3, 0.0)])
    resid = s * mid + w[:, None] * (mid - e)
    assert cm.zoom_at_horizon(mid, resid, e, 440.0, inlier_px=0.6) == pytest.approx(s, abs=1e-9)
    # e.g. the point (20, 40): along u = (20, 70) / 72.8, s (p . u) = -0.04 * 3200 / 72.8 = -1.758 px and
    # beta 70 * 72.8 = 1.019 px: 0.739 px inward
    k = 9
    u = (mid[k] - e) / np.linalg.norm(mid[k] - e)
    assert float(resid[k] @ u) == pytest.approx(-1.758 + 1.019, abs=2e-3)
    assert math.isnan(cm.zoom_at_horizon(sky, s * sky, e, 440.0, inlier_px=0.6))


def test_an_edge_track_keeps_only_its_motion_across_the_edge_by_hand():
    """An edge track (a unit normal) keeps n (n . v) of a flow and of each column of the motion field;
    a corner (zeros) all of it."""
    normals = np.array([[0.0, 1.0], [0.0, 0.0]])
    v = np.array([[3.0, 4.0], [3.0, 4.0]])
    np.testing.assert_allclose(cm.project_normal(v, normals), [[0.0, 4.0], [3.0, 4.0]])
    b = cm.project_normal(cm.rotation_zoom_basis(np.array([[100.0, 50.0], [100.0, 50.0]]), F), normals)
    # across a level edge at (100, 50) only v is seen: pan 10, tilt 505, roll -100, zoom 50
    np.testing.assert_allclose(b[0], [[0.0, 0.0, 0.0, 0.0], [10.0, 505.0, -100.0, 50.0]])
    np.testing.assert_allclose(b[1], [[520.0, 10.0, 50.0, 100.0], [10.0, 505.0, -100.0, 50.0]])
    assert cm.project_normal(v, None) is v


def _sliding_zoom(every: int) -> tuple[np.ndarray, ...]:
    """Ground and wall points zoomed in by 0.05 over a baseline; every `every`-th ground track lies on
    one of the paving's level lines and keeps only its vertical motion (the aperture problem)."""
    x = _ground_points(np.random.default_rng(9))
    p0 = F * x[:, :2] / x[:, 2:3]
    keep = (np.abs(p0[:, 0]) < 320) & (np.abs(p0[:, 1]) < 180)
    x, p0 = x[keep], p0[keep]
    lines = (x[:, 1] == 1.6) & (np.arange(len(p0)) % every == 0)
    p1 = np.exp(0.05) * p0
    p1[lines, 0] = p0[lines, 0]
    normals = np.zeros((len(p0), 2))
    normals[lines] = (0.0, 1.0)
    return p0, p1, normals


def test_a_zoom_whose_edge_tracks_slide_along_their_edges_is_a_zoom():
    """147 of 494 tracks on level edges: judged in 2-D they leave rotation + zoom 75 % of the points (the
    translation fit's moves that explain about as many need a turn, so the zoom is kept); across their
    edges they fit the zoom, all of them."""
    p0, p1, normals = _sliding_zoom(2)
    mid = 0.5 * (p0 + p1)
    blind = cm.frame_motion(mid, p1, F, earlier=p0, span=8)
    assert blind.explained < cm.EXPLAINED_SHARE and not blind.translation_dir.any()
    m = cm.frame_motion(mid, p1, F, earlier=p0, span=8, normals=normals)
    assert not m.translation_dir.any() and m.explained == 1.0
    # mid -> p1 is a zoom by 2 e^0.05 / (1 + e^0.05): ln 0.02469
    assert m.log_zoom == pytest.approx(math.log(2 * math.exp(0.05) / (1 + math.exp(0.05))), rel=1e-3)
    # the edge tracks near the centre slid by less than the inlier distance: not told from their
    # corners, they count in 2-D and leave a turn of 2e-5 rad (0.03 deg/s at 24 frames/s)
    assert np.abs(m.rotation_rad).max() < 1e-4
    q, inl = cm.fit_rotation_zoom(p0, p1, F, inlier_px=cm.INLIER_PX, normals=normals)
    assert inl.all() and q[3] == pytest.approx(0.05, rel=1e-3)


def test_the_ground_zoom_reads_an_edge_track_across_its_edge():
    """The hand-made ground of the test above with half its points on level edges that kept only
    their vertical motion: one equation each, n . r = s (n . p) + beta (y - horizon) |p - e| (n . u)."""
    s, beta, e = -0.04, 2e-4, np.array([0.0, -30.0])
    ground = np.array([[x, y] for x in (-140.0, -60.0, 20.0, 110.0, 150.0) for y in (10.0, 40.0, 70.0, 85.0)])
    resid = s * ground + (beta * (ground[:, 1] - e[1]))[:, None] * (ground - e)
    normals = np.zeros_like(ground)
    normals[::2] = (0.0, -1.0)  # either way round
    slid = resid.copy()
    slid[::2, 0] = 0.0
    assert cm.zoom_at_horizon(ground, slid, e, 440.0, inlier_px=0.6, normals=normals) == pytest.approx(s, abs=1e-9)


def test_a_tracks_edge_normal_from_the_structure_tensor():
    from cinetransfer.services.detector.camera_motion import edge_normals

    img = np.zeros((60, 90), np.uint8)
    img[30:, :45] = 200  # a level edge on the left, a corner at (45, 30), flat ground at the right
    img[:, 70:] = 90  # an upright edge at x = 70
    n = edge_normals(img, np.array([[20.0, 30.0], [45.0, 30.0], [70.0, 15.0], [57.0, 10.0]]))
    np.testing.assert_allclose(np.abs(n), [[0.0, 1.0], [0.0, 0.0], [1.0, 0.0], [0.0, 0.0]], atol=1e-6)


def _pitched_view(x: np.ndarray, forward_m: float, pitch_rad: float, f: float) -> np.ndarray:
    """Image points (N, 2) of world points x (N, 3; x right, y down, z forward, level) seen by a camera
    `forward_m` along z (moving level), pitched down by `pitch_rad`, focal length f px."""
    c, s = math.cos(pitch_rad), math.sin(pitch_rad)
    r = x - np.array([0.0, 0.0, forward_m])
    xc = np.column_stack([r[:, 0], c * r[:, 1] - s * r[:, 2], s * r[:, 1] + c * r[:, 2]])
    return f * xc[:, :2] / xc[:, 2:3]


def _dolly_zoom_views(step: float, pitch_deg: float) -> tuple[np.ndarray, ...]:
    """World points (ground, a wall 25 m ahead, pillars 7 and 12 m ahead) and their images (N, 2)
    before and after a dolly-zoom `step` m ahead that holds the size of a subject 9 m ahead, from a
    camera 1.6 m up pitched `pitch_deg` down moving level (0.2 px of tracking noise), with log f1/f0."""
    rng = np.random.default_rng(3)
    pillars = np.column_stack([rng.choice([-3.0, 2.5], 80), rng.uniform(-3.0, 1.6, 80), rng.choice([7.0, 12.0], 80)])
    x, f0, pitch = np.vstack([_ground_points(rng), pillars]), 440.0, math.radians(pitch_deg)
    f1 = f0 * (9.0 - step) / 9.0
    p0, p1 = _pitched_view(x, 0.0, pitch, f0), _pitched_view(x, step, pitch, f1)
    keep = (np.abs(p0) < [160, 90]).all(axis=1) & (np.abs(p1) < [160, 90]).all(axis=1)
    noise = rng.normal(0.0, 0.2, (2, keep.sum(), 2))
    return x[keep], p0[keep] + noise[0], p1[keep] + noise[1], math.log(f1 / f0)


def test_a_dolly_zoom_shrinks_the_far_wall_by_only_part_of_the_zoom():
    """A point at depth d scales at s + t_z / d = s (1 - d_s / d) when the zoom s = -t_z / d_s holds
    the subject at d_s: the wall 25 m away behind a subject 9 m away shows 0.64 of the zoom."""
    x, p0, p1, s = _dolly_zoom_views(0.4, 0.0)
    scale = cm._radial_scales(p0, p1, 440.0, np.zeros(3), x[:, 2] == 25.0)[0]
    assert s == pytest.approx(math.log(8.6 / 9.0))
    assert np.median(scale) == pytest.approx(s * (1.0 - 9.0 / 25.0), rel=0.03)


@pytest.mark.parametrize("step, pitch_deg", [(0.4, 0.0), (0.4, 4.0), (-0.33, 4.0), (0.4, 10.0)])
def test_a_dolly_zooms_rate_comes_from_the_ground_not_the_far_wall(step, pitch_deg):
    """The ground, extrapolated to the horizon (the focus of expansion's row for a camera moving
    level), shows all of the zoom; the farthest points alone showed 0.64-0.75 of it."""
    _, p0, p1, s = _dolly_zoom_views(step, pitch_deg)
    pitch = math.radians(pitch_deg)
    t = np.sign(step) * np.array([0.0, -math.sin(pitch), math.cos(pitch)])
    use = np.ones(len(p0), dtype=bool)
    assert cm.zoom_against_dolly(p0, p1, 440.0, np.zeros(3), t, use, inlier_px=1.2) == pytest.approx(s, rel=0.05)


def test_a_dolly_zoom_is_not_left_a_truck_where_the_search_started_it():
    """Tracks of a rendered dolly-zoom: the alternation started from the direction search's best
    settles on a truck with a pan (81 % of the points); started from the optical axis it finds the
    dolly (90 %), and the fit keeps that one."""
    data = json.loads((Path(__file__).parents[1] / "data" / "camera_motion" / "dolly_zoom_tracks.json").read_text())
    p0, p1, f, tol = np.array(data["earlier"]), np.array(data["now"]), data["focal_px"], data["inlier_px"]
    side = cm._alternate(p0, p1, f, np.array([0.96, 0.02, 0.29]) / np.linalg.norm([0.96, 0.02, 0.29]), tol, 5)
    axis = cm._alternate(p0, p1, f, np.array([0.0, 0.0, 1.0]), tol, 5)
    assert abs(side[1][2]) < 0.5 and side[2].mean() < 0.85 < 0.88 < axis[2].mean()
    _, t, inl = cm.fit_rotation_translation(p0, p1, f, np.array(data["rot0_rad"]), inlier_px=tol)
    assert abs(t[2]) > 0.95 and inl.sum() == axis[2].sum()


def test_a_zoom_out_whose_ground_tracks_slide_is_no_dolly():
    """Zooming out, the tracks on the paving slide (their scale over the baseline a third of the
    true one): the translation fit reads a dolly out with the ground the farthest, which the ground
    denies; a real dolly out over the same points keeps its reading."""
    x = _ground_points(np.random.default_rng(9))
    p0 = F * x[:, :2] / x[:, 2:3]
    keep = (np.abs(p0[:, 0]) < 320) & (np.abs(p0[:, 1]) < 180)
    x, p0 = x[keep], p0[keep]
    ground = x[:, 1] == 1.6
    zoomed = np.exp(-0.04) * p0
    zoomed[ground] = p0[ground] + (zoomed[ground] - p0[ground]) / 3.0
    use, t = np.ones(len(p0), dtype=bool), np.array([0.0, 0.0, -1.0])
    assert cm.ground_denies_dolly(p0, zoomed, F, np.zeros(3), t, use)
    x1 = x - np.array([0.0, 0.0, -0.4])
    dolly = F * x1[:, :2] / x1[:, 2:3]
    assert not cm.ground_denies_dolly(p0, dolly, F, np.zeros(3), t, use)
    m = cm.frame_motion(0.5 * (p0 + zoomed), zoomed, F, earlier=p0, span=8)
    assert not m.translation_dir.any() and m.log_zoom < 0.0
    m = cm.frame_motion(0.5 * (p0 + dolly), dolly, F, earlier=p0, span=8)
    np.testing.assert_allclose(m.translation_dir, t, atol=0.02)


def test_a_swaying_camera_that_dollies_keeps_its_dolly_and_no_zoom():
    """A drone dollying in at 1.2 m/s sways as it flies (its pan changes every frame). The dolly's
    sign and its zoom are judged over the baseline with the baseline's own rotation: the last
    frame's pan times the span mispredicted the points by pixels, the far ones seemed to shrink,
    and the output video read a dolly-zoom or a dolly out with a zoom (rows flipping between them)."""
    rng = np.random.default_rng(4)
    pillars = np.column_stack([rng.choice([-3.0, 2.5], 80), rng.uniform(-3.0, 1.6, 80), rng.choice([7.0, 12.0], 80)])
    x = np.vstack([_ground_points(rng), pillars])
    pans = [0.0, 0.003, -0.002, 0.004, -0.003, 0.002, 0.005, -0.001, 0.004]  # attitude per frame [rad]
    views = []
    for k, a in enumerate(pans):
        xc = (x - np.array([0.0, 0.0, 0.05 * k])) @ _rot((0, 1, 0), a)
        views.append(F * xc[:, :2] / xc[:, 2:3])
    keep = np.all([(np.abs(v[:, 0]) < 320) & (np.abs(v[:, 1]) < 180) for v in views], axis=0)
    earlier, p0, p1 = views[0][keep], views[7][keep], views[8][keep]
    m = cm.frame_motion(p0, p1, F, earlier=earlier, span=8)
    assert m.translation_dir[2] > 0.99 and m.log_zoom == 0.0
    # the frame's own pan: 0.005 rad (turning right: negative)
    assert m.rotation_rad[0] == pytest.approx(-0.005, abs=3e-4)


def test_a_frame_whose_parallax_was_not_tested_leaves_its_zoom_and_translation_unknown():
    """From one frame a dolly reads as a zoom: until the tracks span MIN_SPAN frames the zoom and the
    translation are unknown and the smoother takes them from the tested frames around; a
    translation seen anyway, and the rotation, are kept."""
    zoom = cm.FrameMotion(np.array([0.001, 0.0, 0.0]), 0.002, np.zeros(3), 150, 0.97)
    m = cm.parallax_untested(zoom)
    assert math.isnan(m.log_zoom) and np.isnan(m.translation_dir).all()
    np.testing.assert_array_equal(m.rotation_rad, zoom.rotation_rad)
    assert (m.points, m.explained) == (150, 0.97)
    truck = cm.FrameMotion(np.zeros(3), 0.0, np.array([1.0, 0.0, 0.0]), 150, 0.5)
    assert cm.parallax_untested(truck) is truck
    # a dolly read from frame 4 on: the first three rows take the window's dolly, not a zoom
    untested = np.array([[0.0, 0.0, 0.0, math.nan, math.nan, math.nan, math.nan]] * 3)
    tested = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]] * 9)
    style = motion_style(np.vstack([untested, tested]), 24.0, np.zeros(12, dtype=bool))
    assert style["camera_motion_class"][1:4] == ["dolly_in"] * 3


def test_a_dolly_whose_points_all_scale_one_way_keeps_its_sign():
    x = _ground_points(np.random.default_rng(8))
    p0 = F * x[:, :2] / x[:, 2:3]
    x1 = x - np.array([0.0, 0.0, 0.05])
    p1 = F * x1[:, :2] / x1[:, 2:3]
    use = np.ones(len(p0), dtype=bool)
    for given in ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)):
        np.testing.assert_array_equal(cm.dolly_sign(p0, p1, F, np.zeros(3), np.array(given), use), given)


@pytest.mark.parametrize("rates, t, want", [
    ((0.2, -0.3, 0.1, 0.0), None, "static"),
    ((5.0, 0.0, 0.0, 0.0), None, "pan"),
    ((-5.0, 3.0, 0.0, 0.0), None, "pan+tilt"),
    ((0.0, 0.0, -8.0, 0.0), None, "roll"),
    ((0.0, 0.0, 0.0, 0.1), None, "zoom_in"),
    ((4.0, 0.0, 0.0, -0.1), None, "pan+zoom_out"),
    ((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0), "dolly_in"),
    ((0.0, 0.0, 0.0, 0.0), (0.1, 0.0, -0.99), "dolly_out"),
    ((0.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0), "truck"),
    ((0.0, 0.0, 0.0, 0.0), (0.0, -1.0, 0.0), "pedestal"),
    ((6.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0), "orbit"),        # right while turning left
    ((-6.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0), "pan+truck"),   # right while turning right: no centre ahead
    ((0.0, 0.0, 0.0, -0.1), (0.0, 0.0, 1.0), "dolly_zoom"),
    ((math.nan,) * 4, None, ""),
    # beside a translation a pan or tilt counts from ROTATION_BESIDE_TRANSLATION_DPS = 3.0, not 1.5
    ((0.0, -1.8, 0.0, 0.0), (0.0, -1.0, 0.0), "pedestal"),   # the tilt a pedestal's reading trades
    ((0.0, -3.2, 0.0, 0.0), (0.0, -1.0, 0.0), "tilt+pedestal"),
    ((0.0, -1.8, 0.0, 0.0), None, "tilt"),                    # without a translation: 1.5
    ((1.6, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0), "dolly_in"),
    ((-2.9, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0), "truck"),
    ((-3.1, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0), "pan+truck"),
    ((1.6, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0), "orbit"),         # an orbit's pan still from 1.5
    ((0.0, 0.0, 1.6, 0.0), (0.0, 0.0, 1.0), "roll+dolly_in"), # roll is not traded: 1.5
])
def test_classes(rates, t, want):
    assert cm.classify(*rates, None if t is None else np.array(t)) == want


def test_rates_from_poses_by_hand():
    fps = 10.0
    k = np.arange(6)
    yaw, pitch = 0.02 * k, -0.01 * k  # per frame: 0.2 rad/s left, 0.1 rad/s down
    ypr = np.column_stack([yaw, pitch, np.zeros(6)])
    focal = 30.0 * np.exp(0.05 * k)  # 0.5 per second
    r = cm.rates_from_poses(ypr, focal, fps)
    assert math.isnan(r["pan_rate_dps"][0])
    # yaw is about the world's up axis: the camera's own pan is that times cos(pitch), at the step's middle
    np.testing.assert_allclose(r["pan_rate_dps"][1:], math.degrees(0.2) * np.cos(pitch[1:] + 0.005), rtol=1e-5)
    np.testing.assert_allclose(r["tilt_rate_dps"][1:], -math.degrees(0.1), rtol=1e-2)
    # ... and the rest of the yaw turns about the camera's forward axis: a roll of yaw rate x sin(pitch)
    np.testing.assert_allclose(r["roll_rate_dps"][1:], math.degrees(0.2) * np.sin(pitch[1:] + 0.005), rtol=1e-3)
    np.testing.assert_allclose(r["zoom_rate"][1:], 0.5, rtol=1e-9)
    roll = cm.rates_from_poses(np.column_stack([np.zeros(3), np.zeros(3), [0.0, 0.03, 0.06]]), np.full(3, 30.0), 20)
    np.testing.assert_allclose(roll["roll_rate_dps"][1:], math.degrees(0.6), rtol=1e-6)


def test_translation_from_the_vehicle_velocity_in_camera_axes():
    look_east = np.zeros(3)  # yaw 0: looking along world +x
    np.testing.assert_allclose(cm.translation_from_velocity([1.0, 0, 0], look_east, 5.0), [0, 0, 1], atol=1e-12)
    # world +y is the camera's left: x right = -1
    np.testing.assert_allclose(cm.translation_from_velocity([0, 0.5, 0], look_east, 5.0), [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(cm.translation_from_velocity([0, 0, -0.5], look_east, 5.0), [0, 1, 0], atol=1e-12)
    # looking north (yaw 90 deg), flying east: to the camera's right
    np.testing.assert_allclose(cm.translation_from_velocity([1.0, 0, 0], [math.pi / 2, 0, 0], 5.0), [1, 0, 0],
                               atol=1e-12)
    # 0.1 m/s against a subject 10 m away changes its size by 1 %/s: below the least zoom that counts
    assert not cm.translation_from_velocity([0.1, 0, 0], look_east, 10.0).any()
    assert np.isnan(cm.translation_from_velocity([1.0, 0, 0], look_east, 0.0)).all()


def test_smoother_style_per_shot_in_degrees_per_second():
    n, fps = 30, 24.0
    mo = np.zeros((n, 7))
    mo[:15, 0] = math.radians(0.25)  # first shot pans 6 deg/s
    mo[15:, 3] = 0.005                # second zooms in at 0.12 /s
    mo[16, 0] = math.radians(20.0)    # one wild frame: the median keeps it out
    cuts = np.zeros(n, dtype=bool)
    cuts[15] = True
    st = motion_style(mo, fps, cuts)
    assert st["camera_motion_class"][:15] == ["pan"] * 15 and st["camera_motion_class"][15:] == ["zoom_in"] * 15
    np.testing.assert_allclose(st["pan_rate_dps"][:15], 6.0, rtol=1e-5)
    np.testing.assert_allclose(st["zoom_rate"][15:], 0.12, rtol=1e-5)
    assert np.all(st["translation_dir"] == 0.0)


def _instr(k: int = 4, **kw) -> M.Instructions:
    return M.Instructions(fps=24.0, frame_duration_s=1 / 24, joint_names=["nose"],
                          image_targets=np.full((k, 1, 2), 0.5, np.float32), subject_visible=np.ones(k, bool),
                          subject_box=np.zeros((k, 4), np.float32), focus_raw=np.zeros((k, 3), np.float32),
                          focus_smoothed=np.zeros((k, 3), np.float32), focus_in=np.zeros((k, 3), bool), **kw)


def _motion(k: int = 4) -> dict:
    return dict(camera_motion_class=["static", "pan", "pan", ""],
                pan_rate_dps=np.array([0.0, 5.0, 5.0, np.nan], np.float32), tilt_rate_dps=np.zeros(k, np.float32),
                roll_rate_dps=np.zeros(k, np.float32), zoom_rate=np.zeros(k, np.float32),
                translation_dir=np.zeros((k, 3), np.float32))


def test_style_file_carries_the_motion_and_older_files_load(tmp_path):
    p = tmp_path / "style.json"
    I.save_style(p, _instr(**_motion()))
    back = I.load_style(p)
    assert back.camera_motion_class == ["static", "pan", "pan", ""]
    assert back.pan_rate_dps[1] == 5.0 and math.isnan(back.pan_rate_dps[3])
    assert I.slice_instructions(back, 1, 3).camera_motion_class == ["pan", "pan"]
    # a file written before the camera motion existed: no such fields, schema version 2
    d = I.style_to_dict(_instr())
    for name in I.MOTION_FIELDS:
        d["instructions"].pop(name)
    d["instructions"]["schema_version"] = 2
    p.write_text(json.dumps(d))
    old = I.load_style(p)
    assert all(getattr(old, n) is None for n in I.MOTION_FIELDS)


@pytest.mark.parametrize("change, needle", [
    (lambda m: m.pop("zoom_rate"), "zoom_rate missing"),
    (lambda m: m.update(camera_motion_class=["static", "pan", "swoop", "pan"]), "'swoop' is not made of"),
    (lambda m: m.update(tilt_rate_dps=np.zeros(3, np.float32)), "tilt_rate_dps has 3 rows"),
])
def test_inconsistent_motion_fields_are_refused(change, needle):
    m = _motion()
    change(m)
    with pytest.raises(I.StyleFileError, match=needle):
        I.check_consistent(_instr(**m))


def _moving(instr: M.Instructions, classes: list[str], pan: float) -> M.Instructions:
    import dataclasses

    k = len(classes)
    return dataclasses.replace(instr, camera_motion_class=classes, pan_rate_dps=np.full(k, pan, np.float32),
                               tilt_rate_dps=np.zeros(k, np.float32), roll_rate_dps=np.zeros(k, np.float32),
                               zoom_rate=np.zeros(k, np.float32), translation_dir=np.zeros((k, 3), np.float32))


def test_report_section_per_shot_with_truth_from_poses():
    from cinetransfer.report.camera_motion import camera_motion_summary

    k, fps = 8, 24.0
    src = _moving(_instr(k), ["pan"] * k, 6.0)
    out = _moving(_instr(k), ["pan"] * 4 + ["static"] * 4, 6.0)
    stamps = [1_000_000 + i * 41_666_667 for i in range(k)]
    yaw_rate = math.radians(6.0)  # rad/s, to the left
    states = [M.VehicleState(stamp_ns=s, camera_ypr_rad=np.array([yaw_rate * i / fps, 0.0, 0.0]),
                             lens=M.LensState(focal_length_mm=35.0)) for i, s in enumerate(stamps)]
    truths = [M.GroundTruth(stamp_ns=s, frame_index=i, focal_length_mm=35.0) for i, s in enumerate(stamps)]
    summary, series = camera_motion_summary(src, out, states, truths, [(0, 4), (4, 8)])
    a, b = summary["shots"]
    assert a["rows"] == [0, 4] and a["source"]["class"] == "pan" and a["agreement"] == 1.0
    assert b["agreement"] == 0.0 and b["output"]["class"] == "pan"  # the shot's median: 6 deg/s
    assert a["truth"]["pan_rate_dps"] == pytest.approx(6.0, rel=1e-3) and a["truth"]["class"] == "pan"
    assert a["truth"]["zoom_rate"] == 0.0 and a["truth_agreement"] == 1.0
    old, _ = camera_motion_summary(_instr(k), out, states, truths, [(0, k)])
    assert not old["available"] and "older style" in old["reason"]


def test_states_are_interpolated_to_a_frame_stamp_angles_the_short_way():
    from cinetransfer.report.camera_motion import interpolate_states

    stamps = np.array([0, 50_000_000, 100_000_000], np.int64)
    yaw = np.array([[3.1, 0.0, 0.0], [-3.1, 0.2, 0.0], [-3.0, 0.4, 0.0]])
    # a quarter of the way from 3.1 to -3.1 through pi (a step of 2 pi - 6.2 = 0.0832)
    np.testing.assert_allclose(interpolate_states(stamps, yaw, 12_500_000, angles=True),
                               [3.1 + 0.25 * (2 * math.pi - 6.2), 0.05, 0.0], atol=1e-12)
    np.testing.assert_allclose(interpolate_states(stamps, yaw, 75_000_000, angles=True), [-3.05, 0.3, 0.0])
    vel = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.0], [1.0, 2.0, 0.0]])
    np.testing.assert_allclose(interpolate_states(stamps, vel, 20_000_000), [0.4, 0.8, 0.0])
    np.testing.assert_allclose(interpolate_states(stamps, vel, -5), vel[0])  # held beyond the ends
    np.testing.assert_allclose(interpolate_states(stamps, vel, 200_000_000), vel[2])


def test_truth_of_a_steady_pan_from_20_hz_states_at_24_fps_frames_is_steady():
    from cinetransfer.report.camera_motion import truth_rates

    # given states at the 20 Hz control steps of a 6 deg/s pan and frames at 24 fps
    rate = math.radians(6.0)
    states = [M.VehicleState(stamp_ns=i * 50_000_000, camera_ypr_rad=np.array([rate * i * 0.05, 0.0, 0.0]),
                             lens=M.LensState(focal_length_mm=35.0)) for i in range(60)]
    truths = [M.GroundTruth(stamp_ns=round(k * 1e9 / 24), frame_index=k, focal_length_mm=35.0) for k in range(60)]
    pan = truth_rates(states, truths, 60, 24.0)["pan_rate_dps"]
    # then every frame reads 6 deg/s (the last state before each frame read 7.2 five frames in six, 0 the sixth)
    np.testing.assert_allclose(pan[np.isfinite(pan)], 6.0, rtol=1e-6)


def test_report_json_and_page_carry_the_section(tmp_path):
    from cinetransfer.report import build_report, synth

    src = synth.instructions(12)
    src = _moving(src, ["static"] * 12, 0.0)
    summary = build_report(tmp_path, source_style=src, output_style=_moving(src, ["pan"] * 12, 5.0), truths=[],
                           source_video=None, output_video=None, meta={})
    js = json.loads((tmp_path / "report.json").read_text())
    shot = js["camera_motion"]["shots"][0]
    assert shot["source"]["class"] == "static" and shot["output"]["class"] == "pan" and shot["agreement"] == 0.0
    assert shot["truth"] is None and js["camera_motion"]["truth_reason"]
    assert "fig_camera_motion.png" in js["figures"] and (tmp_path / "fig_camera_motion.png").stat().st_size > 0
    page = (tmp_path / "report.html").read_text()
    assert "<h2>Camera motion</h2>" in page and "The source camera was static." in page
    assert summary["camera_motion"] == js["camera_motion"]


def test_people_are_masked_out_of_the_background_with_a_margin():
    from cinetransfer.services.detector.camera_motion import MASK_MARGIN_PX, background_mask

    mask = np.ones((40, 20), dtype=bool)  # a 20 x 40 px person at (100, 60) of a 640 x 360 frame
    p = M.PersonDetection(box_xyxy=np.array([100, 60, 120, 100], np.float32), mask=mask,
                          mask_origin_xy=np.array([100, 60], np.int32))
    boxed = M.PersonDetection(box_xyxy=np.array([400, 200, 440, 280], np.float32), mask=np.zeros((0, 0), bool),
                              mask_origin_xy=np.array([400, 200], np.int32))
    bg = background_mask([p, boxed], 640, 360, (320, 180))  # half size: the person covers x 50-59, y 30-49
    assert bg[40, 55] == 0 and bg[30 - MASK_MARGIN_PX, 55] == 0 and bg[30 - MASK_MARGIN_PX - 1, 55] == 255
    assert bg[120, 210] == 0  # no mask: its box (x 200-219, y 100-139 at half size)
    assert (bg == 255).mean() > 0.9


def test_a_measurement_with_an_impossible_motion_is_unknown_not_a_crash():
    from cinetransfer.services.smoother.features import motion_vector

    cmo = M.CameraMotion(rotation_rad=np.array([1e300, 0.01, 0.0]), log_zoom=50.0,
                         translation_dir=np.array([3.0, 0.0, 0.0]), focal_px=900.0, points=40, explained=0.9)
    v = motion_vector(M.Measurement(camera_motion=cmo))
    assert math.isnan(v[0]) and v[1] == 0.01 and math.isnan(v[3]) and np.isnan(v[4:]).all()
    st = motion_style(np.tile(v, (5, 1)), 24.0, np.zeros(5, dtype=bool))
    assert np.isfinite(st["tilt_rate_dps"][1:]).all() and np.isnan(st["pan_rate_dps"]).all()


def test_an_edge_track_slides_when_it_falls_behind_its_edge_and_out_of_the_corners_beside_it():
    """Everything tilts 3 px down; twelve corners at the left, every other one off by 1 px more or
    less (parallax): off the fit (the tilt, which the twelve corners at the right and the left's other
    six fit) by 0 or 1 px, their median 0.5 px, their robust spread 1.4826 x 0.5 = 0.74 px, so an
    edge track beside them stands out from 0.5 + 3 x 0.74 = 2.72 px. Vertical edges beside them:
    2.5 px ahead of the tilt along the edge (not short of it), 4 px back (against it: slides), 2.5 px
    short (within the corners' spread). At the right, corners off by nothing: an edge track 1 px short
    of the tilt slides (past the inlier distance, 0.3 px, more than three of their spreads, 0)."""
    left = np.array([[-200.0 + 10.0 * i, 0.0] for i in range(12)])
    right = np.array([[100.0 + 10.0 * i, 0.0] for i in range(12)])
    p0 = np.vstack([left, right, [[-145.0, 5.0], [-140.0, 5.0], [-150.0, 5.0], [150.0, 5.0]]])
    p1 = p0.copy()
    p1[:, 1] += 3.0
    p1[:12, 1] += np.tile([0.0, 1.0, 0.0, -1.0], 3)
    p1[24:, 1] += (2.5, -4.0, -2.5, -1.0)
    normals = np.zeros_like(p0)
    normals[24:] = (1.0, 0.0)
    slide = cm.sliding_edges(p0, p1, F, normals, inlier_px=0.3)
    assert slide.tolist() == [False] * 24 + [False, True, False, True]  # corners never slide
    assert not cm.sliding_edges(p0, p1, F, np.zeros_like(p0), inlier_px=0.3).any()


def test_a_dolly_whose_edge_tracks_follow_their_texture_keeps_its_dolly():
    """A dolly (2.4 m/s) over the ground of `_ground_points`, half its ground tracks on the paving's
    receding lines (through the focus of expansion): the dolly moves them along their lines. Judged
    across their edges they lose that parallax and rotation + zoom explains the baseline (a zoom);
    none stands out of the corners beside it, so they count in 2-D and the dolly stands."""
    x = _ground_points(np.random.default_rng(3))
    step = np.array([0.0, 0.0, 0.1])
    proj = [F * (x - k * step)[:, :2] / (x - k * step)[:, 2:3] for k in range(9)]
    keep = np.all([(np.abs(v[:, 0]) < 320) & (np.abs(v[:, 1]) < 180) for v in proj], axis=0)
    earlier, p0, p1 = proj[0][keep], proj[7][keep], proj[8][keep]
    on = (x[keep, 1] == 1.6) & (np.arange(keep.sum()) % 2 == 0)
    mid = 0.5 * (earlier + p1)[on]
    normals = np.zeros_like(p1)
    normals[on] = np.column_stack([-mid[:, 1], mid[:, 0]]) / np.linalg.norm(mid, axis=1)[:, None]
    across = cm.fit_rotation_zoom(earlier, p1, F, inlier_px=2 * cm.INLIER_PX, normals=normals)[1]
    assert across.mean() >= cm.EXPLAINED_SHARE  # counted across their edges: no parallax is tested
    assert cm.sliding_edges(earlier, p1, F, normals, inlier_px=2 * cm.INLIER_PX)[on].sum() < 0.1 * on.sum()
    m = cm.frame_motion(p0, p1, F, earlier=earlier, span=8, normals=normals)
    np.testing.assert_allclose(m.translation_dir, (0, 0, 1), atol=0.02)
    assert m.log_zoom == 0.0


def test_the_rotation_given_a_translation_leaves_the_tracks_on_lines_out_by_hand():
    use = np.array([True] * 14 + [False] * 2)
    on_line = np.zeros(16, dtype=bool)
    on_line[[0, 1, 15]] = True
    assert cm.rotation_off_lines(use, on_line).tolist() == [False] * 2 + [True] * 12 + [False] * 2
    on_line[2] = True  # 11 left, under MIN_POINTS (12): all of `use`
    assert cm.rotation_off_lines(use, on_line).tolist() == use.tolist()


def _tracks_on_the_pavings_lines(step: np.ndarray):
    """The ground of `_ground_points` seen at the work width's lens over 9 frames of a camera moving
    by `step` a frame: (f, earlier, p0, p1, line) with the tracks seen in every frame, those at the
    lower left marked as on the paving's lines and slid 0.3 px to the right in the last frame."""
    f = cm.focal_px(cm.WORK_WIDTH)
    x = _ground_points(np.random.default_rng(5))
    proj = [f * (x - k * step)[:, :2] / (x - k * step)[:, 2:3] for k in range(9)]
    keep = np.all([(np.abs(v[:, 0]) < 160) & (np.abs(v[:, 1]) < 90) for v in proj], axis=0)
    earlier, p0, p1 = (proj[k][keep].copy() for k in (0, 7, 8))
    line = (earlier[:, 0] < -30) & (earlier[:, 1] > 30)
    p1[line, 0] += 0.3
    return f, earlier, p0, p1, line


def test_tracks_sliding_along_the_pavings_lines_do_not_turn_a_dolly():
    """A dolly in (2.4 m/s) over the ground of `_ground_points` at the work width's lens: the ground
    tracks at the lower left lie on the paving's lines and slide 0.3 px to the right along them in
    the last frame (within every inlier distance). In the frame's rotation given the dolly they read
    as a pan to the left and a roll; told as on lines, they are left out and the rotation stays
    near none."""
    f, earlier, p0, p1, line = _tracks_on_the_pavings_lines(np.array([0.0, 0.0, 0.1]))
    fooled = cm.frame_motion(p0, p1, f, earlier=earlier, span=8)
    told = cm.frame_motion(p0, p1, f, earlier=earlier, span=8, lines=line)
    for m in (fooled, told):
        assert m.translation_dir[2] > 0.99
    assert fooled.rotation_rad[0] > 1.2e-4 and fooled.rotation_rad[2] > 1.2e-4  # 0.17 deg/s at 24 frames/s
    np.testing.assert_allclose(told.rotation_rad[[0, 2]], 0.0, atol=5e-5)


def test_a_faint_crossing_line_makes_a_line_but_no_edge():
    """A level step of 150 grey levels crossed by an upright one of 58: where they cross the structure
    tensor's lesser eigenvalue is (58 / 150)^2 = 0.15 of the greater in both windows, over the
    edge's 0.1 and under the line's 0.2; along the level step away from the crossing, 0 (an edge and
    a line); at a tile's corner about 1, and on flat grey nothing."""
    from cinetransfer.services.detector.camera_motion import edges_and_lines

    img = np.full((80, 120), 10, np.uint8)
    img[40:, :] += 150
    img[:, 60:] += 58
    img[5:20, 95:110] = 250
    normals, line = edges_and_lines(img, np.array([[20.0, 40.0], [60.0, 40.0], [95.0, 5.0], [30.0, 15.0]]))
    np.testing.assert_allclose(np.abs(normals), [[0.0, 1.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]], atol=1e-6)
    assert line.tolist() == [True, True, False, False]


def test_a_trucks_rotation_keeps_its_tracks_on_lines():
    """Beside a truck a pan is weakly seen and the tracks on lines help hold it: they are left out
    of a dolly's rotation only, so a truck's motion is the same told or not."""
    f, earlier, p0, p1, line = _tracks_on_the_pavings_lines(np.array([0.1, 0.0, 0.0]))
    plain = cm.frame_motion(p0, p1, f, earlier=earlier, span=8)
    told = cm.frame_motion(p0, p1, f, earlier=earlier, span=8, lines=line)
    assert abs(plain.translation_dir[0]) > 0.9
    np.testing.assert_array_equal(told.rotation_rad, plain.rotation_rad)
    np.testing.assert_array_equal(told.translation_dir, plain.translation_dir)


def _tracks(name):
    data = json.loads((Path(__file__).parents[1] / "data" / "camera_motion" / f"{name}_tracks.json").read_text())
    return (np.array(data["earlier"]), np.array(data["now"]), data["focal_px"], data["inlier_px"],
            np.array(data["rot0_rad"]), data["shown"])


def test_points_behind_the_camera_do_not_count_off_the_optical_axis_by_hand():
    """Five points on their lines: two clearly in front (along > 1), one clearly behind, two within
    the inlier distance either way (far away: either sign). Off the axis the one behind is not
    counted (4); along it (a dolly-zoom's far points scale the wrong way) all five are; a point off
    its line (not an inlier) never counts."""
    inl = np.array([True, True, True, True, True, False])
    along = np.array([3.0, 2.0, -2.5, 0.5, -0.5, -9.0])
    got = cm._in_front_of_lines(inl[None].repeat(2, 0), along[None].repeat(2, 0), np.array([0.1, 0.95]), 1.0)
    np.testing.assert_array_equal(got, [4, 5])
    # the majority's sign wins: flipped, the same point is the one behind
    assert cm._in_front_of_lines(inl, -along, np.array(0.1), 1.0) == 4


def test_a_truck_is_read_as_a_truck_without_a_pan():
    """Tracks of the rendered truck right (no rotation): the alternation settled 8 deg off the truck,
    tilted down and forward, with a pan of 4 deg/s that the tilted direction takes up, and a truck
    left with an 8 deg/s pan explains most points too, with many of them behind the camera. The fit
    now reads the truck to the right within 2 deg and a pan within 1 deg/s of none."""
    a, b, f, tol, rot0, shown = _tracks("truck")
    rot, t, inl = cm.fit_rotation_translation(a, b, f, rot0, inlier_px=tol, shown=shown)
    assert math.degrees(math.acos(t[0])) < 2.0 and inl.mean() >= shown
    assert abs(math.degrees(rot[0]) * 24 / 8) < 1.0  # over the 8-frame baseline at 24 frames/s
    # the truck left with a pan: most points fit it, but not in front of the camera
    left = np.array([-0.89, 0.0, -0.46]) / np.linalg.norm([-0.89, 0.0, -0.46])
    mid, flow = 0.5 * (a + b), b - a
    basis = cm.rotation_zoom_basis(mid, f)[:, :, :3]
    r_left = cm.rotation_given_direction(a, b, f, left, np.ones(len(a), dtype=bool), inlier_px=tol)
    lines = cm._lines(mid, left, f)
    plain = int((cm._off_lines(flow, basis, r_left, *lines) < tol).sum())
    assert cm._count_in_front(flow, basis, r_left, left, lines, tol) < 0.8 * plain


def test_a_pedestal_keeps_the_direction_the_search_found():
    """Tracks of the rendered pedestal up (no rotation): rotation + zoom explains 37 % of them, the
    search's direction near straight up 83 %, but the alternation from it walks to the optical axis
    (65 %, under the share that shows a translation). The search's direction is kept, signed up."""
    a, b, f, tol, rot0, shown = _tracks("pedestal")
    alone = cm._alternate(a, b, f, np.array([-0.19, -0.98, 0.09]) / np.linalg.norm([-0.19, -0.98, 0.09]), tol, 5)
    assert alone[2].mean() < shown and abs(alone[1][2]) > 0.9
    rot, t, inl = cm.fit_rotation_translation(a, b, f, rot0, inlier_px=tol, shown=shown)
    assert t[1] < -0.95 and inl.mean() >= shown
    assert np.all(np.abs(np.degrees(rot) * 24 / 8) < 1.0)


def test_the_polish_moves_a_tilted_truck_onto_the_truck():
    """Exact tracks of a truck right (points 4-30 m away, no rotation): started 8 deg off, tilted
    down and forward, with the rotation that direction asks, the polish comes back within 1 deg."""
    rng = np.random.default_rng(2)
    x = np.column_stack([rng.uniform(-12, 12, 200), rng.uniform(-3, 3, 200), rng.uniform(4, 30, 200)])
    p0 = F * x[:, :2] / x[:, 2:]
    p1 = F * (x - [0.4, 0.0, 0.0])[:, :2] / (x - [0.4, 0.0, 0.0])[:, 2:]
    mid, flow = 0.5 * (p0 + p1), p1 - p0
    basis = cm.rotation_zoom_basis(mid, F)[:, :, :3]
    off = np.array([0.99, -0.1, -0.1]) / np.linalg.norm([0.99, -0.1, -0.1])
    rot = cm.rotation_given_direction(p0, p1, F, off, np.ones(len(p0), dtype=bool), inlier_px=1.2)
    inl = cm._off_lines(flow, basis, rot, *cm._lines(mid, off, F)) < 1.2
    rot2, t, inl2 = cm.polish_direction(mid, flow, basis, F, rot, off, inl, 1.2)
    assert math.degrees(math.acos(min(t[0], 1.0))) < 1.0 and inl2.sum() >= inl.sum()
    np.testing.assert_allclose(rot2, 0.0, atol=2e-3)
    # a dolly is never polished (its checks judge it)
    axis = np.array([0.0, 0.0, 1.0])
    assert cm.polish_direction(mid, flow, basis, F, rot, axis, inl, 1.2)[1] is axis


def test_the_share_that_shows_a_translation_by_hand():
    """EXPLAINED_SHARE and PARALLAX_GAIN more than rotation + zoom explains, or short of
    EXPLAINED_SHARE, PARALLAX_DOMINANT more: 0.1 -> max(0.25, min(0.8, 0.5)) = 0.5,
    0.3 -> max(0.45, min(0.8, 0.7)) = 0.7, 0.5 -> max(0.65, min(0.8, 0.9)) = 0.8, 0.7 -> 0.85."""
    got = [cm.parallax_share_needed(s) for s in (0.1, 0.3, 0.5, 0.7)]
    np.testing.assert_allclose(got, [0.5, 0.7, 0.8, 0.85])


def test_a_pedestal_whose_paving_tracks_slide_is_read_with_the_least_rotation():
    """Tracks of the rendered pedestal up on a frame whose paving tracks slide sideways along their
    lines: rotation + zoom explains 30 % of them, which asks 70 % of a translation. The alternation
    from the optical axis explains 50 points with a tilt of 4 deg/s and a roll of -4.7; straight up
    needs a tilt of -6 deg/s. The fit reads the rise (its main axis up) with under 1 deg/s of
    rotation and at least the share asked."""
    a, b, f, tol, rot0, shown = _tracks("pedestal_lines")
    assert shown == pytest.approx(cm.parallax_share_needed(0.2963), abs=1e-4) and shown < cm.EXPLAINED_SHARE
    axis = cm._alternate(a, b, f, np.array([0.0, 0.0, 1.0]), tol, 5)
    assert abs(axis[1][2]) > 0.9 and np.abs(np.degrees(axis[0]) * 3).max() > 3.0  # 8 frames at 24 frames/s
    up = cm._alternate(a, b, f, np.array([0.0, -1.0, 0.0]), tol, 5)
    assert up[1][1] < -0.99 and abs(math.degrees(up[0][1]) * 3) > 5.0
    rot, t, inl = cm.fit_rotation_translation(a, b, f, rot0, inlier_px=tol, shown=shown)
    assert int(np.argmax(np.abs(t))) == 1 and t[1] < 0.0 and inl.mean() >= shown
    assert np.abs(np.degrees(rot) * 3).max() < 1.0


def test_a_zoom_whose_paving_tracks_slide_is_no_dolly_with_a_pan():
    """Tracks of the rendered zoom in over a 7-frame baseline: the tiles' tracks slide along lines that
    meet to the right, so a dolly 21 deg off the axis with a pan of 3.3 deg/s explains 92 of 93
    points (read as a dolly-zoom); along the axis, with no turn, 85. Within ROTATION_TIE of each
    other the least rotation is kept."""
    a, b, f, tol, rot0, shown = _tracks("zoom_in")
    side = cm._alternate(a, b, f, np.array([0.37, -0.01, 0.93]) / np.linalg.norm([0.37, -0.01, 0.93]), tol, 5)
    assert side[2].sum() == 92 and abs(math.degrees(side[0][0]) * 24 / 7) > 3.0
    rot, t, inl = cm.fit_rotation_translation(a, b, f, rot0, inlier_px=tol, shown=shown)
    assert t[2] > 0.99 and inl.sum() >= side[2].sum() - cm.ROTATION_TIE * len(a)
    assert np.abs(np.degrees(rot) * 24 / 7).max() < 0.5


def test_a_frame_showing_no_parallax_carries_on_the_dolly_before_it():
    dolly = cm.FrameMotion(np.zeros(3), 0.0, np.array([0.0, 0.0, 1.0]), 150, 0.6)
    zoom_in = cm.FrameMotion(np.array([0.001, 0.0, 0.0]), 0.016, np.zeros(3), 120, 0.95)
    m = cm.dolly_carried(zoom_in, dolly)
    assert m.log_zoom == 0.0
    np.testing.assert_array_equal(m.translation_dir, [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(m.rotation_rad, zoom_in.rotation_rad)
    assert (m.points, m.explained) == (120, 0.95)
    # a zoom against the dolly (the dolly-zoom's), no dolly before, a truck before: as they are
    zoom_out = cm.FrameMotion(np.zeros(3), -0.016, np.zeros(3), 120, 0.95)
    assert cm.dolly_carried(zoom_out, dolly) is zoom_out
    assert cm.dolly_carried(zoom_in, None) is zoom_in
    assert cm.dolly_carried(zoom_in, cm.parallax_untested(zoom_in)) is zoom_in
    truck = cm.FrameMotion(np.zeros(3), 0.0, np.array([1.0, 0.0, 0.0]), 150, 0.5)
    assert cm.dolly_carried(zoom_in, truck) is zoom_in
    # a frame that saw a translation itself keeps it
    out = cm.FrameMotion(np.zeros(3), 0.0, np.array([0.0, 0.0, -1.0]), 150, 0.6)
    assert cm.dolly_carried(out, dolly) is out


def test_a_trucks_mirror_by_hand():
    """Both off the axis (|t_z| < DOLLY_AXIS) and a negative dot: a mirror, (0.91, -0.04, 0.41) .
    (-0.99, -0.01, 0.12) = -0.85; one beside it (dot +0.98), a dolly's opposite (t_z 0.95: the
    ground signs a dolly) and a dolly against a truck (dot -0.41, t_z -0.95) are not."""
    truck = np.array([-0.99, -0.01, 0.12])
    assert cm.mirrors_truck(np.array([0.91, -0.04, 0.41]), truck)
    assert not cm.mirrors_truck(np.array([-0.97, 0.11, 0.22]), truck)
    dolly = np.array([0.1, 0.0, 0.95])
    assert not cm.mirrors_truck(-dolly, dolly)
    assert not cm.mirrors_truck(np.array([0.3, 0.0, -0.95]), truck)
    assert not cm.mirrors_truck(truck, np.array([0.3, 0.0, -0.95]))
