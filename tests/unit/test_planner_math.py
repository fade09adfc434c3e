"""The planner's symbolic projection, depth of field and model against hand-computed numbers and
against cinetransfer.shared.camera (the independent numpy implementation)."""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner import cost as J
from cinetransfer.services.planner import model
from cinetransfer.services.planner.constraints import clamp_state
from cinetransfer.shared import camera as cam


def project_sym(point_w, cam_pos, ypr, f_mm, depth_floor=None):
    pc_ = J.world_to_camera(ca.DM(point_w), ca.DM(cam_pos), *ypr)
    u, v = J.project(pc_, f_mm, cam.SENSOR_WIDTH_MM, cam.SENSOR_HEIGHT_MM, depth_floor)
    return float(u), float(v)


# ----------------------------------------------------------------------------- projection
@pytest.mark.parametrize("point, cam_pos, ypr, f, expected", [
    # given a camera at the origin looking along +x: u = 0.5 - f y / (x ws), v = 0.5 - f z / (x hs)
    ((10.0, 1.0, 0.5), (0, 0, 0), (0, 0, 0), 50.0, (0.5 - 50 / (10 * 23.76), 0.5 - 25 / (10 * 13.365))),
    # yaw +90 deg looks along +y: a point on +y is centred; one further left (-x) appears left (u < 0.5)
    ((0.0, 10.0, 0.0), (0, 0, 0), (math.pi / 2, 0, 0), 35.0, (0.5, 0.5)),
    ((-1.0, 10.0, 0.0), (0, 0, 0), (math.pi / 2, 0, 0), 35.0, (0.5 - 35 / (10 * 23.76), 0.5)),
    # pitch up 30 deg: a point on that ray is centred
    ((math.cos(math.radians(30)) * 8, 0.0, 2 + math.sin(math.radians(30)) * 8), (0, 0, 2),
     (0, math.radians(30), 0), 80.0, (0.5, 0.5)),
    # roll 90 deg (camera z axis = world -y): a point at world y = -1 (z = 0) is "up" in the image
    ((10.0, -1.0, 0.0), (0, 0, 0), (0, 0, math.pi / 2), 50.0, (0.5, 0.5 - 50 / (10 * 13.365))),
])
def test_projection_hand_computed(point, cam_pos, ypr, f, expected):
    # when projected symbolically and with shared.camera, then both give the hand-computed numbers
    u, v = project_sym(point, cam_pos, ypr, f)
    assert (u, v) == pytest.approx(expected, abs=1e-12)
    ref = cam.project_world(np.array(point), np.array(cam_pos), np.array(ypr), f)
    assert tuple(ref) == pytest.approx(expected, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-20, 20), min_size=3, max_size=3), st.lists(st.floats(-20, 20), min_size=3, max_size=3),
       st.floats(-math.pi, math.pi), st.floats(-1.4, 1.4), st.floats(-0.5, 0.5), st.floats(20, 500))
def test_projection_matches_shared_camera(point, cam_pos, yaw, pitch, roll, f):
    # given any pose and point in front of the camera, the casadi projection equals shared.camera
    point, cam_pos = np.array(point), np.array(cam_pos)
    pc_ = cam.world_to_camera(point, cam_pos, np.array([yaw, pitch, roll]))
    if pc_[0] < 0.5:
        return
    ref = cam.project_world(point, cam_pos, np.array([yaw, pitch, roll]), f)
    got = project_sym(point, cam_pos, (yaw, pitch, roll), f)
    assert got == pytest.approx(tuple(ref), rel=1e-9, abs=1e-9)
    sym_c = np.asarray(J.world_to_camera(ca.DM(point), ca.DM(cam_pos), yaw, pitch, roll)).ravel()
    np.testing.assert_allclose(sym_c, pc_, atol=1e-9)
    # and the floored depth used in the cost changes the offset from the centre by < 0.1 % for
    # points >= 2 m away (floor 1 m)
    if pc_[0] >= 2.0:
        soft = np.array(project_sym(point, cam_pos, (yaw, pitch, roll), f, depth_floor=1.0))
        assert np.all(np.abs(soft - ref) <= 1e-3 * np.abs(ref - 0.5) + 1e-12)


