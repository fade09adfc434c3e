"""The report's figures drawn in the figure process are the very files drawn in-process, and a
figure process that cannot draw leaves the report whole."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cinetransfer.report import build_report, synth
from cinetransfer.report.workers import FigureWorker

K = 24
FIGS = ("fig_frames.png", "fig_joints.png", "fig_focus.png", "fig_error.png")


def _report(tmp, name, **kw):
    src = synth.instructions(K)
    truths = synth.truths(src.image_targets, first_index=10)
    sv = synth.video(tmp / "source.mp4", src.image_targets)
    return build_report(tmp / name, source_style=src, output_style=src, truths=truths, source_video=sv,
                        output_video=sv, meta={"fps": 24.0, "repeated_slots": [3]}, **kw)


def test_figures_from_the_figure_process_are_the_same_files(tmp_path):
    # given a report drawn in this process, and the same report with a figure process
    here = _report(tmp_path, "here")
    with FigureWorker() as worker:
        there = _report(tmp_path, "there", figure_worker=worker)
    # then every figure is there, byte for byte the same, and so are the numbers
    assert there["figures"] == here["figures"] and set(FIGS) <= set(there["figures"])
    assert not there["figure_errors"]
    for name in there["figures"]:
        assert (tmp_path / "there" / name).read_bytes() == (tmp_path / "here" / name).read_bytes(), name
    drop = ("generated", "report_s", "inputs", "video", "per_frame", "people")
    assert json.dumps({k: v for k, v in there.items() if k not in drop}, sort_keys=True) == \
        json.dumps({k: v for k, v in here.items() if k not in drop}, sort_keys=True)


def test_a_closed_figure_process_leaves_the_figures_to_this_one(tmp_path):
    # given a figure process that was stopped before the report
    worker = FigureWorker()
    worker.close()
    # when the report is built with it
    summary = _report(tmp_path, "closed", figure_worker=worker)
    # then the figures are drawn here all the same
    assert set(FIGS) <= set(summary["figures"]) and not summary["figure_errors"]
    for name in FIGS:
        assert (tmp_path / "closed" / name).stat().st_size > 0


def test_the_videos_colours_are_the_figures_own_without_matplotlib():
    from cinetransfer.report.figures import hex_rgb

    # '#1f77b4': bytes 31, 119, 180, each over 255 (what matplotlib's to_rgb gives)
    assert hex_rgb("#1f77b4") == (31 / 255, 119 / 255, 180 / 255)
    assert hex_rgb("#222222") == (34 / 255,) * 3
    with pytest.raises(ValueError):
        hex_rgb("tab:blue")


def test_a_report_with_a_figure_process_never_imports_matplotlib_here(tmp_path):
    # given a fresh interpreter that builds a report with its figures drawn in a figure process
    code = textwrap.dedent(f"""
        import sys
        from pathlib import Path
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_report_workers import _report
        from cinetransfer.report.workers import FigureWorker
        if __name__ == "__main__":
            with FigureWorker() as worker:
                summary = _report(Path({str(tmp_path)!r}), "fresh", figure_worker=worker)
            assert summary["video"] and not summary["figure_errors"], summary["figure_errors"]
            print("matplotlib" in sys.modules)
    """)
    script = tmp_path / "build.py"
    script.write_text(code)
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    # then the figures and the side-by-side video are made, and matplotlib was only the figure process's
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "False"
