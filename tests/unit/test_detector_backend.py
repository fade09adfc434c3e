"""A detector that runs its fallback backend (the box-first models missing) is named as such, the
style `cinetransfer extract` writes says it, and the report states it and a source and output
measured by different backends."""
import json
import subprocess
import sys

import pytest

from cinetransfer import detector_backend as DB
from cinetransfer.report.detectors import detector_facts

BOX_FIRST = {"backend": "box_first", "fallback": None}
FALLBACK = {"backend": "mediapipe (box_first unavailable)", "fallback": "box_first: m.tflite is missing"}


@pytest.fixture
def no_box_models(tmp_path, monkeypatch):
    """An install whose box-first models are missing (box_models.models_dir reads the variable)."""
    empty = tmp_path / "no-models"
    empty.mkdir()
    monkeypatch.setenv("CT_DETECTOR_MODELS", str(empty))
    return empty


def test_facts_name_the_backend_and_why_a_fallback_ran():
    assert DB.facts("box_first") == BOX_FIRST
    assert DB.facts("mediapipe") == {"backend": "mediapipe", "fallback": None}  # chosen, not a fallback
    assert DB.facts(FALLBACK["backend"], FALLBACK["fallback"]) == FALLBACK
    # only the name known (the detector's health not received): still a fallback
    assert DB.facts(FALLBACK["backend"])["fallback"] == DB.UNKNOWN_REASON
    assert not DB.is_fallback(BOX_FIRST) and not DB.is_fallback(None) and DB.is_fallback(FALLBACK)
    # the fix is said once: appended unless the reason (the detector's own) says it already
    assert DB.warning("source style", FALLBACK, "").endswith(f"box-first detector; {DB.FIX}")
    said = {"backend": FALLBACK["backend"], "fallback": "m.tflite is missing: re-run ./setup.sh"}
    assert DB.warning("source style", said, "").endswith("(m.tflite is missing: re-run ./setup.sh), which "
                                                         "measures otherwise than the box-first detector")


def test_the_real_detector_without_its_box_first_models_says_it_runs_a_fallback(no_box_models):
    from cinetransfer.services.detector.config import DetectorConfig
    from cinetransfer.services.detector.core import Detector

    with Detector(DetectorConfig(focus=False, threads=1)) as det:
        f = DB.of_detector(det)
    assert f["backend"] == "mediapipe (box_first unavailable)"
    assert str(no_box_models) in f["fallback"] and "re-run ./setup.sh" in f["fallback"]
    line = DB.warning("source style", f, "")
    assert "fallback backend 'mediapipe (box_first unavailable)'" in line and "\n" not in line


def test_extract_names_a_fallback_backend_in_the_style_file(no_box_models, tmp_path, data):
    out = tmp_path / "style.json"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "extract", str(data / "sam2_juggle_1280x720.mp4"),
                        "-o", str(out), "--stop", "3", "--quiet"], capture_output=True, text=True, timeout=280)
    assert r.returncode == 0, r.stderr[-3000:]
    d = json.loads(out.read_text())
    assert d["diagnostics"]["detector"]["backend"] == "mediapipe (box_first unavailable)"
    assert str(no_box_models) in d["diagnostics"]["detector"]["fallback"]
    said = [w for w in d["warnings"] if "fallback backend" in w]  # (beside: "3 of 247 frames measured")
    assert len(said) == 1 and "./setup.sh" in said[0]
    assert "warning: measured: the detector ran the fallback backend" in r.stderr
    from cinetransfer.transfer import style_detector

    assert style_detector(out) == d["diagnostics"]["detector"]  # what the transfer records in meta.json


def test_the_report_states_a_fallback_and_backends_that_differ():
    both = detector_facts({"detectors": {"source": BOX_FIRST, "output": BOX_FIRST}})
    assert both == {"source": BOX_FIRST, "output": BOX_FIRST, "same_backend": True, "notes": []}
    mixed = detector_facts({"detectors": {"source": FALLBACK, "output": BOX_FIRST}})
    assert mixed["same_backend"] is False and len(mixed["notes"]) == 2
    assert mixed["notes"][0].startswith("the source style was measured by the detector's fallback backend "
                                        "'mediapipe (box_first unavailable)' (box_first: m.tflite is missing)")
    assert "not measured the same way" in mixed["notes"][1]
    fallback_both = detector_facts({"detectors": {"source": FALLBACK, "output": FALLBACK}})
    assert fallback_both["same_backend"] is True and [n.split(" style")[0] for n in fallback_both["notes"]] == [
        "the source", "the output"]
    # a --style file (source unknown) or an older meta.json: nothing is claimed either way
    assert detector_facts({"detectors": {"source": None, "output": BOX_FIRST}})["same_backend"] is None
    assert detector_facts({}) == {"source": None, "output": None, "same_backend": None, "notes": []}
