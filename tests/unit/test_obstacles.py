"""Keep-out obstacles: the cylinders' geometry (shared/obstacles.py), a scene's own (sim/obstacles.py), the
planner's soft constraint (planner/obstacles.py) and the bridge's envelope check, against hand-computed values."""
import math

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.services.autopilot_bridge.safety import envelope_breach, return_point
from cinetransfer.services.autopilot_bridge.sim.obstacles import CROWN_SLICES, crown_slices, scene_obstacles
from cinetransfer.services.autopilot_bridge.sim.scene import load_scene
from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.obstacles import (N_OBSTACLE_SLOTS, STAGE_SIZE, obstacle_params, obstacle_rows,
                                                    stage_heights, stage_obstacle_params)
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.obstacles import (Obstacle, intrusion_m, keep_out_radius_m, nearest_keep_outs, obstacles_from,
                                           push_clear, push_out, towards)

TRUNK = Obstacle(0.0, 0.0, 0.15, 0.0, 2.2)
CROWN = Obstacle(0.0, 0.0, 1.3, 1.75, 4.75)


def test_keep_out_radius_grows_by_a_round_clearance():
    # beside the trunk's band: radius + clearance; 0.8 m over its top: + sqrt(1 - 0.64); 1.1 m over: none
    assert keep_out_radius_m(TRUNK, 1.6, 1.0) == pytest.approx(1.15)
    assert keep_out_radius_m(TRUNK, 3.0, 1.0) == pytest.approx(0.15 + 0.6)
    assert keep_out_radius_m(TRUNK, 3.3, 1.0) is None
    # 0.15 m under the crown's band: nearly the whole clearance; 1 m under: the radius alone
    assert keep_out_radius_m(CROWN, 1.6, 1.0) == pytest.approx(1.3 + math.sqrt(1 - 0.15 ** 2))
    assert keep_out_radius_m(CROWN, 0.75, 1.0) == pytest.approx(1.3) and keep_out_radius_m(CROWN, 0.7, 1.0) is None


def test_intrusion_is_the_clearance_left_unkept():
    # bark 0.45 - 0.15 = 0.30 m from the lens with a 1 m clearance: 0.70 m inside
    assert intrusion_m([TRUNK], (0.45, 0.0, 1.6), 1.0) == pytest.approx(0.70)
    assert intrusion_m([TRUNK], (2.0, 0.0, 1.6), 1.0) == pytest.approx(-0.85)  # kept, by 0.85 m
    assert intrusion_m([TRUNK], (0.45, 0.0, 3.3), 1.0) == -math.inf  # over the trunk's top by more than 1 m


def test_push_out_moves_radially_to_the_distance():
    out = push_out([Obstacle(0, 0, 0.5, 0, 2)], (0.3, 0.4, 1.0), 1.0)
    np.testing.assert_allclose(out, (0.9, 1.2, 1.0))  # radius 1.5 along (0.6, 0.8)
    np.testing.assert_allclose(push_out([Obstacle(0, 0, 0.5, 0, 2)], (0.0, 0.0, 1.0), 1.0), (1.5, 0.0, 1.0))
    np.testing.assert_allclose(push_out([Obstacle(0, 0, 0.5, 0, 2)], (3.0, 0.0, 1.0), 1.0), (3.0, 0.0, 1.0))


def test_nearest_keep_outs_within_reach_without_the_ones_inside():
    far = Obstacle(5.0, 0.0, 0.25, 0.0, 4.0)
    near = Obstacle(-2.0, 0.0, 0.25, 0.0, 4.0)
    high = Obstacle(1.0, 0.0, 0.25, 10.0, 12.0)
    got = nearest_keep_outs([far, TRUNK, CROWN, near, high], (0.5, 0.0, 1.6), clearance_m=1.0, reach_m=3.0, count=3)
    # crown keep-out 2.289 m (0.5 from its axis: 1.79 inside), trunk 1.15 (inside the crown's circle: left out),
    # near 1.25 m round an axis 2.5 away (1.25 beyond), far 3.25 beyond (out of reach), high: 8.4 m over
    assert [k for k, _ in got] == [CROWN, near]
    assert [r for _, r in got] == pytest.approx([1.3 + math.sqrt(1 - 0.15 ** 2), 1.25])
    assert nearest_keep_outs([far, near], (0.5, 0.0, 1.6), clearance_m=1.0, reach_m=9.0, count=1) == [(near, 1.25)]


