"""Safety layer: rejection of non-finite setpoints, geofence/altitude/speed/accel/subject clamps,
lens and gimbal limits, motion rate limiting — and that every one of them is counted."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cinetransfer.services.autopilot_bridge.config import BridgeConfig, ConfigError, MavlinkConfig, SafetyConfig
from cinetransfer.services.autopilot_bridge.safety import (
    SafetyLayer, clamp_geofence, inside_geofence, push_from_subject, subject_centre_xy, wrap_angle)
from cinetransfer.shared import messages as M


def sp(pos=(1.0, 2.0, 5.0), vel=(0.0, 0.0, 0.0), acc=(0.0, 0.0, 0.0), ypr=(0.0, 0.0, 0.0), lens=None, **kw):
    return M.Setpoint(position_m=np.array(pos, float), velocity_mps=np.array(vel, float),
                      acceleration_mps2=np.array(acc, float), camera_ypr_rad=np.array(ypr, float),
                      lens=lens or M.LensState(focal_length_mm=35.0, focus_distance_m=5.0, f_number=4.0), **kw)


CFG = SafetyConfig(geofence_radius_m=10.0, altitude_min_m=1.0, altitude_max_m=20.0, speed_max_mps=2.0,
                   accel_max_mps2=1.0, min_subject_distance_m=2.0)


def test_given_a_setpoint_inside_all_limits_when_checked_then_it_passes_unchanged_and_is_counted():
    s = SafetyLayer(CFG)
    r = s.check(sp())
    assert r.accepted and r.clamps == ()
    np.testing.assert_array_equal(r.setpoint.position_m, [1.0, 2.0, 5.0])
    assert s.counters["sp_checked"] == 1 and s.counters["sp_accepted"] == 1


@pytest.mark.parametrize("field,bad", [
    ("pos", (math.nan, 0.0, 5.0)), ("pos", (0.0, math.inf, 5.0)), ("vel", (0.0, -math.inf, 0.0)),
    ("acc", (math.nan, 0.0, 0.0)), ("ypr", (0.0, math.nan, 0.0)),
])
def test_given_non_finite_values_when_checked_then_rejected_and_counted(field, bad):
    s = SafetyLayer(CFG)
    r = s.check(sp(**{field: bad}))
    assert not r.accepted and "finite" in r.reason
    assert s.counters["sp_rejected_nonfinite"] == 1 and s.counters["sp_accepted"] == 0


def test_given_infinite_lens_or_unknown_mode_when_checked_then_rejected():
    s = SafetyLayer(CFG)
    assert not s.check(sp(lens=M.LensState(focal_length_mm=math.inf))).accepted
    assert not s.check(sp(mode="barrel-roll")).accepted
    assert s.counters["sp_rejected_nonfinite"] == 1 and s.counters["sp_rejected_mode"] == 1


def test_given_nan_lens_values_when_checked_then_current_lens_is_kept():
    s = SafetyLayer(CFG)
    now = M.LensState(focal_length_mm=80.0, focus_distance_m=12.0, f_number=2.8)
    r = s.check(sp(lens=M.LensState(focal_length_mm=50.0)), lens_now=now)
    assert r.accepted
    assert (r.setpoint.lens.focal_length_mm, r.setpoint.lens.focus_distance_m, r.setpoint.lens.f_number) == \
        (50.0, 12.0, 2.8)


@pytest.mark.parametrize("shape,pos,expect", [
    ("cylinder", (30.0, 40.0, 5.0), (6.0, 8.0, 5.0)),  # radius 10 along the same bearing
    ("box", (30.0, -4.0, 5.0), (10.0, -4.0, 5.0)),
    ("box", (-30.0, -40.0, 5.0), (-10.0, -10.0, 5.0)),
])
def test_given_out_of_fence_position_when_checked_then_clamped_to_the_fence(shape, pos, expect):
    cfg = SafetyConfig(geofence_shape=shape, geofence_radius_m=10.0, geofence_half_extent_m=(10.0, 10.0),
                       min_subject_distance_m=0.0)
    s = SafetyLayer(cfg)
    r = s.check(sp(pos=pos))
    assert r.accepted and "clamp_geofence" in r.clamps
    np.testing.assert_allclose(r.setpoint.position_m, expect, atol=1e-9)
    assert s.counters["clamp_geofence"] == 1


def test_geofence_is_centred_on_home():
    cfg = SafetyConfig(home_m=(100.0, 0.0, 50.0), geofence_radius_m=10.0, altitude_min_m=1.0, altitude_max_m=20.0)
    p, hit = clamp_geofence(np.array([100.0, 5.0, 55.0]), cfg)
    assert not hit
    r = SafetyLayer(cfg).check(sp(pos=(100.0, 5.0, 10.0)))  # below home + 1 m
    assert r.setpoint.position_m[2] == pytest.approx(51.0) and "clamp_altitude" in r.clamps


@pytest.mark.parametrize("z,expect", [(-3.0, 1.0), (0.5, 1.0), (25.0, 20.0), (7.0, 7.0)])
def test_given_altitude_outside_band_when_checked_then_clamped(z, expect):
    s = SafetyLayer(CFG)
    r = s.check(sp(pos=(0.0, 5.0, z)))
    assert r.setpoint.position_m[2] == pytest.approx(expect)
    assert s.counters["clamp_altitude"] == (1 if z != expect else 0)


def test_given_excessive_feed_forward_when_checked_then_speed_and_accel_clamped():
    s = SafetyLayer(CFG)
    r = s.check(sp(vel=(3.0, 4.0, 0.0), acc=(0.0, 0.0, 5.0)))
    np.testing.assert_allclose(r.setpoint.velocity_mps, [1.2, 1.6, 0.0])
    np.testing.assert_allclose(r.setpoint.acceleration_mps2, [0.0, 0.0, 1.0])
    assert s.counters["clamp_speed"] == 1 and s.counters["clamp_accel"] == 1


def test_given_setpoint_too_close_to_subject_when_checked_then_pushed_out_radially():
    s = SafetyLayer(CFG)
    subj = np.array([3.0, 0.0])
    r = s.check(sp(pos=(3.5, 0.0, 5.0)), subject_xy=subj)
    assert "clamp_subject_distance" in r.clamps
    np.testing.assert_allclose(r.setpoint.position_m, [5.0, 0.0, 5.0])  # 2 m out, same bearing
    # exactly on the subject: pushed towards the vehicle
    r = s.check(sp(pos=(3.0, 0.0, 5.0)), subject_xy=subj, vehicle_xy=np.array([3.0, -7.0]))
    np.testing.assert_allclose(r.setpoint.position_m, [3.0, -2.0, 5.0])
    assert s.counters["clamp_subject_distance"] == 2


def test_given_subject_on_the_fence_edge_when_push_leaves_fence_then_rejected_as_conflict():
    s = SafetyLayer(CFG)  # radius 10, min distance 2
    r = s.check(sp(pos=(9.9, 0.0, 5.0)), subject_xy=np.array([9.5, 0.0]))
    assert not r.accepted and s.counters["sp_rejected_subject_conflict"] == 1


def test_given_gimbal_and_lens_out_of_range_when_checked_then_clamped_and_yaw_wrapped():
    s = SafetyLayer(CFG)
    r = s.check(sp(ypr=(3 * math.pi / 2, 1.2, -1.0),
                   lens=M.LensState(focal_length_mm=2000.0, focus_distance_m=0.01, f_number=0.5)))
    y, p, rl = r.setpoint.camera_ypr_rad
    assert y == pytest.approx(-math.pi / 2) and p == pytest.approx(CFG.pitch_max_rad)
    assert rl == pytest.approx(-CFG.roll_max_rad)
    assert (r.setpoint.lens.focal_length_mm, r.setpoint.lens.focus_distance_m, r.setpoint.lens.f_number) == \
        (CFG.focal_length_max_mm, CFG.focus_distance_min_m, CFG.f_number_min)
    assert s.counters["clamp_gimbal"] == 1 and s.counters["clamp_lens"] == 1


def test_given_a_climb_faster_than_the_vehicle_climbs_when_checked_then_the_vertical_speed_is_clamped():
    s = SafetyLayer(CFG)  # climb_max_mps: the default profile's 1.0
    r = s.check(sp(vel=(1.0, 0.0, -1.5)))  # norm 1.8 < 2: only the climb limit bites
    np.testing.assert_allclose(r.setpoint.velocity_mps, [1.0, 0.0, -1.0])
    assert s.counters["clamp_speed"] == 1
    mc = s.limit_motion(target_pos=np.array([0.0, 0.0, 10.0]), target_vel=np.zeros(3), prev_pos=np.zeros(3),
                        prev_vel=np.zeros(3), dt_s=0.1)  # a jump straight up is approached at 1 m/s, not 2
    np.testing.assert_allclose(mc.position_m, [0.0, 0.0, 0.1])


def test_limit_motion_moves_at_most_max_speed_and_changes_velocity_at_most_max_accel():
    s = SafetyLayer(CFG)
    pos, vel = np.zeros(3), np.zeros(3)
    for _ in range(50):  # 1 s at 50 Hz towards a target 100 m away
        mc = s.limit_motion(target_pos=np.array([100.0, 0.0, 0.0]), target_vel=np.array([2.0, 0.0, 0.0]),
                            prev_pos=pos, prev_vel=vel, dt_s=0.02)
        assert np.linalg.norm(mc.position_m - pos) <= 2.0 * 0.02 + 1e-12
        assert np.linalg.norm(mc.velocity_mps - vel) <= 1.0 * 0.02 + 1e-12
        pos, vel = mc.position_m, mc.velocity_mps
    assert pos[0] == pytest.approx(2.0) and vel[0] == pytest.approx(1.0)
    assert s.counters["clamp_position_rate"] == 50 and s.counters["clamp_velocity_rate"] == 50


def test_helpers():
    assert wrap_angle(math.pi) == pytest.approx(math.pi) and wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(2 * math.pi + 0.1) == pytest.approx(0.1)
    p, hit = push_from_subject(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0]), 0.0)
    assert not hit
    subj = M.SubjectState(joints_m=np.array([[1.0, 2.0, 0.0], [3.0, 4.0, 1.0], [np.nan, np.nan, np.nan]]))
    np.testing.assert_allclose(subject_centre_xy(subj), [2.0, 3.0])
    assert subject_centre_xy(M.SubjectState(joints_m=np.full((2, 3), np.nan))) is None
    assert subject_centre_xy(None) is None


finite = st.floats(-1e4, 1e4, allow_nan=False)
anything = st.one_of(finite, st.just(math.nan), st.just(math.inf), st.just(-math.inf))


@settings(max_examples=300, deadline=None)
@given(pos=st.tuples(anything, anything, anything), vel=st.tuples(anything, anything, anything),
       subj=st.one_of(st.none(), st.tuples(st.floats(-8, 8), st.floats(-8, 8))),
       shape=st.sampled_from(["cylinder", "box"]))
def test_property_accepted_setpoints_are_finite_inside_fence_and_band_and_within_speed(pos, vel, subj, shape):
    cfg = SafetyConfig(geofence_shape=shape, geofence_radius_m=10.0, geofence_half_extent_m=(10.0, 10.0),
                       altitude_min_m=1.0, altitude_max_m=20.0, speed_max_mps=2.0, min_subject_distance_m=2.0)
    s = SafetyLayer(cfg)
    sxy = None if subj is None else np.array(subj)
    r = s.check(sp(pos=pos, vel=vel), subject_xy=sxy)
    if not all(map(math.isfinite, (*pos, *vel))):
        assert not r.accepted
        return
    if not r.accepted:
        assert r.reason.startswith("no point inside the geofence")
        return
    out = r.setpoint
    assert np.all(np.isfinite(out.position_m)) and inside_geofence(out.position_m, cfg)
    assert np.linalg.norm(out.velocity_mps) <= 2.0 + 1e-9
    if sxy is not None:
        assert np.linalg.norm(out.position_m[:2] - sxy) >= 2.0 - 1e-6
    assert s.counters["sp_checked"] == 1


@pytest.mark.parametrize("cls,kw,field", [
    (SafetyConfig, {"geofence_shape": "sphere"}, "geofence_shape"),
    (SafetyConfig, {"altitude_min_m": 10.0, "altitude_max_m": 5.0}, "altitude_min_m"),
    (SafetyConfig, {"speed_max_mps": -1.0}, "speed_max_mps"),
    (SafetyConfig, {"accel_max_mps2": math.nan}, "accel_max_mps2"),
    (SafetyConfig, {"watchdog_timeout_s": 0.0}, "watchdog_timeout_s"),
    (SafetyConfig, {"min_subject_distance_m": -1.0}, "min_subject_distance_m"),
    (MavlinkConfig, {"setpoint_rate_hz": 2.0}, "setpoint_rate_hz"),
    (MavlinkConfig, {"autopilot": "betaflight"}, "autopilot"),
    (MavlinkConfig, {"source_system": 300}, "source_system"),
    (BridgeConfig, {"backend": "carla"}, "backend"),
    (BridgeConfig, {"jpeg_quality": 101}, "jpeg_quality"),
])
def test_invalid_config_is_refused_naming_the_field(cls, kw, field):
    with pytest.raises(ConfigError, match=field):
        cls(**kw)
