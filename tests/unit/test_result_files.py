"""Result files are whole or absent, truncated inputs are said out loud,
and instructions nothing can fly are refused (by `load_style` and by the planner)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cinetransfer.shared.measurements_file import write_measurements
from cinetransfer.shared import instructions as I
from cinetransfer.services.smoother.cli import smooth_main
from cinetransfer.services.smoother.core import smooth_measurements
from cinetransfer.services.smoother.synthetic import walking_sequence
from cinetransfer.shared import messages as M
from cinetransfer.shared.atomic import AtomicFile, atomic_write
from cinetransfer.shared.plausible import unusable_targets

SOURCE = M.SourceInfo(path="clip.mp4", width=640, height=480, fps=24.0, n_frames=48)


# ----------------------------------------------------------------------------- atomic writes
def test_atomic_write_replaces_the_file_whole_and_leaves_no_temporary(tmp_path):
    p = tmp_path / "r.json"
    p.write_text("old")
    with atomic_write(p) as fh:
        fh.write("new, half")
        assert p.read_text() == "old"  # a reader during the write sees the previous file
        fh.write(" and the rest")
    assert p.read_text() == "new, half and the rest"
    assert [x.name for x in tmp_path.iterdir()] == ["r.json"]


def test_a_failed_atomic_write_leaves_the_previous_file_and_no_temporary(tmp_path):
    p = tmp_path / "r.json"
    p.write_text("old")
    with pytest.raises(RuntimeError), atomic_write(p) as fh:
        fh.write("half")
        raise RuntimeError("disk full")
    assert p.read_text() == "old"
    assert [x.name for x in tmp_path.iterdir()] == ["r.json"]


def test_two_writers_of_one_path_do_not_share_a_temporary_file(tmp_path):
    a, b = AtomicFile(tmp_path / "x", binary=True), AtomicFile(tmp_path / "x", binary=True)
    assert a.tmp_path != b.tmp_path
    a.file.write(b"a")
    b.file.write(b"b")
    a.commit()
    b.commit()
    assert (tmp_path / "x").read_bytes() == b"b"


# ----------------------------------------------------------------------------- truncated inputs
def _cut(path, n_bytes):
    data = path.read_bytes()
    path.write_bytes(data[:-n_bytes])


def test_smooth_on_a_truncated_measurements_file_is_a_clear_error(tmp_path, capsys):
    """Before: exit 0 without a word, and a style of fewer frames than the file held."""
    m = tmp_path / "m.msgpack"
    write_measurements(m, walking_sequence(48), source=SOURCE)
    _cut(m, 100)
    out = tmp_path / "style.json"
    assert smooth_main([str(m), "-o", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "ends inside a record" in err
    assert not out.exists()


def test_smooth_allow_truncated_uses_the_complete_records_flags_the_style_and_warns(tmp_path, capsys):
    m = tmp_path / "m.msgpack"
    write_measurements(m, walking_sequence(48), source=SOURCE)
    _cut(m, 100)
    out = tmp_path / "style.json"
    assert smooth_main([str(m), "-o", str(out), "--quiet", "--allow-truncated"]) == 0
    err = capsys.readouterr().err
    assert "truncated" in err and "warning" in err
    style = I.load_style_file(out)
    rows = style.instructions.image_targets.shape[0]
    assert rows == 47 and style.instructions.source.n_frames == rows
    assert any("declares 48 frames but 47" in w for w in style.warnings)


def test_a_truncated_video_gives_a_style_whose_frame_count_agrees_with_its_rows_and_says_so(tmp_path):
    """A container that promises 120 frames of which 48 decode (a cut download)."""
    res = smooth_measurements(walking_sequence(48), source=SOURCE.__class__(**{**SOURCE.__dict__, "n_frames": 120}))
    ins = res.instructions
    assert ins.source.n_frames == ins.image_targets.shape[0] == 48
    assert len(res.warnings) == 1 and "declares 120 frames but 48" in res.warnings[0]
    p = tmp_path / "style.json"
    I.save_style(p, ins, None, res.warnings)  # --no-diagnostics keeps the warning
    assert json.loads(p.read_text())["warnings"] == list(res.warnings)
    assert I.load_style_file(p).warnings == res.warnings


def test_a_complete_source_gives_no_warning():
    res = smooth_measurements(walking_sequence(48), source=SOURCE)
    assert res.warnings == () and res.instructions.source.n_frames == 48


# ----------------------------------------------------------------------------- unusable targets
def _with_targets(ins: M.Instructions, value: float) -> M.Instructions:
    import dataclasses

    return dataclasses.replace(ins, image_targets=np.full_like(ins.image_targets, value))


@pytest.fixture(scope="module")
def good():
    return smooth_measurements(walking_sequence(24), source=SOURCE.__class__(**{**SOURCE.__dict__, "n_frames": 24}))


@pytest.mark.parametrize("value, words", [(np.nan, "all NaN"), (1e6, "image widths"), (-1e6, "image widths")])
def test_load_style_refuses_targets_nothing_can_fly(tmp_path, good, value, words):
    bad = _with_targets(good.instructions, value)
    assert words in unusable_targets(bad)
    p = tmp_path / "style.json"
    I.save_style(p, bad)
    with pytest.raises(I.StyleFileError, match=words):
        I.load_style(p)
    assert I.load_style_file(p).instructions.image_targets.shape == bad.image_targets.shape  # still plottable


def test_real_targets_are_fine(good):
    assert unusable_targets(good.instructions) == ""
    slightly_out = _with_targets(good.instructions, 1.3)  # a joint just out of frame is a real target
    assert unusable_targets(slightly_out) == ""