def test_settings_spelling_is_checked():
    assert obstacles_from([[1, 2, 0.5, 0, 3]]) == (Obstacle(1.0, 2.0, 0.5, 0.0, 3.0),)
    assert Obstacle(1.0, 2.0, 0.5, 0.0, 3.0).as_list() == [1.0, 2.0, 0.5, 0.0, 3.0]
    for bad in ([1, 2, 0.5, 0], [1, 2, 0, 0, 3], [1, 2, 0.5, 3, 3], [1, 2, math.nan, 0, 3], "1,2,3,4,5"):
        with pytest.raises(ConfigError, match=r"obstacles_m\[0\]"):
            obstacles_from([bad])
    with pytest.raises(ConfigError, match="obstacles_m"):
        pc.replace(pc.PlannerConfig(), obstacles_m=((1.0, 2.0, -1.0, 0.0, 3.0),)).validate()


def test_courtyard_obstacles_are_its_pillars_trunks_and_crowns():
    obs = scene_obstacles(load_scene("courtyard"))
    # six pillars (0.5 m wide, 4 m tall) and three trees (a trunk and the crown's slices); no box (walls, van)
    assert len(obs) == 6 + 3 * (1 + CROWN_SLICES) and CROWN_SLICES == 24
    assert Obstacle(-2.0, 4.5, 0.25, 0.0, 4.0) in obs
    # tree_3: trunk 0.3 m wide, 2.2 m tall; crown 2.6 m wide, 3 m tall, centred 0.35 x 3 m above the trunk's top
    assert Obstacle(-6.0, -9.0, 0.15, 0.0, 2.2) in obs
    assert len([o for o in obs if (o.x_m, o.y_m) == (-6.0, -9.0)]) == 1 + CROWN_SLICES
    crown = crown_slices((-6.0, -9.0, 2.2 + 1.05), (1.3, 1.3, 1.5), 6)
    assert [o.z_min_m for o in crown] == pytest.approx([1.75, 2.25, 2.75, 3.25, 3.75, 4.25])
    assert crown[-1].z_max_m == pytest.approx(4.75)
    # each slice as wide as the ellipsoid at its band's edge nearest the centre (3.25 m): 1.0, 0.5, 0, 0, 0.5, 1.0 m
    widths = [1.3 * math.sqrt(1 - (g / 1.5) ** 2) for g in (1.0, 0.5, 0.0, 0.0, 0.5, 1.0)]
    assert [o.radius_m for o in crown] == pytest.approx(widths)
    assert scene_obstacles(load_scene("open_country")) == ()


def test_planner_rows_are_the_distance_past_radius_and_clearance():
    params = np.zeros(3 * N_OBSTACLE_SLOTS)
    params[0:3] = (0.0, 0.0, 1.5)  # a 0.5 m cylinder with a 1 m clearance; the other slots empty
    rows = np.asarray(obstacle_rows(np.array([3.0, 4.0]), np.zeros(N_OBSTACLE_SLOTS), params)).ravel()
    assert rows[0] == pytest.approx(math.sqrt(25 + 1e-4) - 1.5)
    assert np.all(rows[1:] > 0)  # an empty slot holds everywhere
    rows = np.asarray(obstacle_rows(np.array([0.6, 0.8]), np.array([0.5] + [0.0] * (N_OBSTACLE_SLOTS - 1)),
                                    params)).ravel()
    assert rows[0] == pytest.approx(math.sqrt(1 + 1e-4) + 0.5 - 1.5)  # short by 0.5, the slack makes it up


