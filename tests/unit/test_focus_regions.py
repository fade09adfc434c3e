"""The one definition of the focus regions (shared.focus_regions), used by the style and the truth."""
from __future__ import annotations

import numpy as np

from cinetransfer.shared.focus_regions import FOREGROUND_MIN_ROWS, feet_row, foreground_present, region_masks


def test_the_foreground_is_the_band_below_the_feet_without_the_subject():
    # given a 10 x 4 frame with the subject in rows 2-6 of column 1, and one stray subject pixel in row 7
    subj = np.zeros((10, 4), bool)
    subj[2:7, 1] = True
    subj[7, 2] = True
    # then the feet are at row 8 and the foreground is rows 8-9, the background the rest
    assert feet_row(subj) == 8
    fg, s, bg = region_masks(subj, feet_row(subj), True)
    assert fg.sum() == 8 and fg[8:].all() and not fg[:8].any()
    assert (s == subj).all()
    assert (fg ^ s ^ bg).all() and not (fg & bg).any()  # a partition of the frame
    # and a band that is no foreground leaves it to the background
    fg, _, bg = region_masks(subj, feet_row(subj), False)
    assert not fg.any() and bg.sum() == 40 - 6


def test_the_band_is_a_foreground_by_its_height_in_the_frame_not_in_a_grids_rows():
    # given a 540-row frame: 3 % of it is 16.2 rows
    assert FOREGROUND_MIN_ROWS == 0.03
    # then feet at row 524 (16 rows below) are no foreground, at 523 (17 rows) one; no subject, none
    assert not foreground_present(524, 540) and foreground_present(523, 540)
    assert foreground_present(523.8, 540) and not foreground_present(None, 540)
    # a threshold of its own (the smoother's configuration) is a share of the frame too
    assert foreground_present(500, 540, 0.07) and not foreground_present(503, 540, 0.07)


def test_no_subject_means_no_foreground_and_the_whole_frame_background():
    assert feet_row(np.zeros((5, 5), bool)) is None
    fg, s, bg = region_masks(None, None, True, (5, 5))
    assert not fg.any() and not s.any() and bg.all()


def test_the_extraction_judges_the_band_in_frame_pixels_not_in_focus_map_rows():
    # given a 960 x 540 frame read on a 160 x 90 focus map (6 px a row), a person whose mask ends at frame row
    # 523 (17 px above the bottom) and one ending at 524 (16 px: under 3 % of 540, 16.2)
    from cinetransfer.services.smoother.features import focus_fractions

    infocus = np.ones((90, 160), bool)

    def fg_share(feet_px: int) -> float:
        mask = np.ones((feet_px - 300, 40), bool)  # rows 300..feet_px-1, columns 400-439
        out, _ = focus_fractions(infocus, [(mask, 400, 300)], np.array([[400.0, 300.0, 440.0, feet_px]]),
                                 (960, 540), foreground_min_rows=0.03, margin=0.0)
        return out[0, 0]

    # then the first has a foreground and the second none, though on the map both leave 3 rows (18 px)
    # below the feet, which the map's rows rounded up from 3 % (2.7 rows) would have counted
    assert fg_share(523) == 1.0 and np.isnan(fg_share(524))
