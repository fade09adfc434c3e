"""Pure pieces of the side-of-subject and camera-motion terms, against hand-computed values."""
import dataclasses
import math

import casadi as ca
import numpy as np
import pytest

from cinetransfer.services.planner import camera_motion as CM
from cinetransfer.services.planner import cost as J
from cinetransfer.services.planner.side_of_subject import (camera_bearing, carrot, side_targets, style_view,
                                                           wanted_bearing)
from cinetransfer.shared import messages as M
from cinetransfer.shared.facing import heading_from_joints, subject_heading

NAMES = ["left_shoulder", "right_shoulder", "left_hip", "right_hip"]
FRONT = np.array([[0.56, 0.40], [0.44, 0.40], [0.53, 0.60], [0.47, 0.60]])
BACK = FRONT[[1, 0, 3, 2]]


def _f(v) -> float:  # noqa: ANN001
    return float(ca.DM(v))


# ------------------------------------------------------------------ heading from joints
def test_heading_from_joints_is_the_left_right_axis_crossed_with_up():
    # a body facing -x: its left (+y in the body) is world -y; (left - right) = (0, -0.38, 0);
    # (L_y, -L_x) = (-0.38, 0): forward is -x, heading pi
    joints = np.array([[0.0, -0.19, 1.44], [0.0, 0.19, 1.44], [0.0, -0.11, 0.95], [0.0, 0.11, 0.95]])
    assert heading_from_joints(NAMES, joints) == pytest.approx(math.pi)
    # turned to face +y: left is -x: (left - right) = (-0.6, 0, 0) -> forward (0, 0.6): pi/2
    joints = np.array([[-0.19, 0.0, 1.44], [0.19, 0.0, 1.44], [-0.11, 0.0, 0.95], [0.11, 0.0, 0.95]])
    assert heading_from_joints(NAMES, joints) == pytest.approx(math.pi / 2)
    # a shoulder axis at 45 deg between +x and +y ((left - right) = (-0.2, 0.2)) alone: forward (0.2, 0.2)
    joints = np.array([[-0.1, 0.1, 1.4], [0.1, -0.1, 1.4], [np.nan] * 3, [np.nan] * 3])
    assert heading_from_joints(NAMES, joints) == pytest.approx(math.pi / 4)


def test_heading_from_joints_is_nan_without_a_usable_axis():
    assert math.isnan(heading_from_joints(NAMES, np.full((4, 3), np.nan)))
    assert math.isnan(heading_from_joints(["nose"], np.zeros((1, 3))))
    # left and right one above the other (the axis is vertical): no direction on the ground
    assert math.isnan(heading_from_joints(NAMES, np.array([[0, 0, 1.5], [0, 0, 1.4], [0, 0, 1.0], [0, 0, 0.9]])))


def test_subject_heading_prefers_the_given_one_and_wraps_it():
    joints = np.array([[0.0, -0.19, 1.44], [0.0, 0.19, 1.44], [0.0, -0.11, 0.95], [0.0, 0.11, 0.95]])
    assert subject_heading(0.3, NAMES, joints) == pytest.approx(0.3)
    assert subject_heading(2 * math.pi + 0.3, NAMES, joints) == pytest.approx(0.3)
    assert subject_heading(float("nan"), NAMES, joints) == pytest.approx(math.pi)
    assert subject_heading(None, NAMES, joints) == pytest.approx(math.pi)


def test_subject_state_heading_is_nan_by_default():
    assert math.isnan(M.SubjectState().heading_rad)


# ------------------------------------------------------------------ side of the subject
def test_style_view_reads_front_back_and_side_on():
    assert style_view(FRONT, NAMES) == 1
    assert style_view(BACK, NAMES) == -1
    side = FRONT.copy()
    side[:, 0] = 0.5  # every pair on top of each other
    assert style_view(side, NAMES) == 0
    assert style_view(np.full((4, 2), np.nan), NAMES) == 0


def test_wanted_bearing_is_the_heading_for_a_front_view_and_opposite_for_a_back_view():
    assert wanted_bearing(0.5, 1) == pytest.approx(0.5)
    assert wanted_bearing(0.5, -1) == pytest.approx(0.5 + math.pi)
    assert math.isnan(wanted_bearing(0.5, 0))
    assert math.isnan(wanted_bearing(float("nan"), 1))


def test_camera_bearing_and_carrot():
    assert camera_bearing(np.array([-5.0, 0.0, 1.6]), np.array([0.0, 0.0, 1.2])) == pytest.approx(math.pi)
    assert camera_bearing(np.array([1.0, 1.0]), np.array([0.0, 0.0])) == pytest.approx(math.pi / 4)
    assert math.isnan(camera_bearing(np.zeros(3), np.zeros(3)))
    # within the step: the wanted bearing itself
    assert carrot(0.0, 0.5) == pytest.approx(0.5)
    # far off: 90 deg towards it the shorter way (from 170 deg to -170 deg: +20 deg, across pi)
    assert carrot(0.0, 2.0) == pytest.approx(math.radians(90))
    assert carrot(math.radians(170), math.radians(-170)) == pytest.approx(math.radians(190))
    # straight behind: the way of increasing bearing, whichever way the angle is written
    assert carrot(math.pi, 0.0) == pytest.approx(math.pi + math.radians(90))
    assert carrot(0.0, math.pi) == pytest.approx(math.radians(90))