def test_extended_projection_is_the_pinhole_in_view_and_has_no_false_minimum():
    x = ca.SX.sym("x", 3)
    f_mm = 50.0
    u, v = J.project_extended(x, f_mm, cam.SENSOR_WIDTH_MM, cam.SENSOR_HEIGHT_MM)
    proj = ca.Function("p", [x], [ca.vertcat(u, v)])
    rng = np.random.default_rng(3)
    # given points within 60 deg of the optical axis: exactly shared.camera's pinhole
    for _ in range(200):
        th, ph, r = rng.uniform(0, math.radians(59.9)), rng.uniform(-math.pi, math.pi), rng.uniform(0.5, 50)
        p = r * np.array([math.cos(th), math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph)])
        np.testing.assert_allclose(np.asarray(proj(p)).ravel(), cam.project_normalised(p, f_mm), rtol=1e-12,
                                   atol=1e-12)
    # and any direction, behind the camera included, maps to a bounded image point
    h_max = math.tan(math.pi / 3) + (2 * math.pi / 3) * 4  # h(pi) in units of f / sensor size
    for _ in range(200):
        p = rng.normal(size=3) * 10
        uv = np.asarray(proj(p)).ravel()
        assert np.all(np.isfinite(uv))
        assert abs(uv[0] - 0.5) <= h_max * f_mm / cam.SENSOR_WIDTH_MM + 1e-9
    # and a camera that only turns (yaw, pitch) reaches the target from any start, behind
    # included: the error has no false minimum (IPOPT from 24 starts, pitch kept in +-80 deg)
    yp = ca.SX.sym("yp", 2)
    joint = np.array([6.0, 2.0, 1.5])
    pc_ = J.world_to_camera(ca.DM(joint), ca.DM.zeros(3), yp[0], yp[1])
    obj = J.joint_image_error(pc_, 0.55, 0.45, f_mm, cam.SENSOR_WIDTH_MM, cam.SENSOR_HEIGHT_MM)
    solver = ca.nlpsol("s", "ipopt", {"x": yp, "f": obj}, {"ipopt": {"print_level": 0, "sb": "yes"},
                                                             "print_time": False})
    starts = [(math.atan2(2, 6) + math.pi, 0.0), (math.atan2(2, 6) + math.pi + 0.01, -0.2)]
    starts += [(rng.uniform(-math.pi, math.pi), rng.uniform(-1.2, 1.2)) for _ in range(22)]
    for y0 in starts:
        r = solver(x0=y0, lbx=[-10, -1.4], ubx=[10, 1.4])
        assert float(r["f"]) < 1e-10, (y0, float(r["f"]))
        got = cam.project_world(joint, np.zeros(3), np.array([float(r["x"][0]), float(r["x"][1]), 0.0]), f_mm)
        np.testing.assert_allclose(got, [0.55, 0.45], atol=1e-5)
    # and the (optional) floored depth of `project` keeps it finite behind the camera too
    assert float(J.soft_depth(-1e3, 1.0)) == pytest.approx(1.0) and float(J.soft_depth(30.0, 1.0)) == 30.0


# ----------------------------------------------------------------------------- depth of field
def test_dof_hand_computed():
    # given f = 50 mm, A = 4, c = 0.05 mm: H = 2500 / 0.2 + 50 = 12550 mm
    h = 12.55
    assert float(J.hyperfocal_m(50.0, 4.0, 0.05)) == pytest.approx(h)
    assert cam.hyperfocal_m(50.0, 4.0, 0.05) == pytest.approx(h)
    # when focused at 5 m: D_n = 5 (12.55 - 0.05) / (12.55 + 5 - 0.1) = 62.5 / 17.45, D_f = 62.5 / 7.55
    inv_n, inv_f = (float(v) for v in J.inverse_dof_limits(50.0, 4.0, 5.0, 0.05))
    assert 1 / inv_n == pytest.approx(62.5 / 17.45, rel=1e-12)
    assert 1 / inv_f == pytest.approx(62.5 / 7.55, rel=1e-12)
    near, far = cam.dof_limits_m(50.0, 4.0, 5.0, 0.05)
    assert (near, far) == pytest.approx((62.5 / 17.45, 62.5 / 7.55), rel=1e-12)


