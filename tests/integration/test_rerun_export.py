"""`cinetransfer rerun`: a recording's vehicle position, lens, setpoints and per-frame joint errors
become Rerun scalars. The pure parts are checked against hand-computed values; the export is
opened with rerun-sdk's own reader (skipped where the optional rerun-sdk is not installed)."""
import subprocess
import sys

import numpy as np
import pytest

from cinetransfer.rerun_export import Followed, joint_errors, setpoint_values, vehicle_values
from cinetransfer.shared.instructions import save_style
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M
from cinetransfer.runlog import RunWriter

S = 1_000_000_000
NAMES = ["left_shoulder", "right_shoulder"]


def test_joint_errors_by_hand():
    truth = {"joint_names": ["nose", "left_shoulder", "right_shoulder"],
             "joints_norm": [[0.5, 0.5], [0.1, 0.2], [0.9, 0.9]], "joints_visible": [True, True, False]}
    # left shoulder: (0.1, 0.2) vs (0.4, 0.6) -> 0.3-0.4-0.5 triangle; right shoulder is not visible
    got = joint_errors(truth, np.array([[0.4, 0.6], [0.0, 0.0]]), NAMES)
    assert got == pytest.approx({"left_shoulder": 0.5, "mean": 0.5})
    # a joint without a target (NaN) is left out; nothing compared -> no mean
    assert joint_errors(truth, np.array([[np.nan, np.nan], [0.0, 0.0]]), NAMES) == {}


def test_the_followed_frame_is_the_newest_tracking_setpoint_at_or_before_the_stamp():
    f = Followed()
    for stamp, frame, mode in ((30, 3, "track"), (10, 1, "track"), (20, 2, "track"), (25, 9, "hold")):
        f.add({"stamp_ns": stamp, "instruction_frame": frame, "mode": mode})
    assert [f.at(t) for t in (5, 10, 19, 25, 30, 99)] == [None, 1, 1, 2, 3, 3]


def test_values_skip_nulls():
    v = vehicle_values({"position_m": [1.0, None, 3.0], "lens": {"focal_length_mm": 35.0, "focus_distance_m": None}})
    assert v["vehicle/position/x"] == 1.0 and v["vehicle/position/y"] is None and v["lens/focal_length_mm"] == 35.0
    assert v["lens/focus_distance_m"] is None
    sp = setpoint_values({"instruction_frame": -1, "position_m": [0.0, 0.0, 2.5]})
    assert sp["setpoint/instruction_frame"] is None and sp["setpoint/position/z"] == 2.5


def _instructions(k: int) -> M.Instructions:
    targets = np.zeros((k, 2, 2), np.float32)
    targets[:, 0] = (0.5, 0.5)  # left shoulder wanted at the centre
    targets[:, 1] = (0.25, 0.5)
    return M.Instructions(fps=24.0, frame_duration_s=1 / 24, joint_names=NAMES, image_targets=targets,
                          subject_visible=np.ones(k, bool), subject_box=np.zeros((k, 4), np.float32),
                          focus_raw=np.zeros((k, 3), np.float32), focus_smoothed=np.zeros((k, 3), np.float32),
                          focus_in=np.zeros((k, 3), bool))


