"""The standoff a subject soft before a sharp background needs (services/planner/separation.py)."""
import math

import pytest

from cinetransfer.services.planner.separation import (APERTURE_MARGIN, background_soft_distance_m,
                                                      background_soft_standoff_m, best_separation_m, framing_k,
                                                      separation_distance_m, standoff_m)
from cinetransfer.shared import camera as cam


def test_standoff_by_hand():
    # given 4 mm per metre of framing, f/1, c = 0.05 mm, the soft circle 4 c and a point-like subject:
    # a = 1000 * 1 * 0.05 * 5 / 16 = 15.625 m, and d = a (f = 62.5 mm, H = 78.125 m, H / 5 = d)
    assert standoff_m(4.0, f_number=1.0, coc_mm=0.05, defocus_ratio=4.0, mu_m=0.0) == pytest.approx(15.625)
    # and with the subject 1 m deep: d = (a + sqrt(a^2 + 4 a)) / 2
    assert standoff_m(4.0, f_number=1.0, coc_mm=0.05, defocus_ratio=4.0, mu_m=1.0) == pytest.approx(16.568, abs=1e-3)
    assert math.isnan(standoff_m(0.0, f_number=1.0, coc_mm=0.05, defocus_ratio=4.0, mu_m=1.0))


def test_standoff_against_the_lens_model():
    # at the standoff with the focus at the hyperfocal distance of c, the far limit of c is at
    # infinity and the near limit of the soft circle lies at d + mu (to the focal length's share)
    k, a_num, c, r, mu = 4.2, 1.0, 0.05, 4.0, 1.0
    d = standoff_m(k, f_number=a_num, coc_mm=c, defocus_ratio=r, mu_m=mu)
    f = k * d
    s = cam.hyperfocal_m(f, a_num, c)
    assert math.isinf(cam.dof_limits_m(f, a_num, s * 1.0001, c)[1])
    near_soft = cam.dof_limits_m(f, a_num, s, r * c)[0]
    assert near_soft == pytest.approx(d + mu, rel=0.01)
    # and from nearer at the same framing the subject's far edge is still inside the soft circle's field
    f2 = k * 0.8 * d
    s2 = cam.hyperfocal_m(f2, a_num, c)
    assert cam.dof_limits_m(f2, a_num, s2, r * c)[0] < 0.8 * d + mu


def test_softest_subject_distance():
    # the subject's blur at H is c (H / d - 1) with H = k^2 d^2 / (1000 A c) up to the longest focus:
    # at k = 4.2 mm/m, f/1, c = 0.05 mm, s_max = 100 m: d* = sqrt(5000) / 4.2 = 16.84 m (H = 100 m)
    d = best_separation_m(4.2, f_number_min=1.0, coc_mm=0.05, focus_max_m=100.0)
    assert d == pytest.approx(16.836, abs=1e-3)
    assert cam.hyperfocal_m(4.2 * d, 1.0, 0.05) == pytest.approx(100.0, abs=0.1)

    def blur(dd):  # softest subject at dd with the far limit at infinity and the focus within reach
        f = 4.2 * dd
        a_num = max(1.0, f * f / (0.05 * (100.0 * 1000.0 - f)))
        s = cam.hyperfocal_m(f, a_num, 0.05)
        return cam.blur_diameter_mm(dd, f, a_num, s)
    assert blur(d) > blur(0.9 * d) and blur(d) > blur(1.1 * d)


def test_separation_distance_takes_the_hardest_row_and_the_caps():
    # no row wanting the subject soft before a sharp background: nothing raised
    kw = dict(f_number_min=1.0, coc_mm=0.05, mu_m=1.0, focus_max_m=100.0, focal_max_mm=500.0)
    assert separation_distance_m([], [], **kw) == 0.0
    assert separation_distance_m([float("nan")], [4.0], **kw) == 0.0
    # the softest row asked for sets it, at the aperture margin (a tight framing: within reach)
    d = separation_distance_m([6.0, 6.0], [2.0, 4.0], **kw)
    assert d == pytest.approx(standoff_m(6.0, f_number=APERTURE_MARGIN, coc_mm=0.05, defocus_ratio=4.0, mu_m=1.0))
    # a looser framing in a later row needs more than the softest distance: that one
    assert separation_distance_m([6.0, 4.2], [4.0, 4.0], **kw) == pytest.approx(16.836, abs=1e-3)
    # and the longest focal length caps it too (k d <= f_max)
    assert separation_distance_m([4.2], [4.0], **{**kw, "focal_max_mm": 60.0}) == pytest.approx(60.0 / 4.2)
    # a keep-out per row: each row's own
    per_row = {**kw, "mu_m": [1.0, 0.3]}
    assert separation_distance_m([6.0, 6.0], [4.0, 4.0], **per_row) == pytest.approx(
        standoff_m(6.0, f_number=APERTURE_MARGIN, coc_mm=0.05, defocus_ratio=4.0, mu_m=1.0))
    assert separation_distance_m([6.0], [4.0], **{**kw, "mu_m": [0.3]}) == pytest.approx(
        standoff_m(6.0, f_number=APERTURE_MARGIN, coc_mm=0.05, defocus_ratio=4.0, mu_m=0.3))


