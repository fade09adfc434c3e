"""The report plays in a real browser: headless Chromium (Debian's) opens report.html with the
network off, and the side-by-side H.264 video reaches readyState >= 2 with the right duration —
embedded in the page, and linked beside it (--no-embed)."""
import shutil

import pytest

from cinetransfer.report import build_report
from cinetransfer.report.browser_check import check, verdict
from cinetransfer.shared.video import probe
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
from test_report_build import K, _run  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("chromium") is None,
                                reason="needs Debian's chromium (.ci/run installs it)")


@pytest.mark.parametrize("embed", [True, False], ids=["embedded", "linked"])
def test_report_video_plays_offline_in_headless_chromium(tmp_path, embed):
    # given a report of a 36-frame run at 24 fps
    src, out, truths, sv, ov = _run(tmp_path)
    summary = build_report(tmp_path / "rep", source_style=src, output_style=out, truths=truths, source_video=sv,
                           output_video=ov, meta={"fps": 24.0}, embed_images=embed)
    video = tmp_path / "rep" / "report_video.mp4"
    info = probe(video)
    assert info["codec"] == "h264" and info["faststart"] and info["frames"] == K, info
    assert summary["video"]["duration_s"] == pytest.approx(K / 24.0)
    # when Chromium opens the page offline
    result = check(tmp_path / "rep" / "report.html", timeout_s=120)
    # then the video has data and lasts 1.5 s, and nothing was asked of the network
    assert verdict(result) == [], result
    assert result["video"]["duration"] == pytest.approx(K / 24.0, abs=1 / 24)
    assert result["video"]["width"] == summary["video"]["width"]