@settings(max_examples=80, deadline=None)
@given(st.floats(20, 500), st.floats(1, 22), st.floats(0.6, 200))
def test_reciprocal_dof_matches_shared_camera(f, a, s):
    # given any lens state, 1/D_n and 1/D_f equal the reciprocals of shared.camera's limits,
    # with 1/D_f <= 0 exactly where the far limit is infinite (s >= H)
    inv_n, inv_f = (float(v) for v in J.inverse_dof_limits(f, a, s, cam.COC_MM))
    near, far = cam.dof_limits_m(f, a, s)
    assert inv_n == pytest.approx(1.0 / near, rel=1e-9)
    if math.isinf(far):
        assert inv_f <= 1e-12
    else:
        assert inv_f == pytest.approx(1.0 / far, rel=1e-7, abs=1e-12)


def test_dof_cost_is_smooth_across_the_hyperfocal_distance():
    # given the far limit at infinity as target (one-sided), the cost and its gradient stay finite
    # and continuous as the focus distance crosses H, where D_f itself jumps to infinity
    s = ca.SX.sym("s")
    inv_n, inv_f = J.inverse_dof_limits(50.0, 4.0, s, 0.05)
    c2 = J.dof_cost(inv_n, inv_f, 6.0, w_near=1.0, g_near=1 / 7.0, w_far=1.0, g_far=1 / 9.0, far_one_sided=0)
    fun = ca.Function("c", [s], [c2, ca.gradient(c2, s)])
    h = 12.55
    vals = [[float(v) for v in fun(x)] for x in (h - 1e-6, h, h + 1e-6)]
    assert all(math.isfinite(v) for row in vals for v in row)
    assert vals[0][0] == pytest.approx(vals[2][0], rel=1e-5) and vals[0][1] == pytest.approx(vals[2][1], rel=1e-4)
    one = J.dof_cost(inv_n, inv_f, 6.0, w_near=0.0, g_near=0.0, w_far=1.0, g_far=-0.01, far_one_sided=1)
    f1 = ca.Function("c", [s], [one])
    # and the one-sided far term is zero once 1/D_f <= -0.01 (s a bit past H), positive before
    assert float(f1(h * 1.3)) == 0.0
    assert float(f1(h * 0.5)) > 0.0


def test_an_absent_foreground_makes_the_near_limit_one_sided():
    # the source shows no foreground: the near limit that would keep it out of focus only has to be
    # no farther than the subject's
    got = J.reciprocal_targets(5.0, 7.0, near_foreground_m=1.0, far_margin_inv_m=0.01, fg_absent=True)
    assert got == pytest.approx((1, 1 / 5.0, 1, 1 / 7.0, 0, 1))
    got = J.reciprocal_targets(0.0, math.inf, near_foreground_m=1.0, far_margin_inv_m=0.01, fg_absent=True)
    assert got == pytest.approx((1, 1.0, 1, -0.01, 1, 0))  # a foreground in focus is not absent: unchanged


def test_one_sided_near_term_by_hand():
    # no foreground in the source, subject in focus from 1 m (g_n = 1/m): a near limit at or nearer
    # than 1 m costs nothing, a near limit farther than that costs (d (1/D_n - g_n))^2
    near = ca.SX.sym("inv_near")
    c = ca.Function("c", [near], [J.dof_cost(near, 0.0, 6.0, w_near=1.0, g_near=1.0, w_far=0.0, g_far=0.0,
                                             far_one_sided=0, near_one_sided=1)])
    assert float(c(1.0 / 0.8)) == 0.0  # near limit at 0.8 m: in focus from 0.8 m on, 1 m included
    assert float(c(1.0 / 2.0)) == pytest.approx((6.0 * (0.5 - 1.0)) ** 2)  # at 2 m: 9.0
    two = ca.Function("c", [near], [J.dof_cost(near, 0.0, 6.0, w_near=1.0, g_near=1.0, w_far=0.0, g_far=0.0,
                                               far_one_sided=0)])
    assert float(two(1.0 / 0.8)) == pytest.approx((6.0 * 0.25) ** 2)  # two-sided: 2.25


