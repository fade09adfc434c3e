"""A transfer whose detector runs its fallback backend (the box-first models missing where it runs,
as when a transfer starts while ./setup.sh is still installing them) says so: one warning line
per detector pass, the style is not kept in the style cache, and meta.json and the report name
the backend. Real processes over Zenoh, the real detector; a few frames."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

FRAMES = 6
FALLBACK = "mediapipe (box_first unavailable)"


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_a_fallback_detector_is_warned_not_cached_and_reported(data, tmp_path):
    # given an install whose box-first models are missing (the detector reads $CT_DETECTOR_MODELS)
    empty = tmp_path / "no-models"
    empty.mkdir()
    out = tmp_path / "run"
    env = {**os.environ, "CT_DETECTOR_MODELS": str(empty)}
    # when a transfer runs
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                        "--scene", "open_country", "-o", str(out), "--max-frames", str(FRAMES), "--preroll", "1",
                        "--rig", "fallback"], capture_output=True, text=True, timeout=800, env=env)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-5000:]
    # then its log warns once for the source's pass and once for the output's, with the fix
    warned = [ln for ln in r.stderr.splitlines() if "the detector ran the fallback backend" in ln]
    assert len(warned) == 2, r.stderr[-5000:]
    assert all(f"'{FALLBACK}'" in ln and "re-run ./setup.sh" in ln and "WARNING" in ln for ln in warned)
    assert "source style:" in warned[0] and "it is not kept in the style cache" in warned[0]
    assert "output style:" in warned[1]
    # and the style is not in the cache (nothing else was stored there either)
    styles = Path(os.environ["CT_CACHE_DIR"]) / "styles"
    assert not styles.exists() or not any(styles.iterdir())
    assert "kept in the cache" not in r.stderr
    # and style.json says how it was measured
    style = json.loads((out / "style.json").read_text())
    assert len(style["warnings"]) == 1 and FALLBACK in style["warnings"][0]
    # and meta.json names each pass's backend and why the box-first one did not run
    meta = json.loads((out / "meta.json").read_text())
    assert meta["style_origin"] == "extracted"
    for which in ("source", "output"):
        assert meta["detectors"][which]["backend"] == FALLBACK
        assert meta["detectors"][which]["fallback"]
    assert str(empty) in meta["detectors"]["output"]["fallback"]  # the transfer's own detector: its reason
    # and the report states it (not a degraded take: the goals are judged)
    rep = json.loads((out / "report.json").read_text())
    assert rep["detectors"]["same_backend"] is True
    assert [n.split(" style")[0] for n in rep["headline"]["detectors"]] == ["the source", "the output"]
    assert "(degraded take)" not in rep["headline"]["goals_met"]
    assert (out / "report.html").read_text().count("<b>Detector:</b>") == 2
