"""What the planner's map shows the camera (services/planner/scene_depth.py), against hand-computed values."""
from __future__ import annotations

import numpy as np
import pytest

from cinetransfer.services.planner import scene_depth as SD
from cinetransfer.shared import camera as cam
from cinetransfer.shared.surfaces import Surface

H_S = 13.365
SENSOR = cam.Sensor()


def _depths(uv, surfaces):
    # a level camera 2 m up at the origin whose bottom row looks 0.5 below its axis (the focal length equals the
    # sensor height)
    return SD.ray_hits(np.array(uv, float), (0.0, 0.0, 2.0), (0.0, 0.0, 0.0), focal_mm=H_S, sensor=SENSOR,
                       ground_z_m=0.0, surfaces=surfaces)[0]


def test_the_ground_and_the_surfaces_by_hand():
    hedge = Surface(3.0, -5.0, 3.0, 5.0, 0.0, 1.0)
    backdrop = Surface(30.0, 5.0, 30.0, -5.0, 0.0, 10.0)
    # given only the ground: the bottom row's centre sees it 2 / 0.5 = 4 m ahead, the centre row nothing (the sky)
    assert _depths([[0.5, 1.0], [0.5, 0.5]], ()) == pytest.approx([1 / 4.0, 0.0])
    # given a hedge 3 m ahead, 1 m high: the bottom row meets it at 2 - 0.5 x 3 = 0.5 m high, 3 m away, before
    # the ground; and a backdrop 30 m ahead: the centre row meets it at 2 m high
    got = _depths([[0.5, 1.0], [0.5, 0.5]], (hedge, backdrop))
    assert got == pytest.approx([1 / 3.0, 1 / 30.0])
    # and the frame's left edge looks 0.5 x 23.76 / 13.365 = 0.889 to the side: 26.7 m off the axis at 30 m, past
    # the backdrop's 5 m, so it sees the sky
    assert _depths([[0.0, 0.5]], (backdrop,)) == pytest.approx([0.0])


def test_a_depth_is_along_the_optical_axis_as_the_projection_has_it():
    # given a camera pitched 8 deg down and yawed 20 deg at 60 mm, and a point on a surface
    pos, ypr = np.array([1.0, -2.0, 3.0]), np.array([np.radians(20.0), np.radians(-8.0), 0.0])
    wall = Surface(20.0, -30.0, 20.0, 30.0, -1.0, 20.0)
    p = np.array([20.0, 4.0, 2.5])
    uv = cam.project_world(p, pos, ypr, 60.0)
    # then the ray through its image point sees it at its depth along the camera's axis
    x, _ = SD.ray_hits(uv[None], pos, ypr, focal_mm=60.0, sensor=SENSOR, ground_z_m=-5.0, surfaces=(wall,))
    assert 1.0 / x[0] == pytest.approx(float(cam.world_to_camera(p, pos, ypr)[0]), rel=1e-9)


def test_the_regions_medians_by_hand():
    rows = lambda pts: (pts[:, 1], np.ones(len(pts)))  # noqa: E731 - each point's row as its "depth"
    # given the feet at mid-frame: the band's rows 0.5-1 (median 0.75), the rows above 0-0.5 (median 0.25)
    assert SD.region_medians_and_flips(0.5, rows)[:2] == pytest.approx((0.75, 0.25))
    # and with the feet at the bottom row no band; at the top no background
    fg, bg = SD.region_medians_and_flips(1.0, rows)[:2]
    assert np.isnan(fg) and bg == pytest.approx(0.5)
    assert np.isnan(SD.region_medians_and_flips(0.0, rows)[1])


def test_each_region_s_flip_is_that_of_what_its_median_ray_meets():
    hedge = Surface(3.0, -5.0, 3.0, 5.0, 0.0, 1.0, 1.27)
    backdrop = Surface(30.0, 5.0, 30.0, -5.0, 0.0, 10.0, 1.1)
    # given the same camera: the bottom row meets the hedge, the centre row the backdrop, and a row 0.05 below the
    # centre the backdrop too (0.5 m up at 30 m) before the ground 2 / 0.05 = 40 m away; the left edge the sky
    inv, flip = SD.ray_hits(np.array([[0.5, 1.0], [0.5, 0.5], [0.5, 0.55], [0.0, 0.5]]), (0.0, 0.0, 2.0),
                            (0.0, 0.0, 0.0), focal_mm=H_S, sensor=SENSOR, ground_z_m=0.0, surfaces=(hedge, backdrop))
    assert inv == pytest.approx([1 / 3.0, 1 / 30.0, 1 / 30.0, 0.0])
    # the ground and the sky have the one circle's own flip
    assert flip == pytest.approx([1.27, 1.1, 1.1, 1.0])
    # and a region's flip is its median ray's: rows as depths, the flip 2 on the lower half of each region's rays
    hits = lambda pts: (pts[:, 1], np.where(pts[:, 1] > np.median(pts[:, 1]), 2.0, 1.0))  # noqa: E731
    fg, bg, fg_flip, bg_flip = SD.region_medians_and_flips(0.5, hits)
    assert (fg, bg) == pytest.approx((0.75, 0.25)) and (fg_flip, bg_flip) == (2.0, 2.0)
