"""benchmarks/eval_camera_motion_transfer.py judges a transfer's report: the output's class
agreement pooled over the shots by their rows, and the framing goals, each against hand-made
report.json contents."""
from __future__ import annotations

import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def ev():
    return load_benchmark("eval_camera_motion_transfer")


def _report(shots, goals):
    return {"camera_motion": {"shots": shots}, "headline": {"goals_met": "8/8", "goals": goals}}


def _shot(a, b, agreement, src="pan", out="pan"):
    return {"rows": [a, b], "source": {"class": src}, "output": {"class": out}, "truth": {"class": out},
            "agreement": agreement}


MET = {"extraction_joint_error": "met", "truth_joint_error": "met"}


def test_agreement_is_pooled_by_rows(ev):
    # 30 rows at 1.0 and 10 rows at 0.2: (30 + 2) / 40 = 0.8
    assert ev.pooled_agreement([_shot(0, 30, 1.0), _shot(30, 40, 0.2)]) == pytest.approx(0.8)
    assert ev.pooled_agreement([_shot(0, 30, None)]) is None


def test_a_move_is_met_only_with_agreement_and_framing(ev):
    ok = ev.judge_report(_report([_shot(0, 48, 0.9)], MET))
    assert ok["met"] and ok["agreement"] == pytest.approx(0.9) and ok["output_class"] == ["pan"]
    low = ev.judge_report(_report([_shot(0, 48, 0.5, out="truck")], MET))
    assert not low["met"] and low["output_class"] == ["truck"]
    framing = ev.judge_report(_report([_shot(0, 48, 1.0)], {**MET, "truth_joint_error": "missed"}))
    assert not framing["met"] and framing["framing"]["truth_joint_error"] == "missed"
    nothing = ev.judge_report({"headline": {}})
    assert not nothing["met"] and nothing["agreement"] is None and nothing["framing"]["truth_joint_error"] == "missing"


def test_the_mark_needs_the_pre_roll_it_waits_for(ev, tmp_path, capsys):
    # the walker waits on his mark for the pre-roll: without --preroll there is no wait to write
    assert ev.main([str(tmp_path), "-o", str(tmp_path / "runs"), "--mark"]) == 2
    assert "--mark needs --preroll" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def test_the_crop_subject_needs_the_pre_roll_and_no_mark(ev, tmp_path, capsys):
    # the crops' person waits on his mark for the pre-roll too; the courtyard's mark is for the rendered moves
    assert ev.main([str(tmp_path), "-o", str(tmp_path / "runs"), "--crop-subject"]) == 2
    assert "--crop-subject needs --preroll" in capsys.readouterr().err
    assert ev.main([str(tmp_path), "-o", str(tmp_path / "runs"), "--crop-subject", "--mark", "--preroll", "5"]) == 2
    assert "--mark is for the rendered moves" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