def test_framing_k_from_a_row_by_hand():
    # shoulders at 1.45 m, hips at 0.95 m (0.5 m apart) seen 0.1 of the frame apart on a 13.365 mm high
    # sensor: 1.3365 mm for 0.5 m, 2.673 mm of focal length per metre of distance (e.g. 53.5 mm at 20 m)
    assert framing_k([0.40, 0.40, 0.50, 0.50], [1.45, 1.45, 0.95, 0.95], 13.365) == pytest.approx(2.673)
    # a joint without a target or position does not count; too few or too flat: unknown
    assert framing_k([0.40, float("nan"), 0.50], [1.45, 1.45, 0.95], 13.365) == pytest.approx(2.673)
    assert math.isnan(framing_k([0.40, float("nan")], [1.45, 0.95], 13.365))
    assert math.isnan(framing_k([0.40, 0.41], [1.0, 1.05], 13.365))


def test_background_soft_standoff_by_hand():
    # 4 mm per metre of framing, f/1, c = 0.05 mm, the soft circle 4 c: a = 1000 * 1 * 0.05 * 4 / 16 = 12.5 m
    kw = dict(f_number=1.0, coc_mm=0.05, defocus_ratio=4.0)
    # a background at infinity is blurred by 4 c from d = a on (f^2 / (A d) = k^2 d / 1000 = 0.2 mm)
    assert background_soft_standoff_m(4.0, behind_m=math.inf, **kw) == pytest.approx(12.5)
    # 30 m behind the subject: d = a beta / (beta - a) = 12.5 * 30 / 17.5
    assert background_soft_standoff_m(4.0, behind_m=30.0, **kw) == pytest.approx(21.4286, abs=1e-3)
    # within a of the subject no distance gives it; a framing that says nothing: unknown
    assert math.isinf(background_soft_standoff_m(4.0, behind_m=10.0, **kw))
    assert math.isnan(background_soft_standoff_m(float("nan"), behind_m=30.0, **kw))


def test_background_soft_standoff_against_the_lens_model():
    # at the standoff, focused on the subject, the far limit of the soft circle is the background
    # (to the focal length's share); from nearer at the same framing it lies beyond the background
    k, a_num, c, r, beta = 4.0, 1.0, 0.05, 4.0, 30.0
    d = background_soft_standoff_m(k, f_number=a_num, coc_mm=c, defocus_ratio=r, behind_m=beta)
    assert cam.dof_limits_m(k * d, a_num, d, r * c)[1] == pytest.approx(d + beta, rel=0.02)
    assert cam.blur_diameter_mm(d + beta, k * d, a_num, d) == pytest.approx(r * c, rel=0.02)
    near = 0.8 * d
    assert cam.dof_limits_m(k * near, a_num, near, r * c)[1] > near + beta


def test_background_soft_distance_takes_the_hardest_row_and_the_lens():
    kw = dict(f_number_min=1.0, coc_mm=0.05, behind_m=30.0, focal_max_mm=500.0)
    assert background_soft_distance_m([], [], **kw) == 0.0
    assert background_soft_distance_m([float("nan")], [4.0], **kw) == 0.0
    # the loosest framing sets it, at the aperture margin
    want = background_soft_standoff_m(4.0, f_number=APERTURE_MARGIN, coc_mm=0.05, defocus_ratio=4.0, behind_m=30.0)
    assert background_soft_distance_m([6.0, 4.0], [4.0, 4.0], **kw) == pytest.approx(want)
    # the longest focal length caps it; a background too near for any distance raises nothing
    assert background_soft_distance_m([4.0], [4.0], **{**kw, "focal_max_mm": 60.0}) == pytest.approx(15.0)
    assert background_soft_distance_m([4.0], [4.0], **{**kw, "behind_m": 5.0}) == 0.0


