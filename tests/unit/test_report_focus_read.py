"""Which labels within the lens's reach the extraction can read, each region judged by where the focus
estimator flips on it (cinetransfer.report.focus_read), against hand-computed values and a brute-force
search over the lens's settings."""
from __future__ import annotations

import numpy as np
import pytest

from cinetransfer.report import focus_reach as FR
from cinetransfer.report import focus_read as FD
from cinetransfer.shared.camera import COC_MM

LENS = FR.Lens(50.0, (0.5, 100.0), (1.0, 16.0))
#: a hedge 6.8 m away below the runner's feet, the runner at 10 m, the backdrop at 40 m (each region at one depth)
DEPTHS = np.array([np.full(20, 1 / 6.8), np.full(20, 1 / 10.0), np.full(20, 1 / 40.0)])
SUBJECT_ONLY = np.array([False, True, False])  # foreground soft, subject sharp, background soft
ALL = np.ones(3, bool)


def shared_blur() -> float:
    """By hand: at f/1 the field's half-width in inverse depth is (1 - f/s) / (H - f), H = f^2 / (N c) + f; the
    foreground and the background are equally soft at 1/s halfway between them, each (x_f - x_b) / 2 over it."""
    f = 0.05
    h = f * f / (1.0 * COC_MM / 1000.0) + f
    u = 0.5 * (1 / 6.8 + 1 / 40.0)
    return (1 / 6.8 - 1 / 40.0) / 2.0 / ((1.0 - f * u) / (h - f))


def test_the_hand_computed_shared_blur_is_just_past_one_circle():
    # H = 18.756 m, 1/s = 0.0860 (11.6 m), half-width 0.0532: (0.1471 - 0.025) / 2 / 0.0532 = 1.147 circles
    assert shared_blur() == pytest.approx(1.147, abs=0.002)


def test_flips_of_one_circle_read_what_the_truth_can_give():
    assert FR.unreachable_labels(LENS, SUBJECT_ONLY, ALL, DEPTHS) == []
    assert FD.unreadable_labels(LENS, SUBJECT_ONLY, ALL, DEPTHS, np.ones(3)) == []


def test_soft_regions_flipping_below_the_shared_blur_are_read_soft():
    b = shared_blur()
    assert FD.unreadable_labels(LENS, SUBJECT_ONLY, ALL, DEPTHS, np.array([b - 0.01, 1.0, b - 0.01])) == []


def test_soft_regions_flipping_past_the_shared_blur_cannot_be_read_soft_together():
    b = shared_blur()
    flips = np.array([b + 0.02, 1.0, b + 0.02])
    out = FD.unreadable_labels(LENS, SUBJECT_ONLY, ALL, DEPTHS, flips)
    # the background is granted before the foreground (subject, background, foreground): the foreground is not read
    assert [(u.region, u.kind) for u in out] == [(0, "read")]
    # with the background read soft (at its flip, b + 0.02), the most the foreground gets is 2 b - (b + 0.02)
    assert f"read soft only past {b + 0.02:.2f} circles" in out[0].reason
    assert f"at most {b - 0.02:.2f} circles" in out[0].reason
    lo, hi = FD.blur_range(LENS, 0, [1, 2], SUBJECT_ONLY, DEPTHS, flips)
    assert hi == pytest.approx(b - 0.02, abs=0.01)


def test_a_soft_region_alone_is_read_up_to_the_most_blur_the_sharp_subject_allows():
    # foreground soft, subject sharp, no background: the most blur of the hedge at 6.8 m is at f/1 with the
    # field's far limit at the runner (1/s = x_s - sigma(s), sigma = (1 - f/s) / (H - f)): (x_f - 1/s) / sigma
    # = (x_f - x_s) / sigma + 1 circles, 1/s solved by iteration (0.0469: 21.3 m; 1.88 circles)
    asked, judged = SUBJECT_ONLY, np.array([True, True, False])
    _, most = FD.blur_range(LENS, 0, [1], asked, DEPTHS, np.ones(3))
    f, h = 0.05, 0.05 ** 2 / (COC_MM / 1000.0) + 0.05
    u = 0.1
    for _ in range(50):
        u = 0.1 - (1 - f * u) / (h - f)
    want = (1 / 6.8 - u) / ((1 - f * u) / (h - f))
    assert want == pytest.approx(1.88, abs=0.01)
    assert most == pytest.approx(want, abs=0.01)
    assert FD.unreadable_labels(LENS, asked, judged, DEPTHS, np.array([want - 0.02, 1.0, 1.0])) == []
    assert [u.region for u in FD.unreadable_labels(LENS, asked, judged, DEPTHS, np.array([want + 0.02, 1, 1]))] == [0]


