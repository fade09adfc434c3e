"""benchmarks/camera_motion_mark.py: the courtyard's walker waiting on his mark, checked against
hand-computed points of his loop and against the simulator's own script."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import load_benchmark

LOOP = [[[0.0, 2.0]], [[3.0, 2.0], [3.0, -2.0], [0.0, -2.0]]]


@pytest.fixture(scope="module")
def mk():
    return load_benchmark("camera_motion_mark")


def test_path_after_a_distance_starts_on_the_leg_reached(mk):
    # 1.2 m up the first 4 m leg from (0, -2): (0, -0.8), then every corner still ahead
    assert mk.path_after((0.0, -2.0), LOOP, 1.2) == [[0.0, -0.8], [0.0, 2.0], [3.0, 2.0], [3.0, -2.0], [0.0, -2.0]]
    # 5.5 m: past the 4 m leg, 1.5 m along the 3 m one
    assert mk.path_after((0.0, -2.0), LOOP, 5.5) == [[1.5, 2.0], [3.0, 2.0], [3.0, -2.0], [0.0, -2.0]]
    # the loop is 14 m long: 15.2 m wraps round to 1.2 m
    assert mk.path_after((0.0, -2.0), LOOP, 15.2)[0] == pytest.approx([0.0, -0.8])


def test_mark_subject_waits_then_walks_the_rest(mk):
    subject = {"clip": "walker", "loop": True, "start_m": [0.0, -2.0], "facing_deg": 180,
               "script": [{"action": "walk", "path_m": p, "speed_mps": 1.2} for p in LOOP]}
    out = mk.mark_subject(subject, 1.0, 7.5)
    assert out["start_m"] == [0.0, -0.8] and out["facing_deg"] == pytest.approx(90.0) and out["loop"] is False
    assert out["script"][0] == {"action": "walk", "path_m": [[0.0, -0.8]], "speed_mps": 1.2, "duration_s": 7.5}
    assert out["script"][1]["path_m"][0] == [0.0, 2.0] and out["clip"] == "walker"
    with pytest.raises(ValueError, match="only walks"):
        mk.mark_subject({**subject, "script": [{"action": "stand", "duration_s": 1.0}]}, 1.0, 5.0)


def test_the_marked_walker_is_where_the_sources_film_him(mk, tmp_path):
    # given the scene written for a 4 s wait
    from cinetransfer.services.autopilot_bridge.sim.scene import load_scene
    from cinetransfer.services.autopilot_bridge.sim.subject import SubjectScript
    marked = load_scene(str(mk.write_mark_scene(tmp_path / "scene.yaml", wait_s=4.0)))
    bundled = load_scene("courtyard")
    a, b = SubjectScript(marked.subject), SubjectScript(bundled.subject)
    # then he stands still on his mark until the take and then walks as the bundled walker does 1 s into his loop
    assert np.linalg.norm(a.pose_at(2.0).velocity_mps) == 0.0
    for t in (0.1, 0.5, 1.5):
        assert a.pose_at(4.0 + t).position_m == pytest.approx(b.pose_at(mk.PHASE_S + t).position_m, abs=1e-6)
        assert a.pose_at(4.0 + t).velocity_mps == pytest.approx(b.pose_at(mk.PHASE_S + t).velocity_mps, abs=1e-6)
