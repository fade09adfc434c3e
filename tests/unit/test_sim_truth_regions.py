"""The simulator's region truth (sim/truth.py): a foreground judged by the band's height in the frame."""
from __future__ import annotations

import numpy as np

from cinetransfer.services.autopilot_bridge.sim.truth import region_truth


def _frame(feet: int) -> tuple[np.ndarray, np.ndarray]:
    """100 x 10 px: the subject in column 4 from row 10 to `feet`, 5 m away; the ground 4 m, the sky beyond."""
    depth = np.full((100, 10), np.inf)
    depth[60:] = 4.0
    subject = np.zeros((100, 10), bool)
    subject[10:feet, 4] = True
    depth[subject] = 5.0
    return depth, subject


def test_a_band_under_three_percent_is_no_foreground_but_keeps_its_depths():
    # given feet 2 rows above the bottom (2 % of the frame) and 4 rows above (4 %)
    short = region_truth(*_frame(98), 50.0, 2.0, 5.0, 0.05)
    tall = region_truth(*_frame(96), 50.0, 2.0, 5.0, 0.05)
    # then only the taller band is a foreground; both keep the band's depths (the ground, 4 m)
    assert list(short["region_present"]) == [False, True, True] and np.isnan(short["region_focus_fraction"][0])
    assert list(tall["region_present"]) == [True, True, True]
    assert np.allclose(short["region_inverse_depth"][0], 0.25) and np.allclose(tall["region_inverse_depth"][0], 0.25)


def test_the_foreground_judged_at_full_resolution_decides_on_a_subsampled_grid():
    # given the 4 % band read from every 4th row (25 rows: its one band row) but judged a foreground
    # at full resolution, and the 2 % band judged none
    depth, subject = _frame(96)
    judged = region_truth(depth[2::4], subject[2::4], 50.0, 2.0, 5.0, 0.05, foreground=True)
    depth, subject = _frame(98)
    short = region_truth(depth[2::4], subject[2::4], 50.0, 2.0, 5.0, 0.05, foreground=False)
    # then the verdict given is kept: the grid's own rows (its band row 24 of 25: 4 %) would count the
    # 2 % band a foreground
    assert judged["region_present"][0] and not short["region_present"][0]
    assert region_truth(depth[2::4], subject[2::4], 50.0, 2.0, 5.0, 0.05)["region_present"][0]