def test_planner_slots_hold_the_nearest_with_the_clearance():
    obs = scene_obstacles(load_scene("courtyard"))
    p = obstacle_params(obs, (-6.5, -9.2, 1.6), clearance_m=1.0, reach_m=3.0)
    # tree_3's crown slice 2.125-2.25 m (0.525 m over the camera, 1 m under the crown's centre): the widest
    # keep-out there, 1.82 m; the other slices and the trunk (1.15) lie inside it; no pillar's keep-out within 3 m
    np.testing.assert_allclose(p[:3], (-6.0, -9.0, 1.3 * math.sqrt(1 - (1.0 / 1.5) ** 2) + math.sqrt(1 - 0.525 ** 2)))
    np.testing.assert_array_equal(p[3:], 0.0)


def test_stage_heights_are_the_last_plan_at_each_stage_time():
    plan_z = [1.0, 1.2, 1.4, 1.6]  # 0.1 s apart: 0.0-0.3 s
    # 0.05 s after it, stages 1-4 lie at 0.15, 0.25, 0.35, 0.45 s: halfway twice, then held at its last
    np.testing.assert_allclose(stage_heights(plan_z, 0.1, 0.05, 4, 9.0), [1.3, 1.5, 1.6, 1.6])
    np.testing.assert_allclose(stage_heights(None, 0.1, 0.0, 3, 1.6), [1.6, 1.6, 1.6])  # no plan: the measured
    for jump in (-0.01, 0.31):  # a clock that jumped outside the plan: the measured height, as the solve forgets it
        np.testing.assert_allclose(stage_heights(plan_z, 0.1, jump, 2, 1.7), [1.7, 1.7])


def test_each_stage_holds_the_keep_outs_at_its_own_height():
    obs = scene_obstacles(load_scene("courtyard"))
    p = stage_obstacle_params(obs, (-6.5, -9.2, 1.6), [1.6, 2.1, 6.0], clearance_m=1.0, reach_m=3.0)
    assert p.shape == (3, STAGE_SIZE)
    # at 1.6 m the slice 2.125-2.25 m, as obstacle_params at the measured height (1.82 m)
    np.testing.assert_array_equal(p[0], obstacle_params(obs, (-6.5, -9.2, 1.6), clearance_m=1.0, reach_m=3.0))
    # at 2.1 m (a climb of 0.5 m under tree_3's crown): the slice 2.5-2.625 m, 0.4 m over the camera and 0.625 m
    # under the centre, is the widest keep-out: 1.3 sqrt(1 - (0.625/1.5)^2) + sqrt(1 - 0.4^2) = 2.098 m
    want = 1.3 * math.sqrt(1 - (0.625 / 1.5) ** 2) + math.sqrt(1 - 0.4 ** 2)
    np.testing.assert_allclose(p[1, :3], (-6.0, -9.0, want))
    assert want == pytest.approx(2.098, abs=1e-3)
    # 6.0 m is 1.25 m over the crown's top (4.75 m), past the clearance: nothing there
    np.testing.assert_array_equal(p[2], 0.0)
    np.testing.assert_array_equal(p[:2, 3:], 0.0)  # no pillar's keep-out within 3 m at any height


def test_a_far_obstacle_is_out_of_reach_at_every_height():
    # axis 5 m away, r 1 + c 1 at most: 3 m from its keep-out; a 2.9 m reach never holds it, 3.0 does
    far = [Obstacle(5.0, 0.0, 1.0, 0.0, 3.0)]
    np.testing.assert_array_equal(stage_obstacle_params(far, (0, 0, 1), [1.0, 2.0], clearance_m=1.0, reach_m=2.9),
                                  0.0)
    # with 3.0: held at 1.0 m (5 - 2 = 3); at 3.5 m, 0.5 over its top, the keep-out is 1 + sqrt(0.75) = 1.87 m,
    # 3.13 m away: out of reach at that stage
    p = stage_obstacle_params(far, (0, 0, 1), [1.0, 3.5], clearance_m=1.0, reach_m=3.0)
    np.testing.assert_allclose(p[:, :3], [(5.0, 0.0, 2.0), (0.0, 0.0, 0.0)])


