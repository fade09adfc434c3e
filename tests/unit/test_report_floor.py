"""The truth joint error's floor (report/floor.py): hand-computed fits and the simulator's own projection."""
from __future__ import annotations

import numpy as np
import pytest

from cinetransfer.report import fidelity as F
from cinetransfer.report.floor import billboard_joints, joint_error_floor
from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend
from cinetransfer.services.autopilot_bridge.sim.scene import load_scene
from cinetransfer.shared import messages as M

NAMES = ["left_shoulder", "right_shoulder", "left_hip", "right_hip"]


def floor_of(q, p, aspect=1.0, names=NAMES):
    q, p = np.asarray(q, float)[None], np.asarray(p, float)[None]
    return joint_error_floor(p, np.ones(p.shape[:2], bool), q, names, aspect)


def test_a_scaled_and_shifted_pose_is_reached_exactly():
    q = [[0.2, 1.4], [-0.2, 1.4], [0.15, 0.9], [-0.15, 0.9]]  # metres, Y up; left shoulder on the image right
    p = [[0.5 + 0.1 * x, 0.6 - 0.1 * y] for x, y in q]
    fl = floor_of(q, p)
    assert fl.mean() == pytest.approx(0.0, abs=1e-5) and fl.counts[0] == 4


def test_a_tilted_pair_costs_its_height_difference():
    # shoulders level on the billboard (Y 0), tilted in the target by 0.1 in y: without roll both land on
    # one row, so the summed error is at least |0.5 - 0.6| = 0.1, and x is met exactly: mean 0.05
    fl = floor_of([[1.0, 0.0], [-1.0, 0.0]], [[0.6, 0.5], [0.4, 0.6]], names=NAMES[:2])
    assert fl.mean() == pytest.approx(0.05, abs=1e-5)


def test_looking_up_or_down_only_shortens_the_body():
    # hips 1 m below the shoulders; the target wants them 0.4 below with shoulders 0.2 apart: a vertical
    # scale 4x the horizontal one, which no view gives when the image is square (aspect 1) ...
    q = [[0.5, 0.0], [-0.5, 0.0], [0.5, -1.0], [-0.5, -1.0]]
    p = [[0.6, 0.3], [0.4, 0.3], [0.6, 0.7], [0.4, 0.7]]
    assert floor_of(q, p, aspect=1.0).mean() > 0.05
    # ... but a frame 4x wider than tall does (a, b = 0.2, 0.4: b <= 4 a)
    assert floor_of(q, p, aspect=4.0).mean() == pytest.approx(0.0, abs=1e-5)
    # squashing is always possible: the same hips 0.05 below
    p_short = [[0.6, 0.3], [0.4, 0.3], [0.6, 0.35], [0.4, 0.35]]
    assert floor_of(q, p_short, aspect=1.0).mean() == pytest.approx(0.0, abs=1e-5)


def test_a_person_seen_from_behind_is_matched_left_for_right():
    q = [[0.2, 1.4], [-0.2, 1.4], [0.15, 0.9], [-0.15, 0.9]]
    p = [[0.5 - 0.1 * x, 0.6 - 0.1 * y] for x, y in q]  # mirrored: left shoulder on the image left
    assert floor_of(q, p).mean() == pytest.approx(0.0, abs=1e-5)


def test_uncompared_joints_do_not_count():
    q = np.array([[[0.5, 0.0], [-0.5, 0.0], [0.5, -1.0], [-0.5, -1.0]]])
    p = np.array([[[0.6, 0.3], [0.4, 0.3], [0.0, 0.0], [1.0, 1.0]]])  # hips far off, but not compared
    fl = joint_error_floor(p, np.array([[True, True, False, False]]), q, NAMES, 16 / 9)
    assert fl.mean() == pytest.approx(0.0, abs=1e-5) and fl.counts[0] == 2
    none = joint_error_floor(p, np.zeros((1, 4), bool), q, NAMES, 16 / 9)
    assert np.isnan(none.mean()) and np.isnan(none.per_frame[0])


