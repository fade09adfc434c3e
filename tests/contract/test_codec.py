"""Every message round-trips through the codec; the decoder survives garbage."""
import dataclasses

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cinetransfer.shared import codec
from cinetransfer.shared import messages as M


def sample_messages():
    rng = np.random.default_rng(0)
    lens = M.LensState(focal_length_mm=35.0, focus_distance_m=5.0, f_number=2.8,
                       sensor_width_mm=23.76, sensor_height_mm=13.365, coc_mm=0.05)
    person = M.PersonDetection(box_xyxy=np.array([10, 20, 110, 220], np.float32), confidence=0.93,
                               mask_origin_xy=np.array([10, 20], np.int32), mask=rng.random((200, 100)) > 0.5)
    kp = rng.random((17, 2)).astype(np.float32) * 100
    kp[3] = np.nan
    yield M.Frame(stamp_ns=123, seq=4, source="x.mp4", index=7, fps=24.0,
                  image=rng.integers(0, 255, (36, 64, 3), dtype=np.uint8), lens=lens)
    yield M.Measurement(stamp_ns=1, frame_index=3, fps=24.0, width=64, height=36, people=[person],
                        skeletons=[M.Skeleton(keypoints_px=kp, confidences=np.ones(17, np.float32), person_index=0)],
                        focus_map=rng.integers(0, 255, (9, 16), dtype=np.uint8), lens=lens, detector="mediapipe")
    k = 5
    tg = rng.random((k, 4, 2)).astype(np.float32)
    tg[2, 1] = np.nan
    yield M.Instructions(source=M.SourceInfo(path="a.mp4", width=640, height=360, fps=24.0, n_frames=k),
                         fps=24.0, frame_duration_s=1 / 24,
                         joint_names=list(M.COCO17_NAMES[5:7] + M.COCO17_NAMES[11:13]),
                         image_targets=tg, subject_visible=np.ones(k, bool),
                         subject_box=rng.random((k, 4)).astype(np.float32),
                         focus_raw=rng.random((k, 3)).astype(np.float32),
                         focus_smoothed=rng.random((k, 3)).astype(np.float32),
                         focus_in=rng.random((k, 3)) > 0.5, theta=0.5, mu_m=1.0,
                         camera_motion_class=["static"] * (k - 1) + ["pan+dolly_in"],
                         pan_rate_dps=rng.random(k).astype(np.float32), tilt_rate_dps=np.full(k, np.nan, np.float32),
                         roll_rate_dps=np.zeros(k, np.float32), zoom_rate=rng.random(k).astype(np.float32),
                         translation_dir=rng.random((k, 3)).astype(np.float32))
    yield M.Setpoint(position_m=np.array([1.0, 2.0, 3.0]), camera_ypr_rad=np.array([0.1, -0.2, 0.0]), lens=lens,
                     horizon_t_s=np.arange(3) * 0.1, horizon_position_m=rng.random((3, 3)),
                     horizon_camera_ypr_rad=rng.random((3, 3)), horizon_lens=rng.random((3, 3)), solver_status="ok")
    yield M.VehicleState(position_m=np.ones(3), lens=lens, mode="sim", armed=True, backend="sim")
    yield M.SubjectState(subject_id="p", joints_m=rng.random((17, 3)), velocity_mps=np.array([1.0, 0, 0]))
    yield M.Command(action="start", args={"t0": 1.5, "name": "take1", "flag": True})
    yield M.Health(node="planner", received=3, counters={"solver": "ok", "solve_ms": 4.2})
    yield M.GroundTruth(frame_index=2, joints_norm=rng.random((17, 2)).astype(np.float32),
                        joints_visible=np.ones(17, bool), subject_distance_m=5.0, dof_near_m=4.0,
                        region_present=np.array([True, True, False]), region_in_focus=np.array([False, True, False]),
                        region_focus_fraction=np.array([0.1, 0.9, np.nan], np.float32))
    yield M.StreamEnd(source=M.SourceInfo(path="a.mp4", width=640, height=360, fps=24.0, n_frames=5), frames=5,
                      reason="end of file")
    yield M.SimClock(stamp_ns=5_000_000_050, epoch_ns=5_000_000_000, step=1, period_s=0.05, lockstep=True, pace=0.0)


def assert_same(a, b, ignore=()):
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        if f.name in ignore:
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), f.name
        elif dataclasses.is_dataclass(x):
            assert_same(x, y)
        elif isinstance(x, list) and x and dataclasses.is_dataclass(x[0]):
            for u, v in zip(x, y, strict=True):
                assert_same(u, v)
        elif isinstance(x, float) and np.isnan(x):
            assert np.isnan(y)
        else:
            assert x == y, f.name


def test_sample_covers_every_type():
    assert {type(m).__name__ for m in sample_messages()} == set(M.MESSAGE_TYPES)


@pytest.mark.parametrize("msg", list(sample_messages()), ids=lambda m: type(m).__name__)
def test_round_trip(msg):
    assert_same(msg, codec.decode(codec.encode(msg)))


@pytest.mark.parametrize("cls", list(M.MESSAGE_TYPES.values()), ids=lambda c: c.__name__)
def test_default_instances_round_trip(cls):
    assert_same(cls(), codec.decode(codec.encode(cls())))