def test_bridge_counts_the_measured_vehicle_in_a_keep_out_as_a_breach():
    cfg = SafetyConfig(obstacles_m=((10.0, 0.0, 0.15, 0.0, 2.2),), min_obstacle_distance_m=1.0,
                       breach_tolerance_m=0.25, breach_return_margin_m=1.0)
    # bark 0.30 m away: 0.70 inside the clearance, beyond the 0.25 tolerance; 0.9 m away: 0.10 inside, tolerated
    assert envelope_breach(np.array([10.45, 0.0, 1.6]), cfg)
    assert not envelope_breach(np.array([11.05, 0.0, 1.6]), cfg)
    # flown back to the clearance plus the return margin (2 m, round: 0.3 m over the trunk's top), radially
    np.testing.assert_allclose(return_point(np.array([10.45, 0.0, 2.5]), cfg),
                               (10.0 + 0.15 + math.sqrt(4 - 0.3 ** 2), 0.0, 2.5))
    # out of the breach only once half the margin beyond the clearance (as at the geofence)
    assert envelope_breach(np.array([11.55, 0.0, 1.6]), cfg, tol_m=-0.5)
    assert not envelope_breach(np.array([11.70, 0.0, 1.6]), cfg, tol_m=-0.5)
    assert SafetyConfig(obstacles_m=([1, 2, 0.5, 0, 3],)).obstacles_m == ((1.0, 2.0, 0.5, 0.0, 3.0),)


def test_the_transfer_gives_planner_and_bridge_the_scene_obstacles(tmp_path):
    """One derivation, handed to both nodes through the deploy config; the planner imports no simulator."""
    import argparse

    from cinetransfer.job import deploy_config
    from cinetransfer.services.autopilot_bridge import service as bridge
    from cinetransfer.services.planner import service as planner

    cfg = deploy_config(tmp_path, 7447, "rig", "courtyard", extraction=False)
    ap = argparse.ArgumentParser()
    planner.add_config_arguments(ap)
    p = planner.config_from_args(ap.parse_args(["--config", str(cfg)]))
    b = bridge.config_from_args(bridge.build_parser().parse_args(["--config", str(cfg)])).safety
    want = tuple(tuple(o.as_list()) for o in scene_obstacles(load_scene("courtyard")))
    assert p.obstacles_m == b.obstacles_m == want and len(want) == 81
    assert p.bounds.min_obstacle_distance_m == b.min_obstacle_distance_m == 1.0
    assert "*id" not in cfg.read_text()  # written out in full for each node, no YAML alias


def test_push_clear_pushes_again_out_of_a_neighbour_or_says_it_cannot():
    a, b = Obstacle(0.0, 0.0, 0.5, 0.0, 3.0), Obstacle(1.8, 0.0, 0.5, 0.0, 3.0)
    # one keep-out (0.5 + 0.5 = 1.0): straight out to its ring, clear at once
    p, ok = push_clear([a], (0.5, 0.0, 1.0), 0.5)
    assert ok
    np.testing.assert_allclose(p, (1.0, 0.0, 1.0))
    # on the line between two keep-outs 1.8 m apart: out of a to x 1.0 is 0.8 inside b, out of b back to 0.8,
    # 0.2 inside a, and so on: no pass clears it
    p, ok = push_clear([a, b], (0.5, 0.0, 1.0), 0.5)
    assert not ok and intrusion_m([a, b], p, 0.5) > 0.1
    # off the line the pushes climb out of the overlap: clear of both
    p, ok = push_clear([a, b], (0.5, 0.3, 1.0), 0.5)
    assert ok and intrusion_m([a, b], p, 0.5) <= 1e-9 and p[1] > 0.3


