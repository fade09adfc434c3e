"""Every frame whose focus label is not the source's gets one reason per side (report/focus_misses.py)."""
from __future__ import annotations

import numpy as np

from cinetransfer.report import fidelity as F
from cinetransfer.report import focus_misses as FM
from cinetransfer.report import reach_frames as RF
from cinetransfer.shared import messages as M


def _track(focus_in, present, frac=None, available=None) -> F.Track:
    focus_in, present = np.asarray(focus_in, bool), np.asarray(present, bool)
    n = focus_in.shape[0]
    t = F.empty_track(n, 0)
    frac = np.where(focus_in, 0.9, 0.1) if frac is None else np.asarray(frac, float)
    return F.Track(xy=t.xy, ok=t.ok, available=np.ones(n, bool) if available is None else np.asarray(available, bool),
                   frac=frac, smoothed=t.smoothed, focus_in=focus_in, present=present)


def test_each_missed_frame_gets_one_kind_and_its_reason():
    # given six frames; the source asks the foreground soft, the subject sharp, the background soft
    asked = np.tile([False, True, False], (6, 1))
    src = _track(asked, np.ones((6, 3), bool))
    # the truth: frame 0 as asked; frame 1 foreground sharp and out of reach; frame 2 background sharp
    # within reach; frame 3 no foreground; frame 4 no truth; frame 5 as asked
    t_in = asked.copy()
    t_in[1, 0] = t_in[2, 2] = True
    t_present = np.ones((6, 3), bool)
    t_present[3, 0] = False
    truth = _track(t_in, t_present, available=[1, 1, 1, 1, 0, 1])
    # the extraction: frame 0 subject soft (the truth has it sharp); frame 1 foreground sharp; frame 2
    # background sharp; frame 3 foreground sharp (where the truth sees none); frame 5 no background
    e_in = asked.copy()
    e_in[0, 1] = False
    e_in[1, 0] = e_in[2, 2] = e_in[3, 0] = True
    e_present = np.ones((6, 3), bool)
    e_present[5, 2] = False
    ext = _track(e_in, e_present)
    reach = RF.Reach.none(6)
    reach.judged[:] = [1, 1, 1, 1, 0, 1]
    reach.unreachable[1, 0] = True
    reach.reasons[1, 0] = "foreground soft with subject sharp: needs f/0.9 (the lens opens to f/1)"
    truths = [M.GroundTruth(dof_near_m=8.0, dof_far_m=float("nan")) if i == 2 else None for i in range(6)]

    tm = FM.explain(src, truth, truth, reach, truths, "truth")
    em = FM.explain(src, ext, truth, reach, truths, "extraction")

    # then the truth's misses: out of reach (the limit named), the flight's (its depth of field named),
    # no foreground in frame 3, no data in frame 4
    assert tm.kind[1, 0] == "out_of_reach" and "needs f/0.9" in tm.why[1, 0]
    assert tm.kind[2, 2] == "controller"
    assert "background soft was within the lens's reach" in tm.why[2, 2]
    assert "90% of its pixels inside the depth of field 8 m to infinity" in tm.why[2, 2]
    assert tm.kind[3, 0] == "absent" and list(tm.kind[4]) == ["no_data"] * 3
    assert (tm.kind[[0, 5]] == "").all()
    # and the extraction's: its own misread where the truth is right, the same physics and flight where the
    # truth misses too, reach not judged where the truth sees no foreground, and its own missing background
    assert em.kind[0, 1] == "extraction" and "the truth has subject sharp" in em.why[0, 1]
    assert em.kind[1, 0] == "out_of_reach" and em.kind[2, 2] == "controller"
    assert em.kind[3, 0] == "unjudged" and "the truth sees no foreground" in em.why[3, 0]
    assert em.kind[5, 2] == "absent" and em.kind[4, 1] == ""  # frame 4: the extraction agrees, no truth needed
    # and the kinds add up to the frames not agreeing, per region
    c = FM.counts(em)
    assert c["foreground"] == {"out_of_reach": 1, "controller": 0, "extraction": 0, "absent": 0, "unjudged": 1,
                               "no_data": 0}
    assert sum(c["background"].values()) == 2 and sum(FM.counts(tm)["subject"].values()) == 1