def test_side_targets_mask_only_front_and_back_rows():
    rows_xy = np.stack([FRONT, BACK, np.full((4, 2), np.nan)])
    out = side_targets(rows_xy, [0, 1, 2], NAMES, heading_rad=0.0, bearing_now=math.pi)
    # front view wanted at bearing 0 from pi: carrot pi + 90 deg; back view wanted at pi: there already
    assert out[0] == pytest.approx([0.0, -1.0, 1.0], abs=1e-12)
    assert out[1] == pytest.approx([-1.0, 0.0, 1.0])
    assert out[2].tolist() == [0.0, 0.0, 0.0]
    assert not side_targets(rows_xy, [0], NAMES, heading_rad=float("nan"), bearing_now=0.0).any()


def test_bearing_cos_and_shortfall_by_hand():
    assert _f(J.bearing_cos(ca.DM([3.0, 0.0]), ca.DM([1.0, 0.0]))) == pytest.approx(1.0, abs=1e-6)
    assert _f(J.bearing_cos(ca.DM([0.0, 2.0]), ca.DM([1.0, 0.0]))) == pytest.approx(0.0, abs=1e-6)
    assert _f(J.bearing_cos(ca.DM([1.0, math.sqrt(3)]), ca.DM([1.0, 0.0]))) == pytest.approx(0.5, abs=1e-6)
    free = math.radians(45)
    # within 45 deg: free; a quarter round: cos 45 - 0; opposite: cos 45 + 1
    assert _f(J.bearing_shortfall(ca.DM([1.0, 0.5]), ca.DM([1.0, 0.0]), free)) == 0.0
    assert _f(J.bearing_shortfall(ca.DM([0.0, 2.0]), ca.DM([1.0, 0.0]), free)) == pytest.approx(0.70711, abs=1e-5)
    assert _f(J.bearing_shortfall(ca.DM([-2.0, 0.0]), ca.DM([1.0, 0.0]), free)) == pytest.approx(1.70711, abs=1e-5)


# ------------------------------------------------------------------ camera-motion terms
def test_log_rates_and_travel_residual_by_hand():
    assert _f(J.log_rate(4.0, 40.0)) == pytest.approx(0.1)
    # camera 4 m behind the subject along -x, backing away at 0.4 m/s: d ln d/dt = 0.4 / 4
    assert _f(J.distance_log_rate(ca.DM([-4.0, 0.0, 0.0]), ca.DM([-0.4, 0.0, 0.0]))) == pytest.approx(0.1, abs=1e-6)
    # along the direction: no residual; sideways 1 m/s at v_max 2: 0.5; backwards 1 m/s: 0.5 in the hinge
    r = ca.DM(J.travel_residual(ca.DM([1.0, 0.0, 0.0]), ca.DM([1.0, 0.0, 0.0]), 0.5)).full().ravel()
    assert r == pytest.approx([0, 0, 0, 0])
    r = ca.DM(J.travel_residual(ca.DM([0.0, 1.0, 0.0]), ca.DM([1.0, 0.0, 0.0]), 0.5)).full().ravel()
    assert r == pytest.approx([0, 0.5, 0, 0])
    r = ca.DM(J.travel_residual(ca.DM([-1.0, 0.0, 0.0]), ca.DM([1.0, 0.0, 0.0]), 0.5)).full().ravel()
    assert r == pytest.approx([0, 0, 0, -0.5])
    # a least speed of 0.8 m/s along it: 1 m/s is enough, 0.5 m/s falls 0.3 short (0.15 at v_max 2)
    r = ca.DM(J.travel_residual(ca.DM([1.0, 0.0, 0.0]), ca.DM([1.0, 0.0, 0.0]), 0.5, 0.8)).full().ravel()
    assert r == pytest.approx([0, 0, 0, 0])
    r = ca.DM(J.travel_residual(ca.DM([0.5, 0.0, 0.0]), ca.DM([1.0, 0.0, 0.0]), 0.5, 0.8)).full().ravel()
    assert r == pytest.approx([0, 0, 0, -0.15])
    # sideways speed off the optical axis: along it nothing; 1 m/s left and 2 m/s forward at v_max 2: 0.5 left
    r = ca.DM(J.sideways_velocity(ca.DM([2.0, 1.0, 0.0]), ca.DM([1.0, 0.0, 0.0]), 0.5)).full().ravel()
    assert r == pytest.approx([0, 0.5, 0])
    s2 = math.sqrt(0.5)  # axis at 45 deg in x-y: (1, 0, 0) splits into (0.5, 0.5, 0) along, (0.5, -0.5, 0) off
    r = ca.DM(J.sideways_velocity(ca.DM([1.0, 0.0, 0.0]), ca.DM([s2, s2, 0.0]), 1.0)).full().ravel()
    assert r == pytest.approx([0.5, -0.5, 0])
    # a dolly's rails: the axis pitched down by 30 deg (cos, 0, -sin) levelled to (1, 0, 0); 0 keeps the axis
    c, sn = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    assert ca.DM(J.level_rail(ca.DM([c, 0.0, -sn]), 1.0)).full().ravel() == pytest.approx([1.0, 0.0, 0.0])
    assert ca.DM(J.level_rail(ca.DM([c, 0.0, -sn]), 0.0)).full().ravel() == pytest.approx([c, 0.0, -sn])
    # along that axis at 1 m/s it sinks 0.5 m/s off the rails: 0.25 at v_max 2
    r = ca.DM(J.sideways_velocity(ca.DM([c, 0.0, -sn]), J.level_rail(ca.DM([c, 0.0, -sn]), 1.0), 0.5)).full().ravel()
    assert r == pytest.approx([0, 0, -0.25])
    # speed along the optical axis: 2 m/s forward at v_max 2 is 1; at 45 deg, (1, 0, 0) has sqrt(0.5) along
    assert _f(J.along_velocity(ca.DM([2.0, 1.0, 0.0]), ca.DM([1.0, 0.0, 0.0]), 0.5)) == pytest.approx(1.0)
    assert _f(J.along_velocity(ca.DM([1.0, 0.0, 0.0]), ca.DM([s2, s2, 0.0]), 1.0)) == pytest.approx(s2)