def test_bridge_pushes_a_setpoint_out_of_every_keep_out_or_refuses_it():
    from cinetransfer.services.autopilot_bridge.safety import SafetyLayer
    from cinetransfer.shared import messages as M

    def sp(pos):
        return M.Setpoint(stamp_ns=1, position_m=np.array(pos), velocity_mps=np.zeros(3),
                          acceleration_mps2=np.zeros(3), camera_ypr_rad=np.zeros(3), lens=M.LensState())

    trunk = (5.0, 0.0, 0.15, 0.0, 2.2)
    cfg = SafetyConfig(obstacles_m=(trunk,), min_obstacle_distance_m=1.0, geofence_radius_m=50.0,
                       altitude_min_m=1.0, altitude_max_m=20.0)
    s = SafetyLayer(cfg)
    # a setpoint 0.35 m from the trunk's axis goes out radially to 0.15 + 1.0
    r = s.check(sp((5.35, 0.0, 1.5)))
    assert r.accepted and s.counters["clamp_obstacle"] == 1
    np.testing.assert_allclose(r.setpoint.position_m, (6.15, 0.0, 1.5))
    # between two trunks whose keep-outs overlap on the line: no clear point there, refused
    s2 = SafetyLayer(SafetyConfig(obstacles_m=(trunk, (6.5, 0.0, 0.15, 0.0, 2.2)), min_obstacle_distance_m=1.0,
                                  geofence_radius_m=50.0, altitude_min_m=1.0, altitude_max_m=20.0))
    r2 = s2.check(sp((5.8, 0.0, 1.5)))
    assert not r2.accepted and s2.counters["sp_rejected_subject_conflict"] == 1


def test_a_return_point_between_two_keep_outs_clears_both():
    cfg = SafetyConfig(obstacles_m=((0.0, 0.0, 0.5, 0.0, 3.0), (1.8, 0.0, 0.5, 0.0, 3.0)),
                       min_obstacle_distance_m=0.5, breach_return_margin_m=0.0, geofence_radius_m=50.0,
                       home_m=(0.0, 0.0, 0.0), altitude_min_m=1.0, altitude_max_m=20.0)
    q = return_point(np.array([0.5, 0.3, 1.5]), cfg)
    obstacles = obstacles_from(cfg.obstacles_m)
    assert intrusion_m(obstacles, q, 0.5) <= 1e-9


def test_towards_is_the_way_to_the_obstacles_own_cylinder():
    # beside the crown's band, 1 m out from its side and 0.75 m under it: 1.25 m along (-0.8, 0, 0.6)
    n, d = towards(CROWN, (2.3, 0.0, 1.0))
    assert n == pytest.approx((-0.8, 0.0, 0.6)) and d == pytest.approx(1.25)
    n, d = towards(CROWN, (0.0, 0.0, 0.5))  # on its axis, under it: straight up
    assert n == pytest.approx((0.0, 0.0, 1.0)) and d == pytest.approx(1.25)
    assert towards(TRUNK, (0.1, 0.0, 1.0)) == ((0.0, 0.0, 0.0), 0.0)  # inside the trunk itself


#: a trunk and a crown apart, braking at 2 m/s^2 from 4 m/s: keep-outs within 4 m of a position bound it
_BRAKE = dict(min_obstacle_distance_m=1.0, accel_max_mps2=2.0, speed_max_mps=4.0, climb_max_mps=4.0,
              geofence_radius_m=50.0, altitude_min_m=0.0, altitude_max_m=20.0)