@pytest.mark.parametrize("focus, d, mu, expected", [
    # (fg, subject, bg) -> (w_near, g_near, w_far, g_far, far_one_sided, near_one_sided)  [DESIGN §1.2]
    ((False, True, False), 6.0, 1.0, (1, 1 / 5.0, 1, 1 / 7.0, 0, 0)),  # subject: D_n* = d - mu, D_f* = d + mu
    ((False, False, True), 6.0, 1.0, (1, 1 / 7.0, 1, -0.01, 1, 0)),  # background: D_n* = d + mu, D_f* = inf
    ((True, False, False), 6.0, 1.0, (1, 1 / 1.0, 1, 1 / 5.0, 0, 0)),  # foreground: D_n* = 0 -> 1 m, D_f* = d - mu
    ((False, False, False), 6.0, 1.0, (0, 0, 0, 0, 0, 0)),  # nothing controlled
    ((True, True, True), 6.0, 1.0, (1, 1.0, 1, -0.01, 1, 0)),  # everything: D_n* = 0 -> 1 m, D_f* = inf
])
def test_reciprocal_targets(focus, d, mu, expected):
    near, far = cam.desired_dof_limits(*focus, d, mu)
    got = J.reciprocal_targets(near, far, near_foreground_m=1.0, far_margin_inv_m=0.01)
    assert got == pytest.approx(expected)


def test_far_limit_for_a_larger_circle_by_hand():
    # given f = 50 mm, f/4, focus 5 m: H - f = 50^2 / (4 x 0.05) mm = 12.5 m, spread = 4.95 / (5 x 12.5)
    inv_n, inv_f = (float(v) for v in J.inverse_dof_limits(50.0, 4.0, 5.0, 0.05))
    assert (inv_n, inv_f) == pytest.approx((0.2 + 0.0792, 0.2 - 0.0792))
    # when the circle is 4 x larger (0.2 mm), the spread is 4 x 0.0792 = 0.3168 about 1/s = 0.2:
    # 1/D_f = -0.1168 (the far limit at infinity), as inverse_dof_limits computes it for 0.2 mm
    assert float(J.far_limit_for_circle(inv_n, inv_f, 4.0)) == pytest.approx(-0.1168)
    assert float(J.far_limit_for_circle(inv_n, inv_f, 4.0)) == pytest.approx(
        float(J.inverse_dof_limits(50.0, 4.0, 5.0, 0.2)[1]))
    # and a ratio of 1 leaves it as it is
    assert float(J.far_limit_for_circle(inv_n, inv_f, 1.0)) == pytest.approx(inv_f)


def test_defocus_ratio_follows_how_soft_the_source_subject_is():
    # given theta 0.5: B = 0.44 is 0.06 / 0.5 = 0.12 below it, B = 0 all of it, B = 0.6 above it
    assert J.subject_softness(0.44, 0.5) == pytest.approx(0.12)
    assert J.subject_softness(0.0, 0.5) == 1.0 and J.subject_softness(0.6, 0.5) == 0.0
    assert J.subject_softness(float("nan"), 0.5) == 1.0  # no subject in the source: plainly soft
    # then a far limit that keeps the subject out asks for a 1 + 3 x 0.12 = 1.36 x circle, or the full 4 x;
    # any other stage for the circle itself
    assert J.defocus_ratio(True, 4.0, 0.12) == pytest.approx(1.36)
    assert J.defocus_ratio(True, 4.0, 1.0) == 4.0 and J.defocus_ratio(False, 4.0, 1.0) == 1.0


def test_a_borderline_sharp_label_weighs_as_little_as_it_is_sharp():
    # given theta 0.5 and the band 0.1: B = 0.505 lies 0.005 / 0.1 = 0.05 of the way above it, 0.56 0.6 of it
    assert J.label_sharpness(0.505, 0.5) == pytest.approx(0.05)
    assert J.label_sharpness(0.56, 0.5) == pytest.approx(0.6)
    # then a plainly sharp label weighs in full, one at or below theta nothing, and one not measured in full
    assert J.label_sharpness(0.95, 0.5) == 1.0 and J.label_sharpness(0.5, 0.5) == 0.0
    assert J.label_sharpness(0.3, 0.5) == 0.0 and J.label_sharpness(float("nan"), 0.5) == 1.0
    # and with no band every label weighs in full
    assert J.label_sharpness(0.505, 0.5, band=0.0) == 1.0


@pytest.mark.parametrize("focus, expected", [
    # (fg, subject, bg): the far limit keeps the subject out where D_f* = d - mu
    ((False, False, False), True),  # nothing in focus (defocus_when_none)
    ((True, False, False), True),  # foreground only
    ((False, False, True), False),  # background only: D_f* = inf (the near limit keeps the subject out)
    ((False, True, False), False),
    ((True, True, True), False),
    ((True, False, True), False),  # fg and bg: D_f* = inf, the subject is not controlled
])
def test_far_keeps_subject_out(focus, expected):
    assert J.far_keeps_subject_out(*focus) is expected