def _run(tmp_path, n: int = 10):
    """n steps: vehicle at x = i, focus at i + 1 m, setpoint z = 2 + i following frame i, and a
    camera frame whose left shoulder is 0.1*i/10 right of its target (the right one exactly on it)."""
    with RunWriter(tmp_path / "run.mcap", {"started": "test"}) as w:
        for i in range(n):
            stamp, lens = 100 * S + i * S // 24, M.LensState(focal_length_mm=35.0, focus_distance_m=i + 1.0,
                                                              f_number=4.0, sensor_width_mm=23.76,
                                                              sensor_height_mm=13.365)
            w.write("ct/r/vehicle/state", codec.encode(M.VehicleState(
                stamp_ns=stamp, position_m=np.array([float(i), 0.0, 2.0]), lens=lens)), t_ns=S + i * S // 10)
            w.write("ct/r/planner/setpoint", codec.encode(M.Setpoint(
                stamp_ns=stamp, mode="track", instruction_frame=i, position_m=np.array([0.0, 0.0, 2.0 + i]),
                lens=lens)), t_ns=S + i * S // 10 + 1)
            joints = np.full((17, 2), np.nan, np.float32)
            joints[M.COCO17_NAMES.index("left_shoulder")] = (0.5 + 0.01 * i, 0.5)
            joints[M.COCO17_NAMES.index("right_shoulder")] = (0.25, 0.5)
            w.write("ct/r/sim/truth", codec.encode(M.GroundTruth(
                stamp_ns=stamp, frame_index=i, joints_norm=joints, joints_visible=np.isfinite(joints[:, 0]))),
                t_ns=S + i * S // 10 + 2)
            frame = M.Frame(stamp_ns=stamp, index=i, fps=24.0, lens=lens, image=np.full((48, 64, 3), 20 * i, np.uint8))
            w.write("ct/r/camera/frame", codec.encode(frame), t_ns=S + i * S // 10 + 3)
    save_style(tmp_path / "style.json", _instructions(n))


def _contents(rrd) -> tuple[dict[str, list[float]], dict[str, set[str]]]:
    """(scalar series by entity in stamp order, column names by entity) of an .rrd, read by rerun-sdk."""
    from rerun.chunk import RrdReader

    out: dict[str, list[float]] = {}
    columns: dict[str, set[str]] = {}
    for chunk in RrdReader(rrd).stream().collect().stream():
        rb = chunk.to_record_batch()
        columns.setdefault(chunk.entity_path, set()).update(rb.schema.names)
        if "Scalars:scalars" in rb.schema.names:
            col = rb.column("Scalars:scalars").to_pylist()
            order = np.argsort(rb.column("message_publish_time").to_numpy())
            out.setdefault(chunk.entity_path, []).extend(col[int(i)][0] for i in order)
    return out, columns


def test_the_export_opens_in_rerun_with_every_value_as_scalars(tmp_path):
    pytest.importorskip("rerun", reason="rerun-sdk is optional (pip install 'cinetransfer[rerun]')")
    _run(tmp_path)
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "rerun", str(tmp_path / "run.mcap")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    s, columns = _contents(tmp_path / "run.rrd")
    assert s["/r/vehicle/position/x"] == [float(i) for i in range(10)]
    assert s["/r/lens/focus_distance_m"] == [i + 1.0 for i in range(10)]
    assert s["/r/setpoint/position/z"] == [2.0 + i for i in range(10)]
    assert s["/r/setpoint/lens/focal_length_mm"] == [35.0] * 10
    assert s["/r/setpoint/instruction_frame"] == [float(i) for i in range(10)]
    assert s["/r/joint_error/left_shoulder"] == pytest.approx([0.01 * i for i in range(10)], abs=1e-6)
    assert s["/r/joint_error/right_shoulder"] == pytest.approx([0.0] * 10, abs=1e-6)
    assert s["/r/joint_error/mean"] == pytest.approx([0.005 * i for i in range(10)], abs=1e-6)
    # on the timelines of Rerun's MCAP import, beside the video, the transforms and the calibration it imports
    assert {"message_log_time", "message_publish_time", "frame"} <= columns["/r/joint_error/mean"]
    assert "VideoStream:sample" in columns["/ct/r/camera/frame"]
    assert "Transform3D:translation" in columns["/ct/r/tf/drone"]
    assert "Pinhole:image_from_camera" in columns["/ct/r/camera/frame/calibration"]


def test_rerun_export_refuses_a_foreign_file_in_one_line(tmp_path):
    pytest.importorskip("rerun", reason="rerun-sdk is optional (pip install 'cinetransfer[rerun]')")
    (tmp_path / "x.mcap").write_bytes(b"not mcap")
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "rerun", str(tmp_path / "x.mcap")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "not an MCAP file" in r.stderr and "Traceback" not in r.stderr