def test_bridge_cuts_the_velocity_into_a_keep_out_to_the_braking_speed():
    from cinetransfer.services.autopilot_bridge.safety import clamp_outward_velocity

    cfg = SafetyConfig(obstacles_m=(TRUNK.as_list(),), **_BRAKE)
    # 2 m from the trunk's keep-out (bark 3 m away): at most sqrt(2 x 2 x 2) m/s towards it; sideways untouched
    v, hit = clamp_outward_velocity(np.array([3.15, 0.0, 1.6]), np.array([-3.0, 1.0, 0.0]), cfg)
    assert hit and v == pytest.approx((-math.sqrt(8.0), 1.0, 0.0))
    # at the keep-out's edge: nothing towards it; away from it: untouched
    v, hit = clamp_outward_velocity(np.array([1.15, 0.0, 1.6]), np.array([-1.0, 0.5, 0.0]), cfg)
    assert hit and v == pytest.approx((0.0, 0.5, 0.0))
    v, hit = clamp_outward_velocity(np.array([1.15, 0.0, 1.6]), np.array([1.0, 0.5, 0.0]), cfg)
    assert not hit and v == pytest.approx((1.0, 0.5, 0.0))
    # 8.85 m from it, beyond the 4 m braking distance at full speed: untouched
    v, hit = clamp_outward_velocity(np.array([10.0, 0.0, 1.6]), np.array([-4.0, 0.0, 0.0]), cfg)
    assert not hit


def test_bridge_cuts_a_climb_into_a_crown_overhead():
    from cinetransfer.services.autopilot_bridge.safety import clamp_outward_accel, clamp_outward_velocity

    cfg = SafetyConfig(obstacles_m=(CROWN.as_list(),), **_BRAKE)
    # on the axis 1.25 m under the crown: 0.25 m under its keep-out, climbing at most sqrt(2 x 2 x 0.25) = 1 m/s
    v, hit = clamp_outward_velocity(np.array([0.0, 0.0, 0.5]), np.array([0.3, 0.0, 1.5]), cfg)
    assert hit and v == pytest.approx((0.3, 0.0, 1.0))
    # beside and under its band, along (-0.8, 0, 0.6) 1.25 m from it: 1.4 m/s towards it cut to 1, by 0.4 along that
    v, hit = clamp_outward_velocity(np.array([2.3, 0.0, 1.0]), np.array([-1.0, 0.0, 1.0]), cfg)
    assert hit and v == pytest.approx((-1.0 + 0.32, 0.0, 1.0 - 0.24))
    # the acceleration towards it is left to the velocity's bound (only the fence and the band take it away)
    a, hit = clamp_outward_accel(np.array([2.3, 0.0, 1.0]), np.array([-1.0, 0.5, 0.5]), cfg)
    assert not hit and a == pytest.approx((-1.0, 0.5, 0.5))


def test_bridge_setpoints_and_ticks_do_not_move_into_a_keep_out():
    from cinetransfer.services.autopilot_bridge.safety import SafetyLayer
    from cinetransfer.shared import messages as M

    s = SafetyLayer(SafetyConfig(obstacles_m=(TRUNK.as_list(),), **_BRAKE))
    sp = M.Setpoint(stamp_ns=1, position_m=np.array([0.35, 0.0, 1.6]), velocity_mps=np.array([-1.0, 0.5, 0.0]),
                    acceleration_mps2=np.array([-1.0, 0.0, 0.0]), camera_ypr_rad=np.zeros(3), lens=M.LensState())
    # pushed out to the keep-out's edge at 1.15 m: no velocity towards the trunk is forwarded
    r = s.check(sp)
    assert r.accepted and r.setpoint.position_m == pytest.approx((1.15, 0.0, 1.6))
    assert r.setpoint.velocity_mps == pytest.approx((0.0, 0.5, 0.0))
    assert s.counters["clamp_velocity_outward"] == 1
    # a tick's commanded position 1 m from the keep-out: at most sqrt(2 x 2 x 1) = 2 m/s towards it
    mc = s.limit_motion(target_pos=np.array([2.15, 0.0, 1.6]), target_vel=np.array([-3.0, 0.0, 0.0]),
                        prev_pos=np.array([2.15, 0.0, 1.6]), prev_vel=np.array([-3.0, 0.0, 0.0]), dt_s=0.01)
    assert mc.velocity_mps == pytest.approx((-2.0, 0.0, 0.0)) and "clamp_velocity_outward" in mc.clamps
