"""Fidelity metrics (cinetransfer.report.fidelity) against hand-computed values on synthetic runs."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cinetransfer.report import fidelity as F
from cinetransfer.report import synth

K = 48
ALL_OFF = np.zeros((K, 3), bool)


def _subject_in_focus(k: int = K) -> np.ndarray:
    return np.tile([False, True, False], (k, 1))


def test_constant_offset_gives_that_error_by_extraction_and_truth():
    # given an output 0.01 right of every source target, and a truth 0.03 below
    src = synth.instructions(K)
    out = synth.instructions(K, image_targets=src.image_targets + np.float32([0.01, 0.0]))
    truths = synth.truths(src.image_targets + np.float32([0.0, 0.03]))
    # when
    s = F.compute_fidelity(src, out, truths).summary
    # then: |dx| = 0.01 exactly, |dy| = 0, Euclidean 0.01, std 0, for every joint and overall
    ex = s["extraction"]["joints"]
    assert ex["overall"]["euclidean"]["mean"] == pytest.approx(0.01, abs=1e-6)
    assert ex["overall"]["euclidean"]["std"] == pytest.approx(0.0, abs=1e-6)
    assert ex["overall"]["x"]["mean"] == pytest.approx(0.01, abs=1e-6)
    assert ex["overall"]["y"]["mean"] == pytest.approx(0.0, abs=1e-6)
    assert ex["overall"]["euclidean"]["n"] == K * 4
    for name in synth.JOINTS:
        assert ex["per_joint"][name]["euclidean"]["mean"] == pytest.approx(0.01, abs=1e-6)
        assert ex["per_joint"][name]["euclidean"]["n"] == K
    tr = s["truth"]["joints"]
    assert tr["overall"]["euclidean"]["mean"] == pytest.approx(0.03, abs=1e-6)
    assert tr["overall"]["y"]["mean"] == pytest.approx(0.03, abs=1e-6)
    # and the goals: 0.01 <= 0.05 met; 0.03 <= 0.03 met (boundary included)
    g = {x["id"]: x for x in s["goals"]}
    assert g["extraction_joint_error"]["status"] == "met"
    assert g["truth_joint_error"]["status"] == "met"
    assert s["alignment"]["compared_frames"] == K and s["alignment"]["mode"] == "index"


def test_mixed_offsets_mean_and_std_by_hand():
    # given half the frames off by (0.03, 0.04) (Euclidean 0.05) and half exact
    src = synth.instructions(K)
    tg = src.image_targets.copy()
    tg[: K // 2] += np.float32([0.03, 0.04])
    out = synth.instructions(K, image_targets=tg)
    s = F.compute_fidelity(src, out).summary
    eu = s["extraction"]["joints"]["overall"]["euclidean"]
    # then mean 0.025, population std 0.025, max 0.05
    assert eu["mean"] == pytest.approx(0.025, abs=1e-6)
    assert eu["std"] == pytest.approx(0.025, abs=1e-6)
    assert eu["max"] == pytest.approx(0.05, abs=1e-6)
    assert s["goals"][0]["id"] == "extraction_joint_error" and s["goals"][0]["status"] == "met"


def test_large_error_misses_goal():
    src = synth.instructions(K)
    out = synth.instructions(K, image_targets=src.image_targets + np.float32([0.06, 0.0]))
    s = F.compute_fidelity(src, out, synth.truths(src.image_targets + np.float32([0.0, 0.04]))).summary
    g = {x["id"]: x["status"] for x in s["goals"]}
    assert g["extraction_joint_error"] == "missed"
    assert g["truth_joint_error"] == "missed"


def test_flipped_focus_booleans_give_zero_agreement():
    # given every focus boolean of the output and truth flipped
    src = synth.instructions(K)
    flipped = ~_subject_in_focus()
    out = synth.instructions(K, focus_in=flipped)
    s = F.compute_fidelity(src, out, synth.truths(src.image_targets, focus_in=flipped)).summary
    for measure in ("extraction", "truth"):
        for region in F.REGIONS:
            fo = s[measure]["focus"][region]
            assert fo["agreement"] == 0.0
            assert fo["n_frames"] == K
    assert all(g["status"] == "missed" for g in s["goals"] if "focus" in g["id"])
    assert s["headline"]["goals_met"] == "2/8"  # the two joint goals (identical joints) are met


def test_partial_focus_agreement_and_absent_regions():
    # given the background label flipped in the last 12 of 48 frames, and no foreground in the
    # first 8 output frames
    src = synth.instructions(K)
    fin = _subject_in_focus()
    fin[36:, 2] = True
    pres = np.ones((K, 3), bool)
    pres[:8, 0] = False
    out = synth.instructions(K, focus_in=fin, present=pres)
    fo = F.compute_fidelity(src, out).summary["extraction"]["focus"]
    # then background agreement 36/48 = 75 %; foreground judged on 40 frames only (100 %)
    assert fo["background"]["agreement"] == pytest.approx(36 / 48)
    assert fo["foreground"]["n_frames"] == 40
    assert fo["foreground"]["agreement"] == 1.0
    assert fo["foreground"]["presence_agreement"] == pytest.approx(40 / 48)
    assert fo["subject"]["agreement"] == 1.0
    # |b| error: raw fraction is 0.9 in focus / 0.1 out in the synthetic messages
    assert fo["background"]["fraction_error"]["mean"] == pytest.approx(12 * 0.8 / 48, abs=1e-6)


def test_region_absent_everywhere_is_not_judged():
    src = synth.instructions(K)
    pres = np.ones((K, 3), bool)
    pres[:, 0] = False
    out = synth.instructions(K, present=pres)
    s = F.compute_fidelity(src, out).summary
    assert s["extraction"]["focus"]["foreground"]["agreement"] is None
    g = {x["id"]: x["status"] for x in s["goals"]}
    assert g["extraction_focus_foreground"] == "n/a"
    assert g["extraction_focus_subject"] == "met"


def test_missing_output_style_is_reported_and_truth_still_computed():
    src = synth.instructions(K)
    s = F.compute_fidelity(src, None, synth.truths(src.image_targets),
                           output_missing_reason="extraction crashed").summary
    assert s["extraction"]["available"] is False
    assert s["extraction"]["reason"] == "extraction crashed"
    assert s["extraction"]["joints"] is None
    assert s["truth"]["available"] is True
    assert s["truth"]["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.0, abs=1e-7)
    g = {x["id"]: x["status"] for x in s["goals"]}
    assert g["extraction_joint_error"] == "n/a" and g["truth_joint_error"] == "met"
    assert s["headline"]["goals_met"] == "4/4"


def test_nothing_to_compare():
    src = synth.instructions(K)
    s = F.compute_fidelity(src, None, []).summary
    assert not s["extraction"]["available"] and not s["truth"]["available"]
    assert s["headline"]["goals_met"] == "0/0"
    assert s["alignment"]["compared_frames"] == 0


def test_only_frames_seen_on_both_sides_count():
    # given the subject invisible in 8 output frames and one joint NaN in 4 source frames, and
    # a large error exactly in those frames
    src_tg = synth.targets(K)
    src_tg[:4, 0] = np.nan
    src = synth.instructions(K, image_targets=src_tg)
    out_tg = synth.targets(K)
    vis = np.ones(K, bool)
    vis[10:18] = False
    out_tg[10:18] += 0.5
    out = synth.instructions(K, image_targets=out_tg, visible=vis)
    s = F.compute_fidelity(src, out).summary
    ex = s["extraction"]["joints"]
    # then the error is zero and the counts are exact
    assert ex["overall"]["euclidean"]["mean"] == pytest.approx(0.0, abs=1e-7)
    assert ex["per_joint"]["left_shoulder"]["euclidean"]["n"] == K - 8 - 4
    assert ex["per_joint"]["right_hip"]["euclidean"]["n"] == K - 8
    assert ex["frames_compared"] == K - 8
    # and the joint-frames left out are counted by cause (4 joints): the source's 4 NaN targets,
    # the output's 8 invisible frames x 4 joints; the rest compared
    assert len(src.joint_names) == 4
    assert ex["joint_frames_without_target"] == 4
    assert ex["joint_frames_target_unseen"] == 32
    assert ex["joint_frames_compared"] == 4 * K - 4 - 32


def test_truth_visibility_and_frame_offset():
    # given truths indexed from frame 500 (the simulator's counter) with a hidden joint
    src = synth.instructions(K)
    vis = np.ones((K, 4), bool)
    vis[:, 3] = False
    truths = synth.truths(src.image_targets + np.float32(0.01), first_index=500, visible=vis)
    s = F.compute_fidelity(src, None, truths).summary
    tj = s["truth"]["joints"]
    assert tj["per_joint"]["right_hip"]["euclidean"]["n"] == 0
    assert tj["per_joint"]["right_hip"]["euclidean"]["mean"] is None
    assert tj["per_joint"]["left_hip"]["euclidean"]["mean"] == pytest.approx(0.01 * math.sqrt(2), abs=1e-6)
    assert s["alignment"]["output_frames"] == K  # truth 500 is output frame 0


def test_common_length_when_lengths_differ():
    # given a 48-frame source and a 30-frame output extraction plus 60 truths
    src = synth.instructions(K)
    out = synth.instructions(30, image_targets=synth.targets(K)[:30] + np.float32([0.02, 0.0]))
    truths = synth.truths(np.concatenate([synth.targets(K), synth.targets(12)]))
    s = F.compute_fidelity(src, out, truths).summary
    assert s["alignment"]["output_frames"] == 60
    assert s["alignment"]["compared_frames"] == K
    assert s["extraction"]["joints"]["overall"]["euclidean"]["n"] == 30 * 4
    assert s["extraction"]["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.02, abs=1e-6)
    assert s["truth"]["joints"]["overall"]["euclidean"]["n"] == K * 4


def test_fps_mismatch_maps_by_time():
    # given a 24 fps source and a 12 fps output that shows every second source pose
    src = synth.instructions(K, fps=24.0)
    out = synth.instructions(K // 2, fps=12.0, image_targets=src.image_targets[::2])
    s = F.compute_fidelity(src, out).summary
    assert s["alignment"]["mode"] == "time"
    assert s["alignment"]["compared_frames"] == K // 2
    assert s["extraction"]["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.0, abs=1e-7)
    t, k, mode = F.align_rows(5, 12.0, 100, 24.0)
    assert list(k) == [0, 2, 4, 6, 8] and mode == "time"
    t, k, mode = F.align_rows(5, 24.0, 3, 24.0)
    assert list(k) == [0, 1, 2, -1, -1] and mode == "index"


def test_joint_names_matched_by_name_not_position():
    # given an output whose joints come in another order
    src = synth.instructions(K)
    order = [3, 2, 1, 0]
    out = synth.instructions(K, image_targets=src.image_targets[:, order],
                             joint_names=[synth.JOINTS[i] for i in order])
    s = F.compute_fidelity(src, out).summary
    assert s["extraction"]["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.0, abs=1e-7)


def test_output_first_frame_offsets_rows():
    # given an extraction that starts at video frame 6: row r is output frame 6 + r
    src = synth.instructions(K)
    out = synth.instructions(K - 6, image_targets=src.image_targets[6:], first_frame=6)
    s = F.compute_fidelity(src, out).summary
    assert s["extraction"]["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.0, abs=1e-7)
    assert s["extraction"]["joints"]["overall"]["euclidean"]["n"] == (K - 6) * 4


def test_per_frame_error_series():
    src = synth.instructions(K)
    tg = src.image_targets.copy()
    tg[5] += np.float32([0.0, 0.1])
    vis = np.ones(K, bool)
    vis[7] = False
    fid = F.compute_fidelity(src, synth.instructions(K, image_targets=tg, visible=vis))
    err = fid.series["error_extraction"]
    assert err.shape == (K,)
    assert err[5] == pytest.approx(0.1, abs=1e-6)
    assert err[0] == pytest.approx(0.0, abs=1e-7)
    assert math.isnan(err[7])
    assert np.isnan(fid.series["error_truth"]).all()  # no truth given


def test_stats_of_empty_and_nan():
    assert F.stats(np.array([])) == {"mean": None, "std": None, "max": None, "n": 0}
    assert F.stats(np.array([np.nan, 1.0, 3.0])) == {"mean": 2.0, "std": 1.0, "max": 3.0, "n": 2}


def test_align_gives_the_video_its_tracks_before_the_goals():
    # given a 48-frame source and a 30-frame output extraction plus 60 truths (as above)
    src = synth.instructions(K)
    out = synth.instructions(30, image_targets=synth.targets(K)[:30] + np.float32([0.02, 0.0]))
    truths = synth.truths(np.concatenate([synth.targets(K), synth.targets(12)]))
    # when aligned alone
    a = F.align(src, out, truths)
    # then: 60 output frames, the 48 with a source row compared, row k = frame k, t = k / 24
    assert a.n_out == 60 and int(a.keep.sum()) == K and a.mode == "index"
    assert list(a.k) == list(range(K)) and a.t[1] == pytest.approx(1 / 24)
    # the extraction covers its 30 frames only, the truth all 48
    assert int(a.out.available.sum()) == 30 and int(a.truth.available.sum()) == K
    v = a.series()
    assert v["source_first_frame"] == 0 and v["joint_names"] == list(src.joint_names)
    # and the fidelity from it holds the very same tracks and the same numbers as without it
    f = F.compute_fidelity(src, out, truths, aligned=a)
    assert f.series["source"] is a.src and f.series["extraction"] is a.out and f.series["truth"] is a.truth
    assert f.summary["extraction"]["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.02, abs=1e-6)
    assert f.summary == F.compute_fidelity(src, out, truths).summary
