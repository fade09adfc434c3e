"""The fidelity report end to end on synthetic runs: report.json, report.html, figures, the truth
file and `cinetransfer report RUN_DIR`."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from cinetransfer.report import build_report, synth
from cinetransfer.report import cli as report_cli
from cinetransfer.report.figures import credit_for, read_frames
from cinetransfer.report.truthfile import TruthFileError, TruthWriter, read_truths, write_truths
from cinetransfer.shared.instructions import save_style
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M

K = 36
FIGS = ("fig_frames.png", "fig_joints.png", "fig_focus.png", "fig_error.png")
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _strict_json(path: Path) -> dict:
    def no_constants(name: str):
        raise ValueError(f"non-standard JSON constant {name} in {path}")

    return json.loads(path.read_text(encoding="utf-8"), parse_constant=no_constants)


def _run(tmp: Path, *, with_output: bool = True, with_video: bool = True):
    """A synthetic run: output 0.01 off in x, background label flipped in the last third."""
    src = synth.instructions(K)
    out_tg = src.image_targets + np.float32([0.01, 0.0])
    fin = np.tile([False, True, False], (K, 1))
    fin[2 * K // 3:, 2] = True
    out = synth.instructions(K, image_targets=out_tg, focus_in=fin) if with_output else None
    truths = synth.truths(src.image_targets, focus_in=fin, first_index=200)
    src_video = synth.video(tmp / "source.mp4", src.image_targets) if with_video else None
    out_video = synth.video(tmp / "output.mp4", out_tg, colour=(30, 110, 50)) if with_video else None
    return src, out, truths, src_video, out_video


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("report")
    src, out, truths, sv, ov = _run(tmp)
    meta = {"scene": "park", "source": str(sv), "credit": "Footage: Test Credit <b>CC BY</b>",
            "timings": {"total_s": 12.5}, "fps": 24.0}
    summary = build_report(tmp / "rep", source_style=src, output_style=out, truths=truths, source_video=sv,
                           output_video=ov, meta=meta)
    return tmp / "rep", summary


def test_report_files_written(report):
    outdir, _ = report
    for name in ("report.html", "report.json", *FIGS):
        p = outdir / name
        assert p.is_file() and p.stat().st_size > 0, name
    for name in FIGS:
        data = (outdir / name).read_bytes()
        assert data[:8] == PNG_MAGIC, name
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.shape[0] > 200 and img.shape[1] > 600, name
        assert img.std() > 5, f"{name} is blank"


def test_report_json_keys_and_numbers(report):
    outdir, summary = report
    js = _strict_json(outdir / "report.json")
    for key in ("format", "version", "joint_names", "alignment", "extraction", "truth", "goals", "headline",
                "meta", "figures", "per_frame", "credit"):
        assert key in js, key
    assert js["format"] == "cinetransfer-report" and js["version"] == 1
    assert js["joint_names"] == list(synth.JOINTS)
    assert sorted(js["figures"]) == sorted(FIGS) and js["figure_errors"] == {}
    ex, tr = js["extraction"], js["truth"]
    assert ex["available"] and tr["available"]
    assert ex["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.01, abs=1e-6)
    assert tr["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.0, abs=1e-6)
    # background flipped in 12 of 36 frames, for the extraction and the truth alike
    assert ex["focus"]["background"]["agreement"] == pytest.approx(24 / 36)
    assert tr["focus"]["background"]["agreement"] == pytest.approx(24 / 36)
    assert ex["focus"]["subject"]["agreement"] == 1.0
    goals = {g["id"]: g["status"] for g in js["goals"]}
    assert goals == {"extraction_joint_error": "met", "extraction_focus_foreground": "met",
                     "extraction_focus_subject": "met", "extraction_focus_background": "missed",
                     "truth_joint_error": "met", "truth_focus_foreground": "met", "truth_focus_subject": "met",
                     "truth_focus_background": "missed"}
    assert js["headline"]["goals_met"] == "6/8"
    assert js["alignment"]["compared_frames"] == K and js["alignment"]["output_fps"] == pytest.approx(24.0)
    assert len(js["per_frame"]["joint_error_extraction"]) == K
    assert js["meta"]["scene"] == "park"
    # the returned summary is what was written (plus nothing hidden)
    assert summary["headline"] == js["headline"]


def test_report_html_is_self_contained_and_coloured(report):
    outdir, _ = report
    html = (outdir / "report.html").read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>") and html.rstrip().endswith("</html>")
    # every figure embedded; nothing fetched from the network
    assert html.count("src='data:image/png;base64,") == len(FIGS)
    assert not re.search(r"(src|href)=['\"]https?://", html)
    assert "<script" not in html
    # goal colouring: 6 met, 2 missed cells in the goals table (+ the joint/focus tables)
    assert html.count("<td class='met'>met</td>") == 6
    assert html.count("<td class='missed'>missed</td>") == 2
    assert "66.7 %" in html  # background agreement
    # meta printed, credit escaped
    assert "Footage: Test Credit &lt;b&gt;CC BY&lt;/b&gt;" in html
    assert "total_s" in html and "park" in html


def test_missing_output_style_is_reported(tmp_path):
    src, _, truths, sv, ov = _run(tmp_path, with_output=False)
    s = build_report(tmp_path / "rep", source_style=src, output_style=None, truths=truths, source_video=sv,
                     output_video=ov, meta={})
    js = _strict_json(tmp_path / "rep" / "report.json")
    assert js["extraction"]["available"] is False
    assert "extraction" in js["extraction"]["reason"]
    assert js["truth"]["available"] is True
    assert {g["status"] for g in js["goals"] if g["measure"] == "extraction"} == {"n/a"}
    assert s["headline"]["extraction"] == {"available": False, "reason": js["extraction"]["reason"]}
    html = (tmp_path / "rep" / "report.html").read_text(encoding="utf-8")
    assert "Extraction on the output: not available." in html
    for name in FIGS:
        assert (tmp_path / "rep" / name).stat().st_size > 0


def test_style_paths_unreadable_output_and_no_videos(tmp_path):
    # given style files on disk (the smoother's format), a corrupt output style and no videos
    src, out, truths, _, _ = _run(tmp_path, with_video=False)
    save_style(tmp_path / "style.json", src)
    (tmp_path / "output_style.json").write_text("{not json", encoding="utf-8")
    s = build_report(tmp_path / "rep", source_style=tmp_path / "style.json",
                     output_style=tmp_path / "output_style.json", truths=truths, source_video=None,
                     output_video=None, meta={"scene": "x"})
    assert s["extraction"]["available"] is False
    assert "could not be read" in s["extraction"]["reason"]
    assert s["truth"]["joints"]["overall"]["euclidean"]["n"] == K * 4
    assert (tmp_path / "rep" / "fig_frames.png").read_bytes()[:8] == PNG_MAGIC  # placeholders drawn
    # and a good output style file gives the same numbers as the message
    save_style(tmp_path / "output_style.json", out)
    s2 = build_report(tmp_path / "rep2", source_style=tmp_path / "style.json",
                      output_style=tmp_path / "output_style.json", truths=[], source_video=None,
                      output_video=None, meta={})
    assert s2["extraction"]["joints"]["overall"]["euclidean"]["mean"] == pytest.approx(0.01, abs=1e-6)
    assert s2["truth"]["available"] is False


def test_a_fallback_detector_and_backends_that_differ_are_stated_goals_kept(tmp_path):
    # given a run whose source was measured by the detector's fallback backend, its output by box_first
    src, out, truths, _, _ = _run(tmp_path, with_video=False)
    fallback = {"backend": "mediapipe (box_first unavailable)", "fallback": "box_first: m.tflite is missing"}
    meta = {"detectors": {"source": fallback, "output": {"backend": "box_first", "fallback": None}}}
    s = build_report(tmp_path / "rep", source_style=src, output_style=out, truths=truths, source_video=None,
                     output_video=None, meta=meta)
    plain = build_report(tmp_path / "plain", source_style=src, output_style=out, truths=truths, source_video=None,
                         output_video=None, meta={})
    # then report.json, its headline and the page say both
    js = _strict_json(tmp_path / "rep" / "report.json")
    assert js["detectors"]["same_backend"] is False and len(js["detectors"]["notes"]) == 2
    assert js["headline"]["detectors"] == js["detectors"]["notes"]
    html = (tmp_path / "rep" / "report.html").read_text(encoding="utf-8")
    assert html.count("<b>Detector:</b>") == 2 and "not measured the same way" in html
    # and it is not a degraded take: the goals are judged as without it
    assert s["goals"] == plain["goals"] and s["headline"]["goals_met"] == plain["headline"]["goals_met"]
    assert "detectors" not in plain["headline"] and plain["detectors"]["notes"] == []


def test_unreadable_source_style_raises(tmp_path):
    (tmp_path / "style.json").write_text('{"format": "other"}', encoding="utf-8")
    with pytest.raises(ValueError, match="style"):
        build_report(tmp_path, source_style=tmp_path / "style.json", output_style=None, truths=[],
                     source_video=None, output_video=None, meta={})


def test_truth_file_round_trip_and_truncation(tmp_path):
    src = synth.instructions(5)
    truths = synth.truths(src.image_targets, first_index=7)
    p = tmp_path / "truth.msgpack"
    assert write_truths(p, truths) == 5
    back = read_truths(p)
    assert [t.frame_index for t in back] == [7, 8, 9, 10, 11]
    assert np.allclose(back[2].joints_norm, truths[2].joints_norm, equal_nan=True)
    assert back[0].region_in_focus.tolist() == [False, True, False]
    # each record is a 4-byte little-endian length + one codec payload
    data = p.read_bytes()
    n0 = int.from_bytes(data[:4], "little")
    assert isinstance(codec.decode(data[4:4 + n0], M.GroundTruth), M.GroundTruth)
    # a run cut short mid-record keeps the complete records
    p.write_bytes(data[:-10])
    assert len(read_truths(p)) == 4
    # appending
    with TruthWriter(p, append=False) as w:
        w.write(truths[0])
    with TruthWriter(p, append=True) as w:
        w.write(truths[1])
    assert [t.frame_index for t in read_truths(p)] == [7, 8]
    # a record that is not a GroundTruth is refused with its position
    bad = codec.encode(M.Command(action="stop"))
    p.write_bytes(len(bad).to_bytes(4, "little") + bad)
    with pytest.raises(TruthFileError, match="record 0"):
        read_truths(p)


def test_credit_from_manifest(tmp_path):
    (tmp_path / "MANIFEST.md").write_text(
        "| file | video | what | licence | gt |\n|---|---|---|---|---|\n"
        "| `clip.mp4` | H.264 | a man | CC BY 3.0 — \"(CC) Someone\" | none |\n", encoding="utf-8")
    (tmp_path / "clip.mp4").write_bytes(b"")
    assert credit_for(tmp_path / "clip.mp4") == "clip.mp4: CC BY 3.0 — \"(CC) Someone\""
    assert credit_for(tmp_path / "other.mp4") == ""
    assert credit_for(None) == ""


def test_read_frames_picks_exact_frames(tmp_path):
    p = tmp_path / "ramp.avi"
    wr = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"MJPG"), 24.0, (64, 48))
    for i in range(12):
        wr.write(np.full((48, 64, 3), i * 20, np.uint8))
    wr.release()
    frames = read_frames(p, [9, 0, 4, 40])
    assert sorted(frames) == [0, 4, 9]  # frame 40 does not exist
    for i, img in frames.items():
        assert img.shape == (48, 64, 3)
        assert abs(float(img.mean()) - i * 20) < 4


def _run_dir(tmp: Path) -> Path:
    run = tmp / "run"
    run.mkdir()
    src, out, truths, sv, ov = _run(tmp)
    save_style(run / "style.json", src)
    save_style(run / "output_style.json", out)
    ov.rename(run / "output.mp4")
    write_truths(run / "truth.msgpack", truths)
    (run / "meta.json").write_text(json.dumps({"source": str(sv), "scene": "meadow", "fps": 24.0}))
    return run


def test_cli_rebuilds_report_from_run_folder(tmp_path, capsys):
    run = _run_dir(tmp_path)
    assert report_cli.main([str(run)]) == 0
    js = _strict_json(run / "report.json")
    assert js["headline"]["goals_met"] == "6/8"
    assert js["truth"]["frames"] == K
    assert js["meta"]["scene"] == "meadow"
    assert js["alignment"]["output_frames"] == K
    printed = capsys.readouterr().out
    assert "report.html" in printed and "goals_met" in printed
    assert "meadow" in (run / "report.html").read_text(encoding="utf-8")
    # a folder without style.json is refused
    (tmp_path / "empty").mkdir()
    assert report_cli.main([str(tmp_path / "empty")]) == 2


def test_report_command_is_registered(tmp_path):
    run = _run_dir(tmp_path)
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "report", str(run), "-o", str(tmp_path / "o"),
                        "--no-embed"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    html = (tmp_path / "o" / "report.html").read_text(encoding="utf-8")
    assert "src='fig_joints.png'" in html  # linked, not embedded
    assert (tmp_path / "o" / "fig_joints.png").is_file()


def test_repeated_frames_are_stated_in_the_report(tmp_path):
    # given a real-time recording where 3 of the output frames repeat the previous one
    src, out, truths, sv, ov = _run(tmp_path)
    meta = {"scene": "park", "fps": 24.0, "clock_mode": "realtime", "instruction_frames": K, "recorded_frames": K,
            "repeated_frames": 3, "repeated_slots": [4, 5, 20]}
    summary = build_report(tmp_path / "rep", source_style=src, output_style=out, truths=truths, source_video=sv,
                           output_video=ov, meta=meta)
    # then report.json and report.html say so: count, share, clock
    rec = _strict_json(tmp_path / "rep" / "report.json")["recording"]
    assert rec["repeated_frames"] == 3 and rec["repeated_share"] == pytest.approx(3 / K, abs=1e-4)
    assert rec["clock"] == "realtime" and "repeat the previous frame" in rec["notes"][0]
    html = (tmp_path / "rep" / "report.html").read_text()
    assert "3 of 36 output frames (8.3%) repeat the previous frame" in html
    assert "wall clock (real time)" in html
    assert summary["recording"] == rec
    # and a lockstep recording carries no such note
    meta.update(clock_mode="lockstep", repeated_frames=0, repeated_slots=[])
    s2 = build_report(tmp_path / "rep2", source_style=src, output_style=out, truths=truths, source_video=sv,
                      output_video=ov, meta=meta)
    assert s2["recording"]["notes"] == [] and "repeat the previous frame" not in \
        (tmp_path / "rep2" / "report.html").read_text()


def test_camera_roll_at_the_recorded_frames_and_the_note_it_gives():
    from cinetransfer.report.build import camera_roll_deg, recording_facts
    from cinetransfer.shared import messages as M

    def state(t, roll):
        return M.VehicleState(stamp_ns=t, camera_ypr_rad=np.array([0.0, 0.0, roll]))

    states = [state(20, -0.2), state(0, 0.0), state(10, 0.1)]  # any order
    # frames at 5, 10, 15, 25 see the rolls 0, 0.1, 0.1, -0.2 rad; a frame before every state has none
    roll = camera_roll_deg(states, [5, 10, 15, 25, -1])
    deg = np.degrees([0.0, 0.1, 0.1, 0.2])
    assert roll == {"p50": round(float(np.percentile(deg, 50)), 2), "p95": round(float(np.percentile(deg, 95)), 2),
                    "max": round(float(deg.max()), 2)}
    assert camera_roll_deg(states, [-5]) is None
    # a rolled camera is said in the report's notes; a level one is not
    meta = {"instruction_frames": 4, "recorded_frames": 4}
    assert any("rolled" in n for n in recording_facts(meta, roll)["notes"])
    assert recording_facts(meta, {"p50": 0.0, "p95": 0.0, "max": 0.0})["notes"] == []


def test_frames_out_of_the_lens_reach_are_shown_per_region_and_shot_and_carried(tmp_path):
    # given a run whose truth records the regions' depths: in its first 12 frames the foreground lies at
    # the subject's depth while the source asks it soft with the subject sharp (at 100 mm, lens f/1-22)
    import dataclasses

    src, out, truths, _, _ = _run(tmp_path, with_video=False)
    src = dataclasses.replace(src, focus_in=np.tile([False, True, False], (K, 1)))
    lim = np.float32([0.5, 100.0, 1.0, 22.0])
    depth = [np.full(20, 1 / 4.0), np.full(20, 1 / 7.0), np.full(20, 1 / 30.0)]
    truths = [dataclasses.replace(t, focal_length_mm=100.0, lens_limits=lim,
                                  region_inverse_depth=np.float32([depth[1] if i < 12 else depth[0], *depth[1:]]))
              for i, t in enumerate(truths)]
    build_report(tmp_path / "rep", source_style=src, output_style=out, truths=truths, source_video=None,
                 output_video=None, meta={})
    js = _strict_json(tmp_path / "rep" / "report.json")
    # then report.json carries them per frame and as a run, and both agreements, named
    reach = js["focus_reach"]
    assert reach["frames_judged"] == K and reach["unreachable_frames"] == {"foreground": 12, "subject": 0,
                                                                            "background": 0}
    (run,) = reach["runs"]
    assert (run["region"], run["shot"], run["first_frame"], run["last_frame"], run["frames"]) == \
        ("foreground", 0, 0, 11, 12)
    assert run["reason"].startswith("foreground at the subject's depth")
    pf = js["per_frame"]["focus_unreachable"]
    assert pf["foreground"][0] == run["reason"] and pf["foreground"][12] is None and set(pf["subject"]) == {None}
    fo = js["truth"]["focus"]["foreground"]
    assert fo["n_frames_unreachable"] == 12 and fo["n_frames_reachable"] == K - 12
    # and the page shows the run and both agreements
    html = (tmp_path / "rep" / "report.html").read_text(encoding="utf-8")
    assert "Frames out of the lens&#x27;s reach" in html or "Frames out of the lens's reach" in html
    assert "label agreement, all frames" in html and "label agreement, reachable frames (judged)" in html
    assert "foreground at the subject&#x27;s depth" in html or "foreground at the subject's depth" in html


def test_every_frame_whose_label_is_not_the_sources_is_explained_per_frame(tmp_path):
    # given the run above: the foreground at the subject's depth in frames 0-11 (asked soft, filmed soft), and
    # the background filmed sharp in the last third where the source asks it soft and a lens could give it
    # (background 30 m behind a subject at 7 m, 100 mm, f/1-22)
    import dataclasses

    src, out, truths, _, _ = _run(tmp_path, with_video=False)
    src = dataclasses.replace(src, focus_in=np.tile([False, True, False], (K, 1)))
    lim = np.float32([0.5, 100.0, 1.0, 22.0])
    depth = [np.full(20, 1 / 4.0), np.full(20, 1 / 7.0), np.full(20, 1 / 30.0)]
    truths = [dataclasses.replace(t, focal_length_mm=100.0, lens_limits=lim, dof_near_m=20.0, dof_far_m=40.0,
                                  region_inverse_depth=np.float32([depth[1] if i < 12 else depth[0], *depth[1:]]))
              for i, t in enumerate(truths)]
    build_report(tmp_path / "rep", source_style=src, output_style=out, truths=truths, source_video=None,
                 output_video=None, meta={})
    js = _strict_json(tmp_path / "rep" / "report.json")
    # then both sides count the last third's background as the flight's miss, and nothing else
    late = K - 2 * K // 3
    for side in ("truth", "extraction"):
        counts = js["focus_misses"][side]
        assert counts["background"]["controller"] == late and sum(counts["background"].values()) == late
        assert sum(counts["foreground"].values()) == 0 and sum(counts["subject"].values()) == 0
        kinds = js["per_frame"]["focus_miss_kind"][side]["background"]
        assert kinds[: 2 * K // 3] == [None] * (2 * K // 3) and set(kinds[2 * K // 3:]) == {"controller"}
        why = js["per_frame"]["focus_miss_why"][side]["background"][-1]
        assert "within the lens's reach" in why and "depth of field 20 m to 40 m" in why
    run_rows = [(r["side"], r["region"], r["kind"], r["first_frame"], r["last_frame"])
                for r in js["focus_misses"]["runs"]]
    assert run_rows == [(side, "background", "controller", 2 * K // 3, K - 1) for side in ("truth", "extraction")]
    # and the page shows the counts, the runs and each frame with its reason
    html = (tmp_path / "rep" / "report.html").read_text(encoding="utf-8")
    assert "Why a label is not the source" in html and "missed by the flight (within reach)" in html
    assert f"each of the {2 * late} frame-regions with its reason" in html
