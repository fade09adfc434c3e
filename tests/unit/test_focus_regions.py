"""The one definition of the focus regions (shared.focus_regions), used by the style and the truth."""
from __future__ import annotations

import numpy as np

from cinetransfer.shared.focus_regions import feet_row, region_masks


def test_the_foreground_is_the_band_below_the_feet_without_the_subject():
    # given a 10 x 4 frame with the subject in rows 2-6 of column 1, and one stray subject pixel in row 7
    subj = np.zeros((10, 4), bool)
    subj[2:7, 1] = True
    subj[7, 2] = True
    # then the feet are at row 8 and the foreground is rows 8-9, the background the rest
    assert feet_row(subj) == 8
    fg, s, bg = region_masks(subj, feet_row(subj), min_rows=2)
    assert fg.sum() == 8 and fg[8:].all() and not fg[:8].any()
    assert (s == subj).all()
    assert (fg ^ s ^ bg).all() and not (fg & bg).any()  # a partition of the frame
    # and a band shorter than min_rows is no foreground
    fg, _, bg = region_masks(subj, feet_row(subj), min_rows=3)
    assert not fg.any() and bg.sum() == 40 - 6


def test_no_subject_means_no_foreground_and_the_whole_frame_background():
    assert feet_row(np.zeros((5, 5), bool)) is None
    fg, s, bg = region_masks(None, None, 1, (5, 5))
    assert not fg.any() and not s.any() and bg.all()
