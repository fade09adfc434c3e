"""The README's command twice on one clip: the second run reuses the first run's style from the
cache (no extraction), and the two give the same frames and the same report."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cinetransfer.report.repeatable import report_figures as figures
from cinetransfer.services.detector import box_models
from cinetransfer.report.truthfile import read_truths

FRAMES = 24  # one second of the 24 fps clip


def transfer(data, out, *extra):
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                        "--scene", "open_country", "-o", str(out), "--max-frames", str(FRAMES), "--preroll", "1",
                        "--rig", out.name, *extra], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-5000:]
    return r, json.loads((out / "meta.json").read_text())


def video_frames(path) -> list[np.ndarray]:
    import cv2

    cap, out = cv2.VideoCapture(str(path)), []
    while True:
        ok, img = cap.read()
        if not ok:
            cap.release()
            return out
        out.append(img)


@pytest.mark.slow
# a style measured by the detector's fallback backend is never cached (tests/integration/test_detector_fallback.py)
@pytest.mark.skipif(not box_models.available()[0], reason="box-first models not installed (npm missing at ./setup.sh)")
@pytest.mark.timeout(2700)  # three 3-D transfers on a loaded machine, each bounded by its own timeout
def test_the_same_take_twice_gives_the_same_frames_and_report_the_second_from_the_cache(data, tmp_path):
    # given the command run once (its style extracted by the nodes and kept in the cache) ...
    _, first = transfer(data, tmp_path / "first")
    assert first["style_origin"] == "extracted"
    entries = list((Path(os.environ["CT_CACHE_DIR"]) / "styles").iterdir())
    assert len(entries) == 1
    # ... when it runs again on the unchanged clip
    r, again = transfer(data, tmp_path / "again")
    # then the style comes from the cache, said in one log line, and no extraction node ran
    assert again["style_origin"] == "cache"
    assert "reusing the measurements of sam2_juggle_1280x720.mp4 from the cache" in r.stderr
    assert not (tmp_path / "again" / "deploy" / "detector.log").exists()
    assert (tmp_path / "first" / "style.json").read_bytes() == (tmp_path / "again" / "style.json").read_bytes()
    # and meta.json names the backend that measured it, kept with the cache entry
    box_first = {"backend": "box_first", "fallback": None}
    assert first["detectors"] == again["detectors"] == {"source": box_first, "output": box_first}
    # and the output was measured while it was filmed
    assert first["output_measured"].startswith("while filming") and again["output_measured"].startswith("while")
    # and the two takes are the same, frame for frame and bit for bit
    ta, tb = read_truths(tmp_path / "first" / "truth.msgpack"), read_truths(tmp_path / "again" / "truth.msgpack")
    assert len(ta) == len(tb) == FRAMES
    for a, b in zip(ta, tb, strict=True):
        assert np.array_equal(a.joints_norm, b.joints_norm) and np.array_equal(a.region_in_focus, b.region_in_focus)
    fa, fb = video_frames(tmp_path / "first" / "output.mp4"), video_frames(tmp_path / "again" / "output.mp4")
    assert len(fa) == len(fb) == FRAMES and all(np.array_equal(x, y) for x, y in zip(fa, fb))
    # and so is the report: every figure, goal and per-frame value
    assert figures(tmp_path / "first") == figures(tmp_path / "again")

    # --no-cache extracts again (and leaves the cache as it was)
    _, fresh = transfer(data, tmp_path / "fresh", "--no-cache", "--no-eval")
    assert fresh["style_origin"] == "extracted"
    assert list((Path(os.environ["CT_CACHE_DIR"]) / "styles").iterdir()) == entries