def test_a_subject_read_sharp_only_near_the_focus_leaves_no_room_for_a_soft_background_behind_him():
    # subject sharp at 10 m, background soft at 12 m, no foreground. The background soft by its flip of one circle
    # needs 1/s >= x_b + sigma (0.0833 + 0.0532 at f/1 = 0.137, 7.3 m), where the subject is (0.137 - 0.1) / 0.0532
    # = 0.69 circles soft: read sharp only if his flip passes that (in front of him: 1/s <= 0.030, 1.31 circles)
    depths = np.array([np.full(20, np.nan), np.full(20, 1 / 10.0), np.full(20, 1 / 12.0)])
    asked, judged = np.array([False, True, False]), np.array([False, True, True])
    assert FD.unreadable_labels(LENS, asked, judged, depths, np.ones(3)) == []
    assert FD.unreadable_labels(LENS, asked, judged, depths, np.array([1.0, 0.72, 1.0])) == []
    out = FD.unreadable_labels(LENS, asked, judged, depths, np.array([1.0, 0.66, 1.0]))
    assert [(u.region, u.kind) for u in out] == [(2, "read")]  # the subject is granted first


def _brute_force_reads(lens: FR.Lens, asked, judged, inv_depth, flips) -> bool:
    """Whether some setting on a dense grid reads every judged region as asked: per region the share of its
    samples whose blur (focus_reach.blur_circles, the thin lens's) is within its flip, against one half."""
    n = np.geomspace(*lens.f_number, 60)[:, None]
    s = np.geomspace(*lens.focus_m, 800)[None, :]
    ok = np.ones((n.size, s.size), bool)
    for r in np.flatnonzero(judged):
        blur = np.stack([FR.blur_circles(lens.focal_mm, n, s, x, lens.coc_mm) for x in inv_depth[r]])
        share = (blur <= flips[r]).mean(axis=0)
        ok &= share >= 0.5 if asked[r] else share < 0.5
    return bool(ok.any())


def test_no_frame_a_brute_force_search_reads_as_asked_is_called_unreadable():
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(40):
        lens = FR.Lens(float(rng.uniform(20, 90)), (0.5, 100.0), (1.0, 16.0))
        centres = rng.uniform(3.0, 40.0, 3)
        inv = np.sort(1.0 / (centres[:, None] * rng.uniform(0.9, 1.1, (3, 20))), axis=1)
        asked = rng.random(3) < 0.5
        judged = np.ones(3, bool)
        flips = rng.uniform(0.8, 1.4, 3)
        if _brute_force_reads(lens, asked, judged, inv, flips):
            checked += 1
            assert FD.unreadable_labels(lens, asked, judged, inv, flips) == [], (lens, asked, inv, flips)
    assert checked >= 10  # enough reachable frames drawn for the check to mean something


def test_the_focus_for_a_blur_gives_that_blur():
    # by hand: 50 mm f/1, H - f = 50^2 / 0.13365 mm = 18.706 m; a point at 10 m one circle behind the focus:
    # 1/s = (0.1 + 1 / 18.706) / (1 + 0.05 / 18.706) = 0.15305, s = 6.534 m (as the iteration in the test above)
    s = FD.focus_for_blur(50.0, 1.0, 0.1, 1.0, True)
    assert s == pytest.approx(6.534, abs=0.002)
    for x, b, behind in ((0.1, 1.0, True), (1 / 6.8, 1.25, False), (1 / 40.0, 0.6, True)):
        s = FD.focus_for_blur(50.0, 1.4, x, b, behind)
        assert FR.blur_circles(50.0, 1.4, s, x) == pytest.approx(b, rel=1e-9)
        assert (1 / s > x) == behind
    assert FD.focus_for_blur(50.0, 1.0, 0.01, 1.0, False) == FD.FOCUS_FAR_M  # 1/s would be below 0
