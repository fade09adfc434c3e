"""The bearing a waiting subject is filmed from before a truck, against hand-computed geometry."""
import math

import numpy as np
import pytest

from cinetransfer.services.planner.clear_side import (clear_bearing, segment_clear, side_wanted_for, stands_clear,
                                                      travel_in_world, truck_travel)
from cinetransfer.shared.obstacles import Obstacle

RIGHT = np.array([0.0, -1.0, 0.0])  # the planner camera frame: x forward, y left


def post(x, y):
    """A post 0.5 m wide (kept 1.5 m from its axis with a 1 m clearance), 0-3 m high."""
    return Obstacle(x, y, 0.5, 0.0, 3.0)


def test_truck_travel_sums_the_truck_rows_sideways_speed():
    classes = [frozenset({"truck"}), frozenset({"pan", "truck"}), frozenset({"pan"}), None, frozenset({"truck"})]
    travel = np.array([RIGHT, RIGHT, RIGHT, RIGHT, RIGHT])
    swing = np.array([0.1, -0.1, 0.1, 0.1, math.nan])
    # two truck rows with a swing: 0.1 rad/s x 10 m over 1/10 s each = 0.1 m to the right each
    assert truck_travel(classes, travel, swing, 10.0, 10.0) == pytest.approx([0.0, -0.2])
    assert not truck_travel(classes[2:4], travel[2:4], swing[2:4], 10.0, 10.0).any()


def test_travel_in_world_turns_the_camera_frame_to_look_at_the_subject():
    # at bearing 0 the camera stands on +x of the subject looking along -x: its right is +y
    assert travel_in_world(0.0, [0.0, -4.0]) == pytest.approx([0.0, 4.0])
    assert travel_in_world(0.0, [2.0, 0.0]) == pytest.approx([-2.0, 0.0])
    # at bearing 90 deg it looks along -y: its right is -x
    assert travel_in_world(math.pi / 2, [0.0, -4.0]) == pytest.approx([-4.0, 0.0])


def test_segment_clear_uses_the_keep_out_radius_at_the_height():
    assert not segment_clear([0, 0], [10, 0], 1.5, [post(5, 1)], 1.0)  # 1 m from the path, keeps 1.5 m
    assert segment_clear([0, 0], [10, 0], 1.5, [post(5, 2)], 1.0)
    assert segment_clear([0, 0], [10, 0], 1.5, [post(12, 0)], 1.0)  # 2 m beyond the path's end
    assert not segment_clear([0, 0], [10, 0], 1.5, [post(11.4, 0)], 1.0)
    # 0.6 m over the top: keeps 0.5 + sqrt(1 - 0.36) = 1.3 m
    assert segment_clear([0, 0], [10, 0], 3.6, [post(5, 1.4)], 1.0)
    assert not segment_clear([0, 0], [10, 0], 3.6, [post(5, 1.2)], 1.0)
    assert segment_clear([0, 0], [10, 0], 4.1, [post(5, 0)], 1.0)  # over it by more than the clearance


def test_clear_bearing_keeps_a_clear_start_and_turns_the_nearest_way_otherwise():
    subject, cam, truck = [0.0, 0.0], [10.0, 0.0], [0.0, -4.0]  # trucking right 4 m: (10, 0) -> (10, 4)
    assert clear_bearing(subject, cam, 1.5, truck, [post(10, 6)], 1.0) == pytest.approx(0.0)
    step = math.pi / 2  # candidates: 0, +90 deg ((0, 10) -> (-4, 10)), -90 deg ((0, -10) -> (4, -10))
    blocked = [post(10, 3)]
    assert clear_bearing(subject, cam, 1.5, truck, blocked, 1.0, step_rad=step) == pytest.approx(math.pi / 2)
    blocked.append(post(-2, 10))
    assert clear_bearing(subject, cam, 1.5, truck, blocked, 1.0, step_rad=step) == pytest.approx(-math.pi / 2)
    blocked.append(post(2, -10))
    assert math.isnan(clear_bearing(subject, cam, 1.5, truck, blocked, 1.0, step_rad=step))
    assert math.isnan(clear_bearing(subject, subject, 1.5, truck, blocked, 1.0))


def test_clear_bearing_in_five_degree_steps():
    # at bearing b the path starts at 10 (cos b, sin b) and runs 4 m along (-sin b, cos b); a post at c whose
    # foot falls on it lies |10 - c.(cos b, sin b)| from it. Post (9, 2): 0 deg 1.000 (blocked), -5 1.208,
    # -10 1.484 (blocked: it keeps 1.5 m), -15 1.84 from the path's end (clear); the other way the start at
    # +5 deg, (9.96, 0.87), is 1.48 m from the post: that way closes
    got = clear_bearing([0, 0], [10, 0], 1.5, [0.0, -4.0], [post(9, 2)], 1.0)
    assert math.degrees(got) == pytest.approx(-15.0)


def test_clear_bearing_turns_no_further_than_the_camera_gets_round_the_subject():
    # 45 deg steps from (10, 0), trucking right 4 m, (10, 3) blocks the start. +45 deg stands on a post (the
    # way closes there); -45 deg's path (7.07, -7.07) -> (9.90, -4.24) passes 1.3 m from (11, -5); +90 deg's
    # path (0, 10) -> (-4, 10) is clear but lies beyond the post, so -90 deg's (0, -10) -> (4, -10) is taken
    posts = [post(10, 3), post(7.07, 7.07), post(11, -5)]
    got = clear_bearing([0, 0], [10, 0], 1.5, [0.0, -4.0], posts, 1.0, step_rad=math.pi / 4)
    assert math.degrees(got) == pytest.approx(-90.0)
    got = clear_bearing([0, 0], [10, 0], 1.5, [0.0, -4.0], posts[::2], 1.0, step_rad=math.pi / 4)
    # with no post at +45 deg its path (7.07, 7.07) -> (4.24, 9.90) is clear, and that way is tried first
    assert math.degrees(got) == pytest.approx(45.0)


def test_side_wanted_for_asks_past_the_clear_bearing_by_the_free_angle():
    assert math.degrees(side_wanted_for(0.0, math.radians(20))) == pytest.approx(65.0)
    assert math.degrees(side_wanted_for(0.0, math.radians(-100))) == pytest.approx(-90.0)  # at most 90 deg away
    assert math.degrees(side_wanted_for(math.radians(170), math.radians(-170))) == pytest.approx(235.0)
    assert math.isnan(side_wanted_for(0.3, 0.3))
    assert math.isnan(side_wanted_for(0.3, math.nan))


def test_stands_clear_is_outside_every_keep_out():
    # post(5, 0) keeps 1.5 m from its axis at 1.5 m high, 0.5 + sqrt(1 - 0.36) = 1.3 m at 3.6 m
    assert not stands_clear([6.4, 0.0], 1.5, [post(5, 0)], 1.0)
    assert stands_clear([6.5, 0.0], 1.5, [post(5, 0)], 1.0)
    assert stands_clear([6.4, 0.0], 3.6, [post(5, 0)], 1.0) and not stands_clear([6.2, 0.0], 3.6, [post(5, 0)], 1.0)
    # a path of no travel is its start standing
    assert segment_clear([6.4, 0.0], [0.0, 0.0], 1.5, [post(5, 0)], 1.0) is False
    assert segment_clear([6.5, 0.0], [0.0, 0.0], 1.5, [post(5, 0)], 1.0) is True
