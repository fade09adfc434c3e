"""Where a row's depth of field goes (services/planner/focus_field.py), against hand-computed values."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cinetransfer.services.planner import focus_field as FF
from cinetransfer.shared import camera as cam

H_S = 13.365


def test_ground_depth_by_hand():
    # given a level camera 2 m up whose bottom row looks 0.5 (the focal length equals the sensor height) below
    # its axis: tan = 0.5, the ground 4 m ahead
    assert FF.ground_inverse_depth(1.0, height_m=2.0, pitch_rad=0.0, focal_mm=H_S, sensor_height_mm=H_S) \
        == pytest.approx(1 / 4.0)
    # and a camera pitched 30 deg down sees the ground on its axis 2 / sin 30 = 4 m away
    assert FF.ground_inverse_depth(0.5, height_m=2.0, pitch_rad=-math.pi / 6, focal_mm=50.0, sensor_height_mm=H_S) \
        == pytest.approx(1 / 4.0)
    # and a level camera's centre row meets the ground only at infinity
    assert FF.ground_inverse_depth(0.5, height_m=2.0, pitch_rad=0.0, focal_mm=50.0, sensor_height_mm=H_S) == 0.0


def test_ground_depth_matches_the_projection_of_a_ground_point():
    # given a camera 3 m up, pitched 8 deg down at 60 mm, and a ground point 14 m ahead, 1 m to the side
    pos, ypr = np.array([0.0, 0.0, 3.0]), np.array([0.0, math.radians(-8.0), 0.0])
    p = np.array([14.0, 1.0, 0.0])
    v = float(cam.project_world(p, pos, ypr, 60.0)[1])
    depth = float(cam.world_to_camera(p, pos, ypr)[0])
    # then the row it is seen at gives its depth along the axis
    x = FF.ground_inverse_depth(v, height_m=3.0, pitch_rad=ypr[1], focal_mm=60.0, sensor_height_mm=H_S)
    assert 1.0 / x == pytest.approx(depth, rel=1e-9)


def test_the_band_spans_feet_to_bottom_and_its_median_is_the_mean():
    kw = {"height_m": 2.0, "pitch_rad": 0.0, "focal_mm": H_S, "sensor_height_mm": H_S, "min_rows": 0.03}
    band = FF.ground_band(0.75, **kw)
    # rows 0.75 and 1.0: t = 0.25 and 0.5, depths 8 m and 4 m; the rows are even in inverse depth
    assert band.inv_top == pytest.approx(1 / 8.0) and band.inv_bottom == pytest.approx(1 / 4.0)
    assert band.inv_median == pytest.approx(0.5 * (1 / 8.0 + 1 / 4.0)) and band.bottom_m == pytest.approx(4.0)
    # and there is no band under 3 % of the frame high, from under the ground, or looking above the horizon
    assert FF.ground_band(0.98, **kw) is None
    assert FF.ground_band(0.75, **{**kw, "height_m": -1.0}) is None
    assert FF.ground_band(0.75, **{**kw, "pitch_rad": math.radians(40)}) is None


def test_narrowest_spread_by_hand():
    # 1000 A c / f^2: f/1.2, 0.05 mm, 60 mm -> 60 / 3600 per metre
    assert FF.narrowest_spread(60.0, 1.2, 0.05) == pytest.approx(1 / 60.0)


def test_a_sharp_foreground_is_aimed_at_the_bottom_row_within_what_the_lens_can_narrow():
    band = FF.Band(inv_top=1 / 15.0, inv_bottom=1 / 10.0)
    # given nothing kept out: the bottom row's ground, 10 m
    assert FF.foreground_near_m(band, math.inf, spread_min=1 / 60.0, soft_ratio=4.0) == pytest.approx(10.0)
    # given the subject kept out 14 m away by the visible field (4 x the circle) and a lens whose narrowest
    # spread is 1/60 per metre: the near limit no farther than 1 / (1/14 + 5/60) = 6.46 m
    near = FF.foreground_near_m(band, 14.0, spread_min=1 / 60.0, soft_ratio=4.0)
    assert near == pytest.approx(1 / (1 / 14.0 + 5 / 60.0)) and near == pytest.approx(6.46, abs=0.01)
    # and a lens that narrows enough aims it at the bottom row again
    assert FF.foreground_near_m(band, 14.0, spread_min=1e-3, soft_ratio=4.0) == pytest.approx(10.0)


def test_only_the_foreground_sharp_blurs_the_subject_by_the_asked_circles_by_hand():
    # given the subject 14 m away, a planning circle 3/8 of the one circle, its half-width 1/60 per metre at
    # the aperture planned for, and the far limit's circle 4 x the planning circle
    near, far = FF.foreground_limits(14.0, spread=1 / 60.0, sharp_ratio=0.375, far_ratio=4.0, subject_blur=1.3)
    # then the focus 1/s = 1/14 + 1.3 (1/60) / 0.375: the subject 1.3 circles of c out of focus
    x_s = 1 / 14.0 + 1.3 / 60.0 / 0.375
    assert 1 / near == pytest.approx(x_s + 1 / 60.0) and 1 / far == pytest.approx(x_s - 4 / 60.0)
    # the field of c (8/3 x the planning circle's, 2/45 per metre) ends at 1/14 + 0.3 x 2/45: 11.8 m
    assert 1 / (x_s - 1 / 60.0 / 0.375) == pytest.approx(11.80, abs=0.01)
    # and a far limit of the sharpness circle alone (a switch previewed) keeps the caller's targets
    assert FF.foreground_limits(14.0, spread=1 / 60.0, sharp_ratio=0.375, far_ratio=1.0) is None


def test_a_shallow_band_asks_the_subject_less_blur_by_hand():
    sigma = 0.15  # the one circle's half-width per metre (parkour at 32 mm, f/1.2)
    # given a subject 10 m away and ground below his feet down to 0.4 circles in front of him (0.16 per metre)
    band = FF.Band(inv_top=0.1, inv_bottom=0.1 + 0.4 * sigma)
    # then the field's edge a quarter of the way in: 1 + 0.25 x 0.4 = 1.1 circles, the least
    assert FF.band_subject_blur(10.0, band, spread=sigma) == pytest.approx(1.1)
    # and a band 0.6 circles deep asks 1 + 0.25 x 0.6 = 1.15: three quarters of it inside the field
    deeper = FF.Band(inv_top=0.1, inv_bottom=0.1 + 0.6 * sigma)
    blur = FF.band_subject_blur(10.0, deeper, spread=sigma)
    assert blur == pytest.approx(1.15)
    assert (0.6 - (blur - 1.0)) / 0.6 == pytest.approx(0.75)
    # and a band 2 circles deep (45 mm and 12 m) keeps the 1.3 circles every texture reads soft
    assert FF.band_subject_blur(10.0, FF.Band(0.1, 0.1 + 2 * sigma), spread=sigma) == pytest.approx(1.3)
    # and a band only 0.2 circles deep keeps the least: the subject read soft comes first
    assert FF.band_subject_blur(10.0, FF.Band(0.1, 0.1 + 0.2 * sigma), spread=sigma) == pytest.approx(1.1)
    # and no band known keeps 1.3
    assert FF.band_subject_blur(10.0, None, spread=sigma) == FF.SUBJECT_BLUR_CIRCLES


def test_with_only_the_subject_sharp_the_focus_stands_in_front_of_him_where_the_field_is_wide():
    sigma = 0.04  # the one circle's half-width per metre (58 mm, f/1: parkour)

    def band(circles: float) -> FF.Band:  # the band's median `circles` of c in front of a subject 14 m away
        return FF.Band(inv_top=1 / 14.0, inv_bottom=1 / 14.0 + 2 * circles * sigma)

    # given the band's median 0.78 circles in front of him (inside c's field with the focus on him: parkour's):
    # a quarter of a circle in front of him, 0.01 per metre
    assert FF.SHARP_SUBJECT_BLUR == 0.25
    assert FF.focus_ahead_inv_m(14.0, band(0.78), fg_absent=False, spread=sigma) == pytest.approx(0.01)
    # given it 1.2 circles in front: (1.5 - 1.2) / 0.5 of that, 0.006 per metre
    assert FF.focus_ahead_inv_m(14.0, band(1.2), fg_absent=False, spread=sigma) == pytest.approx(0.006)
    # and half a circle asked: 0.02 and 0.012 per metre
    assert FF.focus_ahead_inv_m(14.0, band(0.78), fg_absent=False, spread=sigma, subject_blur=0.5) \
        == pytest.approx(0.02)
    assert FF.focus_ahead_inv_m(14.0, band(1.2), fg_absent=False, spread=sigma, subject_blur=0.5) \
        == pytest.approx(0.012)
    # given it 1.5 circles or more in front (the dancer's 1.8-2.0): nothing
    assert FF.focus_ahead_inv_m(14.0, band(1.5), fg_absent=False, spread=sigma) == 0.0
    assert FF.focus_ahead_inv_m(14.0, band(2.0), fg_absent=False, spread=sigma) == 0.0
    # and no foreground in the source, or no band known: nothing
    assert FF.focus_ahead_inv_m(14.0, band(0.78), fg_absent=True, spread=sigma) == 0.0
    assert FF.focus_ahead_inv_m(14.0, None, fg_absent=False, spread=sigma) == 0.0


def test_shifted_limits_keep_their_width_in_inverse_depth_by_hand():
    # given d -+ mu = 13 and 15 m moved 0.02 per metre nearer
    near, far = FF.shifted_limits(13.0, 15.0, 0.02)
    # then 1 / (1/13 + 0.02) = 10.32 m and 1 / (1/15 + 0.02) = 11.54 m
    assert near == pytest.approx(1 / (1 / 13 + 0.02)) and near == pytest.approx(10.32, abs=0.01)
    assert far == pytest.approx(11.54, abs=0.01)
    assert 1 / near - 1 / far == pytest.approx(1 / 13 - 1 / 15)
    # and unmoved they are the same
    assert FF.shifted_limits(13.0, 15.0, 0.0) == pytest.approx((13.0, 15.0))


def test_the_ground_behind_the_subject_by_hand():
    # given a level camera 2 m up whose focal length equals the sensor height, the feet at row 0.75: the ground
    # there 2 / 0.25 = 8 m away, the horizon at the centre row
    kw = {"height_m": 2.0, "pitch_rad": 0.0, "focal_mm": H_S, "sensor_height_mm": H_S}
    assert FF.ground_behind_inv_m(0.75, 0.0, **kw) == pytest.approx(1 / 8.0)
    # then a fifth of the rows above the feet (0.6-0.75) see the ground nearer than at row 0.6: 2 / 0.1 = 20 m
    assert FF.ground_behind_inv_m(0.75, 0.2, **kw) == pytest.approx(1 / 20.0)
    # and half of them reach above the horizon (row 0.375): no ground there, 0
    assert FF.ground_behind_inv_m(0.75, 0.5, **kw) == 0.0
    # and an unknown view says nothing
    assert FF.ground_behind_inv_m(math.nan, 0.2, **kw) == 0.0


def test_the_rack_lead_stops_where_the_background_would_enter_the_field_by_hand():
    # given her 8 m away, the one circle's half-width 0.05 per metre, the background 40 m away, the lens at 15 m/s:
    # the far limit 1/s - 0.05 stays nearer than 1/40 while s < 1 / (0.025 + 0.05) = 13.33 m
    cap = FF.rack_lead_cap_s(8.0, 1 / 40.0, spread=0.05, rate_mps=15.0)
    # then the focus may leave her 5.33 m, 0.356 s, before the switch
    assert cap == pytest.approx((1 / 0.075 - 8.0) / 15.0) and cap == pytest.approx(0.3556, abs=1e-4)
    # and a background at infinity stops it at the hyperfocal distance 1 / 0.05 = 20 m: 12 m, 0.8 s
    assert FF.rack_lead_cap_s(8.0, 0.0, spread=0.05, rate_mps=15.0) == pytest.approx(0.8)
    # and a background inside the field with the focus on him (18 m away, the far limit 1 / (1/18 - 0.02) =
    # 28.1 m beyond the lawn 25 m away) is sharp before the switch whatever the lead: no cap
    assert FF.rack_lead_cap_s(18.0, 1 / 25.0, spread=0.02, rate_mps=15.0) == math.inf
    # and on the line (the far limit exactly at the background) no cap either
    assert FF.rack_lead_cap_s(10.0, 0.05, spread=0.05, rate_mps=15.0) == math.inf
    # and an unknown background or a lens that cannot move gives no lead
    assert FF.rack_lead_cap_s(8.0, math.nan, spread=0.05, rate_mps=15.0) == 0.0
    assert FF.rack_lead_cap_s(8.0, 0.025, spread=0.05, rate_mps=0.0) == 0.0


def test_the_settled_soft_subject_blur_starts_the_sharp_zone_at_the_ground_by_hand():
    # given his back 20 m away, the one circle's half-width 0.025 per metre, the ground at 25 m: the zone at
    # 1/20 - (b - 1) 0.025 = 1/25 asks b = 1.4
    b = FF.settled_subject_blur(20.0, 1 / 25.0, spread=0.025, most=1.5)
    assert b == pytest.approx(1.4)
    # (the focus then at 1/20 - 1.4 x 0.025 = 0.015 per metre, the zone's near edge at 0.015 + 0.025 = 1/25)
    assert 1 / 20.0 - b * 0.025 + 0.025 == pytest.approx(1 / 25.0)
    # and a ground 30 m away would allow 1.67: `most` (1.5) is asked
    assert FF.settled_subject_blur(20.0, 1 / 30.0, spread=0.025, most=1.5) == 1.5
    # and a ground 22 m away would ask 1.18: never under LEAST_SOFT_SUBJECT_BLUR (1.3)
    assert FF.LEAST_SOFT_SUBJECT_BLUR == 1.3
    assert FF.settled_subject_blur(20.0, 1 / 22.0, spread=0.025, most=1.5) == pytest.approx(1.3)
    # and no ground behind him (0): `most`
    assert FF.settled_subject_blur(20.0, 0.0, spread=0.025, most=1.5) == 1.5


def test_the_focus_before_a_rack_stands_in_front_of_him_by_the_background_by_hand():
    # given the runner 15 m away, the ground behind him 20 m away, the one circle's half-width 0.03 per metre: with
    # the focus on him the ground is (1/15 - 1/20) / 0.03 = 0.556 circles soft
    # then 1.5 circles ask the focus 0.944 circles in front, 0.0283 per metre, when nothing caps it
    ahead = FF.rack_ahead_inv_m(15.0, 1 / 20.0, spread=0.03, background_blur=1.5, most=2.0)
    assert ahead == pytest.approx((1.5 - (1 / 15 - 1 / 20) / 0.03) * 0.03) and ahead == pytest.approx(0.02833, abs=1e-5)
    # and at most `most` circles (0.4): 0.012 per metre, he 0.4 circles soft, still sharp
    assert FF.rack_ahead_inv_m(15.0, 1 / 20.0, spread=0.03, background_blur=1.5, most=0.4) == pytest.approx(0.012)
    # and the dancer 8 m away, her ground 37.5 m away, 0.079 per metre: 1.245 circles soft on her, 0.255 asked
    assert FF.rack_ahead_inv_m(8.0, 1 / 37.5, spread=0.079, background_blur=1.5, most=0.4) == pytest.approx(
        1.5 * 0.079 - (1 / 8 - 1 / 37.5), abs=1e-9)
    # and a background soft enough with the focus on him (1/8 - 1/40 = 0.1 = 2 circles of 0.05) asks nothing
    assert FF.rack_ahead_inv_m(8.0, 1 / 40.0, spread=0.05, background_blur=1.5, most=0.4) == 0.0
    # and no ground seen behind him (0) or an unknown one asks nothing
    assert FF.rack_ahead_inv_m(15.0, 0.0, spread=0.03, background_blur=1.5, most=0.4) == 0.0
    assert FF.rack_ahead_inv_m(15.0, math.nan, spread=0.03, background_blur=1.5, most=0.4) == 0.0


def test_the_three_labels_come_together_where_both_soft_regions_are_equally_blurred_by_hand():
    kw = {"spread": 0.0536, "otherwise_inv_m": 0.02}
    # given a runner 10.6 m away, the hedge in front at 6.8 m and the backdrop at 40 m, the one circle's spread
    # 0.0536 /m: the focus where both are as soft, 1/s = (1/6.8 + 1/40) / 2 = 0.08603 /m (11.62 m), 0.155 circles
    # behind him (within the quarter circle he may carry), both 1.139 circles soft: past 1.04, wholly there
    x = FF.three_label_focus_inv_m(10.6, 1 / 6.8, 1 / 40.0, **kw)
    assert x == pytest.approx(0.5 * (1 / 6.8 + 1 / 40.0) - 1 / 10.6)
    assert x < 0
    # and a subject farther from the midpoint than a quarter circle keeps it: 0.1 + 0.25 x 0.1 = 0.125 /m, the
    # nearer region then 1.75 circles soft and the farther 1.25
    assert FF.three_label_focus_inv_m(10.0, 0.3, 0.0, spread=0.1, otherwise_inv_m=0.0) == pytest.approx(0.025)
    # and where the two could share 0.9 circles at most (under 0.95) the caller's move stands
    assert FF.three_label_focus_inv_m(10.0, 0.145, 0.055, spread=0.05, otherwise_inv_m=0.01) == pytest.approx(0.01)
    # and at 0.995 circles (the midpoint 0.1 /m on him, the regions 0.04975 /m either side), half way from 0.95 to
    # 1.04: half way between the two moves
    assert FF.three_label_focus_inv_m(10.0, 0.14975, 0.05025, spread=0.05, otherwise_inv_m=0.01) \
        == pytest.approx(0.005)
    # and the caller's move with the foreground behind him, the background in front, or a depth unknown
    for fg, bg in ((0.05, 0.02), (0.3, 0.2), (math.nan, 0.02)):
        assert FF.three_label_focus_inv_m(10.0, fg, bg, spread=0.05, otherwise_inv_m=0.01) == 0.01


def test_the_three_labels_are_balanced_by_margin_past_each_region_s_flip_by_hand():
    kw = {"spread": 0.05, "otherwise_inv_m": 0.0}
    # given a subject 10 m away (0.1 /m), the foreground at 0.16 /m and the background at 0.04 /m: equal circles
    # put the focus on him, both 1.2 circles soft; with the foreground flipping at 1.3 circles and the background
    # at 1.1 the focus moves (1.3 - 1.1) / 2 = 0.1 circles behind him, 0.005 /m: both then 0.1 circles past
    x = FF.three_label_focus_inv_m(10.0, 0.16, 0.04, flips=(1.3, 1.1), **kw)
    assert x == pytest.approx(-0.005)
    assert (0.16 - (0.1 + x)) / 0.05 - 1.3 == pytest.approx((0.1 + x - 0.04) / 0.05 - 1.1)
    # and equal flips leave the equal-circle focus, even where the truth's 1.03 circles would not hold there
    assert FF.three_label_focus_inv_m(10.0, 0.16, 0.04, flips=(1.2, 1.2), **kw) == pytest.approx(0.0)
    assert FF.three_label_focus_inv_m(10.0, 0.3, 0.0, spread=0.1, otherwise_inv_m=0.0, flips=(1.2, 1.2)) \
        == pytest.approx(0.025)
    # and the subject's 0.35 circles bound the move: with the regions at 0.2 and 0 /m (2 circles each), flips
    # 2.0 and 1.0 would ask 0.5 circles behind him, 0.35 stand
    assert FF.three_label_focus_inv_m(10.0, 0.2, 0.0, flips=(2.0, 1.0), **kw) == pytest.approx(-0.0175)
    # and so does the truth's 1.03 circles on the less flipping region: 1.1 shared, the background may lose 0.07
    # circles of blur only (0.0035 /m), although the flips ask 0.1
    assert FF.three_label_focus_inv_m(10.0, 0.155, 0.045, flips=(1.3, 1.1), **kw) == pytest.approx(-0.0035)
