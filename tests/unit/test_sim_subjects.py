"""Subject library: every person loads, its joints land on its cut-out, the detector finds it.

The detector check renders each subject in each bundled scene (swapped in with
`load_scene(scene, subject=NAME)`, as `--subject` does) at times spread over its whole script, so
every action it does is seen, from a camera that moves sideways (and up, never below the scene's camera height: in
focus_hedge the hedge then hides the legs) and zooms. A frame counts when a
MediaPipe skeleton's median joint distance to the ground-truth joints is < 3 % of the image.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend
from cinetransfer.services.autopilot_bridge.sim.scene import (ASSETS_DIR, SceneError, load_scene, parse_scene,
                                                              scene_names, subject_info, subject_names)
from cinetransfer.services.autopilot_bridge.sim.subject import load_clip

SUBJECTS = ("juggler", "dancer", "runner", "walker")
N_FRAMES = 50


def test_the_library_has_four_different_people_from_four_clips_with_credits():
    assert set(SUBJECTS) <= set(subject_names())
    credits = (ASSETS_DIR / "CREDITS.md").read_text()
    sources = set()
    for name in SUBJECTS:
        clip = load_clip(name)
        info = subject_info(name)
        assert clip.frames and clip.actions and 1.4 < clip.height_m < 2.1
        sources.add(info["source"])
        assert info["source"] in credits and f"`{name}" in credits
        for act in clip.actions.values():
            assert act.frames and all(0 <= i < len(clip.frames) for i in act.frames)
        for fr in clip.frames:
            assert fr.texture.shape[2] == 4 and fr.joints_px.shape == (17, 2)
            h, w = fr.texture.shape[:2]
            # the joints lie on the cut-out (inside it, on opaque pixels for hips and shoulders)
            for j in (5, 6, 11, 12):
                x, y = fr.joints_px[j]
                assert 0 <= x < w and 0 <= y < h
                assert fr.texture[int(y), int(x), 3] > 0, (name, j)
    assert len(sources) == 4
    assert sorted(load_clip("juggler").actions) == ["juggle", "stand"]
    assert sorted(load_clip("dancer").actions) == ["dance", "twirl"]
    assert sorted(load_clip("runner").actions) == ["run", "vault"]
    assert sorted(load_clip("walker").actions) == ["walk"]


def _doc(clip: str, action: str) -> dict:
    return {"name": "t", "vehicle": {"position_m": [-5, 0, 1.5], "lens": {"focal_length_mm": 35,
                                                                          "focus_distance_m": 5, "f_number": 4}},
            "subject": {"clip": clip, "script": [{"action": action, "duration_s": 1.0}]}}


def test_an_action_the_subject_lacks_is_an_error_naming_the_subject_and_its_actions():
    with pytest.raises(SceneError, match=r"subject.script\[0\].action: subject 'dancer' has no action 'juggle'; "
                                         r"its actions: \['dance', 'twirl'\]"):
        parse_scene(_doc("dancer", "juggle"))
    with pytest.raises(SceneError, match=r"subject 'nobody' is not in the library; subjects: \["):
        load_scene("open_country", subject="nobody")


def test_walk_plays_the_gait_at_a_rate_matching_its_stride():
    scene = load_scene("open_country_25d", subject="walker")
    sim = SimBackend(scene, epoch_ns=0, render=False, truth=False)
    sub = sim.renderer.subject
    nat = sub.clip.actions["walk"].speed_mps
    _, fps_nat = sub.playback("walk", nat)
    _, fps_half = sub.playback("walk", nat / 2)
    assert fps_half == pytest.approx(fps_nat / 2)
    # the runner does a 'walk' with its running clip, slowed to the walking speed
    runner = SimBackend(load_scene("open_country_25d", subject="runner"), epoch_ns=0, render=False,
                        truth=False).renderer.subject
    act, fps = runner.playback("walk", 1.2)
    assert act.name == "run" and fps == pytest.approx(act.fps * 1.2 / act.speed_mps)


def test_swapping_the_subject_keeps_the_scene_and_uses_the_persons_height_and_actions():
    a = load_scene("open_country")
    b = load_scene("open_country", subject="runner")
    assert a.subject.clip == "dancer" and b.subject.clip == "runner"
    assert b.subject.height_m == pytest.approx(load_clip("runner").height_m)
    assert {s.action for s in b.subject.script} <= {"run", "vault", "walk"}
    assert a.layers == b.layers


def _aim(view, target_m: np.ndarray, height_m: float, fill: float):
    """A view from `view.position_m` looking at `target_m`, zoomed so the person fills `fill`."""
    d = target_m - view.position_m
    yaw = math.atan2(d[1], d[0])
    dist = float(np.hypot(d[0], d[1]))
    pitch = math.atan2(d[2], dist)
    focal = fill * view.sensor.height_mm * dist / height_m
    return dataclasses.replace(view, ypr_rad=np.array([yaw, pitch, 0.0]), focal_mm=float(np.clip(focal, 20, 300)),
                               focus_m=dist)


def render_subject_flight(scene_name: str, subject: str, n: int):
    """(image, ground truth) of n frames spread over the subject's whole script period."""
    sim = SimBackend(load_scene(scene_name, subject=subject), epoch_ns=0)
    r = sim.renderer
    period = r.subject.script.period_s
    p0 = np.array(sim.scene.vehicle.position_m)
    for k in range(n):
        t = (k + 0.5) * period / n
        pose = r.subject.script.pose_at(t)
        pos = p0 + [0.0, 1.5 * math.sin(2 * math.pi * k / n), 0.2 * (1 + math.cos(2 * math.pi * k / n))]
        view = dataclasses.replace(sim.view(), position_m=pos)
        target = pose.position_m + [0, 0, 0.5 * r.subject.spec.height_m]
        view = _aim(view, target, r.subject.spec.height_m, 0.55 + 0.2 * math.sin(1.3 * k))
        img, geo = r.render(view, t)
        yield img, geo, view


