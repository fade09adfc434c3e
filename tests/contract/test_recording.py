"""Recordings (run.mcap): the JSON schemas are generated from shared/messages.py and match it;
every message survives recording and reading back; the mcap library reads every channel's
schema; damaged, foreign and interrupted files behave as docs/recording.md says."""
import dataclasses
import json
import subprocess
import sys
import typing

import jsonschema
import pytest

from cinetransfer import runlog
from cinetransfer.shared import codec, jsonmsg
from cinetransfer.shared import messages as M
from cinetransfer.shared.codec import _hints
from test_codec import assert_same, sample_messages


def _check_schema_matches(cls: type, schema: dict) -> None:
    names = [f.name for f in dataclasses.fields(cls) if f.name not in jsonmsg.OMIT.get(cls, ())]
    assert list(schema["properties"]) == names and schema["required"] == names, cls.__name__
    hints = _hints(cls)
    for f in dataclasses.fields(cls):
        if f.name not in schema["properties"]:
            continue
        s, tp = schema["properties"][f.name], hints[f.name]
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        target = inner[0] if typing.get_origin(tp) in (typing.Union, __import__("types").UnionType) else tp
        if dataclasses.is_dataclass(target):
            _check_schema_matches(target, s)
        elif typing.get_origin(target) is list and dataclasses.is_dataclass(typing.get_args(target)[0]):
            _check_schema_matches(typing.get_args(target)[0], s["items"])
        elif "shape" in f.metadata and s.get("type") in ("array", ["array", "null"]):
            depth, node = 0, s
            while node.get("type") in ("array", ["array", "null"]):
                depth, node = depth + 1, node["items"]
            assert depth == len(f.metadata["shape"]), f.name
        assert s.get("description") == f.metadata.get("doc", s.get("description")), f.name


@pytest.mark.parametrize("cls", list(M.MESSAGE_TYPES.values()), ids=lambda c: c.__name__)
def test_json_schema_is_generated_from_the_dataclass_and_matches_it(cls):
    schema = jsonmsg.message_schema(cls)
    jsonschema.Draft202012Validator.check_schema(schema)
    _check_schema_matches(cls, schema)


@pytest.mark.parametrize("msg", list(sample_messages()), ids=lambda m: type(m).__name__)
def test_json_form_validates_and_round_trips(msg):
    obj = json.loads(json.dumps(jsonmsg.to_json(msg), allow_nan=False))  # strict JSON: NaN travels as null
    jsonschema.validate(obj, jsonmsg.message_schema(type(msg)))
    back = jsonmsg.from_json(type(msg), obj)
    assert_same(msg, back, ignore=("image",))


def _write_samples(path, **kw):
    with runlog.RunWriter(path, {"description": "samples"}, **kw) as w:
        for i, msg in enumerate(sample_messages()):
            key = "ct/r/camera/frame" if isinstance(msg, M.Frame) else f"ct/r/{type(msg).__name__.lower()}/x"
            w.write(key, codec.encode(msg), t_ns=1000 + i)
        w.write("ct/r/garbage/x", b"not a message", t_ns=2000)