def test_raw_frame_decodes_zero_copy():
    img = np.arange(720 * 1280 * 3, dtype=np.uint32).astype(np.uint8).reshape(720, 1280, 3)
    payload = codec.encode(M.Frame(image=img))
    out = codec.decode(payload)
    assert np.shares_memory(out.image, np.frombuffer(payload, np.uint8))
    assert not out.image.flags.writeable
    assert np.array_equal(out.image, img)


def test_jpeg_frame_is_smaller_and_close():
    y, x = np.mgrid[0:360, 0:640]
    img = np.stack([x % 256, y % 256, (x + y) % 256], -1).astype(np.uint8)
    raw, jpg = codec.encode(M.Frame(image=img)), codec.encode(M.Frame(image=img), jpeg_quality=90)
    assert len(jpg) < len(raw) / 3
    out = codec.decode(jpg).image
    assert out.shape == img.shape and np.abs(out.astype(int) - img).mean() < 4


def test_wrong_schema_version_is_refused_with_both_versions():
    payload = codec.encode(M.Health(node="x"))
    start, header, _ = codec._split(payload)
    header["v"] = 99
    h = msgpack.packb(header, use_bin_type=True)
    bad = codec._PREFIX.pack(codec.MAGIC, codec.FORMAT, len(h)) + h
    with pytest.raises(codec.DecodeError, match="version 99 is not supported.*reads version 1"):
        codec.decode(bad)


@pytest.mark.parametrize("mutate,match", [
    (lambda d: d.pop("node"), "missing field"),
    (lambda d: d.__setitem__("received", "three"), "expected int"),
    (lambda d: d.__setitem__("uptime_s", float("inf")), "non-finite"),
    (lambda d: d.__setitem__("uptime_s", float("nan")), "non-finite"),
])
def test_field_validation(mutate, match):
    payload = codec.encode(M.Health(node="x"))
    _, header, _ = codec._split(payload)
    mutate(header["d"])
    h = msgpack.packb(header, use_bin_type=True)
    with pytest.raises(codec.DecodeError, match=match):
        codec.decode(codec._PREFIX.pack(codec.MAGIC, codec.FORMAT, len(h)) + h)


def test_encode_rejects_what_decode_would_reject():
    with pytest.raises(codec.EncodeError, match="NaN"):
        codec.encode(M.Setpoint(position_m=np.array([0.0, np.nan, 1.0])))
    with pytest.raises(codec.EncodeError, match="shape"):
        codec.encode(M.Setpoint(position_m=np.zeros(4)))
    with pytest.raises(codec.EncodeError, match="not a top-level"):
        codec.encode(M.LensState())


def test_unknown_type_and_expected_type():
    payload = codec.encode(M.Command(action="start"))
    with pytest.raises(codec.DecodeError, match="expected a Setpoint"):
        codec.decode(payload, M.Setpoint)
    _, header, _ = codec._split(payload)
    header["t"] = "Nope"
    h = msgpack.packb(header, use_bin_type=True)
    with pytest.raises(codec.DecodeError, match="unknown message type"):
        codec.decode(codec._PREFIX.pack(codec.MAGIC, codec.FORMAT, len(h)) + h)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=512))
def test_garbage_raises_only_decode_error(data):
    with pytest.raises(codec.DecodeError):
        codec.decode(data)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_corrupted_valid_payloads_never_crash(data):
    msgs = list(sample_messages())
    payload = bytearray(codec.encode(msgs[data.draw(st.integers(0, len(msgs) - 1))]))
    for _ in range(data.draw(st.integers(1, 8))):
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(payload)))
    try:
        codec.decode(bytes(payload[:cut]))
    except codec.DecodeError:
        pass


def test_summaries_are_one_line():
    for msg in sample_messages():
        s = codec.summary(msg)
        assert s and "\n" not in s


def test_older_schema_version_decodes_with_defaults_for_later_fields():
    # given a Measurement payload of version 1 (before shot_change existed)
    payload = codec.encode(M.Measurement(frame_index=4, shot_change=0.7))
    _, header, blob = codec._split(payload)
    header["v"] = 1
    del header["d"]["shot_change"]
    h = msgpack.packb(header, use_bin_type=True)
    head = codec._PREFIX.pack(codec.MAGIC, codec.FORMAT, len(h)) + h
    old = head + b"\0" * ((-len(head)) % codec._ALIGN) + bytes(blob)
    # then it decodes, the new field taking its default
    m = codec.decode(old)
    assert m.frame_index == 4 and np.isnan(m.shot_change)
    # but a version-2 payload without the field is malformed
    header["v"] = 2
    h = msgpack.packb(header, use_bin_type=True)
    head = codec._PREFIX.pack(codec.MAGIC, codec.FORMAT, len(h)) + h
    with pytest.raises(codec.DecodeError, match="shot_change: missing field"):
        codec.decode(head + b"\0" * ((-len(head)) % codec._ALIGN) + bytes(blob))
    # and versions outside the readable range are refused, naming the range
    header["v"] = M.Measurement.SCHEMA_VERSION + 1
    h = msgpack.packb(header, use_bin_type=True)
    with pytest.raises(codec.DecodeError, match=f"reads versions 1 to {M.Measurement.SCHEMA_VERSION}"):
        codec.decode(codec._PREFIX.pack(codec.MAGIC, codec.FORMAT, len(h)) + h)