def test_runs_group_consecutive_frames_of_one_kind():
    kind = np.full((5, 3), "", dtype=object)
    why = np.full((5, 3), "", dtype=object)
    kind[0:3, 2] = "controller"
    kind[3, 2] = "out_of_reach"
    why[0, 2], why[2, 2], why[1, 2], why[3, 2] = "a", "c", "b", "d"
    rows = FM.runs(FM.Misses(kind, why), np.arange(5) / 24.0, "truth")
    assert [(r["kind"], r["first_frame"], r["last_frame"], r["frames"], r["reason"], r["reason_last"])
            for r in rows] == [("controller", 0, 2, 3, "a", "c"), ("out_of_reach", 3, 3, 1, "d", None)]
    assert {r["side"] for r in rows} == {"truth"} and {r["region"] for r in rows} == {"background"}


def test_a_miss_within_reach_names_where_the_lens_gives_the_labels_together_by_hand():
    # given one frame asking the foreground soft, the subject sharp and the background soft, filmed at 100 mm by a
    # lens held at f/2 (the one circle c = 0.134 mm: H - f = 100^2 / (2 x 0.134) mm = 37.313 m), the foreground at
    # 5 m, the subject at 10 m, the background at 50 m; the flight filmed the foreground sharp
    asked = np.array([[False, True, False]])
    src = _track(asked, np.ones((1, 3), bool))
    got = np.array([[True, True, False]])
    truth = _track(got, np.ones((1, 3), bool))
    inv = np.array([np.full(20, 1 / 5.0), np.full(20, 1 / 10.0), np.full(20, 1 / 50.0)], np.float32)
    t = M.GroundTruth(dof_near_m=4.0, dof_far_m=20.0, focal_length_mm=100.0,
                      lens_limits=np.array([0.5, 100.0, 2.0, 2.0], np.float32), region_inverse_depth=inv)
    reach = RF.Reach.none(1)
    reach.judged[:] = True
    tm = FM.explain(src, truth, truth, reach, [t], "truth")
    # then a controller's miss whose reason names the three labels together: the subject sharp bounds the focus,
    # |1/10 - 1/s| <= (1 - 0.1/s) / 37.313 for s in 7.908-13.625 m (the foreground is soft beyond 5.76 m, the
    # background up to 21.4 m), and the soft regions' medians are softest together where their blurs meet,
    # 1/s = (1/5 + 1/50) / 2 = 0.11, each 0.09 / ((1 - 0.1 x 0.11) / 37.313) = 3.40 circles
    assert tm.kind[0, 0] == "controller"
    why = tm.why[0, 0]
    assert "subject sharp, background soft, foreground soft together at f/2-2 with the focus 7.91-13.6 m" in why
    assert "the soft regions' medians at most 3.40 circles soft, at f/2 and 9.09 m" in why
    # and with the foreground out of reach (say, its soft label needing a wider aperture), a background miss names
    # the labels the verdict grants together, the subject's and the background's: the subject bounds the focus
    # (the background is soft up to 21.4 m), and the background is softest with the focus nearest, at 7.91 m
    truth_bg = _track(np.array([[False, True, True]]), np.ones((1, 3), bool))
    reach.unreachable[0, 0] = True
    why = FM.explain(src, truth_bg, truth_bg, reach, [t], "truth").why[0, 2]
    assert "(subject sharp, background soft together at f/2-2 with the focus 7.91-13.6 m" in why
    assert "at f/2 and 7.91 m)" in why and "foreground" not in why
    # and without the truth's depths and lens range, the reason as before
    reach.unreachable[0, 0] = False
    bare = FM.explain(src, truth, truth, reach, [M.GroundTruth(dof_near_m=4.0, dof_far_m=20.0)], "truth")
    assert "within the lens's reach; the flight filmed it sharp" in bare.why[0, 0]