@pytest.mark.parametrize("focus, expected", [
    # (fg, subject, bg): the near limit keeps the subject out where D_n* = d + mu
    ((False, False, True), True),  # background only: focus beyond the subject
    ((False, False, False), False), ((True, False, False), False), ((False, True, False), False),
    ((True, True, True), False), ((True, False, True), False), ((False, True, True), False),
])
def test_near_keeps_subject_out(focus, expected):
    assert J.near_keeps_subject_out(*focus) is expected


def test_near_limit_for_a_larger_circle_hand_computed():
    # given f = 50 mm, A = 4, focused at 5 m with c = 0.05 mm: 1/D_n = 17.45 / 62.5, 1/D_f = 7.55 / 62.5
    inv_n, inv_f = 17.45 / 62.5, 7.55 / 62.5
    # then for a 4 x circle the near limit sits 4 spreads nearer than 1/s = 0.2: 0.2 + 4 x 0.0792 = 0.5168
    assert float(J.near_limit_for_circle(inv_n, inv_f, 4.0)) == pytest.approx(0.2 + 4 * (17.45 - 12.5) / 62.5)
    # which is the near limit shared.camera gives for c = 0.2 mm
    assert float(J.near_limit_for_circle(inv_n, inv_f, 4.0)) == pytest.approx(
        1.0 / cam.dof_limits_m(50.0, 4.0, 5.0, 0.2)[0], rel=1e-9)
    assert float(J.near_limit_for_circle(inv_n, inv_f, 1.0)) == pytest.approx(inv_n)


def test_visible_defocus_only_once_the_switch_is_reached():
    # given rows 2-4 keep the subject out (rows 0-1 and 5 keep it in)
    keeps_out = [False, False, True, True, True, False]
    # at row 1 the switch is still ahead: no stage gets the larger circle, not even rows 2-4
    assert not J.switched_out(keeps_out, 1, 3)
    # at row 2 it has happened: rows 2-4 do
    assert J.switched_out(keeps_out, 2, 2) and J.switched_out(keeps_out, 2, 4)
    # and a stage past the run (row 5, subject in again) does not
    assert not J.switched_out(keeps_out, 3, 5)


# ----------------------------------------------------------------------------- model
@pytest.mark.parametrize("roll", [False, True])
def test_model_step_is_exact_for_constant_inputs(roll):
    # given a state and constant inputs, one step of dt equals the closed-form integration
    lay = model.Layout(roll)
    rng = np.random.default_rng(1)
    x = rng.normal(size=lay.nx)
    u = rng.normal(size=lay.nu)
    dt = 0.3
    xn = model.step(lay, x, u, dt)
    np.testing.assert_allclose(xn[lay.P], x[lay.P] + x[lay.V] * dt + 0.5 * u[lay.ACC] * dt * dt)
    np.testing.assert_allclose(xn[lay.V], x[lay.V] + u[lay.ACC] * dt)
    assert xn[lay.YAW] == pytest.approx(x[lay.YAW] + u[lay.YAW_RATE] * dt)
    assert xn[lay.PITCH] == pytest.approx(x[lay.PITCH] + u[lay.PITCH_RATE] * dt)
    if roll:
        assert xn[lay.ROLL] == pytest.approx(x[lay.ROLL] + u[lay.ROLL_RATE] * dt)
    for si, ui in ((lay.F, lay.F_RATE), (lay.S, lay.S_RATE), (lay.A, lay.A_RATE)):
        assert xn[si] == pytest.approx(x[si] + u[ui] * dt)
    # and two half steps equal one full step (exact discretisation)
    np.testing.assert_allclose(model.step(lay, model.step(lay, x, u, dt / 2), u, dt / 2), xn, atol=1e-12)


