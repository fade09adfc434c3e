"""Smoother core: main subject, bridging, bad input, ordering, mask/skeleton, focus formulation."""
from __future__ import annotations

import random

import numpy as np
import pytest

from cinetransfer.services.smoother import focus as F
from cinetransfer.services.smoother.config import ConfigError, SmootherConfig
from cinetransfer.services.smoother.core import (SmootherInputError, features_from_measurements, smooth_measurements,
                                                 smooth_sequence)
from cinetransfer.services.smoother.synthetic import H, W, measurement, person, skeleton_in, walking_sequence
from cinetransfer.shared import messages as M


def subject_x0(result):
    return result.diagnostics["raw_box"][:, 0] * W


def test_viterbi_picks_the_continuous_subject_over_a_flickering_one():
    # Given a subject walking in every frame (conf 0.7) and a bystander of higher confidence (0.98)
    # present in every third frame, far away
    ms = walking_sequence(90, flicker=True)
    # When smoothed
    r = smooth_measurements(ms)
    # Then every frame follows the walking subject, never the bystander at x0 = 480
    assert r.instructions.subject_visible.all()
    x0 = subject_x0(r)
    assert np.nanmax(x0) < 300
    assert np.all(r.diagnostics["person"] == 0)


def test_person_present_in_most_frames_wins_over_a_confident_short_one():
    # Given A in all 60 frames (conf 0.6) and B (conf 0.99) only in the first 20, both static
    ms = []
    for i in range(60):
        ppl = [person([100, 100, 200, 400], 0.6)]
        if i < 20:
            ppl.insert(0, person([400, 100, 500, 400], 0.99))
        ms.append(measurement(i, ppl))
    r = smooth_measurements(ms)
    # Then A is the subject throughout (no switch from B to A mid-way)
    np.testing.assert_allclose(subject_x0(r), 100, atol=1e-3)


def test_dropout_is_bridged_and_long_absence_is_not_visible():
    ms = walking_sequence(120, flicker=False, focus=False)
    # short dropout (6 frames = 0.25 s at 24 fps) and a long absence (40 frames)
    for i in list(range(30, 36)) + list(range(60, 100)):
        ms[i] = measurement(i, [], [])
    r = smooth_measurements(ms)
    ins = r.instructions
    assert ins.subject_visible[30:36].all() and r.diagnostics["bridged"][30:36].all()
    assert not ins.subject_visible[60:100].any()
    assert ins.subject_visible[100:].all()
    # bridged targets are finite and lie between the neighbours; invisible ones are NaN
    assert np.isfinite(ins.image_targets[30:36]).all()
    x = ins.image_targets[:, 0, 0]
    assert x[29] < x[33] < x[36]
    assert np.isnan(ins.image_targets[60:100]).all() and np.isnan(ins.subject_box[60:100]).all()


def test_missing_frames_are_gaps_bridged():
    ms = walking_sequence(60, flicker=False)
    ms = [m for m in ms if not 20 <= m.frame_index < 24]  # the measurements never arrived
    r = smooth_measurements(ms)
    assert r.instructions.image_targets.shape[0] == 60
    assert r.instructions.subject_visible.all() and r.diagnostics["gaps"] == 4
    assert not r.instructions.valid  # gaps mark the output as degraded


def test_out_of_order_and_duplicates_give_the_same_result():
    ms = walking_sequence(80)
    ref = smooth_measurements(ms).instructions
    shuffled = ms + ms[10:20]
    random.Random(1).shuffle(shuffled)
    r = smooth_measurements(shuffled)
    assert r.diagnostics["duplicates"] == 10
    np.testing.assert_array_equal(r.instructions.image_targets, ref.image_targets)
    np.testing.assert_array_equal(r.instructions.focus_in, ref.focus_in)


@pytest.mark.parametrize("ms, needle", [
    ([], "empty"),
    ([measurement(i) for i in range(10)], "no person"),
])
def test_no_person_or_empty_is_a_clear_error(ms, needle):
    with pytest.raises(SmootherInputError, match=needle):
        smooth_measurements(ms)


