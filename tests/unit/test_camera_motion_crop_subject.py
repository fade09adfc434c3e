"""benchmarks/camera_motion_crop_subject.py: the walker moving as a crop source's person moved,
checked against hand-computed places and against the simulator's own script."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def cs():
    return load_benchmark("camera_motion_crop_subject")


def test_crop_pixels_go_back_through_the_inverse_homography(cs):
    # a crop that halves the source and shifts it by (10, 20): crop = 0.5 * source + (10, 20)
    h = np.array([[0.5, 0.0, 10.0], [0.0, 0.5, 20.0], [0.0, 0.0, 1.0]])
    back = cs.crop_to_source(np.array([[10.0, 20.0], [60.0, 70.0]]), h)
    assert back == pytest.approx(np.array([[0.0, 0.0], [100.0, 100.0]]))


def test_person_track_is_the_joints_centre_and_torso_in_the_source(cs):
    # shoulders at y 0.25, hips at y 0.75 of a 200 x 100 crop that is the source scaled by 0.5
    h = np.diag([0.5, 0.5, 1.0])
    joints = np.array([[[0.4, 0.25], [0.6, 0.25], [0.4, 0.75], [0.6, 0.75]]])
    centre, torso = cs.person_track(joints, [h], (200, 100))
    # crop px: x 80/120, y 25/75 -> source px doubled: centre (200, 100), torso 100
    assert centre[0] == pytest.approx([200.0, 100.0]) and torso[0] == pytest.approx(100.0)


def test_person_track_bridges_joints_the_style_leaves_out(cs):
    h = np.eye(3)
    full = [[0.4, 0.25], [0.6, 0.25], [0.4, 0.75], [0.6, 0.75]]
    no_shoulder = [[np.nan, np.nan], [0.6, 0.25], [0.4, 0.75], [0.6, 0.75]]
    nothing = [[np.nan, np.nan]] * 4
    joints = np.array([full, no_shoulder, nothing, [[x + 0.1, y] for x, y in full]])
    centre, torso = cs.person_track(joints, [h] * 4, (100, 100))
    # one shoulder left: the centre of the three others (46.67, 58.33), the torso from it to the hips' mid
    assert centre[1] == pytest.approx([160 / 3, 175 / 3]) and torso[1] == pytest.approx(math.hypot(10.0, 50.0))
    # no joint: halfway between its neighbours
    assert centre[2] == pytest.approx([(160 / 3 + 60.0) / 2, (175 / 3 + 50.0) / 2])
    assert torso[2] == pytest.approx((math.hypot(10.0, 50.0) + 50.0) / 2)


def test_camera_frame_path_places_the_person_by_his_torso(cs):
    # a 1000 px wide source of 62 deg: f = 500 / tan(31 deg) = 832.1 px; a 0.5 m torso 83.21 px long
    # stands 5 m away; 100 px right of the centre column he is 100 / 832.1 * 5 = 0.6009 m right
    f = 500.0 / math.tan(math.radians(31.0))
    torso = np.array([f * 0.5 / 5.0] * 3)
    centre = np.array([[499.5, 0.0], [549.5, 0.0], [599.5, 0.0]])
    path = cs.camera_frame_path(centre, torso, (1000, 600))
    assert path == pytest.approx(np.array([[0.0, 0.0], [0.3004, 0.0], [0.6009, 0.0]]), abs=1e-4)
    # his torso 83.21, 124.8, 166.4 px on the median line: he comes from 5 m to 3.333 m to 2.5 m
    grow = np.array([f * 0.1, f * 0.15, f * 0.2])
    fit = grow
    depth = cs.camera_frame_path(centre[:1].repeat(3, 0), grow, (1000, 600))[:, 1]
    assert depth == pytest.approx(f * 0.5 / fit - f * 0.5 / fit[0])
    # filmed from 8.572 m (twice the source's 4.286 m) he comes twice as far to grow by as much
    far = cs.camera_frame_path(centre[:1].repeat(3, 0), grow, (1000, 600), distance_m=2 * f * 0.5 / fit[0])
    assert far[:, 1] == pytest.approx(2 * depth) and far[:, 0] == pytest.approx(0.0)


def test_median_line_ignores_a_wild_sample(cs):
    # 150 + 2k px on nine rows but the first read 100: slopes from it are 52, 27, ...; the median of
    # the 36 pairs' slopes is 2, the line through the rest 150 + 2k
    v = 150.0 + 2.0 * np.arange(9)
    v[0] = 100.0
    assert cs.median_line(v) == pytest.approx(150.0 + 2.0 * np.arange(9))


def test_knots_average_round_each_knot_and_keep_the_ends(cs):
    path = np.c_[np.arange(10.0), np.zeros(10)]
    idx, pts = cs.knots(path, every=4)
    # knots at frames 0, 4, 8 and the last (9); 4 is the mean of frames 2-6, 8 of 7-9 (narrowed at the
    # end), the ends are the path's own
    assert list(idx) == [0, 4, 8, 9] and pts[:, 0] == pytest.approx([0.0, 4.0, 8.0, 9.0])


def test_world_axes_right_of_a_camera_looking_along_x_is_minus_y(cs):
    right, fwd = cs.world_axes((-5.0, 0.0), (0.0, 0.0))
    assert right == pytest.approx([0.0, -1.0]) and fwd == pytest.approx([1.0, 0.0])


def test_walk_script_waits_then_reaches_each_knot_on_time(cs):
    places = np.array([[0.0, 0.0], [0.5, 0.0], [0.505, 0.0], [0.5, 1.0]])
    steps = cs.walk_script(places[0], places, np.array([0, 6, 12, 18]), 24.0, wait_s=3.0)
    assert steps[0] == {"action": "walk", "path_m": [[0.0, 0.0]], "speed_mps": 1.0, "duration_s": 3.0}
    # 0.5 m in 6 frames = 0.25 s: 2 m/s; then 5 mm is stood for its 0.25 s; then 1 m in 0.25 s
    assert steps[1] == {"action": "walk", "path_m": [[0.5, 0.0]], "speed_mps": 2.0}
    assert steps[2] == {"action": "walk", "path_m": [[0.5, 0.0]], "speed_mps": 1.0, "duration_s": 0.25}
    assert steps[3]["path_m"] == [[0.5, 1.0]] and steps[3]["speed_mps"] == pytest.approx(4.0)


def test_the_scene_walker_is_where_the_crop_person_was(cs, tmp_path):
    # given a static crop source (the crop is the source scaled, never moving) whose person's joints
    # slide right by 0.02 of the crop's width a frame, torso constant
    from benchmarks.camera_motion_sources import CLIPS, MOVES
    from cinetransfer.services.autopilot_bridge.sim.scene import load_scene
    from cinetransfer.services.autopilot_bridge.sim.subject import SubjectScript

    static = next(m for m in MOVES if m.name == "static")
    clip, (w, h) = CLIPS[0]
    truth = {"name": static.name, "origin": f"crop of {clip} from frame 0", "fps": 24.0, "frames": 25}
    x = 0.02 * np.arange(25)[:, None]
    targets = np.stack([np.c_[0.45 + x, 0.3 + 0 * x], np.c_[0.55 + x, 0.3 + 0 * x],
                        np.c_[0.45 + x, 0.6 + 0 * x], np.c_[0.55 + x, 0.6 + 0 * x]], axis=1)
    style = tmp_path / "style.json"
    style.write_text(json.dumps({"instructions": {"source": {"width": w, "height": h},
                                                  "image_targets": targets.tolist()}}))
    # (laid across the view from the drone's start: no pass flown to find where it settles)
    scene = load_scene(str(cs.write_crop_scene(tmp_path / "scene.yaml", truth, style, wait_s=4.0, passes=0)))
    script = SubjectScript(scene.subject)
    # then the juggler stands on his mark, and then where the source's person stood, to the camera's right
    assert scene.subject.clip == "juggler" and np.linalg.norm(script.pose_at(2.0).velocity_mps) == 0.0
    homs, _ = cs.crop_homographies(truth, (w, h))
    scale = homs[0][0, 0]  # crop px per source px
    torso_src = 0.3 * h / scale
    metres_per_src_px = cs.TORSO_M / torso_src
    # 24 frames at 0.02 crop widths a frame: 0.48 * w crop px -> source px -> metres (depth constant)
    expect = 0.48 * w / scale * metres_per_src_px
    right, _ = cs.world_axes(tuple(load_scene("open_country").vehicle.position_m[:2]), (0.0, 0.0))
    here = np.asarray(script.pose_at(4.0).position_m[:2])
    moved = np.asarray(script.pose_at(4.0 + 24.5 / 24.0).position_m[:2]) - here
    assert moved == pytest.approx(expect * right, abs=1e-3)
