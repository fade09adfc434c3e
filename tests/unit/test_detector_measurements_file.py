"""The measurements file: round trip, truncation, corruption, versioning."""
from __future__ import annotations

import dataclasses
import struct

import msgpack
import numpy as np
import pytest

from cinetransfer.shared import measurements_file as mf
from cinetransfer.shared.messages import LensState, Measurement, PersonDetection, Skeleton, SourceInfo


def _measurement(i: int) -> Measurement:
    mask = np.zeros((40, 20), bool)
    mask[5:35, 3:17] = True
    p = PersonDetection(box_xyxy=np.array([10, 20, 30, 60], np.float32), confidence=0.8,
                        mask_origin_xy=np.array([10, 20], np.int32), mask=mask)
    kp = np.full((17, 2), np.nan, np.float32)
    kp[0] = (15.0, 25.0)
    s = Skeleton(keypoints_px=kp, confidences=np.linspace(0, 1, 17, dtype=np.float32), person_index=0)
    return Measurement(stamp_ns=i * 41_666_667, frame_index=i, fps=24.0, width=64, height=48, people=[p],
                       skeletons=[s], focus_map=np.full((12, 16), i, np.uint8), source="clip.mp4",
                       lens=LensState(focal_length_mm=35.0), detector="mediapipe")


def test_round_trip_keeps_every_field(tmp_path):
    # given three measurements and a source
    ms = [_measurement(i) for i in range(3)] + [Measurement(frame_index=3, width=64, height=48)]
    src = SourceInfo(path="clip.mp4", width=64, height=48, fps=24.0, n_frames=4, sha256="ab")
    # when written and read back
    n = mf.write_measurements(tmp_path / "m.msgpack", ms, source=src, detector="mediapipe",
                              config={"num_poses": 6}, focus_map_scale=0.25)
    got = mf.read_measurements(tmp_path / "m.msgpack")
    # then everything survives
    assert n == 4 and len(got) == 4 and not got.truncated
    assert dataclasses.asdict(got.header.source) == dataclasses.asdict(src) and got.source.fps == 24.0
    assert got.header.detector == "mediapipe" and got.header.config == {"num_poses": 6}
    assert got.header.focus_map_scale == 0.25
    for a, b in zip(ms, got):
        assert b.frame_index == a.frame_index and b.stamp_ns == a.stamp_ns
        assert len(b.people) == len(a.people)
    assert np.array_equal(got[1].people[0].mask, ms[1].people[0].mask)
    assert np.array_equal(got[2].focus_map, ms[2].focus_map)
    assert np.isnan(got[0].skeletons[0].keypoints_px[1]).all()
    assert got[0].lens.focal_length_mm == 35.0
    assert got[3].people == [] and got[3].focus_map is None
    assert [m.frame_index for m in mf.iter_measurements(tmp_path / "m.msgpack")] == [0, 1, 2, 3]
    assert mf.read_header(tmp_path / "m.msgpack").source.sha256 == "ab"


@pytest.mark.parametrize("cut", [1, 7, 100])
def test_truncated_file_keeps_complete_records(tmp_path, cut):
    p = tmp_path / "m.msgpack"
    mf.write_measurements(p, [_measurement(i) for i in range(3)])
    data = p.read_bytes()
    p.write_bytes(data[:-cut])
    got = mf.read_measurements(p)
    assert got.truncated and [m.frame_index for m in got] == [0, 1]
    with pytest.raises(mf.MeasurementsFileError, match="ends inside"):
        mf.read_measurements(p, strict=True)


def test_streaming_writer_in_place_file_is_readable_before_close(tmp_path):
    p = tmp_path / "m.msgpack"
    w = mf.MeasurementsWriter(p, source=SourceInfo(path="x"), atomic=False)
    w.write(_measurement(0))
    w._f.flush()
    assert len(mf.read_measurements(p)) == 1
    w.close()
    with pytest.raises(ValueError):
        w.write(_measurement(1))


def test_given_the_default_writer_when_writing_then_path_appears_only_complete_on_close(tmp_path):
    """Temp-then-rename (STYLE §11): while writing, `path` holds the previous file (here none);
    on close the complete file is renamed into place and no temporary file is left."""
    p = tmp_path / "m.msgpack"
    p.write_bytes(b"previous run")
    w = mf.MeasurementsWriter(p, source=SourceInfo(path="x"))
    w.write(_measurement(0))
    w._f.flush()
    assert p.read_bytes() == b"previous run"
    w.close()
    assert len(mf.read_measurements(p, strict=True)) == 1
    assert sorted(x.name for x in tmp_path.iterdir()) == ["m.msgpack"]


@pytest.mark.parametrize("content,match", [
    (b"", "bad magic"),
    (b"hello world, not a file", "bad magic"),
    (mf.MAGIC, "no header"),
    (mf.MAGIC + struct.pack("<I", 3) + b"\xc1\xc1\xc1", "corrupt header"),
    (mf.MAGIC + struct.pack("<I", 0xFFFFFFF0), "implausible"),
])
def test_not_a_measurements_file(tmp_path, content, match):
    p = tmp_path / "bad.msgpack"
    p.write_bytes(content)
    with pytest.raises(mf.MeasurementsFileError, match=match):
        mf.read_measurements(p)


def test_unsupported_version_and_corrupt_record(tmp_path):
    p = tmp_path / "v.msgpack"
    head = msgpack.packb({"format": mf.FORMAT_NAME, "version": 99, "source": {}}, use_bin_type=True)
    p.write_bytes(mf.MAGIC + struct.pack("<I", len(head)) + head)
    with pytest.raises(mf.MeasurementsFileError, match="version 99"):
        mf.read_measurements(p)
    q = tmp_path / "c.msgpack"
    mf.write_measurements(q, [_measurement(0)])
    data = bytearray(q.read_bytes())
    hdr_len = struct.unpack_from("<I", data, len(mf.MAGIC))[0]
    rec = len(mf.MAGIC) + 4 + hdr_len + 4
    data[rec:rec + 3] = b"XXX"  # codec magic of record 1
    q.write_bytes(bytes(data))
    with pytest.raises(mf.MeasurementsFileError, match="record 1 is corrupt"):
        mf.read_measurements(q)


def test_missing_file(tmp_path):
    with pytest.raises(mf.MeasurementsFileError, match="no such"):
        mf.read_measurements(tmp_path / "nope.msgpack")