@pytest.mark.slow
@pytest.mark.parametrize("scene", [n for n in scene_names() if load_scene(n).world == "2.5d"])  # cut-outs
@pytest.mark.parametrize("subject", SUBJECTS)
def test_detector_finds_every_subject_in_every_scene_and_its_joints_land_on_the_cut_out(pose_detector, scene, subject):
    pose_detector.reset()
    found, errors = 0, []
    for k, (img, geo, _view) in enumerate(render_subject_flight(scene, subject, N_FRAMES)):
        m = pose_detector.process(img, k, k * 41_666_667 + 1)
        h, w = img.shape[:2]
        errs = [float(np.nanmedian(np.linalg.norm(sk.keypoints_px / [w, h] - geo["joints_norm"], axis=1)))
                for sk in m.skeletons]
        best = min(errs) if errs else math.inf
        errors.append(best)
        found += best < 0.03
    assert found >= 0.98 * N_FRAMES, f"{subject} in {scene}: found in {found}/{N_FRAMES}; {np.round(errors, 3)}"
    assert float(np.median(errors)) <= 0.02, f"{subject} in {scene}: median joint error {np.median(errors):.4f}"


def test_the_walkers_default_loop_sets_off_towards_the_camera_and_turns_smoothly_round_it():
    """The take opens on his front (he walks towards where the bundled cameras start) and the turn keeps it
    reachable: he turns left, the README scene's camera starts on his left, and no corner turns him more
    than 15 deg (the octagon's 45 deg corners threw a camera resting 45 deg off his front side-on)."""
    from cinetransfer.services.autopilot_bridge.sim.make_subjects import LIBRARY

    assert subject_info("walker")["default_script"] == LIBRARY["walker"]["default_script"]  # asset = generator
    scene = load_scene("open_country", subject="walker")
    start = np.array(scene.subject.start_m)
    path = np.array([start] + [p for st in scene.subject.script for p in st.path_m])
    legs = np.diff(path, axis=0)
    to_camera = np.array(scene.vehicle.position_m[:2]) - start
    cos = legs[0] @ to_camera / (np.linalg.norm(legs[0]) * np.linalg.norm(to_camera))
    assert math.degrees(math.acos(cos)) < 25.0
    assert legs[0][0] * to_camera[1] - legs[0][1] * to_camera[0] > 0  # the camera on his left
    headings = np.unwrap(np.arctan2(legs[:, 1], legs[:, 0]))
    turns = np.degrees(np.diff(headings))
    assert np.all(turns > 0) and turns.max() <= 15.1  # (waypoints rounded to the mm)
    assert np.allclose(path[-1], start, atol=1e-3)  # a closed loop: it repeats without a jump