def test_every_message_survives_a_recording_and_the_mcap_library_reads_every_schema(tmp_path):
    # given a recording of one message of every type, and one payload nobody can decode
    path = tmp_path / "run.mcap"
    _write_samples(path)
    # then our reader gives back the same messages (the frame's image within JPEG error) and the raw bytes
    got = list(runlog.read_run(path))
    want = list(sample_messages())
    assert [k for _, k, _ in got][-1] == "ct/r/garbage/x" and got[-1][2] == b"not a message"
    for (_, _, payload), msg in zip(got, want, strict=False):
        back = codec.decode(payload)
        assert_same(msg, back, ignore=("image",))
        if isinstance(msg, M.Frame):
            assert back.image.shape == msg.image.shape
    assert len(got) == len(want) + 1
    # and the mcap library itself reads it with every channel's schema: JSON schemas of ours, foxglove's
    # protobuf schemas for images, calibration and transforms
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.id: s for s in summary.schemas.values()}
        by_topic = {c.topic: (c.message_encoding, schemas[c.schema_id] if c.schema_id else None)
                    for c in summary.channels.values()}
        n = sum(1 for _ in reader.iter_messages())
    assert n == summary.statistics.message_count
    assert by_topic["ct/r/camera/frame"][1].name == "foxglove.CompressedVideo"  # H.264
    assert by_topic["ct/r/camera/frame/calibration"][1].name == "foxglove.CameraCalibration"
    assert {by_topic[t][1].name for t in ("ct/r/tf/drone", "ct/r/tf/camera", "ct/r/tf/subject")} == \
        {"foxglove.FrameTransform"}
    for t, (enc, schema) in by_topic.items():
        if t == "ct/r/garbage/x":
            assert enc == runlog.RAW_ENCODING and schema is None
        elif enc == "json":
            cls = {jsonmsg.schema_name(c): c for c in M.MESSAGE_TYPES.values()}[schema.name]
            assert json.loads(schema.data) == jsonmsg.message_schema(cls), t
        else:
            assert enc == "protobuf" and schema.encoding == "protobuf", t


def test_a_reader_of_some_keys_gets_exactly_those_messages_of_the_whole_read(tmp_path):
    path = tmp_path / "run.mcap"
    _write_samples(path)
    everything = list(runlog.read_run(path))
    keys = {k for _, k, _ in everything}
    assert "ct/r/camera/frame" in keys and len(keys) > 3
    small = {k for k in keys if k != "ct/r/camera/frame"}
    some = sorted(small)[:2]
    assert list(runlog.read_run(path, only=some)) == [m for m in everything if m[1] in some]
    assert list(runlog.read_run(path, only=small)) == [m for m in everything if m[1] in small]
    # a frame is rebuilt from its image and its info channel (K/info) when its key is asked for
    frames = list(runlog.read_run(path, only={"ct/r/camera/frame"}))
    assert [k for _, k, _ in frames] == ["ct/r/camera/frame"]
    assert codec.decode(frames[0][2]).image.shape == codec.decode(
        next(p for _, k, p in everything if k == "ct/r/camera/frame")).image.shape
    assert list(runlog.read_run(path, only=[])) == []


def test_typed_messages_are_the_decoded_messages_of_those_keys_without_frames_or_raw(tmp_path):
    path = tmp_path / "run.mcap"
    _write_samples(path)
    everything = list(runlog.read_run(path))
    typed_keys = {k for _, k, p in everything if k not in ("ct/r/camera/frame", "ct/r/garbage/x")}
    got = list(runlog.RunReader(path).typed(typed_keys | {"ct/r/camera/frame", "ct/r/garbage/x"}))
    want = [(t, k, codec.decode(p)) for t, k, p in everything if k in typed_keys]
    assert [(t, k) for t, k, _ in got] == [(t, k) for t, k, _ in want] and len(got) > 3
    for (_, _, a), (_, _, b) in zip(got, want):
        assert type(a) is type(b)
        assert_same(b, a)
    assert list(runlog.RunReader(path).typed(set())) == []


