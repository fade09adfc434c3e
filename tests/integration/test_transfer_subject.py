"""A transfer onto another person: the juggle clip's style flown with `--subject walker` in the
juggler's own lawn scene in the 2.5-D fast mode (a cut-out, seen from behind; the scene's juggler
swapped out), through the real processes. The bridge films the walker, and the report names both
people and shows them side by side."""
import json
import subprocess
import sys

import pytest
import yaml

FRAMES = 36


@pytest.mark.slow
def test_transfer_with_a_subject_different_from_the_source(data, tmp_path):
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                        "--scene", "lawn_juggler_25d", "--subject", "walker", "-o", str(out),
                        "--max-frames", str(FRAMES), "--preroll", "2", "--rig", "subj"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-5000:]
    cfg = yaml.safe_load((out / "deploy" / "transfer.yaml").read_text())
    bridge = next(n for n in cfg["nodes"] if n["name"] == "autopilot_bridge")
    assert bridge["args"][bridge["args"].index("--subject") + 1] == "walker"
    meta = json.loads((out / "meta.json").read_text())
    assert meta["subject"] == "walker" and meta["same_person_as_source"] is False
    assert meta["recorded_frames"] == FRAMES
    report = json.loads((out / "report.json").read_text())
    people = report["people"]
    assert "juggler" in people["source_person"] and "TUD-Stadtmitte" in people["target_person"]
    assert (out / "fig_people.png").is_file()
    html = (out / "report.html").read_text()
    assert "target (filmed)" in html and "TUD-Stadtmitte" in html
    # the walker was really filmed: the detector found a person in the output's frames
    out_style = json.loads((out / "output_style.json").read_text())
    assert out_style is not None
    assert report["headline"]["truth"]["joint_error_mean"] < 0.1
    # the walker is seen from behind: left/right compared by image side, and the report says so,
    # with the by-name error (a shoulder width off on the shoulders) next to it
    truth = report["headline"]["truth"]
    assert truth["frames_by_image_side"] > FRAMES // 2
    assert truth["joint_error_by_name"] > truth["joint_error_mean"]
    assert "by image side" in html


def test_transfer_help_lists_the_subjects():
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", "--help"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0
    for name in ("juggler", "dancer", "runner", "walker"):
        assert name in r.stdout
