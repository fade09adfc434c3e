"""How far behind the subject a bundled scene's background stands (cinetransfer/scene_background.py)."""
import math
from types import SimpleNamespace as NS

import pytest

from cinetransfer.scene_background import background_behind_m
from cinetransfer.services.autopilot_bridge.sim.scene import load_scene


def _scene(layers=(), objects=(), camera=(-7.0, 0.0, 1.0), subject=(0.0, 0.0)):
    return NS(subject=NS(start_m=subject), vehicle=NS(position_m=camera), layers=tuple(layers), objects=tuple(objects))


def test_focus_hedge_background_is_the_trees_30_m_behind():
    # the juggler starts at the origin, the camera at x = -7 m, the trees and building stand at x = 30 m
    assert background_behind_m(load_scene("focus_hedge")) == pytest.approx(30.0)


def test_nearest_background_in_view_counts():
    wall = NS(region="background", facing="fixed", position_m=(20.0, 0.0))
    behind_camera = NS(region="background", facing="fixed", position_m=(-20.0, 0.0))
    far_aside = NS(region="background", facing="fixed", position_m=(5.0, 12.0))  # 67 deg off the line of sight
    hedge = NS(region="foreground", facing="fixed", position_m=(3.0, 0.0))
    sky = NS(region="sky", facing="camera", position_m=(0.0, 0.0))
    tree = NS(position_m=(12.0, 3.0))
    assert background_behind_m(_scene([wall, behind_camera, far_aside, hedge, sky])) == pytest.approx(20.0)
    assert background_behind_m(_scene([wall], [tree])) == pytest.approx(12.0)
    assert math.isinf(background_behind_m(_scene([behind_camera, hedge, sky])))
    assert math.isinf(background_behind_m(_scene([wall], subject=(-7.0, 0.0))))  # camera on the subject