def test_motion_classes_and_direction_conversion():
    assert CM.motion_classes("pan+zoom_in") == {"pan", "zoom_in"}
    assert CM.motion_classes("static") == {"static"}
    assert CM.motion_classes("") is None and CM.motion_classes(float("nan")) is None
    # source frame x right, y down, z forward -> planner x forward, y left, z up
    assert CM.planner_camera_direction(np.array([0.0, 0.0, -1.0])).tolist() == [-1.0, 0.0, 0.0]  # dolly out
    assert CM.planner_camera_direction(np.array([1.0, 0.0, 0.0])) == pytest.approx([0, -1, 0])  # truck right
    assert CM.planner_camera_direction(np.array([0.0, -2.0, 0.0])) == pytest.approx([0, 0, 1])  # pedestal up
    assert CM.planner_camera_direction(np.array([np.nan, 0, 0])).tolist() == [0, 0, 0]
    assert CM.planner_camera_direction(np.zeros(3)).tolist() == [0, 0, 0]


def _style(cls, pan=np.nan, tilt=np.nan, roll=np.nan, zoom=np.nan, travel=(0.0, 0.0, 0.0)) -> CM.MotionStyle:
    return CM.MotionStyle([CM.motion_classes(cls)], np.radians([[pan, tilt, roll]]), np.array([zoom]),
                          np.array([CM.planner_camera_direction(np.array(travel))]))


def test_row_terms_follow_the_class():
    # static (hold still): every rate and the zoom asked to be 0, whatever the measured rates say, in place
    t = CM.row_terms(_style("static", pan=0.1, zoom=0.001), 0, control_roll=True)
    assert t[CM.RATE_MASKS].tolist() == [1, 1, 1] and t[CM.ZOOM_MASK] == 1 and t[CM.STILL] == 1
    assert not t[CM.RATES].any() and t[CM.ZOOM] == 0 and not np.delete(t, [6, 7, 8, CM.ZOOM_MASK, CM.STILL]).any()
    assert CM.row_terms(_style("static"), 0, control_roll=False)[CM.RATE_MASKS].tolist() == [1, 1, 0]
    t = CM.row_terms(_style("pan", pan=10.0, tilt=3.0), 0, control_roll=False)
    assert t[CM.RATES.start] == pytest.approx(math.radians(10)) and t[CM.RATE_MASKS].tolist() == [1, 0, 0]
    t = CM.row_terms(_style("roll", roll=5.0), 0, control_roll=False)
    assert not t[CM.RATE_MASKS].any() and t[CM.STILL] == 1  # no roll control: no roll term (the camera stays put)
    assert t[CM.ZOOM_MASK] == 1 and t[CM.ZOOM] == 0  # turned in place without a zoom: the focal length holds
    t = CM.row_terms(_style("dolly_zoom", zoom=0.1, travel=(0, 0, -1)), 0, control_roll=False)
    assert t[CM.ZOOM] == 0.1 and t[CM.ZOOM_MASK] == 1 and t[CM.DOLLY_ZOOM_MASK] == 1 and t[CM.DISTANCE_RATE] == 0.1
    assert t[CM.TRAVEL].tolist() == [-1, 0, 0] and t[CM.TRAVEL_MASK] == 1
    t = CM.row_terms(_style("zoom_in", zoom=0.1, travel=(0, 0, 1)), 0, control_roll=False)
    assert t[CM.ZOOM_MASK] == 1 and t[CM.DOLLY_ZOOM_MASK] == 0 and t[CM.TRAVEL_MASK] == 0
    t = CM.row_terms(_style("pan", pan=float("nan")), 0, control_roll=False)
    # the class names a pan whose rate is unknown: no rate term, but the camera turned in place
    assert t[CM.STILL] == 1 and t[CM.ZOOM_MASK] == 1 and not np.delete(t, [CM.STILL, CM.ZOOM_MASK]).any()
    assert CM.row_terms(_style("pan+truck", pan=5.0, travel=(1, 0, 0)), 0, control_roll=False)[CM.STILL] == 0
    # a zoom in place stands still along the axis too (there, moving reads as a dolly-zoom); a pan or a
    # static row only sideways (the framing keeps a walker's size by moving along it)
    held = {c: CM.row_terms(_style(c, pan=5.0, zoom=0.1), 0, control_roll=False)[[CM.STILL, CM.STILL_ALONG]].tolist()
            for c in ("zoom_in", "pan+zoom_out", "pan", "static", "dolly_zoom")}
    assert held == {"zoom_in": [1, 1], "pan+zoom_out": [1, 1], "pan": [1, 0], "static": [1, 0], "dolly_zoom": [1, 0]}