def test_background_behind_setting_from_the_flag():
    import argparse

    from cinetransfer.services.planner import config as pc
    from cinetransfer.services.planner.service import add_config_arguments, config_from_args
    from cinetransfer.shared.errors import ConfigError

    p = argparse.ArgumentParser()
    add_config_arguments(p)
    assert math.isinf(config_from_args(p.parse_args([])).background_behind_m)  # unknown: no standoff
    assert config_from_args(p.parse_args(["--background-behind", "30"])).background_behind_m == 30.0
    for bad in (0.0, -5.0, float("nan")):
        with pytest.raises(ConfigError):
            pc.PlannerConfig(background_behind_m=bad).validate()


def test_which_rows_ask_for_a_standoff():
    import numpy as np

    from cinetransfer.services.planner.core import separation_kind
    present, no_bg = np.zeros(3, bool), np.array([False, False, True])
    assert separation_kind(np.array([False, False, True]), present) == "subject_soft"
    assert separation_kind(np.array([False, True, False]), present) == "background_soft"
    assert separation_kind(np.array([True, True, False]), present) == "background_soft"
    assert separation_kind(np.array([False, True, False]), no_bg) is None  # nothing to blur behind
    assert separation_kind(np.array([False, True, True]), present) is None
    assert separation_kind(np.array([False, True, False]), np.ones(3, bool)) is None


def test_a_rack_focus_read_through_nothing_sharp_is_filmed_racking_through():
    import numpy as np

    from cinetransfer.services.planner.core import planned_focus_rows
    sub, none, bg = (False, True, False), (False, False, False), (True, False, True)
    rows = np.array([sub, sub, none, none, bg, bg, none, none, none, sub, none], dtype=bool)
    present = np.zeros(rows.shape, bool)
    got = planned_focus_rows(rows, present, 2)
    # the two "nothing" rows before the background-only row rack through (fg + bg without the subject is
    # one depth of field can't give: background-only); three before a subject row or at the end stay
    want = np.array([sub, sub, (0, 0, 1), (0, 0, 1), (0, 0, 1), (0, 0, 1), none, none, none, sub, none], dtype=bool)
    assert np.array_equal(got, want)
    # a longer run than the limit is a choice of its own; rows without any measurement stay as they are
    assert np.array_equal(planned_focus_rows(rows, present, 1)[2:4], [none, none])
    absent = present.copy()
    absent[2:4] = True
    assert np.array_equal(planned_focus_rows(rows, absent, 2)[2:4], [none, none])


def test_the_keep_out_waits_for_a_rack_to_settle():
    import numpy as np

    from cinetransfer.services.planner.core import keep_out_rows
    sub, bg, none = (False, True, False), (False, False, True), (False, False, False)
    rows = np.array([bg, bg, bg, sub, sub, bg, bg, bg, bg, none, bg, bg], dtype=bool)
    present = np.zeros(rows.shape, bool)
    # a shot that asks for the background alone from its first row keeps the subject out by his own depth
    # at once; after a rack from the subject (row 5) the first two rows keep mu; after "nothing in focus"
    # (a labelled row that keeps him out as well, row 9) too
    want = [True, True, True, False, False, False, False, True, True, False, False, False]
    assert keep_out_rows(rows, present, 2).tolist() == want
    assert keep_out_rows(rows, present, 0).tolist() == [bool(r[2] and not r[1]) for r in rows.tolist()]
    # after rows without a label (a shot the focus map could not read) there is no switch to wait for
    absent = present.copy()
    absent[9] = True
    assert keep_out_rows(rows, absent, 2)[10:].tolist() == [True, True]


def test_the_far_limit_opens_only_once_the_rack_has_switched():
    import numpy as np

    from cinetransfer.services.planner.core import far_previewed
    sub, bg, both = (False, True, False), (False, False, True), (False, True, True)
    focus = np.array([sub, sub, bg, bg], dtype=bool)
    near_out = [False, False, True, True]
    # followed now: a row keeping the background soft; the background-only stages past the switch do
    # not cost their far limit yet, the stages before it do
    assert [far_previewed(focus, near_out, 0, r) for r in range(4)] == [True, True, False, False]
    # once switched, every background-only stage costs it
    assert all(far_previewed(focus, near_out, 2, r) for r in range(2, 4))
    # a row followed now with the background sharp already: previewed as before
    focus2 = np.array([both, both, bg, bg], dtype=bool)
    assert all(far_previewed(focus2, near_out, 0, r) for r in range(4))