def test_boxes_and_joints_stay_inside_the_image():
    # Given a subject leaving the image on the right (raw box and joints beyond the border)
    ms = []
    rng = np.random.default_rng(0)
    for i in range(50):
        b = np.array([500 + 4 * i, 100, 620 + 4 * i, 400.0])
        ms.append(measurement(i, [person(b, 0.9)], [skeleton_in(b, rng=rng, noise=20)]))
    ins = smooth_measurements(ms).instructions
    vis = ins.subject_visible
    assert vis.all()
    assert np.nanmax(ins.subject_box) <= 1.0 + 1e-9 and np.nanmin(ins.subject_box) >= -1e-9
    t = ins.image_targets[np.isfinite(ins.image_targets)]
    assert t.max() <= 1.0 + 1e-9 and t.min() >= -1e-9


def test_smoothing_reduces_joint_noise():
    rng = np.random.default_rng(5)
    ms, truth = [], []
    for i in range(200):
        b = np.array([100 + 1.0 * i, 100, 220 + 1.0 * i, 420.0])
        truth.append(skeleton_in(b).keypoints_px)
        ms.append(measurement(i, [person(b, 0.9)], [skeleton_in(b, rng=rng, noise=6.0)]))
    r = smooth_measurements(ms)
    truth = np.array(truth) / [W, H]
    raw_err = np.nanmean(np.abs(r.diagnostics["raw_joints"] - truth))
    sm_err = np.nanmean(np.abs(r.diagnostics["smoothed_joints"] - truth))
    assert sm_err < 0.6 * raw_err


def test_mask_and_skeleton_of_the_main_subject_are_picked_by_overlap():
    # Given two overlapping people; the main subject's skeleton is listed second
    a = np.array([100, 100, 220, 420.0])
    b = np.array([180, 120, 300, 440.0])
    ms = []
    for i in range(30):
        ppl = [person(a, 0.9), person(b, 0.5 if i % 2 else 0.0)]
        ms.append(measurement(i, ppl, [skeleton_in(b), skeleton_in(a)]))
    r = smooth_measurements(ms)
    assert np.all(r.diagnostics["mask_index"] == 0)
    assert np.all(r.diagnostics["skeleton_index"] == 1)  # the skeleton inside a's mask