def test_a_dolly_rides_its_axis_unless_it_swings_or_is_handheld():
    # a dolly or a dolly-zoom stands still sideways (J_v's reference 0); with a truck, an orbit, a pedestal or a
    # handheld tilt or roll it does not (their travel is sideways, or the operator's sway serves the framing)
    still = {c: CM.row_terms(_style(c, pan=5.0, tilt=3.0, zoom=0.1, travel=(0, 0, 1)), 0,
                             control_roll=False)[CM.STILL]
             for c in ("dolly_in", "dolly_out", "dolly_zoom", "pan+dolly_in", "dolly_in+truck", "dolly_in+orbit",
                       "dolly_in+pedestal", "tilt+dolly_zoom", "truck")}
    assert still == {"dolly_in": 1, "dolly_out": 1, "dolly_zoom": 1, "pan+dolly_in": 1, "dolly_in+truck": 0,
                     "dolly_in+orbit": 0, "dolly_in+pedestal": 0, "tilt+dolly_zoom": 0, "truck": 0}
    # ... and travels at least at twice the rate a translation counts from, where a direction is given
    least = {c: CM.row_terms(_style(c, zoom=0.1, travel=t), 0, control_roll=False)[CM.TRAVEL_MIN]
             for c, t in (("dolly_out", (0, 0, -1)), ("dolly_zoom", (0, 0, 1)), ("dolly_in", (0, 0, 0)),
                          ("truck", (1, 0, 0)), ("tilt+dolly_zoom", (0, 0, 1)))}
    assert least == {"dolly_out": pytest.approx(0.06), "dolly_zoom": pytest.approx(0.06), "dolly_in": 0,
                     "truck": 0, "tilt+dolly_zoom": 0}
    assert not CM.row_terms(_style("dolly_out", zoom=0.1, travel=(0, 0, -1)), 0, control_roll=False)[CM.TRAVEL_MEASURED]


def test_a_dolly_zoom_asks_the_subjects_own_distance_rate():
    # the move holds a point ahead, not the walker: his distance changes as his size and the zoom say
    style = dataclasses.replace(_style("dolly_zoom", zoom=-0.15, travel=(0, 0, 1)), distance_rate=np.array([-0.02]))
    t = CM.row_terms(style, 0, control_roll=False)
    assert t[CM.ZOOM] == -0.15 and t[CM.DOLLY_ZOOM_MASK] == 1 and t[CM.DISTANCE_RATE] == -0.02
    # his size unread: the zoom rate (the move holds his size); handheld: the zoom rate, as before
    assert CM.row_terms(_style("dolly_zoom", zoom=-0.15), 0, control_roll=False)[CM.DISTANCE_RATE] == -0.15
    handheld = dataclasses.replace(_style("tilt+dolly_zoom", tilt=3.0, zoom=-0.15), distance_rate=np.array([-0.02]))
    assert CM.row_terms(handheld, 0, control_roll=False)[CM.DISTANCE_RATE] == -0.15


def test_row_terms_without_a_class_use_clear_rates():
    t = CM.row_terms(_style(None, pan=0.5, tilt=-4.0, zoom=0.005), 0, control_roll=False)
    assert t[CM.RATE_MASKS].tolist() == [0, 1, 0] and t[CM.ZOOM_MASK] == 0


def test_instructions_without_motion_fields_ask_nothing():
    ins = M.Instructions(image_targets=np.zeros((3, 4, 2), dtype=np.float32))
    assert CM.read_motion_style(ins) is None
    assert not CM.stage_motion(None, [0, 1, 2], control_roll=False).any()


def test_the_zoom_rate_is_planned_slower_by_the_setpoint_lead_in_steps():
    from cinetransfer.services.planner.core import flown_rate_factor
    # the plan 0.1 s ahead at 20 Hz: the lens moves 0.1 s of plan per 0.05 s step
    assert flown_rate_factor(0.1, 20.0) == pytest.approx(2.0)
    assert flown_rate_factor(0.05, 20.0) == pytest.approx(1.0)
    assert flown_rate_factor(0.0, 20.0) == 1.0  # no lead: nothing to scale
    assert flown_rate_factor(1.0, 200.0) == 4.0  # bounded


def test_subject_distance_rate_reads_the_size_against_the_lens():
    fps, n = 24.0, 30
    t = np.arange(n) / fps
    # receding at 0.1 /s with the lens held: the box shrinks as exp(-0.1 t)
    h = 0.4 * np.exp(-0.1 * t)
    rate = CM.subject_distance_rate(h, np.zeros(n), fps, np.zeros(n, dtype=bool))
    assert rate == pytest.approx(np.full(n, 0.1), abs=1e-9)
    # zooming in at 0.05 /s while the box grows at 0.02 /s: the subject recedes at 0.03 /s
    h = 0.4 * np.exp(0.02 * t)
    assert CM.subject_distance_rate(h, np.full(n, 0.05), fps, np.zeros(n, dtype=bool)) == pytest.approx(
        np.full(n, 0.03), abs=1e-9)


def test_subject_distance_rate_stays_inside_its_shot_and_needs_what_it_reads():
    fps, n = 24.0, 30
    h = np.r_[np.full(15, 0.2), np.full(15, 0.5)]  # a cut at row 15: each shot's size holds
    starts = np.zeros(n, dtype=bool)
    starts[15] = True
    assert CM.subject_distance_rate(h, np.zeros(n), fps, starts) == pytest.approx(np.zeros(n), abs=1e-12)
    assert np.abs(CM.subject_distance_rate(h, np.zeros(n), fps, np.zeros(n, dtype=bool))[15]) > 1.0  # across it
    zoom = np.zeros(n)
    zoom[3] = np.nan
    h = np.full(n, 0.3)
    h[20:] = np.nan  # the subject lost: too little of the window seen near the end
    rate = CM.subject_distance_rate(h, zoom, fps, np.zeros(n, dtype=bool))
    assert math.isnan(rate[3]) and math.isnan(rate[29]) and rate[0] == 0.0 and rate[10] == 0.0