def test_foreign_and_damaged_files_get_a_clear_error(tmp_path):
    from mcap.writer import Writer

    (tmp_path / "text.mcap").write_text("hello")
    with pytest.raises(runlog.RunFormatError, match="not an MCAP file"):
        runlog.RunReader(tmp_path / "text.mcap")
    # a valid MCAP that is not ours (a ROS 2 bag, say)
    with open(tmp_path / "ros.mcap", "wb") as f:
        w = Writer(f)
        w.start(profile="ros2")
        sid = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
        cid = w.register_channel("/chatter", "cdr", sid)
        w.add_message(cid, log_time=1, data=b"\0\1\0\0\3\0\0\0hi\0", publish_time=1)
        w.finish()
    with pytest.raises(runlog.RunFormatError, match="not a cinetransfer recording.*std_msgs"):
        runlog.RunReader(tmp_path / "ros.mcap")
    # a recording cut inside a record
    _write_samples(tmp_path / "ok.mcap")
    data = (tmp_path / "ok.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(runlog.RunFormatError, match="truncated"):
        runlog.RunReader(tmp_path / "cut.mcap")
    # ... which --salvage reads up to the cut
    assert runlog.RunReader(tmp_path / "cut.mcap", salvage=True).info.messages > 0


INTERRUPTED = """
import os, signal, sys, numpy as np
from cinetransfer import runlog
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M
w = runlog.RunWriter(sys.argv[1], {}, flush_s=0.0)
img = np.zeros((54, 96, 3), np.uint8)
for i in range(30):
    w.write("ct/r/vehicle/state", codec.encode(M.VehicleState(stamp_ns=i, seq=i)))
    w.write("ct/r/camera/frame", codec.encode(M.Frame(stamp_ns=i, seq=i, index=i, image=img)))
os.kill(os.getpid(), signal.SIGKILL)  # no finish(): no summary, no footer
"""


def test_an_interrupted_run_leaves_a_recording_the_reader_opens(tmp_path):
    # given a recorder killed hard in the middle of a run
    path = tmp_path / "run.mcap"
    r = subprocess.run([sys.executable, "-c", INTERRUPTED, str(path)], capture_output=True, timeout=120)
    assert r.returncode == -9, r.stderr
    # then the file opens (no summary) and holds every message up to the kill
    run = runlog.RunReader(path)
    assert run.info.complete is False
    msgs = [codec.decode(p) for _, _, p in run.messages()]
    assert [m.seq for m in msgs if isinstance(m, M.VehicleState)] == list(range(30))
    assert [m.index for m in msgs if isinstance(m, M.Frame)] == list(range(30))
    # and the mcap library's streaming reader reads the same messages before it meets the end
    from mcap.exceptions import EndOfFile
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    n = 0
    with open(path, "rb") as f, pytest.raises(EndOfFile):
        for rec in StreamReader(f).records:
            n += isinstance(rec, Message)
    assert n == 30 * 5  # state and its two transforms, frame image and info


def test_report_refuses_a_run_folder_whose_recording_is_damaged_or_foreign(tmp_path):
    # given a run folder (a style and a synthetic output) whose run.mcap is cut, or someone else's
    from cinetransfer.report import synth
    from cinetransfer.shared.instructions import save_style

    run = tmp_path / "run"
    run.mkdir()
    save_style(run / "style.json", synth.instructions(12))
    _write_samples(tmp_path / "ok.mcap")
    data = (tmp_path / "ok.mcap").read_bytes()
    for bad, why in ((data[: len(data) // 2], "truncated"), (b"\x89MCAP0\r\n" + b"\0" * 40, "MCAP")):
        (run / "run.mcap").write_bytes(bad)
        r = subprocess.run([sys.executable, "-m", "cinetransfer", "report", str(run)], capture_output=True,
                           text=True, timeout=300)
        # then the report says what is wrong with which file and exits non-zero
        assert r.returncode == 1 and "run.mcap" in r.stderr and why in r.stderr, r.stderr
    # and a sound recording is summarised in the report
    (run / "run.mcap").write_bytes(data)
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "report", str(run)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    rep = json.loads((run / "report.json").read_text())
    assert rep["recording_file"]["complete"] is True and "ct/r/camera/frame" in rep["recording_file"]["topics"]


def test_a_message_that_cannot_be_translated_is_kept_as_it_travelled(tmp_path, monkeypatch):
    # given a translation that fails for one message (a bug, say)
    def broken(*a, **k):
        raise RuntimeError("boom")

    path = tmp_path / "run.mcap"
    with runlog.RunWriter(path, {}) as w:
        w.write("ct/r/vehicle/state", codec.encode(M.VehicleState(seq=1)), t_ns=1)
        monkeypatch.setattr(runlog, "views", broken)
        w.write("ct/r/vehicle/state", codec.encode(M.VehicleState(seq=2)), t_ns=2)
        monkeypatch.undo()
        # then the recording goes on, and the message is there, raw
        assert w.errors == 1
    assert [codec.decode(p).seq for _, _, p in runlog.read_run(path)] == [1, 2]


def test_a_recorded_message_that_does_not_fit_its_schema_is_left_out_not_the_run(tmp_path):
    # given a recording in which one vehicle state was tampered with (a position of two numbers)
    from mcap.writer import Writer

    path = tmp_path / "run.mcap"
    schema = json.dumps(jsonmsg.message_schema(M.VehicleState)).encode()
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata(runlog.META_NAME, {"format": runlog.FORMAT, "version": "1", "meta": "{}"})
        sid = w.register_schema(jsonmsg.schema_name(M.VehicleState), "jsonschema", schema)
        cid = w.register_channel("ct/r/vehicle/state", "json", sid, {runlog.ROLE: "message"})
        for seq, pos in ((1, [0.0, 0.0, 1.0]), (2, [0.0, 1.0]), (3, [0.0, 0.0, 3.0])):
            obj = jsonmsg.to_json(M.VehicleState(seq=seq))
            obj["position_m"] = pos
            w.add_message(cid, log_time=seq, data=json.dumps(obj).encode(), publish_time=seq)
        w.finish()
    # then reading it gives the two good ones and counts the bad one
    run = runlog.RunReader(path)
    assert [codec.decode(p).seq for _, _, p in run.messages()] == [1, 3] and run.skipped == 1


def test_frames_encoded_once_give_the_recording_the_videos_very_pictures(tmp_path):
    # given frames written to an mp4 whose writer hands back each frame's H.264 (the recorder's one
    # encode for output.mp4 and run.mcap), and those packets given to the recording
    import av
    import numpy as np

    from cinetransfer.shared.video import H264Writer

    fps, n = 24.0, 30
    yy, xx = np.mgrid[0:48, 0:64]
    # a pattern drifting a pixel a frame (no scene cut for x264 to put a keyframe at)
    imgs = [np.dstack([128 + 100 * np.sin((xx + k) / 6.0), 128 + 100 * np.cos((yy + k) / 5.0),
                       128 + 60 * np.sin((xx + yy) / 9.0)]).astype(np.uint8) for k in range(n)]
    video = H264Writer(tmp_path / "out.mp4", fps, stream_keyframe_s=runlog.KEYFRAME_S)
    packets = []
    with runlog.RunWriter(tmp_path / "run.mcap", {"description": "one encode"}) as w:
        for k, img in enumerate(imgs):
            packets.append(video.write(img))
            w.write("ct/r/camera/frame", codec.encode(M.Frame(stamp_ns=k * 41_666_667, index=k, fps=fps, image=img)),
                    video_packet=packets[-1])
    video.close()
    # then every frame came out with its own packet, a keyframe with SPS/PPS in front every second
    assert all(packets)
    sps = [p.startswith((b"\x00\x00\x00\x01\x67", b"\x00\x00\x01\x67")) for p in packets]
    assert [k for k, s in enumerate(sps) if s] == [0, 24]
    # and the recording's pictures, decoded as replay decodes them, are the mp4's pixel for pixel
    with av.open(str(tmp_path / "out.mp4")) as c:
        mp4 = [f.to_ndarray(format="bgr24") for f in c.decode(video=0)]
    recorded = [codec.decode(p).image for _, key, p in runlog.RunReader(tmp_path / "run.mcap").messages()
                if key == "ct/r/camera/frame"]
    assert len(mp4) == len(recorded) == n
    assert all(np.array_equal(a, b) for a, b in zip(mp4, recorded))
