"""Keep-out obstacles: the cylinders' geometry (shared/obstacles.py), a scene's own (sim/obstacles.py), the
planner's soft constraint (planner/obstacles.py) and the bridge's envelope check, against hand-computed values."""
import math

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.services.autopilot_bridge.safety import envelope_breach, return_point
from cinetransfer.services.autopilot_bridge.sim.obstacles import scene_obstacles
from cinetransfer.services.autopilot_bridge.sim.scene import load_scene
from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.obstacles import N_OBSTACLE_SLOTS, obstacle_params, obstacle_rows
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.obstacles import (Obstacle, covers_height, intrusion_m, nearest_obstacles, obstacles_from,
                                           push_out, surface_distance_m)

TRUNK = Obstacle(0.0, 0.0, 0.15, 0.0, 2.2)
CROWN = Obstacle(0.0, 0.0, 1.3, 1.75, 4.75)


def test_surface_distance_is_horizontal_and_negative_inside():
    assert surface_distance_m(Obstacle(0, 0, 0.5, 0, 1), (3.0, 4.0, 99.0)) == pytest.approx(4.5)
    assert surface_distance_m(Obstacle(1, 1, 0.5, 0, 1), (1.0, 1.2)) == pytest.approx(-0.3)


def test_height_band_counts_within_the_clearance():
    # a camera at 1.6 m flies 0.15 m under the crown: within a 1 m clearance it counts, at 0.7 m it does not
    assert covers_height(CROWN, 1.6, 1.0) and covers_height(CROWN, 0.75, 1.0) and not covers_height(CROWN, 0.7, 1.0)
    assert covers_height(CROWN, 5.75, 1.0) and not covers_height(CROWN, 5.8, 1.0)


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


def test_nearest_obstacles_by_surface_within_reach_without_the_ones_inside():
    far = Obstacle(5.0, 0.0, 0.25, 0.0, 4.0)
    near = Obstacle(-2.0, 0.0, 0.25, 0.0, 4.0)
    high = Obstacle(1.0, 0.0, 0.25, 10.0, 12.0)
    got = nearest_obstacles([far, TRUNK, CROWN, near, high], (0.5, 0.0, 1.6), clearance_m=1.0, reach_m=4.0, count=3)
    # crown surface -0.8, trunk 0.2 (inside the crown's circle: left out), near 2.25, far 4.25 (beyond reach)
    assert got == [CROWN, near]
    assert nearest_obstacles([far, near], (0.5, 0.0, 1.6), clearance_m=1.0, reach_m=9.0, count=1) == [near]


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
    # six pillars (0.5 m wide, 4 m tall) and three trees (trunk + crown); no box (walls, van) gives one
    assert len(obs) == 12
    assert Obstacle(-2.0, 4.5, 0.25, 0.0, 4.0) in obs
    # tree_3: trunk 0.3 m wide, 2.2 m tall; crown 2.6 m wide, 3 m tall, centred 0.35 x 3 m above the trunk's top
    assert Obstacle(-6.0, -9.0, 0.15, 0.0, 2.2) in obs
    crown = next(o for o in obs if (o.x_m, o.y_m, o.radius_m) == (-6.0, -9.0, 1.3))
    assert (crown.z_min_m, crown.z_max_m) == pytest.approx((2.2 + 1.05 - 1.5, 2.2 + 1.05 + 1.5))
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
    p = obstacle_params(obs, (-6.5, -9.2, 1.6), clearance_m=1.0, reach_m=4.0)
    # tree_3's crown (its trunk is inside it); no pillar within 4 m of the camera's surface distance
    np.testing.assert_allclose(p[:3], (-6.0, -9.0, 2.3))
    np.testing.assert_array_equal(p[3:], 0.0)


def test_bridge_counts_the_measured_vehicle_in_a_keep_out_as_a_breach():
    cfg = SafetyConfig(obstacles_m=((10.0, 0.0, 0.15, 0.0, 2.2),), min_obstacle_distance_m=1.0,
                       breach_tolerance_m=0.25, breach_return_margin_m=1.0)
    # bark 0.30 m away: 0.70 inside the clearance, beyond the 0.25 tolerance; 0.9 m away: 0.10 inside, tolerated
    assert envelope_breach(np.array([10.45, 0.0, 1.6]), cfg)
    assert not envelope_breach(np.array([11.05, 0.0, 1.6]), cfg)
    # flown back to the clearance plus the return margin, radially: 0.15 + 1 + 1 = 2.15 m from the axis
    np.testing.assert_allclose(return_point(np.array([10.45, 0.0, 2.5]), cfg), (12.15, 0.0, 2.5))
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
    assert p.obstacles_m == b.obstacles_m == want and len(want) == 12
    assert p.bounds.min_obstacle_distance_m == b.min_obstacle_distance_m == 1.0
    assert "*id" not in cfg.read_text()  # written out in full for each node, no YAML alias