def test_a_dolly_holds_the_lens_and_asks_the_sources_distance_rate():
    style = _style("dolly_in", zoom=0.0, travel=(0, 0, 1))
    t = CM.row_terms(dataclasses.replace(style, distance_rate=np.array([-0.04])), 0, control_roll=False)
    assert t[CM.ZOOM_MASK] == 1 and t[CM.ZOOM] == 0 and t[CM.TRAVEL_MASK] == 1 and t[CM.STILL] == 1
    assert t[CM.DOLLY_ZOOM_MASK] == 1 and t[CM.DISTANCE_RATE] == -0.04
    t = CM.row_terms(style, 0, control_roll=False)  # no size read: the lens still holds, no distance term
    assert t[CM.ZOOM_MASK] == 1 and t[CM.DOLLY_ZOOM_MASK] == 0
    # a dolly with a zoom of its own (or a dolly-zoom) is the zoom's to set
    t = CM.row_terms(dataclasses.replace(_style("zoom_in+dolly_in", zoom=0.1, travel=(0, 0, 1)),
                                         distance_rate=np.array([-0.04])), 0, control_roll=False)
    assert t[CM.ZOOM] == 0.1 and t[CM.DOLLY_ZOOM_MASK] == 0


def test_bearing_rate_round_the_subject_by_hand():
    # camera 4 m behind the subject along -x, sliding right (-y) at 1 m/s: its bearing round him turns left at 1/4
    assert _f(J.bearing_rate(ca.DM([-4.0, 0.0, 0.0]), ca.DM([0.0, -1.0, 0.0]))) == pytest.approx(0.25, abs=1e-6)
    # moving straight at him, or straight up, does not turn it
    assert _f(J.bearing_rate(ca.DM([-4.0, 0.0, 0.0]), ca.DM([1.0, 0.0, 0.5]))) == pytest.approx(0.0, abs=1e-9)
    # off the diagonal (3, 4): 1 m/s across the line of sight at 5 m turns it at 0.2, sign as the yaw
    assert _f(J.bearing_rate(ca.DM([3.0, 4.0, 1.0]), ca.DM([-0.8, 0.6, 0.0]))) == pytest.approx(0.2, abs=1e-6)


def test_subject_bearing_rate_adds_the_drift_across_the_image_to_the_pan():
    fps, n = 24.0, 30
    t = np.arange(n) / fps
    k = 2.0 * math.tan(math.radians(CM.ASSUMED_HFOV_DEG) / 2.0)
    x = 0.5 - np.tan(0.1 * t) / k  # the subject drifts left off the axis at 0.1 rad/s
    rate = CM.subject_bearing_rate(x, np.full(n, 0.05), fps, np.zeros(n, dtype=bool))
    assert rate == pytest.approx(np.full(n, 0.15), abs=1e-9)
    pan = np.full(n, 0.05)
    pan[4] = np.nan
    x[25:] = np.nan  # the subject lost near the end
    starts = np.zeros(n, dtype=bool)
    starts[10] = True
    x[10:] = np.where(np.isfinite(x[10:]), 0.5, np.nan)  # after the cut he holds the centre: the pan alone
    rate = CM.subject_bearing_rate(x, pan, fps, starts)
    assert math.isnan(rate[4]) and math.isnan(rate[29])
    assert rate[2] == pytest.approx(0.15, abs=1e-9) and rate[12] == pytest.approx(0.05, abs=1e-12)


def test_a_truck_or_an_orbit_asks_the_sources_bearing_rate_with_a_dollys_lens_and_distance():
    style = dataclasses.replace(_style("truck", pan=0.0, zoom=0.0, travel=(1, 0, 0)), bearing_rate=np.array([0.12]),
                                distance_rate=np.array([0.05]))
    for name in ("truck", "orbit"):
        t = CM.row_terms(dataclasses.replace(style, classes=[CM.motion_classes(name)]), 0, control_roll=False)
        assert t[CM.BEARING_RATE_MASK] == 1 and t[CM.BEARING_RATE] == 0.12 and t[CM.TRAVEL_MASK] == 1
        # the lens held as the source's, the subject's distance changing at its rate (a dolly's terms)
        assert t[CM.ZOOM_MASK] == 1 and t[CM.ZOOM] == 0 and t[CM.DOLLY_ZOOM_MASK] == 1 and t[CM.DISTANCE_RATE] == 0.05
    t = CM.row_terms(dataclasses.replace(style, classes=[CM.motion_classes("pan+truck")]), 0, control_roll=False)
    assert t[CM.BEARING_RATE_MASK] == 1 and t[CM.RATE_MASKS.start] == 1  # the pan stays asked too
    for other in ("pan", "dolly_in", "static"):
        t = CM.row_terms(dataclasses.replace(style, classes=[CM.motion_classes(other)]), 0, control_roll=False)
        assert t[CM.BEARING_RATE_MASK] == 0 and t[CM.BEARING_RATE] == 0
    # a handheld one (it tilts or rolls too): its lens is the framing's; a truck keeps its bearing rate
    for name, bearing in (("tilt+roll+orbit", 0), ("roll+orbit", 0), ("tilt+truck", 1)):
        t = CM.row_terms(dataclasses.replace(style, classes=[CM.motion_classes(name)]), 0, control_roll=False)
        assert t[CM.ZOOM_MASK] == 0 and t[CM.DOLLY_ZOOM_MASK] == 0 and t[CM.BEARING_RATE_MASK] == bearing
    # an orbit with a zoom of its own is the zoom's to set: no distance term
    zoomed = dataclasses.replace(style, classes=[CM.motion_classes("zoom_in+orbit")], zoom_rate=np.array([0.1]))
    t = CM.row_terms(zoomed, 0, control_roll=False)
    assert t[CM.ZOOM] == 0.1 and t[CM.DOLLY_ZOOM_MASK] == 0 and t[CM.BEARING_RATE_MASK] == 1
    assert CM.row_terms(_style("truck", travel=(1, 0, 0)), 0, control_roll=False)[CM.BEARING_RATE_MASK] == 0
    assert CM.BEARING_RATE_MASK in CM.MOTION_MASKS


