"""One report judges each frame's focus reach once: the whole run and its shots share the verdicts
(reach_frames.reach's memo), with the same results as judging every frame again."""
from __future__ import annotations

import dataclasses

import numpy as np

from cinetransfer.report import fidelity as F
from cinetransfer.report import focus_reach as FR
from cinetransfer.report import reach_frames as RF
from cinetransfer.report import synth
from cinetransfer.report.build import per_shot

S = 20


def at(d_m: float) -> np.ndarray:
    return np.full(S, 1.0 / d_m)


def _run(k: int = 48) -> tuple:
    """k frames at 100 mm asking the foreground soft with the subject sharp: in the first 12 the
    foreground sits at the subject's depth (no lens gives it), in the rest 3 m nearer (reachable)."""
    src = synth.instructions(k, focus_in=np.tile([False, True, False], (k, 1)))
    base = synth.truths(src.image_targets)
    depths = [np.array([at(7.0 if i < 12 else 4.0), at(7.0), at(30.0)]) for i in range(k)]
    truths = [dataclasses.replace(t, focal_length_mm=100.0, lens_limits=np.float32([0.5, 100.0, 1.0, 22.0]),
                                  region_inverse_depth=depths[i].astype(np.float32)) for i, t in enumerate(base)]
    return src, truths


def _same(a: RF.Reach, b: RF.Reach) -> bool:
    return (np.array_equal(a.unreachable, b.unreachable) and np.array_equal(a.judged, b.judged)
            and a.reasons.tolist() == b.reasons.tolist())


def test_the_memo_gives_the_verdicts_judged_afresh_once_per_distinct_frame():
    src, truths = _run()
    asked, present = src.focus_in, np.ones((48, 3), bool)
    memo: RF.Memo = {}
    fresh = RF.reach(asked, present, truths)
    kept = RF.reach(asked, present, truths, memo)
    assert _same(fresh, kept)
    assert kept.unreachable[:12, 0].all() and not kept.unreachable[12:].any()
    # two distinct frames (the foreground at 7 m, at 4 m): two verdicts kept, the first one unreachable
    assert len(memo) == 2
    assert sorted(len(v) for v in memo.values()) == [0, 1]


def test_a_frame_found_in_the_memo_is_not_judged_again():
    # given a memo that holds a verdict for the reachable frames' exact content
    src, truths = _run()
    t = truths[20]
    lens = FR.Lens(100.0, (0.5, 100.0), (1.0, 22.0))
    key = RF.frame_key(lens, src.focus_in[20], np.ones(3, bool), np.asarray(t.region_inverse_depth, float))
    memo: RF.Memo = {key: [FR.Unreachable(2, "depth", "kept verdict")]}
    out = RF.reach(src.focus_in, np.ones((48, 3), bool), truths, memo)
    # then those frames carry the kept verdict and the others are judged
    assert out.unreachable[12:, 2].all() and set(out.reasons[12:, 2]) == {"kept verdict"}
    assert out.unreachable[:12, 0].all() and not out.unreachable[:12, 2].any()


def test_the_shots_reuse_the_whole_runs_verdicts_with_the_same_rows():
    src, truths = _run()
    takes = [{"first_row": 0, "end_row": 20}, {"first_row": 20, "end_row": 48}]
    memo: RF.Memo = {}
    whole = F.compute_fidelity(src, None, truths, reach_memo=memo)
    judged = dict(memo)
    shared = per_shot(src, None, truths, 24.0, takes, None, memo)
    # the shots judge no frame the whole run had not judged, and report what judging afresh reports
    assert memo == judged
    assert shared == per_shot(src, None, truths, 24.0, takes, None)
    assert [s["focus_unreachable_frames"]["foreground"] for s in shared] == [12, 0]
    assert whole.summary["focus_reach"]["unreachable_frames"]["foreground"] == 12
