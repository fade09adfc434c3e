"""Takes of a multi-shot source: the schedule, and the settle time measured on the truth."""
import numpy as np

from cinetransfer.shots import framing_error, settle_report
from cinetransfer.services.planner.core import instructions_from_arrays
from cinetransfer.shared import messages as M
from cinetransfer.transfer import shot_schedule


def style_with_shots(k=20, cuts=(8, 14)):
    ins = instructions_from_arrays(targets=np.full((k, 1, 2), 0.5), joint_names=["nose"], fps=10.0)
    starts = np.zeros(k, bool)
    starts[[0, *cuts]] = True
    return M.Instructions(**{**{f: getattr(ins, f) for f in ("fps", "frame_duration_s", "first_frame", "joint_names",
                                                               "image_targets", "subject_visible", "subject_box",
                                                               "focus_raw", "focus_smoothed", "focus_in", "mu_m")},
                             "shot_start": starts})


def truth_at(x: float) -> M.GroundTruth:
    jn = np.full((17, 2), 0.5, np.float32)
    jn[0] = (x, 0.5)
    return M.GroundTruth(joints_norm=jn, joints_visible=np.ones(17, bool))


def test_schedule_gives_each_shot_a_take_after_a_settle_phase():
    style = style_with_shots()
    takes = shot_schedule(style, preroll_s=1.0, settle_s=0.5, one_take=False)
    assert [(t["first_row"], t["end_row"]) for t in takes] == [(0, 8), (8, 14), (14, 20)]
    assert [t["settle_frames"] for t in takes] == [10, 5, 5]
    # camera frames: 10 pre-roll, 8 of take 1, 5 settling, 6 of take 2, 5 settling, 6 of take 3
    assert [t["first_index"] for t in takes] == [10, 23, 34]
    assert [t["settle_start_index"] for t in takes] == [0, 18, 29]
    one = shot_schedule(style, preroll_s=1.0, settle_s=0.5, one_take=True)
    assert [(t["first_row"], t["end_row"], t["first_index"]) for t in one] == [(0, 20, 10)]


def test_settle_time_is_when_the_framing_stays_within_tolerance():
    style = style_with_shots()
    takes = shot_schedule(style, preroll_s=1.0, settle_s=0.5, one_take=False)
    # truth: take 1 settles at frame 6 (0.6 s); take 2 is off at its start (unreachable)
    xs = {i: (0.9 if i < 6 else 0.51) for i in range(0, 11)}
    xs.update({i: 0.8 - 0.01 * (i - 18) for i in range(18, 24)})
    xs.update({i: 0.5 for i in range(29, 35)})
    truths = {i: truth_at(x) for i, x in xs.items()}
    assert abs(framing_error(truths[7], style, 0) - 0.01) < 1e-6
    rep = settle_report(style, takes, truths)
    assert rep[0]["settled"] and rep[0]["settle_s"] == 0.6
    assert not rep[1]["settled"] and rep[1]["settle_s"] is None
    assert abs(rep[1]["error_at_take_start"] - 0.25) < 1e-6 and abs(rep[1]["best_error_while_settling"] - 0.25) < 1e-6
    assert rep[2]["settled"] and rep[2]["settle_s"] == 0.0


def test_short_shots_are_filmed_on_in_the_take_before():
    from cinetransfer.transfer import merge_short

    assert merge_short([(0, 20), (20, 22), (22, 24), (24, 40)], 12) == [(0, 24), (24, 40)]
    assert merge_short([(0, 3), (3, 30)], 12) == [(0, 30)]
    assert merge_short([(0, 20), (20, 40)], 12) == [(0, 20), (20, 40)]


def test_a_shot_opening_without_the_subject_has_nothing_to_settle_on():
    # given a third shot whose first frame shows no subject (targets NaN: a VFX morph, an empty frame)
    style = style_with_shots()
    style.image_targets[14] = np.nan
    takes = shot_schedule(style, preroll_s=1.0, settle_s=0.5, one_take=False)
    truths = {i: truth_at(0.5) for i in range(0, 35)}
    rep = settle_report(style, takes, truths)
    # then it is reported as such (settled None), not as a take that failed to settle
    assert rep[2]["settled"] is None and rep[2]["settle_s"] is None and rep[2]["error_at_take_start"] is None
    assert rep[0]["settled"] is True and rep[1]["settled"] is True