def test_last_read_in_shot_by_hand():
    v = np.array([0.1, np.nan, 0.2, np.nan, np.nan, np.nan, 0.3])
    starts = np.array([True, False, False, False, True, False, False])
    # carried forward inside a shot, never across a cut nor back before the shot's first value
    out = CM.last_read_in_shot(v, starts)
    assert out[:4].tolist() == [0.1, 0.1, 0.2, 0.2] and np.isnan(out[4:6]).all() and out[6] == 0.3


def test_a_swing_whose_subject_the_source_lost_keeps_its_last_sideways_speed():
    style = dataclasses.replace(_style("orbit", pan=8.0, zoom=0.0, travel=(1, 0, 0)), bearing_rate=np.array([np.nan]),
                                swing_held_rate=np.array([-0.09]))
    t = CM.row_terms(style, 0, control_roll=False)
    assert t[CM.BEARING_RATE_MASK] == 0 and t[CM.TRAVEL_MASK] == 1 and t[CM.TRAVEL_MIN] == pytest.approx(0.09)
    # read on the row: the bearing rate itself, no least speed; no direction of travel: nothing held
    read = CM.row_terms(dataclasses.replace(style, bearing_rate=np.array([0.05])), 0, control_roll=False)
    assert read[CM.BEARING_RATE] == 0.05 and read[CM.TRAVEL_MIN] == 0
    still = CM.row_terms(dataclasses.replace(style, travel=np.zeros((1, 3))), 0, control_roll=False)
    assert still[CM.TRAVEL_MIN] == 0
    assert CM.row_terms(dataclasses.replace(style, classes=[CM.motion_classes("pan")]), 0,
                        control_roll=False)[CM.TRAVEL_MIN] == 0


def test_the_look_gives_way_where_the_source_lost_its_subject():
    ins = M.Instructions(image_targets=np.full((3, 2, 2), 0.5, dtype=np.float32), camera_motion_class=["pan"] * 3,
                         pan_rate_dps=[5.0] * 3)
    ins.image_targets[1:] = np.nan
    ins.image_targets[2, 1] = 0.5  # one joint still framed: the subject is seen
    style = CM.read_motion_style(ins)
    assert style.subject_seen.tolist() == [True, False, True]
    looks = CM.stage_motion(style, [0, 1, 2], control_roll=False)[:, CM.LOOK_OFF]
    assert looks.tolist() == [0, 1, 0]
    # a row without a class asks nothing of the look
    unclassed = dataclasses.replace(style, classes=[None] * 3)
    assert not CM.stage_motion(unclassed, [0, 1, 2], control_roll=False)[:, CM.LOOK_OFF].any()


def test_rates_are_planned_slower_for_the_setpoint_lead_only_where_nothing_is_framed():
    motion = np.zeros((2, CM.N_MOTION))
    motion[:, CM.RATES] = [0.2, 0.1, 0.0]
    motion[:, CM.ZOOM] = 0.1
    motion[1, CM.LOOK_OFF] = 1.0
    CM.plan_for_setpoint_lead(motion, 2.0)
    assert motion[:, CM.ZOOM].tolist() == [0.05, 0.05]  # the lens on every stage
    assert motion[0, CM.RATES].tolist() == [0.2, 0.1, 0.0] and motion[1, CM.RATES].tolist() == [0.1, 0.05, 0.0]


def test_a_row_whose_source_lost_its_subject_asks_the_rates_its_class_leaves_free():
    style = dataclasses.replace(_style("orbit", pan=8.0, tilt=-0.1, roll=0.3, zoom=0.0, travel=(1, 0, 0)),
                                subject_seen=np.array([False]))
    t = CM.row_terms(style, 0, control_roll=False)
    assert t[CM.LOOK_OFF] == 1 and t[CM.RATE_MASKS].tolist() == [1, 1, 0]
    assert t[CM.RATES.start + 1] == pytest.approx(math.radians(-0.1))
    framed = CM.row_terms(dataclasses.replace(style, subject_seen=np.array([True])), 0, control_roll=False)
    assert framed[CM.LOOK_OFF] == 0 and framed[CM.RATE_MASKS].tolist() == [1, 0, 0]


def test_a_truck_or_orbit_that_lost_its_subject_holds_its_rates_harder():
    truck = dataclasses.replace(_style("truck", pan=0.07, tilt=-0.04, zoom=0.0, travel=(1, 0, 0)),
                                subject_seen=np.array([False]))
    t = CM.row_terms(truck, 0, control_roll=False)
    # the truck's free pan and tilt asked as the source's, and weighed by held_rate as well
    assert t[CM.RATES_HELD] == 1 and t[CM.RATE_MASKS].tolist() == [1, 1, 0]
    assert t[CM.RATES.start] == pytest.approx(math.radians(0.07))
    orbit = dataclasses.replace(truck, classes=[CM.motion_classes("orbit")])
    assert CM.row_terms(orbit, 0, control_roll=False)[CM.RATES_HELD] == 1
    # framed, or a move that does not travel sideways (a pan, a dolly): as before
    assert CM.row_terms(dataclasses.replace(truck, subject_seen=np.array([True])), 0,
                        control_roll=False)[CM.RATES_HELD] == 0
    for name in ("pan", "dolly_in"):
        other = dataclasses.replace(truck, classes=[CM.motion_classes(name)])
        assert CM.row_terms(other, 0, control_roll=False)[CM.RATES_HELD] == 0