def test_the_simulators_own_truth_is_within_the_weak_perspective_residual():
    """The simulator's truth joints, as targets, against the billboard poses billboard_joints
    gives for the same stamps: a floor of ~0 (what is left is perspective)."""
    sim = SimBackend("focus_hedge_25d", epoch_ns=0, width=480, height=270)
    sim.start()
    p0 = np.array(sim.scene.vehicle.position_m)
    # climb 2.5 m and look down on him, aimed at his middle 1 m above the origin (the vertical
    # foreshortening the fit has to reproduce)
    sim.apply(M.Setpoint(position_m=p0 + [1.5, 0.8, 2.5], camera_ypr_rad=np.array([-0.144, -0.42, 0.0]),
                         lens=M.LensState(focal_length_mm=30.0, focus_distance_m=float("nan"), f_number=float("nan"))))
    truths = []
    for k in range(144):  # 6 s: the gimbal turns at once, the drone takes ~4 s to climb there
        sim.step(k / 24)
        truths += sim.truths()
    truths = truths[-48:]
    n = len(truths)
    T = F.truth_track(truths, NAMES, n)
    assert T.ok.all()  # he is in the picture
    bb, aspect = billboard_joints(load_scene("focus_hedge_25d"), [t.stamp_ns for t in truths], 0, NAMES)
    assert aspect == pytest.approx(960 / 540)  # the scene's camera (the test renders smaller, same shape)
    assert np.all(bb[:, :2, 1] > bb[:, 2:, 1] + 0.3)  # shoulders above hips, metres
    assert np.all(bb[:, 0, 0] > bb[:, 1, 0])  # he faces the camera: his left shoulder on the image right
    fl = joint_error_floor(T.xy, T.ok, bb, NAMES, aspect)
    assert fl.mean() < 0.003 and fl.counts.sum() == T.ok.sum()
    # the same poses a quarter second late (another juggling frame) are not reached exactly
    late = joint_error_floor(T.xy[6:], T.ok[6:], bb[:-6], NAMES, aspect)
    assert late.mean() > fl.mean()
    assert M.COCO17_NAMES[5] == "left_shoulder"


def test_the_floor_says_why_when_it_cannot_be_computed():
    from cinetransfer.report.floor import run_floor
    from cinetransfer.services.planner.core import instructions_from_arrays

    ins = instructions_from_arrays(targets=np.full((4, 4, 2), 0.5), joint_names=NAMES)
    sim = SimBackend("focus_hedge_25d", epoch_ns=0, width=160, height=90)
    sim.start()
    sim.step(0.0)
    truths = sim.truths()
    sim_meta = {"scene": "focus_hedge_25d", "epoch_ns": 0}
    assert run_floor(ins, [], sim_meta, aligned_by_index=True) == (None, "no ground truth")
    assert "not a simulated run" in run_floor(ins, truths, {}, aligned_by_index=True)[1]
    assert "frame rates differ" in run_floor(ins, truths, {"scene": "focus_hedge_25d", "epoch_ns": 0},
                                             aligned_by_index=False)[1]
    fl, why = run_floor(ins, truths, {"scene": "no_such_scene", "epoch_ns": 0}, aligned_by_index=True)
    assert fl is None and "could not be loaded" in why and "no_such_scene" in why
    fl, why = run_floor(ins, truths, {"scene": "focus_hedge_25d", "epoch_ns": 0}, aligned_by_index=True)
    assert why == "" and fl.counts[0] == 4 and fl.counts[1:].sum() == 0


def test_a_body_seen_from_a_grid_direction_has_a_floor_of_zero_and_another_pose_does_not():
    from cinetransfer.report.floor import body_floor, view_axes

    rng = np.random.default_rng(3)
    joints = rng.normal(0.0, 0.4, (5, 4, 3)) + [2.0, 1.0, 1.0]  # five frames of four joints [m]
    right, up = view_axes(np.radians([40.0]), np.radians([15.0]))
    a, aspect = 0.3, 16 / 9
    targets = np.stack([a * joints @ right[0] + 0.5, 0.4 - aspect * a * joints @ up[0]], axis=-1)
    fl = body_floor(targets, np.ones((5, 4), bool), joints, NAMES, aspect)
    assert fl.mean() == pytest.approx(0.0, abs=1e-4) and list(fl.counts) == [4] * 5
    assert "3-D body" in fl.model
    other = body_floor(targets, np.ones((5, 4), bool), joints[::-1], NAMES, aspect)  # the poses out of order
    assert other.mean() > 0.01


def test_the_3d_worlds_own_truth_is_within_the_grid_and_weak_perspective_residual():
    from cinetransfer.report.floor import run_floor
    from cinetransfer.services.planner.core import instructions_from_arrays

    sim = SimBackend("focus_hedge", epoch_ns=0, width=320, height=180)
    assert sim.scene.world == "3d"
    sim.start()
    truths = []
    for k in range(24):
        sim.step(k / 24)
        truths += sim.truths()
    sim.close()
    T = F.truth_track(truths, NAMES, len(truths))
    assert T.ok.all()
    ins = instructions_from_arrays(targets=T.xy, joint_names=NAMES)
    fl, why = run_floor(ins, truths, {"scene": "focus_hedge", "epoch_ns": 0}, aligned_by_index=True)
    assert why == "" and fl.counts.sum() == T.ok.sum() and "3-D body" in fl.model
    assert fl.mean() < 0.004
