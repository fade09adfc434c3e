"""The report names both people (source clip, target subject) and shows them side by side."""
from __future__ import annotations

import cv2

from cinetransfer.report.html import render_html
from cinetransfer.report.people import make_people, source_person


def test_people_names_the_source_person_and_the_target_subject_with_a_picture(data, tmp_path):
    src = data / "sam2_juggle_1280x720.mp4"
    p = make_people(tmp_path, {"subject": "dancer", "target_person": "the dancer of DAVIS dance-twirl"}, src)
    assert "juggler" in p["source_person"] and p["subject"] == "dancer"
    img = cv2.imread(p["figure"])
    assert img is not None and img.shape[0] == 300 and img.shape[1] > 2 * 300  # frame beside cut-out
    html = render_html({"people": p}, {}, meta={"scene": "open_country"}, embed=False)
    assert "source (style from)" in html and "target (filmed)" in html and "fig_people.png" in html
    assert "the dancer of DAVIS dance-twirl" in html


def test_an_unknown_clip_is_named_by_its_file():
    assert source_person("/x/holiday.mp4") == "the main subject of holiday.mp4"