def test_focus_regions_fractions_from_mask():
    # Subject sharp, everything else blurred; the feet end above the bottom: foreground present.
    b = np.array([200, 40, 300, 360.0])
    fm = np.zeros((H // 2, W // 2), np.uint8)
    m = person(b, 0.9)
    full = m.full_mask(W, H)[::2, ::2]
    fm[full] = 255
    feats = features_from_measurements([measurement(0, [m], [skeleton_in(b)], fm)], SmootherConfig())
    fg, subj, bg = feats[0].focus[0]
    assert subj > 0.97 and bg < 0.02 and fg == pytest.approx(0.0, abs=0.01)
    assert feats[0].focus_none[2] == pytest.approx(full.mean(), abs=0.01)


def focus_schedule(n=240, seed=0):
    """Ground truth in/out per region switching every 40-80 frames, b = truth with realistic noise."""
    rng = np.random.default_rng(seed)
    truth = np.zeros((n, 3))
    for c in range(3):
        s, i = rng.integers(0, 2), 0
        while i < n:
            L = int(rng.integers(40, 80))
            truth[i:i + L, c] = s
            s, i = 1 - s, i + L
    b = np.clip(np.where(truth > 0, 0.8, 0.15) + rng.normal(0, 0.15, truth.shape), 0, 1)
    b[rng.uniform(size=n) < 0.05] = np.nan  # frames without a measurement
    return truth, b


def test_our_focus_formulation_beats_the_literal_one():
    truth, b = focus_schedule()
    ours = F.smooth_focus(b, method="hmm")
    lit = F.smooth_focus(b, method="literal")
    err_ours = np.mean(np.abs(ours - truth))
    err_lit = np.mean(np.abs(lit - truth))
    err_raw = np.nanmean(np.abs(b - truth))
    # The printed formula drives B to 0 whatever b says.
    assert np.nanmax(lit) < 0.05
    assert err_ours < 0.05 < err_lit
    assert err_ours < err_raw
    assert np.mean((ours > 0.5) == (truth > 0.5)) > 0.97


def test_focus_viterbi_and_l2_are_sane():
    truth, b = focus_schedule(seed=2)
    for method in ("viterbi", "l2"):
        B = F.smooth_focus(b, method=method)
        assert np.all((B >= -1e-9) & (B <= 1 + 1e-9))
        assert np.mean((B > 0.5) == (truth > 0.5)) > 0.95, method


def test_literal_subject_baseline_agrees_on_an_easy_case():
    pytest.importorskip("casadi")
    ms = walking_sequence(40, flicker=True, focus=False)
    cfg = SmootherConfig(subject_method="literal")
    r = smooth_sequence(features_from_measurements(ms, cfg), cfg)
    assert r.instructions.subject_visible.all()
    assert np.nanmax(subject_x0(r)) < 300


def test_config_validation_names_the_field():
    with pytest.raises(ConfigError, match="joints"):
        SmootherConfig(joints=("chest",)).validate()
    with pytest.raises(ConfigError, match="theta"):
        SmootherConfig(theta=1.5).validate()


def test_instructions_are_a_valid_message():
    from cinetransfer.shared import codec

    ins = smooth_measurements(walking_sequence(30)).instructions
    back = codec.decode(codec.encode(ins), M.Instructions)
    assert back.image_targets.shape == (30, 4, 2)
    assert back.joint_names == ["left_shoulder", "right_shoulder", "left_hip", "right_hip"]
    assert back.frame_duration_s == pytest.approx(1 / 24)


def test_viterbi_is_exact_against_brute_force():
    """Every assignment (a detection or 'not visible' per frame) enumerated on tiny problems; a step
    between two different detector tracks costs track_switch_cost (not checked across a re-entry), one
    along a track moves at same_track_move x the box change."""
    import itertools

    from cinetransfer.services.smoother.features import FrameFeatures
    from cinetransfer.services.smoother.subject import LEAVE_FACTOR, select_subject

    rng = np.random.default_rng(4)
    kw = dict(move_cost=7.0, miss_cost=1.0, confidence_cost=0.5, reentry_cost=1.5, track_switch_cost=0.8,
              same_track_move=0.3)
    G = 2  # fps 1, max_bridge_s 1 -> steps of up to 2 frames
    for trial in range(25):
        F_ = 6
        feats = []
        for f in range(F_):
            m = int(rng.integers(0, 3))
            bx = rng.uniform(0, 300, (m, 2))
            boxes = np.concatenate([bx, bx + rng.uniform(50, 150, (m, 2))], axis=1)
            feats.append(FrameFeatures(frame_index=f, width=640, height=480, boxes=boxes,
                                       conf=rng.uniform(0.2, 1.0, m), track=rng.integers(-1, 3, m)))

        def cost(path):
            chosen = [(f, k) for f, k in enumerate(path) if k >= 0]
            if not chosen:
                return F_ * kw["miss_cost"]
            c = chosen[0][0] * kw["miss_cost"] + (F_ - 1 - chosen[-1][0]) * kw["miss_cost"]
            for f, k in chosen:
                c += kw["confidence_cost"] * (1 - feats[f].conf[k])
            for (f1, k1), (f2, k2) in zip(chosen[:-1], chosen[1:]):
                g = f2 - f1
                if g <= G:
                    a, b = feats[f1].boxes[k1], feats[f2].boxes[k2]
                    s = 0.5 * (np.hypot(*(a[2:] - a[:2])) + np.hypot(*(b[2:] - b[:2])))
                    t1, t2 = feats[f1].track[k1], feats[f2].track[k2]
                    d = np.linalg.norm(a - b) / s * (kw["same_track_move"] if t1 >= 0 and t1 == t2 else 1.0)
                    c += (g - 1) * kw["miss_cost"] + kw["move_cost"] * d ** 2 / g
                    if t1 >= 0 and t2 >= 0 and t1 != t2:  # leaving a track still there costs LEAVE_FACTOR x
                        c += kw["track_switch_cost"] * (LEAVE_FACTOR if t1 in feats[f2].track else 1.0)
                else:
                    c += (g - 1) * kw["miss_cost"] + kw["reentry_cost"]
            return c

        best = min(cost(p) for p in itertools.product(*[range(-1, f.n_people) for f in feats]))
        sel = select_subject(feats, fps=1.0, max_bridge_s=1.0, **kw)
        assert sel.cost == pytest.approx(best, abs=1e-9), trial
        assert cost(list(sel.person)) == pytest.approx(best, abs=1e-9), trial


def test_joint_unseen_for_longer_than_max_bridge_is_not_controlled():
    # given a joint observed in frames 0-9 and 40-49 only (a close-up hides it for 30 frames)
    from cinetransfer.services.smoother.joints import frames_from_observation, smooth_joints

    F = 50
    joints = np.full((F, 1, 2), np.nan)
    conf = np.zeros((F, 1))
    seen = np.r_[0:10, 40:50]
    joints[seen, 0] = [100.0, 200.0]
    conf[seen] = 0.9
    assert frames_from_observation(conf > 0)[:, 0].tolist()[8:14] == [0, 0, 1, 2, 3, 4]
    out = smooth_joints(joints, conf, np.ones(F, bool), lam=1.0, width=640, height=360, max_gap=12)
    # then frames within 12 of an observation are bridged, the middle of the gap is NaN
    assert np.isfinite(out[:22, 0]).all() and np.isfinite(out[28:, 0]).all()
    assert np.isnan(out[22:28, 0]).all()
    # and without max_gap everything visible is bridged (the paper's formulation)
    assert np.isfinite(smooth_joints(joints, conf, np.ones(F, bool), lam=1.0, width=640, height=360)).all()


def test_joint_outside_the_image_is_not_controlled_in_that_frame():
    # given a hip seen at y = 300 px (of 360) in frames 0-3 and 8-9, placed below the frame
    # (y = 380 px, any confidence) in frames 4-5, and a low-confidence dropout inside the frame in 6-7
    from cinetransfer.services.smoother.joints import outside_image, smooth_joints

    F = 10
    joints = np.full((F, 1, 2), [320.0, 300.0])
    conf = np.full((F, 1), 0.9)
    joints[4:6, 0, 1] = 380.0
    conf[4] = 0.0
    conf[6:8] = 0.0
    assert outside_image(joints, 640, 360)[:, 0].tolist() == [False] * 4 + [True] * 2 + [False] * 4
    out = smooth_joints(joints, conf, np.ones(F, bool), lam=1.0, width=640, height=360, max_gap=12)
    # then it has no target where it is out of frame (not one pulled to the bottom edge, 360 px),
    # the dropout inside the frame is bridged, and every target equals the constant observation
    assert np.isnan(out[4:6, 0]).all()
    assert np.isfinite(out[[0, 1, 2, 3, 6, 7, 8, 9], 0]).all()
    np.testing.assert_allclose(out[[0, 3, 6, 9], 0], [[320.0, 300.0]] * 4, atol=1e-6)


@pytest.mark.parametrize("scores,expect", [
    ([np.nan, .05, .06, .9, .05, .07], [3]),                  # a hard cut
    ([np.nan, .07, .06, .37, .08, .07, .06], [3]),            # a cut between similar palettes
    ([np.nan, .15, .18, .17, .2, .16, .19], []),              # a fast pan: high but not an outlier
    ([.9, .05, .05, .05], []),                                # frame 0 never starts a shot
    ([np.nan, .05, .6, .05, .6, .05, .6, .05], [2, 4, 6]),    # a flickering transition: every jump
    ([np.nan, np.nan, np.nan], []),                           # no scores (older measurements)
])
def test_find_cuts_table(scores, expect):
    from cinetransfer.services.smoother.shots import find_cuts, segments

    cut = find_cuts(np.array(scores))
    assert np.flatnonzero(cut).tolist() == expect
    assert sum(s.stop - s.start for s in segments(cut)) == len(scores)


def test_targets_jump_at_a_cut_instead_of_gliding():
    # given two shots: the subject on the left for 24 frames, then (cut) on the right
    from dataclasses import replace

    from cinetransfer.services.smoother import synthetic as syn
    from cinetransfer.services.smoother.core import smooth_measurements

    ms = []
    for i in range(48):
        box = np.array([60, 100, 160, 400.0]) if i < 24 else np.array([440, 100, 540, 400.0])
        m = syn.measurement(i, [syn.person(box)], [syn.skeleton_in(box, person_index=0)])
        ms.append(replace(m, shot_change=0.9 if i == 24 else 0.05))
    res = smooth_measurements(ms)
    x = res.instructions.image_targets[:, 0, 0]  # left shoulder x, normalised
    # then both shots keep their own framing up to the cut (no ramp across it) ...
    assert abs(x[23] - x[0]) < 0.01 and abs(x[24] - x[47]) < 0.01 and x[24] - x[23] > 0.5
    assert res.diagnostics["cut"].nonzero()[0].tolist() == [24]
    # ... where without shot information the smoothing glides over several frames
    flat = smooth_measurements([replace(m, shot_change=float("nan")) for m in ms])
    xf = flat.instructions.image_targets[:, 0, 0]
    assert abs(xf[23] - xf[0]) > 0.01 or abs(xf[24] - xf[47]) > 0.01


def test_known_cuts_replace_the_found_ones():
    # given the same two shots with no shot-change scores (a transfer's output: same scene each side)
    from dataclasses import replace

    from cinetransfer.services.smoother import synthetic as syn
    from cinetransfer.services.smoother.core import smooth_sequence

    ms = []
    for i in range(48):
        box = np.array([60, 100, 160, 400.0]) if i < 24 else np.array([440, 100, 540, 400.0])
        ms.append(replace(syn.measurement(i, [syn.person(box)], [syn.skeleton_in(box, person_index=0)]),
                          shot_change=float("nan")))
    feats = features_from_measurements(ms, SmootherConfig())
    # when the edit points are given
    res = smooth_sequence(feats, known_cuts=[24, 99])
    # then the shots are cut there (a row out of range is ignored) and the targets jump at once
    assert res.instructions.shot_start.nonzero()[0].tolist() == [0, 24]
    x = res.instructions.image_targets[:, 0, 0]
    assert abs(x[23] - x[0]) < 0.01 and x[24] - x[23] > 0.5
    assert smooth_sequence(feats, known_cuts=[]).instructions.shot_start.nonzero()[0].tolist() == [0]


def test_soft_shot_is_judged_relative_to_its_sharpest_region():
    # given a shot whose sharp subject reads 0.2 (soft footage) against a background at 0.05, no foreground
    b = np.column_stack([np.full(40, np.nan), np.r_[np.full(20, 0.15), np.full(20, 0.25)], np.full(40, 0.05)])
    # when judged as a shot
    out, level = F.soft_shot(b, theta=0.5, floor=0.1)
    # then its sharpest region's median level (0.2) means "in focus": subject 0.75 / 1.0 (capped), background 0.25
    assert level == pytest.approx(0.2)
    assert out[0, 1] == pytest.approx(0.75) and out[-1, 1] == 1.0
    assert out[0, 2] == pytest.approx(0.25) and np.isnan(out[0, 0])
    B = F.smooth_focus(out, fps=24.0)
    assert (B[:, 1] > 0.5).all() and (B[:, 2] < 0.5).all()


@pytest.mark.parametrize("b", [
    np.column_stack([np.full(30, 0.9), np.full(30, 0.3), np.full(30, 0.1)]),  # some region in focus: absolute
    np.column_stack([np.full(30, 0.05), np.full(30, 0.08), np.full(30, 0.02)]),  # all below the floor: all out
    np.full((30, 3), np.nan),  # nothing measured
])
def test_soft_shot_leaves_sharp_blurred_and_unmeasured_shots_alone(b):
    out, level = F.soft_shot(b, theta=0.5, floor=0.1)
    assert np.isnan(level)
    assert np.array_equal(out, b, equal_nan=True)


def test_soft_floor_one_turns_it_off():
    b = np.column_stack([np.full(30, np.nan), np.full(30, 0.3), np.full(30, 0.05)])
    assert np.isnan(F.soft_shot(b, theta=0.5, floor=1.0)[1])
    with pytest.raises(ConfigError):
        SmootherConfig(focus_soft_floor=0.0).validate()


def test_a_shot_without_focus_measurements_has_no_focus_labels():
    # given two shots: the first with a focus map (subject sharp), the second with none (a flash or
    # morph the focus map could not read)
    from dataclasses import replace

    b = np.array([200, 40, 300, 360.0])
    m = person(b, 0.9)
    fm = np.zeros((H // 2, W // 2), np.uint8)
    fm[m.full_mask(W, H)[::2, ::2]] = 255
    ms = [replace(measurement(i, [m], [skeleton_in(b)], fm if i < 24 else None),
                  shot_change=0.9 if i == 24 else 0.05) for i in range(48)]
    res = smooth_measurements(ms)
    sm = res.instructions.focus_smoothed
    # then the first shot is labelled (subject in focus) and the second is unknown, not "out of focus"
    assert res.instructions.shot_start.nonzero()[0].tolist() == [0, 24]
    assert np.isfinite(sm[:24, 1]).all() and res.instructions.focus_in[:24, 1].all()
    assert np.isnan(sm[24:]).all() and not res.instructions.focus_in[24:].any()


def test_a_region_labelled_for_a_frame_or_two_has_no_label():
    n = np.nan
    B = np.array([[1.0, n], [n, 0.2], [0.9, 0.3], [0.8, n], [0.7, 0.1]])
    out = F.drop_short_runs(B, min_run=3)
    # column 0: a one-frame run, then a three-frame run; column 1: runs of two and one
    np.testing.assert_array_equal(np.isnan(out), [[1, 1], [1, 1], [0, 1], [0, 1], [0, 1]])
    np.testing.assert_array_equal(out[2:, 0], [0.9, 0.8, 0.7])
    assert np.array_equal(F.drop_short_runs(B, min_run=1), B, equal_nan=True)  # off


def test_a_left_out_frame_is_not_filled_from_across_a_cut():
    # given a selection that left out the first frame of a new shot, in which a bystander stands where
    # the subject of the previous shot stood (and the new subject elsewhere)
    from cinetransfer.services.smoother import subject as S

    old, new = np.array([440, 100, 540, 400.0]), np.array([60, 100, 160, 400.0])
    ms = [measurement(0, [person(old)], [skeleton_in(old)]),
          measurement(1, [person(new), person(old + 4)], [skeleton_in(new), skeleton_in(old + 4, person_index=1)]),
          measurement(2, [person(new)], [skeleton_in(new)])]
    feats = features_from_measurements(ms, SmootherConfig())
    sel = S.Selection(np.array([0, -1, 0]), np.array([True, False, True]), np.zeros(3, bool), 0.0)
    # then without the cut the overlap with frame 0 fills it with the bystander; with the cut only its
    # own shot's next frame counts, and it gets the new subject
    assert S.extend_runs(feats, sel).person.tolist() == [0, 1, 0]
    assert S.extend_runs(feats, sel, cuts=np.array([False, True, False])).person.tolist() == [0, 0, 0]


def test_joints_seen_for_fewer_frames_than_joint_min_run_are_no_targets():
    """A skeleton found for 3 frames (0.125 s) between long absences gives no targets (no camera
    reframes in that time); one found for 8 frames does. The box path is not changed."""
    ms = walking_sequence(80, flicker=False, focus=False)
    for i in list(range(20, 40)) + list(range(43, 60)) + list(range(68, 80)):
        ms[i] = measurement(i, [], [])
    r = smooth_measurements(ms)
    t = r.instructions.image_targets
    assert np.isnan(t[40:43]).all() and np.isfinite(t[60:68]).all() and np.isfinite(t[:20]).all()
    assert r.instructions.subject_visible[40:43].all()  # the subject is still there, its joints are not targets
    off = smooth_measurements(ms, SmootherConfig(joint_min_run_s=0.0)).instructions.image_targets
    assert np.isfinite(off[40:43]).all()
