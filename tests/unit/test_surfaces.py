"""The scene's known upright surfaces: their settings (shared/surfaces.py), a scene's own
(services/autopilot_bridge/sim/surfaces.py) and the planner's setting."""
from __future__ import annotations

import pytest

from cinetransfer.services.autopilot_bridge.sim.scene import load_scene
from cinetransfer.services.autopilot_bridge.sim.surfaces import scene_surfaces
from cinetransfer.services.planner import config as pc
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.surfaces import Surface, surfaces_from


def test_surfaces_from_their_spelling_and_bad_entries_named():
    assert surfaces_from([[0, -1, 0, 1, 0, 2]]) == (Surface(0.0, -1.0, 0.0, 1.0, 0.0, 2.0),)
    for bad in ([0, 0, 0, 0, 0, 1], [0, -1, 0, 1, 2, 1], [0, -1, 0, 1, 0], [0, -1, 0, 1, 0, float("nan")]):
        with pytest.raises(ConfigError, match=r"surfaces_m\[0\]"):
            surfaces_from([bad])


def test_focus_hedge_hands_its_hedge_and_backdrop_not_its_sky():
    got = scene_surfaces(load_scene("focus_hedge"))
    assert len(got) == 2
    hedge, backdrop = sorted(got, key=lambda s: s.x0_m)
    # the hedge: 1 m high at x = -4, facing the camera's start (-7, 0), across the axis
    assert (hedge.x0_m, hedge.x1_m, hedge.z_min_m, hedge.z_max_m) == pytest.approx((-4.0, -4.0, 0.0, 1.0))
    assert min(hedge.y0_m, hedge.y1_m) < 0 < max(hedge.y0_m, hedge.y1_m)
    # the backdrop: its 160 x 10 m quad at x = 30
    assert (backdrop.x0_m, backdrop.x1_m) == pytest.approx((30.0, 30.0))
    assert abs(backdrop.y1_m - backdrop.y0_m) == pytest.approx(160.0)
    assert backdrop.z_max_m - backdrop.z_min_m == pytest.approx(10.0)


def test_the_planner_holds_its_surfaces_checked():
    cfg = pc.PlannerConfig(surfaces_m=[[0, -1, 0, 1, 0, 2]]).validate()
    assert cfg.surfaces_m == ((0.0, -1.0, 0.0, 1.0, 0.0, 2.0),)
    with pytest.raises(ConfigError, match="surfaces_m"):
        pc.PlannerConfig(surfaces_m=[[0, 0, 0, 0, 0, 1]]).validate()


def test_the_transfer_hands_the_planner_its_scenes_surfaces(tmp_path):
    import yaml

    from cinetransfer import job

    path = job.deploy_config(tmp_path, 17999, "rig", "focus_hedge")
    nodes = {n["name"]: n for n in yaml.safe_load(path.read_text())["nodes"]}
    got = nodes["planner"]["settings"]["surfaces_m"]
    assert got == [s.as_list() for s in scene_surfaces(load_scene("focus_hedge"))] and len(got) == 2
    assert nodes["planner"]["settings"]["ground_z_m"] == 0.0
    assert pc.PlannerConfig(surfaces_m=got).validate().surfaces_m == tuple(tuple(s) for s in got)


def test_a_surface_s_flip_is_its_seventh_number():
    s = surfaces_from([[0, -1, 0, 1, 0, 2, 1.27]])[0]
    assert s.flip_circles == 1.27 and s.as_list() == [0.0, -1.0, 0.0, 1.0, 0.0, 2.0, 1.27]
    assert surfaces_from([[0, -1, 0, 1, 0, 2]])[0].flip_circles == 1.0
    for bad in ([0, -1, 0, 1, 0, 2, 0.0], [0, -1, 0, 1, 0, 2, 1.0, 1.0]):
        with pytest.raises(ConfigError):
            surfaces_from([bad])


def test_focus_hedge_s_surfaces_carry_their_textures_measured_flips():
    # the hedge's crisp texture is read soft from 1.27 circles, the lawn backdrop from 1.10 (docs/report.md)
    flips = sorted(s.flip_circles for s in scene_surfaces(load_scene("focus_hedge")))
    assert flips == [1.1, 1.27]
