"""Style file (JSON + JSON Schema), windows, and the smooth/plot command lines."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cinetransfer.shared import instructions as I
from cinetransfer.services.smoother.cli import plot_main, smooth_main
from cinetransfer.services.smoother.core import smooth_measurements
from cinetransfer.services.smoother.synthetic import measurement, walking_sequence
from cinetransfer.shared import messages as M

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def result():
    ms = walking_sequence(60)
    for i in range(40, 60):  # an absence: NaN rows must survive the round trip
        ms[i] = measurement(i)
    return smooth_measurements(ms)


def test_round_trip_preserves_every_field(tmp_path, result):
    p = tmp_path / "style.json"
    I.save_style(p, result.instructions, result.diagnostics)
    s = I.load_style_file(p)
    a, b = result.instructions, s.instructions
    for name in ("image_targets", "subject_visible", "subject_box", "focus_raw", "focus_smoothed", "focus_in"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert np.isnan(b.image_targets[45]).all()
    for name in ("fps", "frame_duration_s", "first_frame", "final", "joint_names", "theta", "mu_m", "valid"):
        assert getattr(a, name) == getattr(b, name), name
    assert b.source.width == 640
    raw_box = I.diag_array(s.diagnostics, "raw_box")
    np.testing.assert_allclose(raw_box, result.diagnostics["raw_box"], equal_nan=True)
    # the file is strict JSON (no NaN tokens)
    json.loads(p.read_text(), parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))


def test_wrong_version_is_refused_naming_the_needed_version(tmp_path, result):
    d = I.style_to_dict(result.instructions)
    d["version"] = 99
    p = tmp_path / "old.json"
    p.write_text(json.dumps(d))
    with pytest.raises(I.StyleFileError, match=r"version 99 is not supported; this build needs version 1"):
        I.load_style(p)


@pytest.mark.parametrize("mutate, needle", [
    (lambda d: d.update(format="something-else"), "not a cinetransfer style file"),
    (lambda d: d["instructions"]["focus_in"][0].pop(), "focus_in"),
    (lambda d: d["instructions"].update(joint_names=["left_shoulder", "chest"]), "joint_names"),
    (lambda d: d["instructions"].pop("mu_m"), "mu_m"),
    (lambda d: d["instructions"]["subject_visible"].pop(), "subject_visible has 59 rows"),
])
def test_invalid_files_are_refused(tmp_path, result, mutate, needle):
    d = I.style_to_dict(result.instructions)
    mutate(d)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(I.StyleFileError, match=needle):
        I.load_style(p)


def test_the_same_text_is_validated_once_and_a_bad_one_every_time(tmp_path, result, monkeypatch):
    import jsonschema

    calls = []
    real = jsonschema.validate
    monkeypatch.setattr(jsonschema, "validate", lambda *a, **k: (calls.append(1), real(*a, **k)))
    # given a style file read twice, and a copy of it under another name
    p, q = tmp_path / "style.json", tmp_path / "copy.json"
    ins = I.dataclasses.replace(result.instructions, mu_m=1.234)  # a text no other test has read
    I.save_style(p, ins)
    q.write_bytes(p.read_bytes())
    a, b, c = I.load_style_file(p), I.load_style_file(p), I.load_style_file(q)
    # then the schema was checked once for the three (the same content), and they read the same
    assert len(calls) == 1
    for s in (b, c):
        np.testing.assert_array_equal(a.instructions.image_targets, s.instructions.image_targets)
    # and a file whose content changed is checked again: a bad one is refused on every read
    d = I.style_to_dict(ins)
    d["instructions"].pop("mu_m")
    p.write_text(json.dumps(d))
    for _ in range(2):
        with pytest.raises(I.StyleFileError, match="mu_m"):
            I.load_style_file(p)
    assert len(calls) == 3


def test_not_json_is_refused(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(I.StyleFileError, match="not valid JSON"):
        I.load_style(p)


def test_docs_schema_is_the_generated_one():
    on_disk = json.loads((REPO / "docs" / "instructions.schema.json").read_text())
    assert on_disk == I.json_schema(), "regenerate: python -m cinetransfer.shared.instructions " \
                                       "--write-schema docs/instructions.schema.json"


def test_schema_accepts_a_written_file(tmp_path, result):
    import jsonschema

    d = I.style_to_dict(result.instructions, result.diagnostics)
    jsonschema.validate(json.loads(json.dumps(d)), I.json_schema())


def test_window_slice(result):
    w = I.slice_instructions(result.instructions, 50, 60)
    assert w.first_frame == 50 and not w.final and w.image_targets.shape == (10, 4, 2)
    I.check_consistent(w)


def test_smooth_and_plot_command_lines(tmp_path, capsys):
    from cinetransfer.shared.measurements_file import write_measurements

    mpath = tmp_path / "m.msgpack"
    write_measurements(mpath, walking_sequence(48), source=M.SourceInfo(path="synthetic.mp4", width=640, height=480,
                                                                          fps=24.0, n_frames=48))
    out = tmp_path / "style.json"
    assert smooth_main([str(mpath), "-o", str(out), "--quiet", "--joints", "left_shoulder,right_hip"]) == 0
    ins = I.load_style(out)
    assert ins.joint_names == ["left_shoulder", "right_hip"] and ins.source.path == "synthetic.mp4"
    png = tmp_path / "style.png"
    assert plot_main([str(out), "-o", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_smooth_command_line_no_person_is_a_clear_error(tmp_path, capsys):
    from cinetransfer.shared.measurements_file import write_measurements

    mpath = tmp_path / "empty.msgpack"
    write_measurements(mpath, [measurement(i) for i in range(5)])
    assert smooth_main([str(mpath), "-o", str(tmp_path / "s.json"), "--quiet"]) == 1
    assert "no person detected" in capsys.readouterr().err
    assert not (tmp_path / "s.json").exists()


def test_bad_joint_name_is_a_usage_error(tmp_path, capsys):
    assert smooth_main([str(tmp_path / "none.msgpack"), "--joints", "chest"]) == 2
    assert "COCO-17" in capsys.readouterr().err


@pytest.mark.parametrize("fps", [1000.0, 240.5])
def test_a_style_faster_than_the_camera_is_refused_when_read(tmp_path, result, fps):
    import dataclasses

    bad = dataclasses.replace(result.instructions, fps=fps, frame_duration_s=1.0 / fps)
    path = tmp_path / "fast.json"
    path.write_text(json.dumps(I.style_to_dict(bad, result.diagnostics)))
    with pytest.raises(I.StyleFileError, match=r"fps.*240"):
        I.load_style(path)