def test_roll_out_keeps_the_dynamics_exact_and_lands_states_on_their_bounds():
    # given a drone at 1.95 m/s (bound 2) accelerating at 1 m/s^2, the aperture at f/2.9 closing at
    # 2 /s towards its f/2.8 bound, and the focus asked 5 m/s against a 1 m/s rate bound, dt = 0.1 s
    lay = model.Layout(False)
    a, b = model.discrete_matrices(lay, 0.1)
    x0 = np.zeros(lay.nx)
    x0[lay.V.start], x0[lay.F], x0[lay.S], x0[lay.A] = 1.95, 50.0, 5.0, 2.9
    u = np.zeros((2, lay.nu))
    u[:, lay.ACC.start], u[:, lay.S_RATE], u[:, lay.A_RATE] = 1.0, 5.0, -2.0
    x_lo, x_hi = (np.tile(v, (2, 1)) for v in (np.full(lay.nx, -np.inf), np.full(lay.nx, np.inf)))
    x_lo[:, lay.V], x_hi[:, lay.V] = -2.0, 2.0
    x_lo[:, lay.A] = 2.8
    u_lo, u_hi = np.full((2, lay.nu), -1.0), np.full((2, lay.nu), 1.0)
    u_lo[:, lay.A_RATE], u_hi[:, lay.A_RATE] = -3.0, 3.0
    x, uc = model.roll_out(a, b, x0, u, x_lo, x_hi, u_lo, u_hi)
    # then stage 0 accelerates 0.5 (to the 2 m/s bound) and stage 1 not at all; p = v dt + a dt^2 / 2
    assert uc[:, lay.ACC.start].tolist() == pytest.approx([0.5, 0.0])
    assert x[:, lay.V.start].tolist() == pytest.approx([1.95, 2.0, 2.0])
    assert x[:, 0].tolist() == pytest.approx([0.0, 0.195 + 0.0025, 0.1975 + 0.2])
    # the aperture closes at 1 /s to f/2.8, then holds; the focus moves at its rate bound 1 m/s
    assert uc[:, lay.A_RATE].tolist() == pytest.approx([-1.0, 0.0])
    assert x[:, lay.A].tolist() == pytest.approx([2.9, 2.8, 2.8])
    assert x[:, lay.S].tolist() == pytest.approx([5.0, 5.1, 5.2])
    assert x[:, lay.F].tolist() == [50.0, 50.0, 50.0]
    # and every step is the model's own
    for k in range(2):
        np.testing.assert_allclose(x[k + 1], model.step(lay, x[k], uc[k], 0.1), atol=1e-12)


def test_bounds_vectors_follow_the_config():
    b = pc.Bounds()
    lay = model.Layout(False)
    lo, hi = model.state_bounds(lay, b)
    assert (lo[lay.F], hi[lay.F]) == (30.0, 500.0) and (lo[lay.S], hi[lay.S]) == (0.5, 100.0)
    assert (lo[lay.A], hi[lay.A]) == (1.0, 22.0) and list(hi[lay.V]) == [2.0, 2.0, 1.0]  # vertical: the climb rate
    assert list(lo[lay.V]) == [-2.0, -2.0, -1.0]
    assert np.all(np.isinf(lo[lay.P])) and math.isinf(lo[lay.YAW])
    ulo, uhi = model.input_bounds(lay, b)
    assert np.all(uhi[lay.ACC] == 1.2) and uhi[lay.F_RATE] == 20.0 and uhi[lay.S_RATE] == 15.0
    assert uhi[lay.A_RATE] == 3.0 and np.all(ulo == -uhi)


def test_clamp_state_small_vs_large_violations():
    lay = model.Layout(False)
    b = pc.Bounds()
    x = np.zeros(lay.nx)
    x[lay.F], x[lay.S], x[lay.A] = 50.0, 10.0, 4.0
    x[3] = 2.05  # 0.05 over |v| <= 2 (range 4): clamped
    xc, ok = clamp_state(lay, b, x, 0.05)
    assert ok and xc[3] == 2.0
    x[lay.F] = 10.0  # 20 mm under 30 (range 470 -> tolerance 23.5 mm): clamped
    xc, ok = clamp_state(lay, b, x, 0.05)
    assert ok and xc[lay.F] == 30.0
    x[lay.F] = 35.0
    xc, ok = clamp_state(lay, pc.Bounds(focal_length_min_mm=200.0), x, 0.05)
    assert not ok and xc[lay.F] == 35.0  # far out: left as is, the solve will fail on purpose


def test_unwrap_and_wrap():
    assert model.unwrap_near(-3.1, 3.1) == pytest.approx(-3.1 + 2 * math.pi)
    assert model.wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)