def test_subject_elevation_rate_subtracts_the_sinking_in_the_image_from_the_tilt():
    fps, n = 24.0, 30
    t = np.arange(n) / fps
    k = 2.0 * math.tan(math.radians(CM.ASSUMED_HFOV_DEG) / 2.0) * 0.75  # a 4:3 image
    y = 0.5 + np.tan(0.04 * t) / k  # the subject sinks below the axis at 0.04 rad/s
    rate = CM.subject_elevation_rate(y, np.full(n, 0.01), fps, np.zeros(n, dtype=bool), aspect=0.75)
    assert rate == pytest.approx(np.full(n, 0.03), abs=1e-9)  # -(0.01 - 0.04): the camera rises round him
    tilt = np.full(n, 0.01)
    tilt[3] = np.nan
    rate = CM.subject_elevation_rate(np.full(n, 0.5), tilt, fps, np.zeros(n, dtype=bool))
    assert math.isnan(rate[3]) and rate[10] == pytest.approx(-0.01, abs=1e-12)  # held in the image: the tilt alone


def test_pedestal_least_rate_by_hand():
    assert CM.pedestal_least_rate(0.03, 1.0) == 0.03 and CM.pedestal_least_rate(-0.03, -0.8) == 0.03
    assert CM.pedestal_least_rate(0.03, -1.0) == 0 and CM.pedestal_least_rate(0.0, 1.0) == 0
    assert CM.pedestal_least_rate(float("nan"), 1.0) == 0


def test_a_pedestal_rises_at_the_sources_rate_with_the_tilt_and_lens_held():
    style = dataclasses.replace(_style("pedestal", tilt=0.5, zoom=0.0, travel=(0, -1, 0)),
                                elevation_rate=np.array([0.03]))
    t = CM.row_terms(style, 0, control_roll=False)
    assert t[CM.TRAVEL].tolist() == [0, 0, 1] and t[CM.TRAVEL_MASK] == 1 and t[CM.TRAVEL_MIN] == 0.03
    assert t[CM.TRAVEL_MEASURED] == 1  # the source's own speed, weighed as the move (not a dolly's floor)
    assert t[CM.RATE_MASKS].tolist() == [0, 1, 0] and t[CM.RATES.start + 1] == pytest.approx(math.radians(0.5))
    assert t[CM.ZOOM_MASK] == 1 and t[CM.ZOOM] == 0 and t[CM.STILL] == 0
    # a pedestal down read rising asks no speed (the direction term alone, as before), the tilt still held
    down = CM.row_terms(dataclasses.replace(style, travel=np.array([[0.0, 0.0, -1.0]])), 0, control_roll=False)
    assert down[CM.TRAVEL_MIN] == 0 and down[CM.RATE_MASKS.start + 1] == 1
    assert down[CM.TRAVEL_MEASURED] == 0
    # handheld or swinging rows, and styles without the elevation rate, ask as before
    for name in ("tilt+pedestal", "roll+pedestal", "pedestal+orbit"):
        before = CM.row_terms(dataclasses.replace(style, elevation_rate=None, classes=[CM.motion_classes(name)]), 0,
                              control_roll=False)
        after = CM.row_terms(dataclasses.replace(style, classes=[CM.motion_classes(name)]), 0, control_roll=False)
        assert after.tolist() == before.tolist() and after[CM.TRAVEL_MIN] == 0
    old = CM.row_terms(dataclasses.replace(style, elevation_rate=None), 0, control_roll=False)
    assert old[CM.TRAVEL_MIN] == 0 and not old[CM.RATE_MASKS].any() and old[CM.ZOOM_MASK] == 0


def test_zoom_to_come_by_hand():
    # at 10 frames/s: out 0.1/s for 2 rows, in 0.3/s for 1, none for 1 -> ln f steps -0.01, -0.01, +0.03, 0
    got = CM.zoom_to_come(np.array([-0.1, -0.1, 0.3, np.nan]), 10.0)
    # from row 0: down to -0.02 (out 0.02), up to +0.01 (in 0.01); row 1: out 0.01, in 0.02; row 2: in 0.03
    assert got == pytest.approx(np.array([[0.02, 0.01], [0.01, 0.02], [0.0, 0.03], [0.0, 0.0]]))


def test_lens_headroom_by_hand():
    lo, hi = CM.lens_headroom(np.array([0.27, 0.0]), (30.0, 500.0))
    # room to zoom out by e^-0.27 (and the margin) from 30 mm: at least 30 e^0.32 = 41.3 mm; no zoom in asked
    assert math.exp(lo) == pytest.approx(30.0 * math.exp(0.27 + CM.HEADROOM_MARGIN))
    assert hi == pytest.approx(math.log(500.0) + CM.UNUSED_SIDE)  # no zoom in to come: no ceiling inside the range
    lo, hi = CM.lens_headroom(np.array([0.0, 0.1]), (30.0, 500.0))
    assert lo == pytest.approx(math.log(30.0) - CM.UNUSED_SIDE)
    assert math.exp(hi) == pytest.approx(500.0 * math.exp(-0.15))
    lo, hi = CM.lens_headroom(np.array([3.0, 3.0]), (30.0, 500.0))  # more than the range: the middle
    assert lo == hi == pytest.approx(0.5 * (math.log(30.0) + math.log(500.0)))


