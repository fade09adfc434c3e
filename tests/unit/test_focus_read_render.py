"""benchmarks/focus_read_render.py: which region a frame no drawn lens setting reads as asked is called
unreadable by (the reach's order), against hand-made brute-force counts."""
from __future__ import annotations

import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def fr():
    return load_benchmark("focus_read_render")


def row(readable: int, prefix: dict[str, int], judged=(True, True, True)) -> dict:
    """A frame of 'only the subject sharp' as judge_run keeps it: the best setting reads the subject 99 %,
    the background 51 % and the foreground 55 % sharp."""
    return {"frame": 40, "missed": ["foreground"], "asked": [False, True, False], "judged": list(judged),
            "flips": {"foreground": 1.34, "subject": 1.46, "background": 1.11}, "by_flips": {},
            "brute_force": {"readable_settings": readable, "settings": 672, "readable_prefix": prefix,
                            "best": {"margin": -0.053, "f_number": 1.0, "focus_m": 12.37, "worst": "foreground",
                                     "shares": [0.553, 0.992, 0.513]}}}


def test_a_frame_some_setting_reads_as_asked_is_never_unreadable(fr):
    assert fr.verdict(row(1, {"subject": 400, "background": 60, "foreground": 1})) == {}


def test_the_region_named_is_the_first_no_setting_adds_in_the_reachs_order(fr):
    # subject alone and with the background soft are read (385, 63 settings); adding the foreground none
    v = fr.verdict(row(0, {"subject": 385, "background": 63, "foreground": 0}))
    assert list(v) == ["foreground"]
    assert v["foreground"].startswith("subject sharp, background soft, foreground soft: no lens setting of 672")
    assert "reads subject 99%, background 51%, foreground 55% sharp" in v["foreground"]
    # the background soft with the subject sharp already unread: the background is named, its labels only
    v = fr.verdict(row(0, {"subject": 385, "background": 0, "foreground": 0}))
    assert list(v) == ["background"] and v["background"].startswith("subject sharp, background soft: no lens")


def test_the_summary_lists_frames_by_verdict_and_where_the_flips_disagree(fr):
    a, b = row(0, {"subject": 385, "background": 63, "foreground": 0}), row(5, {"subject": 1, "background": 1,
                                                                                "foreground": 5})
    b["frame"] = 41
    s = fr.summarise([a, b])
    assert s["unreadable"] == {"foreground": [40], "subject": [], "background": []}
    assert s["readable"] == [41]
    assert s["flips_disagree"] == [40]  # the flips alone (by_flips empty) called frame 40 readable
