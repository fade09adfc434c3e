"""Which asked focus labels a lens could give (cinetransfer.report.focus_reach, reach_frames), against
hand-computed thin-lens values, and their place in the fidelity report."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cinetransfer.report import fidelity as F
from cinetransfer.report import focus_reach as FR
from cinetransfer.report import reach_frames as RF
from cinetransfer.report import synth
from cinetransfer.shared import camera as cam

S = 20
SKY = np.zeros(S)  # inverse depth 0: at infinity
ABSENT = np.full(S, np.nan)


def at(d_m: float) -> np.ndarray:
    return np.full(S, 1.0 / d_m)


def test_dof_inverse_matches_the_thin_lens_limits():
    # given a 50 mm lens at f/4 focused at 6 m, and one focused beyond its hyperfocal distance
    inv_far, inv_near = FR.dof_inverse(50.0, np.array([4.0, 4.0]), np.array([6.0, 200.0]))
    near, far = cam.dof_limits_m(50.0, 4.0, 6.0)
    # then the reciprocals of shared.camera's limits; a depth of field reaching infinity gives 1/far = 0
    assert inv_near[0] == pytest.approx(1.0 / near, rel=1e-9)
    assert inv_far[0] == pytest.approx(1.0 / far, rel=1e-9)
    assert inv_far[1] == 0.0


def test_subject_soft_before_a_sharp_sky_needs_a_wider_aperture_by_hand():
    # given the subject 12.6 m away at 35 mm, the background the sky, a lens f/1-22 focusing 0.5-100 m,
    # and a style asking subject soft, background sharp
    lens = FR.Lens(35.0, (0.5, 100.0), (1.0, 22.0))
    inv = np.array([ABSENT, at(12.6), SKY])
    out = FR.unreachable_labels(lens, np.array([False, False, True]), np.array([False, True, True]), inv)
    # then by hand: the sky sharp needs s >= H; the subject soft needs D_n = s (H - f) / (H + s - 2 f) > 12.6
    # at s = 100 m at most: H > (1260 + 74.8 f) / 87.4, i.e. N < f^2 / ((H - f) c)
    f = 0.035
    h_needed = (1260.0 + 74.8 * f) / 87.4
    n_needed = (35.0 ** 2) / ((h_needed - f) * 1000.0 * cam.COC_MM)
    assert n_needed == pytest.approx(0.636, abs=0.001)
    assert [u.region for u in out] == [2]  # the subject's label is granted first; the background's is not
    assert out[0].kind == "f_number"
    assert out[0].needs_f_number == pytest.approx(n_needed, rel=0.01)
    assert out[0].reason == "background sharp with subject soft: needs f/0.64 (the lens opens to f/1)"


def test_focus_beyond_the_lens_range_by_hand():
    # given a 100 mm lens focusing only out to 3 m, the subject at 2 m, the sky behind, subject soft asked
    lens = FR.Lens(100.0, (0.5, 3.0), (1.0, 22.0))
    inv = np.array([ABSENT, at(2.0), SKY])
    out = FR.unreachable_labels(lens, np.array([False, False, True]), np.array([False, True, True]), inv)
    # then by hand: s >= H and s (H - f) / (H + s - 2 f) > 2 give the least s where both bounds meet:
    # H^2 - (f + 4) H + 4 f = 0, H = 4.0 m (at f/19.2, inside the lens's range): focus at 4 m or beyond
    assert [(u.region, u.kind) for u in out] == [(2, "focus")]
    assert out[0].needs_focus_m == pytest.approx(4.0, rel=0.01)
    assert "needs focus at 4 m or beyond (the lens focuses to 3 m)" in out[0].reason


def test_foreground_at_the_subjects_depth_is_beyond_any_lens():
    # given the foreground at the subject's own depth (10 m), asked soft while the subject is asked sharp
    lens = FR.Lens(35.0, (0.5, 100.0), (1.0, 22.0))
    inv = np.array([at(10.0), at(10.0), at(30.0)])
    out = FR.unreachable_labels(lens, np.array([False, True, False]), np.array([True, True, True]), inv)
    # then the foreground, and only it, is out of reach, for its depth
    assert [(u.region, u.kind) for u in out] == [(0, "depth")]
    assert out[0].reason.startswith("foreground at the subject's depth")
    # and asked sharp with the subject, the same scene is reachable
    assert FR.unreachable_labels(lens, np.array([True, True, False]), np.array([True, True, True]), inv) == []


def test_reachable_combinations_are_never_excused():
    # given a juggler-like scene: subject 8 m, foreground 4 m, background 40 m, at 50 mm
    lens = FR.Lens(50.0, (0.5, 100.0), (1.0, 22.0))
    inv = np.array([at(4.0), at(8.0), at(40.0)])
    present = np.ones(3, bool)
    # then every combination of labels some lens setting gives is reachable
    for asked in ([False, True, False], [True, True, True], [False, False, True], [True, False, False],
                  [False, True, True], [True, True, False], [False, False, False]):
        assert FR.unreachable_labels(lens, np.array(asked), present, inv) == [], asked
    # and a region whose sample leaves its label possible stays reachable: 9 of the background's 20 quantiles
    # at 8 m (inside any depth of field holding the subject), the rest at infinity: its true share in focus
    # lies between 8/20 and 10/20, so it may be under half
    spread = np.where(np.arange(S) < 9, 1 / 8.0, 0.0)
    inv2 = np.array([ABSENT, at(8.0), spread])
    out = FR.unreachable_labels(lens, np.array([False, True, False]), np.array([False, True, True]), inv2)
    assert out == []


def test_the_sample_bounds_the_true_share_by_one_quantile():
    # given a region's 20 quantiles at (i + 1/2) / 20 of its pixels: with k of them inside a depth of field,
    # its true share inside lies strictly between (k - 1) / 20 and (k + 1) / 20 (inverted CDF)
    rng = np.random.default_rng(3)
    for _ in range(200):
        pix = rng.gamma(rng.uniform(0.5, 4.0), size=rng.integers(50, 4000))
        q = np.quantile(pix, (np.arange(S) + 0.5) / S, method="inverted_cdf")
        a, b = np.sort(rng.uniform(pix.min(), pix.max(), 2))
        k = int(FR.in_focus_count(q, np.array([a]), np.array([b]))[0])
        share = float(np.mean((pix >= a) & (pix <= b)))
        assert (k - 1) / S < share < (k + 1) / S or (k == 0 and share < 1 / S)
    # then "sharp" is possible with 10 of 20 inside and not with 9; "soft" with 10 and not with 11
    assert FR.may_reach(np.array([9, 10]), S, sharp=True).tolist() == [False, True]
    assert FR.may_reach(np.array([10, 11]), S, sharp=False).tolist() == [True, False]


def test_a_foreground_that_cannot_drop_below_half_is_out_of_reach():
    # given the subject at 8 m asked sharp and the foreground asked soft, 11 of its 20 quantiles at the
    # subject's depth and 9 at 3 m: any depth of field holding the subject holds those 11, so at least
    # 10/20 of its pixels are in focus whatever the lens does (a share of 11/20 used to pass as "within
    # 0.1 of the asked side")
    lens = FR.Lens(50.0, (0.5, 100.0), (1.0, 22.0))
    fg = np.where(np.arange(S) < 11, 1 / 8.0, 1 / 3.0)
    inv = np.array([fg, at(8.0), at(40.0)])
    out = FR.unreachable_labels(lens, np.array([False, True, False]), np.ones(3, bool), inv)
    assert [(u.region, u.kind) for u in out] == [(0, "depth")]
    # and with 10 of 20 there it may be under half, so it stays the controller's to meet
    fg10 = np.where(np.arange(S) < 10, 1 / 8.0, 1 / 3.0)
    inv10 = np.array([fg10, at(8.0), at(40.0)])
    assert FR.unreachable_labels(lens, np.array([False, True, False]), np.ones(3, bool), inv10) == []


def test_a_window_narrower_than_a_focus_grid_step_is_found():
    # given a thin foreground slab 10.00-10.02 m away asked sharp, the subject 10.1 m away asked soft, and a
    # 200 mm lens at f/2 only: its depth of field holds the slab without the subject only with its far limit
    # between 10.02 and 10.1 m, focus 9.40-9.47 m (0.75 %), under one step of a 240-point log grid over
    # 0.5-100 m (2.2 %, which called it out of reach)
    exact = FR.Lens(200.0, (0.5, 100.0), (2.0, 2.0), hold_focus=0.0, hold_f_number=0.0)
    fg = 1.0 / np.linspace(10.0, 10.02, S)
    inv = np.array([fg, at(10.1), SKY])
    asked = np.array([True, False, False])
    # then, for a lens that held its focus exactly, the focus distances where a limit meets a quantile's depth
    # find it
    assert FR.unreachable_labels(exact, asked, np.ones(3, bool), inv) == []
    # and the lens as the bridge holds it (focus within 2 %: a wanted s settles anywhere in [s / 1.02, s / 0.98],
    # which needs a window 4.1 % wide) cannot keep it: out of reach on a knife edge, the hold named
    out = FR.unreachable_labels(dataclasses.replace(exact, hold_focus=0.02), asked, np.ones(3, bool), inv)
    assert [(u.region, u.kind) for u in out] == [(0, "hold")]
    assert out[0].reason.endswith("only on a knife edge, narrower than the lens holds (focus ±2 %, f-number ±0)")


def _needed_f_number_for_soft_subject_before_sky(d_m: float, focal_mm: float, focus_m: float) -> float:
    """By hand (thin lens): the largest f-number whose near limit lies beyond d_m when focused at focus_m."""
    f = focal_mm / 1000.0
    h = (d_m * focus_m - 2.0 * d_m * f + focus_m * f) / (focus_m - d_m)  # D_n = s (H - f) / (H + s - 2 f) = d
    return focal_mm ** 2 / ((h - f) * 1000.0 * cam.COC_MM)


def test_a_subject_soft_only_wide_open_is_a_knife_edge_for_the_aperture_hold():
    # given the subject soft before a sharp sky at 35 mm, the lens f/1-22 focusing out to 100 m, and the
    # subject where only f/1.03 or wider gives it (the focus at 100 m, by hand): the lens, asked f/1, may
    # settle at f/1.05 (the bridge sends no change under 0.05)
    lens = FR.Lens(35.0, (0.5, 100.0), (1.0, 22.0))
    asked, present = np.array([False, False, True]), np.array([False, True, True])
    d = next(x for x in np.arange(4.0, 14.0, 0.001) if _needed_f_number_for_soft_subject_before_sky(x, 35.0, 100.0)
             < 1.03)
    inv = np.array([ABSENT, at(d), SKY])
    # then a lens that held f/1 exactly reaches it, the held lens only on a knife edge
    assert FR.unreachable_labels(dataclasses.replace(lens, hold_focus=0.0, hold_f_number=0.0), asked, present,
                                 inv) == []
    assert [(u.region, u.kind) for u in FR.unreachable_labels(lens, asked, present, inv)] == [(2, "hold")]
    # and where f/1.15 does (still f/1.148 with the focus 2 % short of 100 m, by hand) it is reachable
    d2 = next(x for x in np.arange(4.0, 14.0, 0.001) if _needed_f_number_for_soft_subject_before_sky(x, 35.0, 100.0)
              < 1.15)
    assert _needed_f_number_for_soft_subject_before_sky(d2, 35.0, 100.0 / 1.02) > 1.05
    assert FR.unreachable_labels(lens, asked, present, np.array([ABSENT, at(d2), SKY])) == []


def _truths_with_depths(k: int, inv_depth: np.ndarray, focal_mm: float = 100.0) -> list:
    src = synth.instructions(k)
    return [dataclasses.replace(t, focal_length_mm=focal_mm, lens_limits=np.float32([0.5, 100.0, 1.0, 22.0]),
                                region_inverse_depth=inv_depth.astype(np.float32))
            for t in synth.truths(src.image_targets)]


def test_the_report_excludes_unreachable_frames_from_the_judged_agreement_and_shows_both():
    # given 48 frames at 100 mm; the style asks the foreground soft with the subject sharp; in the first 12
    # the foreground is at the subject's depth, in the rest 3 m nearer; the flight films the foreground sharp
    k = 48
    fin_src = np.tile([False, True, False], (k, 1))
    src = synth.instructions(k, focus_in=fin_src)
    near_fg = np.array([at(4.0), at(7.0), at(30.0)])
    same_fg = np.array([at(7.0), at(7.0), at(30.0)])
    truths = _truths_with_depths(k, near_fg)
    truths[:12] = _truths_with_depths(12, same_fg)
    filmed = np.tile([True, True, False], (k, 1))
    truths = [dataclasses.replace(t, region_in_focus=filmed[i]) for i, t in enumerate(truths)]
    fid = F.compute_fidelity(src, None, truths)
    fo = fid.summary["truth"]["focus"]["foreground"]
    # then the raw agreement is 0, judged over the 36 reachable frames it is still 0 (the controller's miss),
    # and the 12 at the subject's depth are named
    assert fo["agreement"] == 0.0 and fo["n_frames"] == 48
    assert fo["n_frames_reachable"] == 36 and fo["n_frames_unreachable"] == 12
    assert fo["agreement_reachable"] == 0.0
    assert fid.summary["focus_reach"] == {"frames_judged": 48,
                                          "unreachable_frames": {"foreground": 12, "subject": 0, "background": 0},
                                          "rate_windows": []}
    reach = fid.series["reach"]
    assert reach.unreachable[:12, 0].all() and not reach.unreachable[12:].any()
    assert reach.reasons[0, 0].startswith("foreground at the subject's depth")
    # and when the flight films the reachable frames right, the judged agreement is 1 while the raw one is 0.75
    filmed[12:] = [False, True, False]
    truths = [dataclasses.replace(t, region_in_focus=filmed[i]) for i, t in enumerate(truths)]
    s = F.compute_fidelity(src, None, truths).summary
    fo = s["truth"]["focus"]["foreground"]
    assert fo["agreement"] == pytest.approx(0.75) and fo["agreement_reachable"] == 1.0
    g = {x["id"]: x for x in s["goals"]}
    assert g["truth_focus_foreground"]["value"] == 1.0 and g["truth_focus_foreground"]["status"] == "met"
    assert s["headline"]["truth"]["focus_agreement"]["foreground"] == pytest.approx(0.75)


def test_a_band_the_truth_counts_no_foreground_is_judged_for_the_extraction_by_its_depths():
    # given 12 frames asking the foreground soft with the subject sharp; the band below the feet lies at the
    # subject's depth; in frames 8-11 the truth counts it no foreground (too short) but keeps its depths,
    # and in frames 10-11 it records none (no band at all); the extraction reads a foreground, sharp, in all 12
    k = 12
    src = synth.instructions(k)
    truths = _truths_with_depths(k, np.array([at(7.0), at(7.0), at(30.0)]))
    present = np.tile([True, True, True], (k, 1))
    present[8:, 0] = False
    truths = [dataclasses.replace(t, region_present=present[i], region_in_focus=np.array([present[i, 0], True, False]),
                                  region_inverse_depth=np.array([ABSENT if i >= 10 else at(7.0), at(7.0), at(30.0)],
                                                                np.float32))
              for i, t in enumerate(truths)]
    out = synth.instructions(k, focus_in=np.tile([True, True, False], (k, 1)))
    s = F.compute_fidelity(src, out, truths)
    # then frames 0-9 are out of reach (the band at the subject's depth), 10-11 cannot be judged
    reach = s.series["reach"]
    assert reach.unreachable[:10, 0].all() and not reach.unreachable[10:, 0].any()
    ext, tru = s.summary["extraction"]["focus"]["foreground"], s.summary["truth"]["focus"]["foreground"]
    assert (ext["n_frames_reachable"], ext["agreement_reachable"]) == (2, 0.0)
    # the truth's own frames are unchanged: its 8 foregrounds, all out of reach
    assert (tru["n_frames"], tru["n_frames_reachable"]) == (8, 0)
    # and each of the extraction's frames says why
    m = s.series["misses"]["extraction"]
    assert list(m.kind[:, 0]) == ["out_of_reach"] * 10 + ["unjudged"] * 2
    assert "no depths to judge its reach by" in m.why[10, 0]
    assert list(s.series["misses"]["truth"].kind[:, 0]) == ["out_of_reach"] * 8 + ["absent"] * 4


def test_runs_group_frames_per_region_and_shot():
    # given frames 2-5 and 8-9 of the foreground unreachable, a shot starting at row 4
    rch = RF.Reach.none(10)
    rch.unreachable[[2, 3, 4, 5, 8, 9], 0] = True
    for i in (2, 3, 4, 5, 8, 9):
        rch.reasons[i, 0] = f"why {i}"
    out = RF.runs(rch, np.arange(10) / 24.0, np.arange(10), shot_rows=[4])
    assert [(r["shot"], r["first_frame"], r["last_frame"], r["frames"]) for r in out] == \
        [(0, 2, 3, 2), (1, 4, 5, 2), (1, 8, 9, 2)]
    assert out[0]["reason"] == "why 2" and out[0]["reason_last"] == "why 3"
    # and a run whose verdicts change kind (a knife edge at each end of frames needing a wider aperture) is cut there
    rch.kinds[[2, 5], 0] = "hold"
    rch.kinds[[3, 4, 8, 9], 0] = "f_number"
    out = RF.runs(rch, np.arange(10) / 24.0, np.arange(10))
    assert [(r["kind"], r["first_frame"], r["last_frame"]) for r in out] == \
        [("hold", 2, 2), ("f_number", 3, 4), ("hold", 5, 5), ("f_number", 8, 9)]


def test_a_recording_without_depths_is_never_judged():
    # given truths of an older recording (no region depths, no lens range)
    src = synth.instructions(8)
    s = F.compute_fidelity(src, None, synth.truths(src.image_targets)).summary
    assert s["focus_reach"]["frames_judged"] == 0
    fo = s["truth"]["focus"]["subject"]
    assert fo["agreement_reachable"] == fo["agreement"] and fo["n_frames_unreachable"] == 0


def test_the_report_names_the_lens_hold_of_every_knife_edge_frame():
    # given 24 frames at 35 mm asking the subject soft before a sharp sky, the subject where only f/1.03 or
    # wider gives it (by hand: reachable only at the lens's widest, on a knife edge for its 0.05 f-number hold)
    k = 24
    d = next(x for x in np.arange(4.0, 14.0, 0.001) if _needed_f_number_for_soft_subject_before_sky(x, 35.0, 100.0)
             < 1.03)
    src = synth.instructions(k, focus_in=np.tile([False, False, True], (k, 1)))
    truths = _truths_with_depths(k, np.array([at(d), at(d), SKY]), focal_mm=35.0)
    fid = F.compute_fidelity(src, None, truths)
    # then every frame's background is out of reach, each frame saying with which hold it was judged
    reach = fid.series["reach"]
    assert reach.unreachable[:, 2].all() and not reach.unreachable[:, :2].any()
    assert all(r == "background sharp with subject soft: only on a knife edge, narrower than the lens holds "
                    "(focus ±2 %, f-number ±0.05)" for r in reach.reasons[:, 2])
    assert fid.summary["focus_reach"]["unreachable_frames"] == {"foreground": 0, "subject": 0, "background": k}


# --- the lens's rates: a rack from the subject to the background ---------------------------------
# 50 mm, f/2 only, c = 0.05 mm: H = 25.05 m. The subject (all samples at 10 m) is sharp for focus in
# [H / (1 + 0.1 (H - f)), (H - 2 f) / (0.1 (H - f) - 1)] = [7.157, 16.633] m; the background (all at
# 40 m) is sharp from H / (1 + 0.025 (H - f)) = 15.415 m on. Subject sharp with background soft:
# [7.157, 15.415); subject soft with background sharp: beyond 16.633 m, 1.218 m further.
RACK_LENS = FR.Lens(50.0, (0.5, 100.0), (2.0, 2.0), coc_mm=0.05, hold_focus=0.0, hold_f_number=0.0)
RACK_DEPTH = np.array([np.full(20, np.nan), np.full(20, 0.1), np.full(20, 0.025)])


def _rack(n_frames: int, switch: int):
    asked = np.array([[False, i < switch, i >= switch] for i in range(n_frames)])
    present = np.tile([False, True, True], (n_frames, 1))
    return asked, present, np.repeat(RACK_DEPTH[None], n_frames, axis=0)


def test_rack_limits_by_hand():
    h = 50.0 * 50.0 / (2.0 * 0.05) / 1000.0 + 0.05
    assert h == pytest.approx(25.05)
    inv_far, inv_near = FR.dof_inverse(50.0, np.array([2.0] * 3), np.array([7.16, 15.42, 16.64]), 0.05)
    assert inv_far[0] < 0.1 < inv_near[0]  # 7.16 m: the subject inside
    assert inv_far[1] < 0.025  # 15.42 m: the background inside
    assert inv_near[2] < 0.1  # 16.64 m: the subject out, in front of the field


def test_rate_limited_rack_misses_the_frames_the_focus_travels():
    asked, judged, depth = _rack(8, 3)
    lenses, slow = [RACK_LENS] * 8, FR.LensRates(0.5, 1.0)
    # the focus moves 0.5 m a frame and both labels need a jump of 1.218 m (15.415 -> 16.633 m): any
    # path misses the combination in two frames (e.g. 15.4, 15.9, 16.4, 16.9 m: frames 3 and 4)
    assert FR.rate_min_misses(lenses, asked, judged, depth, slow, 1.0, (1, 2)) == 2
    # each region alone: the subject turns soft in front of the field (under 7.157 m, one step from 7.2 m)
    # and the background is sharp from 15.415 m, inside the subject's sharp field: no miss
    assert FR.rate_min_misses(lenses, asked, judged, depth, slow, 1.0, (1,)) == 0
    assert FR.rate_min_misses(lenses, asked, judged, depth, slow, 1.0, (2,)) == 0
    # 2 m a frame: 15.4 -> 17.4 m in one frame, nothing is missed
    assert FR.rate_min_misses(lenses, asked, judged, depth, FR.LensRates(2.0, 1.0), 1.0, (1, 2)) == 0
    # 0.25 m a frame: 15.4 -> 16.65 m takes five frames, four missed, with six frames on either side;
    # with three before the switch, missing those three (the focus far all along) is the fewer
    long = _rack(12, 6)
    assert FR.rate_min_misses([RACK_LENS] * 12, *long, FR.LensRates(0.25, 1.0), 1.0, (1, 2)) == 4
    assert FR.rate_min_misses(lenses, asked, judged, depth, FR.LensRates(0.25, 1.0), 1.0, (1, 2)) == 3


def test_rate_limited_rack_moves_on_where_a_frame_is_not_judged():
    asked, judged, depth = _rack(8, 3)
    lenses = [RACK_LENS] * 3 + [None] + [RACK_LENS] * 4  # no truth at the switch: the lens still moves 0.5 m
    assert FR.rate_min_misses(lenses, asked, judged, depth, FR.LensRates(0.5, 1.0), 1.0, (1, 2)) == 1
    judged[3:5, 1] = False  # the subject not judged at frames 3-4: the background alone is sharp on the way
    assert FR.rate_min_misses([RACK_LENS] * 8, asked, judged, depth, FR.LensRates(0.5, 1.0), 1.0, (1, 2)) == 0


# --- the rates' proven lower bound and the frames it excuses ---------------------------------------
# RACK_LENS (f/2 only). With cells of 1/8 of a frame's travel (0.0625 m at 0.5 m a frame): the settings for
# the subject sharp with the background soft end in the cell holding 15.415 m (15.375-15.4375), those for
# the opposite start in the one holding 16.633 m (16.625-16.6875), 20 cells further; a lens may reach cells
# a frame's travel moves it: 8 cells a frame, 3 steps, two frames missed (as rate_min_misses).
FINE = (8, 1)


def _grid(rate_mps: float, dt_s: float = 1.0, cells=FINE) -> FR.RateGrid:
    return FR.rate_grid(RACK_LENS.focus_m, RACK_LENS.f_number, FR.LensRates(rate_mps, 1.0), dt_s, cells)


def _rate_frames(asked, judged, depth, grid: FR.RateGrid, dt_s: float = 1.0) -> list:
    return [FR.RateFrame(i * dt_s, FR.possible_cells(grid, RACK_LENS, asked[i], judged[i], depth[i]))
            for i in range(len(asked))]


def _least(asked, judged, depth, rate_mps: float, dt_s: float = 1.0, cells=FINE) -> int:
    grid = _grid(rate_mps, dt_s, cells)
    return FR.rate_least_misses(_rate_frames(asked, judged, depth, grid, dt_s), grid)


def test_possible_cells_are_the_cells_holding_the_rack_settings_by_hand():
    asked, judged, depth = _rack(2, 1)
    grid = _grid(0.5)
    edges = grid.focus_edges
    before = np.flatnonzero(FR.possible_cells(grid, RACK_LENS, asked[0], judged[0], depth[0])[:, 0])
    after = np.flatnonzero(FR.possible_cells(grid, RACK_LENS, asked[1], judged[1], depth[1])[:, 0])
    # before: from the cell holding 7.157 m to the one holding 15.415 m; after: from the one holding 16.633 m
    assert (edges[before[0]], edges[before[-1] + 1]) == pytest.approx((7.125, 15.4375))
    assert before.size == before[-1] - before[0] + 1
    assert edges[after[0]] == pytest.approx(16.625) and edges[after[-1] + 1] == pytest.approx(100.0)
    assert after[0] - before[-1] == 20


def test_possible_cells_keep_every_setting_that_gives_the_labels():
    # given random scenes and lenses, every (focus, f-number) that gives the labels lies in a possible cell
    rng = np.random.default_rng(3)
    for _ in range(20):
        lens = FR.Lens(float(rng.uniform(30, 200)), (0.5, 100.0), (1.0, 22.0))
        grid = FR.rate_grid(lens.focus_m, lens.f_number, FR.LensRates(15.0, 3.0), 1 / 24)
        depth = np.sort(1.0 / rng.uniform(2.0, 80.0, (3, 20)), axis=1)
        asked, judged = rng.random(3) < 0.5, rng.random(3) < 0.8
        cells = FR.possible_cells(grid, lens, asked, judged, depth)
        s, n = np.meshgrid(np.geomspace(0.5, 99.9, 500), np.geomspace(1.0, 21.9, 80))
        ok = FR._feasible(lens, n.ravel(), s.ravel(), list(np.flatnonzero(judged)), asked, depth)
        i = np.searchsorted(grid.focus_edges, s.ravel(), side="right") - 1
        j = np.searchsorted(grid.f_number_edges, n.ravel(), side="right") - 1
        assert cells[i[ok], j[ok]].all()


def test_rate_least_misses_by_hand_equals_the_grid_count_on_the_racks():
    asked, judged, depth = _rack(8, 3)
    # 0.5 m a frame: two frames missed; 2 m: none; 0.25 m (39 cells, 8 a frame: five steps, four missed, or
    # the three frames before the switch if fewer)
    assert _least(asked, judged, depth, 0.5) == 2
    assert _least(asked, judged, depth, 2.0) == 0
    assert _least(asked, judged, depth, 0.25) == 3
    long = _rack(12, 6)
    assert _least(*long, 0.25) == 4
    # half a second between frames halves the travel: 0.5 m/s moves as 0.25 m a frame
    assert _least(*long, 0.5, dt_s=0.5) == 4
    # each equals rate_min_misses (an upper bound): the bound is exact on these racks
    assert FR.rate_min_misses([RACK_LENS] * 12, *long, FR.LensRates(0.25, 1.0), 1.0, (1, 2)) == 4
    # a frame with nothing judged at the switch: the lens moves on, one frame missed (the grid count's too)
    grid = _grid(0.5)
    frames = _rate_frames(asked, judged, depth, grid)
    frames[3] = FR.RateFrame(3.0, None)
    assert FR.rate_least_misses(frames, grid) == 1


def test_the_lower_bound_on_coarse_cells_by_hand():
    # the report's cells (1/2 of a frame's travel, 0.25 m): the settings end in 15.25-15.5 m and start in
    # 16.5-16.75 m, 5 cells apart. A lens in a cell moves at most 2 cells a frame (a move of exactly 2 cells
    # from the half-open cell [e, e + w) lands below e + 3 w): three steps, two frames missed, as any lens.
    # Cells of a whole frame's travel (the first look's): 15-15.5 m and 16.5-17 m, 3 cells apart, one a
    # frame: two frames missed too
    asked, judged, depth = _rack(8, 3)
    assert _least(asked, judged, depth, 0.5, cells=FR.RATE_BOUND_CELLS) == 2
    assert _least(asked, judged, depth, 0.5, cells=(1, 1)) == 2
    assert FR.rate_min_misses([RACK_LENS] * 8, asked, judged, depth, FR.LensRates(0.5, 1.0), 1.0, (1, 2)) == 2


def _random_rack(rng: np.random.Generator, n_frames: int = 24):
    """A random scene (20 samples a region), labels switching twice, a lens and rates."""
    lens = FR.Lens(float(rng.uniform(60, 120)), (0.5, 30.0), (1.0, 2.8), hold_focus=0.0, hold_f_number=0.0)
    d = rng.uniform(4, 9)
    depth = np.sort(1.0 / np.stack([rng.uniform(2, 6, 20), rng.uniform(d, d + 0.8, 20), rng.uniform(30, 80, 20)]),
                    axis=1)
    fg = rng.random(2) < 0.5  # a rack from the subject to the background, then any labels
    combos = [np.array([fg[0], True, False]), np.array([fg[1], False, True]), rng.random(3) < 0.5]
    cut = np.sort(rng.choice(np.arange(4, n_frames - 4), 2, replace=False))
    asked = np.array([combos[int(i >= cut[0]) + int(i >= cut[1])] for i in range(n_frames)])
    judged = np.tile([rng.random() < 0.5, True, True], (n_frames, 1))
    rates = FR.LensRates(float(rng.uniform(1.5, 5)), float(rng.uniform(0.5, 3.0)))
    return lens, asked, judged, np.repeat(depth[None], n_frames, axis=0), rates


def _greedy_misses(lens, asked, judged, depth, rates, dt_s: float, start) -> int:
    """A lens moved as the simulator moves it (each axis at most its rate's step a frame) towards the nearest
    setting that gives the frame's judged labels: the frames it misses (the may_reach rule, as the bound)."""
    s, n = np.meshgrid(np.linspace(*lens.focus_m, 400), np.linspace(*lens.f_number, 60))
    s, n = s.ravel(), n.ravel()
    at, missed = list(start), 0
    for i in range(len(asked)):
        regions = list(np.flatnonzero(judged[i]))
        ok = FR._feasible(lens, n, s, regions, asked[i], depth[i])
        if ok.any():
            k = np.argmin(np.maximum(np.abs(s[ok] - at[0]) / rates.focus_mps,
                                     np.abs(n[ok] - at[1]) / rates.f_number_ps))
            at = [at[0] + np.clip(s[ok][k] - at[0], -rates.focus_mps * dt_s, rates.focus_mps * dt_s),
                  at[1] + np.clip(n[ok][k] - at[1], -rates.f_number_ps * dt_s, rates.f_number_ps * dt_s)]
        missed += not FR._feasible(lens, np.array([at[1]]), np.array([at[0]]), regions, asked[i], depth[i])[0]
    return missed


def test_the_lower_bound_never_exceeds_a_rate_limited_lens_or_the_grid_count():
    # given random racks filmed 1/24 s apart (stamps rounded to the nanosecond, from an epoch-sized start),
    # the report's bound is at most what a lens moving at the rates misses (greedy paths from several starts)
    # and at most the grid's count (an upper bound on the fewest); where the rates bind (8 of the 12) it meets
    # the grid count, so it is the fewest there
    rng = np.random.default_rng(11)
    met = binding = 0
    for _ in range(12):
        lens, asked, judged, depth, rates = _random_rack(rng)
        stamps = [1_795_783_304_502_860_431 + int(round(i * 1e9 / 24)) for i in range(len(asked))]
        dt = float(np.max(np.diff(stamps))) * 1e-9
        grid = FR.rate_grid(lens.focus_m, lens.f_number, rates, dt, slack_s=1e-9)
        frames = [FR.RateFrame((st - stamps[0]) * 1e-9, FR.possible_cells(grid, lens, asked[i], judged[i], depth[i]))
                  for i, st in enumerate(stamps)]
        bound = FR.rate_least_misses(frames, grid)
        grid_count = FR.rate_min_misses([lens] * len(asked), asked, judged, depth, rates, 1 / 24, (0, 1, 2))
        greedy = min(_greedy_misses(lens, asked, judged, depth, rates, 1 / 24, st)
                     for st in ((0.5, 1.0), (15.0, 2.0), (30.0, 2.8)))
        assert bound <= grid_count and bound <= greedy
        binding += grid_count > 0
        met += grid_count > 0 and bound == grid_count
    assert binding >= 4 and met == binding


def test_rate_frames_time_steps_from_epoch_stamps_exactly():
    # given stamps since the epoch (1.8e18 ns), 1/24 s apart and rounded to the nanosecond: every step moves
    # the lens at most the grid's cells per frame (2), not 3 as float seconds of such stamps would say
    k = 12
    asked, judged, depth = _rack(k, 6)
    truths = _truths_with_depths(k, RACK_DEPTH, focal_mm=50.0)
    truths = [dataclasses.replace(t, lens_limits=np.float32([0.5, 100.0, 2.0, 2.0]),
                                  stamp_ns=1_795_783_304_502_860_431 + int(i * 1e9 / 24)) for i, t in enumerate(truths)]
    frames, grid = RF.rate_frames(asked, judged, truths, FR.LensRates(12.0, 3.0))
    assert {grid.reach(b.t_s - a.t_s) for a, b in zip(frames, frames[1:])} == {FR.RATE_BOUND_CELLS}


def test_rate_windows_excuse_only_the_flights_misses_near_the_switch_up_to_the_bound():
    # given the 12-frame rack at 0.25 m a frame (4 frames forced): the window is four frames either side
    asked, judged, depth = _rack(12, 6)
    grid = _grid(0.25)
    frames = _rate_frames(asked, judged, depth, grid)
    missed = np.zeros(12, bool)
    missed[[0, 6, 7, 8, 9, 10]] = True  # the flight lags five frames, and missed frame 0
    (w,) = FR.rate_windows(frames, grid, asked, missed)
    assert (w.switches, w.first, w.last, w.least) == ((6,), 2, 9, 4)
    assert w.missed == (6, 7, 8, 9) and w.excused == (6, 7, 8, 9)
    # a flight that missed fewer than the bound has only those excused; one that missed nothing none
    missed[:] = False
    missed[[5, 11]] = True
    (w,) = FR.rate_windows(frames, grid, asked, missed)
    assert w.missed == (5,) and w.excused == (5,)
    assert FR.rate_windows(frames, grid, asked, np.zeros(12, bool))[0].excused == ()
    # a rate the rack does not bind: no window
    fast = _grid(2.0)
    assert FR.rate_windows(_rate_frames(asked, judged, depth, fast), fast, asked, np.ones(12, bool)) == []


def test_rate_windows_of_two_racks_apart():
    # given a rack to the background at frame 6 and back at 18, 0.25 m a frame: four frames forced at each
    asked = np.array([[False, not 6 <= i < 18, 6 <= i < 18] for i in range(24)])
    judged = np.tile([False, True, True], (24, 1))
    grid = _grid(0.25)
    frames = _rate_frames(asked, judged, np.repeat(RACK_DEPTH[None], 24, axis=0), grid)
    assert FR.rate_least_misses(frames, grid) == 8
    out = FR.rate_windows(frames, grid, asked, np.ones(24, bool))
    assert [(w.switches, w.first, w.last, w.least, w.excused) for w in out] == \
        [((6,), 2, 9, 4, (4, 5, 6, 7)), ((18,), 14, 21, 4, (16, 17, 18, 19))]
    # racked back 3 frames after: any lens misses three (frames 6-8, or as many on its travels); cut at frame
    # 7 the parts force 1 (frame 5 or 6) and 2 (frames 7-8 or 9-10), adding up to the whole's 3, so it is cut
    back = np.array([[False, not 6 <= i < 9, 6 <= i < 9] for i in range(24)])
    frames = _rate_frames(back, judged, np.repeat(RACK_DEPTH[None], 24, axis=0), grid)
    assert FR.rate_least_misses(frames, grid) == 3
    out = FR.rate_windows(frames, grid, back, np.ones(24, bool))
    assert [(w.switches, w.first, w.last, w.least, w.excused) for w in out] == \
        [((6,), 5, 6, 1, (5,)), ((9,), 7, 10, 2, (8, 9))]


def test_the_report_excuses_rate_misses_per_frame_with_the_rates_and_the_bound():
    # given a rack at 100 mm, f/2 (c = 0.13365 mm: H = 37.51 m), the subject 10 m away and the background 40 m:
    # the subject is sharp up to focus (H - 2 f) / (0.1 (H - f) - 1) = 13.61 m, the background from
    # H / (1 + 0.025 (H - f)) = 19.38 m, 5.77 m further; frames 1/24 s apart, a focus rate of 24 m/s (1 m a
    # frame): six steps, any lens misses five frames. The report's cells of 0.5 m: 13.5-14.0 m and 19.0-19.5 m,
    # 11 cells apart, 2 a frame: six steps, five frames forced, exact; the flight films the switch seven frames
    # late
    k, sw = 36, 12
    asked = np.array([[False, i < sw, i >= sw] for i in range(k)])
    src = synth.instructions(k, focus_in=asked)
    truths = _truths_with_depths(k, RACK_DEPTH, focal_mm=100.0)
    filmed = np.array([[False, i < sw + 7, i >= sw + 7] for i in range(k)])
    truths = [dataclasses.replace(t, lens_limits=np.float32([0.5, 100.0, 2.0, 2.0]), region_in_focus=filmed[i],
                                  stamp_ns=int(i * 1e9 / 24)) for i, t in enumerate(truths)]
    fid = F.compute_fidelity(src, None, truths, lens_rates=FR.LensRates(24.0, 3.0))
    reach = fid.series["reach"]
    # then the window is five frames either side (7-16); the five of the flight's misses in it are excused,
    # the background (granted after the subject), each naming the rates and the bound; without the rates none
    (w,) = fid.summary["focus_reach"]["rate_windows"]
    assert (w["first_frame"], w["last_frame"], w["least_misses"], w["flown_misses"], w["excused"]) == (7, 16, 5, 5, 5)
    assert np.flatnonzero(reach.unreachable[:, 2]).tolist() == [12, 13, 14, 15, 16]
    assert not reach.unreachable[:, :2].any()
    assert reach.reasons[12, 2] == ("background sharp: the focus moves at most 24 m/s and the f-number 3/s, so any "
                                    "lens misses at least 5 of frames 7-16 round the switch at frame 12 (this "
                                    "flight missed 5 of them)")
    assert fid.summary["truth"]["focus"]["background"]["agreement_reachable"] == pytest.approx(29 / 31)
    assert not F.compute_fidelity(src, None, truths).series["reach"].unreachable.any()
    # a flight that racks on time has nothing excused (nor any window: nothing to excuse), nor one whose lens
    # moves fast enough (240 m/s: 10 m a frame, the gap in one)
    on_time = [dataclasses.replace(t, region_in_focus=asked[i]) for i, t in enumerate(truths)]
    assert F.compute_fidelity(src, None, on_time, lens_rates=FR.LensRates(24.0, 3.0)).summary["focus_reach"][
        "rate_windows"] == []
    assert F.compute_fidelity(src, None, truths, lens_rates=FR.LensRates(240.0, 3.0)).summary["focus_reach"][
        "rate_windows"] == []
    # a new take at the switch (half a second between two frames: more than 1.5 steps) may set the lens anew
    retake = [dataclasses.replace(t, stamp_ns=t.stamp_ns + int(0.5e9) * (i >= sw)) for i, t in enumerate(truths)]
    assert F.compute_fidelity(src, None, retake, lens_rates=FR.LensRates(24.0, 3.0)).summary["focus_reach"][
        "rate_windows"] == []
    # and truths without a clock (every stamp 0) are never excused
    still = [dataclasses.replace(t, stamp_ns=0) for t in truths]
    assert F.compute_fidelity(src, None, still, lens_rates=FR.LensRates(24.0, 3.0)).summary["focus_reach"][
        "rate_windows"] == []


def test_blur_in_circles_is_the_thin_lens_blur_diameter_by_hand():
    # given 50 mm at f/2 focused at 10 m, c = 0.05 mm: H - f = 2500 / (2 x 0.05) mm = 25.0 m
    # then a point at 5 m blurs by f^2 |x - s| / (N x (s - f)) = 2500 x 5000 / (2 x 5000 x 9950) = 0.1256 mm,
    # 2.513 circles; the subject at 10 m by none, and one at the near limit of the field by exactly one
    b = FR.blur_circles(50.0, np.array([2.0, 2.0]), np.array([10.0, 10.0]), np.array([0.2, 0.1]), coc_mm=0.05)
    assert b[0] == pytest.approx(2500 * 5000 / (2 * 5000 * 9950) / 0.05, rel=1e-9)
    assert b[0] == pytest.approx(2.513, abs=1e-3) and b[1] == 0.0
    _, inv_near = FR.dof_inverse(50.0, np.array([2.0]), np.array([10.0]), 0.05)
    assert FR.blur_circles(50.0, 2.0, 10.0, inv_near[0], coc_mm=0.05) == pytest.approx(1.0, rel=1e-9)


def test_the_window_of_a_combination_and_how_soft_it_leaves_the_soft_regions_by_hand():
    # given 50 mm at f/2 only, c = 0.05 mm, no hold: foreground at 5 m, subject at 10 m, background at 50 m, the
    # subject asked sharp and the others soft
    lens = FR.Lens(50.0, (0.5, 100.0), (2.0, 2.0), coc_mm=0.05, hold_focus=0.0, hold_f_number=0.0)
    inv = np.array([at(5.0), at(10.0), at(50.0)])
    asked, present = np.array([False, True, False]), np.ones(3, bool)
    w = FR.label_window(lens, asked, present, inv)
    # then the subject bounds the focus (sharp with the focus 7.157-16.633 m), since the background is soft up to
    # 1/s - (s - f) / (s (H - f)) = 1/50: s = 25.05 / 1.5 = 16.7 m and the foreground from 24.95 / 4 = 6.24 m
    assert w.f_number == (2.0, 2.0)
    assert w.focus_m[0] == pytest.approx(7.157, rel=0.006) and w.focus_m[1] == pytest.approx(16.633, rel=0.006)
    # and the soft regions are softest together where their blurs meet: 25 (1 - s/50) = 25 (s/5 - 1), s = 9.09 m,
    # each 25 (1 - 0.1818) / 9.0409 = 2.262 circles
    assert w.best[1] == pytest.approx(9.0909, rel=0.006) and w.soft_circles == pytest.approx(2.2625, abs=0.01)
    # and with the background at 30 m (soft only with the focus under 13.66 m) and the foreground at 9.5 m (soft
    # only beyond 15.29 m) nothing gives the three together, as unreachable_labels says
    inv2 = np.array([at(9.5), at(10.0), at(30.0)])
    assert FR.label_window(lens, asked, present, inv2) is None
    assert [u.region for u in FR.unreachable_labels(lens, asked, present, inv2)] == [0]
    # and with nothing asked soft: the span, and no blur to report
    w = FR.label_window(lens, np.array([True, True, True]), present, np.array([at(9.5), at(10.0), at(11.0)]))
    assert w is not None and w.soft_circles is None