def test_rows_with_a_zoom_to_come_ask_the_lens_for_room():
    fps = 24.0
    ins = M.Instructions(image_targets=np.zeros((3, 4, 2), dtype=np.float32), fps=fps,
                         camera_motion_class=["dolly_zoom", "dolly_zoom", "static"],
                         zoom_rate=np.array([-0.12, -0.12, 0.0], dtype=np.float32))
    style = CM.read_motion_style(ins)
    assert style.zoom_to_come[:, 0] == pytest.approx([0.24 / fps, 0.12 / fps, 0.0], rel=1e-5)
    rows = CM.stage_motion(style, [0, 2], control_roll=False, focal_range_mm=(30.0, 500.0))
    assert rows[0, CM.HEADROOM_MASK] == 1 and rows[1, CM.HEADROOM_MASK] == 0  # nothing left to zoom
    assert math.exp(rows[0, CM.LOG_FOCAL_FLOOR]) == pytest.approx(30.0 * math.exp(0.01 + CM.HEADROOM_MARGIN), rel=1e-5)
    # without the lens's range (a caller that gives none) no headroom is asked
    assert not CM.stage_motion(style, [0], control_roll=False)[0, CM.HEADROOM_MASK]


def test_headroom_shortfall_by_hand():
    f = ca.SX.sym("f")
    h = ca.Function("h", [f], [J.headroom_shortfall(f, math.log(40.0), math.log(100.0))])
    assert np.array(h(32.0)).ravel() == pytest.approx([math.log(40 / 32), 0.0])
    assert np.array(h(50.0)).ravel() == pytest.approx([0.0, 0.0])
    assert np.array(h(200.0)).ravel() == pytest.approx([0.0, math.log(2.0)])


def test_zoom_out_held_by_dolly_by_hand():
    # a dolly in at 0.78 m/s with the subject 13 m ahead closes on him at 0.06 /s: a zoom out of at most that
    assert CM.zoom_out_held_by_dolly(-0.17, 0.78, 13.0) == pytest.approx(-0.06)
    assert CM.zoom_out_held_by_dolly(-0.05, 0.78, 13.0) == -0.05  # slower than the dolly holds: as asked
    # a dolly not under way yet (or backing off) holds no zoom out
    assert CM.zoom_out_held_by_dolly(-0.17, 0.0, 13.0) == 0.0
    assert CM.zoom_out_held_by_dolly(-0.17, -0.5, 13.0) == 0.0
    # a zoom in (the dolly-zoom out) is left as asked
    assert CM.zoom_out_held_by_dolly(0.2, -0.9, 10.0) == 0.2
    assert math.isnan(CM.zoom_out_held_by_dolly(math.nan, 0.5, 13.0))


def test_zoom_in_kept_to_backing_off_by_hand():
    # backing off at 1.3 m/s from a subject 13 m ahead opens the distance at 0.1 /s: a zoom in of at least that
    assert CM.zoom_in_kept_to_backing_off(0.04, -1.3, 13.0) == pytest.approx(0.1)
    assert CM.zoom_in_kept_to_backing_off(0.15, -1.3, 13.0) == 0.15  # faster than the backing off holds: as asked
    # a camera not backing off keeps the zoom in asked; a zoom out (the dolly-zoom in) is left as asked
    assert CM.zoom_in_kept_to_backing_off(0.04, 0.5, 13.0) == 0.04
    assert CM.zoom_in_kept_to_backing_off(-0.17, -1.3, 13.0) == -0.17
    assert CM.zoom_in_kept_to_backing_off(0.0, -1.3, 13.0) == 0.0
    assert math.isnan(CM.zoom_in_kept_to_backing_off(math.nan, -1.3, 13.0))


def test_a_dolly_zoom_outs_zoom_in_is_kept_to_the_backing_off():
    ins = M.Instructions(image_targets=np.zeros((2, 4, 2), dtype=np.float32), fps=24.0,
                         camera_motion_class=["dolly_zoom", "zoom_in"],
                         zoom_rate=np.array([0.04, 0.04], dtype=np.float32))
    style = CM.read_motion_style(ins)
    motion = CM.stage_motion(style, [0, 1], control_roll=False)
    CM.hold_dolly_zooms(motion, style, [0, 1], -1.3, 13.0)  # 1.3 / 13 = 0.1
    assert motion[0, CM.ZOOM] == pytest.approx(0.1) and motion[0, CM.ZOOM_MASK] == 1
    assert motion[1, CM.ZOOM] == pytest.approx(0.04)  # a zoom in place is no dolly-zoom: as the source's


def test_only_dolly_zoom_stages_have_their_zoom_held_by_travel():
    ins = M.Instructions(image_targets=np.zeros((2, 4, 2), dtype=np.float32), fps=24.0,
                         camera_motion_class=["dolly_zoom", "zoom_out"],
                         zoom_rate=np.array([-0.17, -0.17], dtype=np.float32))
    style = CM.read_motion_style(ins)
    motion = CM.stage_motion(style, [0, 1], control_roll=False)
    CM.hold_dolly_zooms(motion, style, [0, 1], 0.65, 13.0)  # 0.65 / 13 = 0.05
    assert motion[0, CM.ZOOM] == pytest.approx(-0.05) and motion[0, CM.ZOOM_MASK] == 1
    assert motion[1, CM.ZOOM] == pytest.approx(-0.17)  # a zoom in place is no dolly-zoom: as the source's