@pytest.mark.parametrize("changes, field", [
    ({"bounds.focal_length_min_mm": 600.0}, "focal_length_min_mm"),
    ({"bounds.speed_max_mps": 0.0}, "speed_max_mps"),
    ({"weights.image": -1.0}, "image"),
    ({"structure.horizon_steps": 0}, "horizon_steps"),
    ({"structure.dt_s": 2.0}, "dt_s"),
    ({"rate_hz": 0.0}, "rate_hz"),
    ({"bounds.altitude_max_m": 0.5}, "altitude_max_m"),
    ({"structure.solver": "snopt"}, "solver"),
    ({"structure.qp_solver": "gurobi"}, "qp_solver"),
    ({"structure.expand": False}, "expand"),  # the SQP is built in SX only (IPOPT takes MX: the baseline)
    ({"structure.sqp_iter": 0}, "sqp_iter"),
])
def test_config_validation_names_the_field(changes, field):
    with pytest.raises(pc.ConfigError, match=field):
        pc.replace(pc.PlannerConfig(), **changes).validate()


def test_config_from_dict_rejects_unknown_fields():
    cfg = pc.from_dict({"rate_hz": 50, "structure": {"horizon_steps": 10}, "weights": {"image": 10}})
    assert cfg.rate_hz == 50 and cfg.structure.horizon_steps == 10 and cfg.weights.image == 10
    with pytest.raises(pc.ConfigError, match="bogus"):
        pc.from_dict({"weights": {"bogus": 1}})


def test_soft_constraint_rows_by_hand():
    from cinetransfer.services.planner import constraints as C

    lay = model.Layout(False)
    x = np.zeros(lay.nx)
    x[lay.P] = [3.0, 4.0, 0.5]  # 5 m from the subject at the origin, 0.5 m high
    x[lay.V] = [1.2, 1.6, 0.0]  # 2 m/s
    lim = C.soft_limits(pc.Bounds())  # floor 1, ceiling 40, distance 2, speed 2
    assert lim == [1.0, 40.0, 2.0, 2.0]
    # one obstacle slot: a cylinder at (3, 0) of radius 0.5 + 1 m clearance; the others empty
    obstacles = np.zeros(3 * C.N_OBSTACLE_SLOTS)
    obstacles[0:3] = [3.0, 0.0, 1.5]
    rows = np.asarray(C.soft_constraints(x, np.zeros(C.N_SOFT), np.zeros(3), lim, obstacles)).ravel()
    # floor violated by 0.5, ceiling 39.5 away, distance 3 beyond 2, speed exactly at its limit, 4 m from the
    # obstacle's axis: 2.5 beyond its radius and clearance; an empty slot: the distance to (0, 0), 5
    empty = [5.0] * (C.N_OBSTACLE_SLOTS - 1)
    np.testing.assert_allclose(rows, [-0.5, 39.5, 3.0, 0.0, 2.5, *empty], atol=1e-4)
    x[lay.V] = [3.0, 0.0, 4.0]  # 5 m/s: 3 over
    rows = np.asarray(C.soft_constraints(x, np.array([0.5, 0, 0, 3.0] + [0.0] * C.N_OBSTACLE_SLOTS), np.zeros(3),
                                         lim, obstacles)).ravel()
    np.testing.assert_allclose(rows, [0.0, 39.5, 3.0, 0.0, 2.5, *empty], atol=1e-4)  # the slacks make up for it


def test_loop_dof_error_treats_absent_regions_like_the_planner():
    from cinetransfer.services.planner.scenarios import _dof_error

    # subject in focus at 6 m (mu 1): near target 5 m, far target 7 m; the DoF is 2..inf
    both = _dof_error(6.0, 2.0, math.inf, (False, True, False), 1.0)
    assert both == pytest.approx((6 * (1 / 2 - 1 / 5)) ** 2 + (6 * (0 - 1 / 7)) ** 2)  # 3.24 + 0.735
    # without a foreground in the source, a near limit nearer than the subject's keeps nothing sharp
    assert _dof_error(6.0, 2.0, math.inf, (False, True, False), 1.0, (True, False, False)) == pytest.approx(
        (6 * (0 - 1 / 7)) ** 2)
    # but a DoF that does not reach the subject still counts
    assert _dof_error(6.0, 5.5, 6.5, (False, True, False), 1.0, (True, False, False)) == pytest.approx(
        (6 * (1 / 5.5 - 1 / 5)) ** 2 + (6 * (1 / 6.5 - 1 / 7)) ** 2)
