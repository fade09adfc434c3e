"""Decoding is total: whatever bytes arrive, `codec.decode` returns a message
or raises DecodeError — never RecursionError, MemoryError, TypeError... — and every node's
handler takes whatever decodes without raising. Fuzzed with hypothesis over deep, huge and odd
msgpack, bounded in run time (fixed example counts, derandomised, no deadline)."""
from __future__ import annotations

import sys
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from attacks import deep_args_command, with_header
from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.services.autopilot_bridge.core import BridgeCore
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M

FUZZ = settings(max_examples=300, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
HANDLER_FUZZ = settings(FUZZ, max_examples=120)
T0 = 1_700_000_000_000_000_000


# ----------------------------------------------------------------------------- strategies
def _nest(depth: int, leaf: object = 1) -> object:
    for _ in range(depth):
        leaf = [leaf]
    return leaf


scalars = st.one_of(st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), st.floats(),
                    st.text(max_size=20), st.binary(max_size=20))
odd_values = st.one_of(
    st.recursive(scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=5), c, max_size=4),
                 max_leaves=30),
    st.integers(0, 900).map(_nest),  # deep: past the codec's depth limit and past the stack
    st.integers(0, 200_000).map(lambda n: [0] * n),  # huge lists
    st.integers(0, 300_000).map(lambda n: "x" * n),  # huge strings
    st.just({"__nd__": "raw", "dt": "<f8", "sh": [2**40, 2**40], "o": 0, "n": 0}),  # huge array claim
    st.just({"__nd__": "jpeg", "dt": "uint8", "sh": [1, 1, 3], "o": 0, "n": 4}),  # corrupt JPEG
    st.just({"__nd__": "raw", "dt": "O", "sh": [1], "o": 0, "n": 8}),  # object dtype
    st.just({"__nd__": "bits", "dt": "bool", "sh": list(range(40)), "o": 0, "n": 1}),  # many dimensions
)


command_args = st.dictionaries(
    st.sampled_from(["altitude_m", "start_frame", "x", ""]),
    st.one_of(scalars, st.lists(scalars, max_size=3), st.integers(0, 40).map(_nest)), max_size=3)


def _same_type_extremes(v):
    """Values of `v`'s type that stay legal for the codec but are extreme for a handler (None if
    `v` is not a scalar)."""
    if isinstance(v, bool):
        return st.booleans()
    if isinstance(v, int):
        return st.sampled_from([0, -1, 1, 2**63 - 1, -(2**63), 10**12]) | st.integers(-(2**63), 2**63 - 1)
    if isinstance(v, float):
        return (st.sampled_from([0.0, -0.0, 1e308, -1e308, 1e-308, 5e-324, float("nan")])
                | st.floats(allow_infinity=False))
    if isinstance(v, str):
        return (st.sampled_from(["", "track", "hold", "start", "takeoff", "x" * 2000, "\x00", "é" * 50])
                | st.text(max_size=30))
    return None


def _get(obj, path):
    for k in path:
        obj = obj[k]
    return obj


def _lens() -> M.LensState:
    return M.LensState(focal_length_mm=35.0, focus_distance_m=5.0, f_number=4.0)


def base_messages() -> dict[str, object]:
    """One valid message of every type a node's handler takes."""
    from cinetransfer.services.planner.core import instructions_from_arrays

    rng = np.random.default_rng(0)
    return {
        "Command": M.Command(stamp_ns=T0, action="takeoff", args={"altitude_m": 5.0}),
        "Setpoint": M.Setpoint(stamp_ns=T0, position_m=np.array([1.0, 2.0, 5.0]), lens=_lens()),
        "VehicleState": M.VehicleState(stamp_ns=T0, position_m=np.array([0.0, 0.0, 5.0]), lens=_lens()),
        "Measurement": M.Measurement(stamp_ns=T0, frame_index=3, fps=24.0, width=64, height=48, people=[
            M.PersonDetection(confidence=0.9, box_xyxy=np.array([10.0, 5.0, 30.0, 40.0], np.float32),
                              mask_origin_xy=np.array([10, 5], np.int32), mask=np.ones((35, 20), bool))],
            skeletons=[M.Skeleton(keypoints_px=rng.uniform(5, 40, (17, 2)).astype(np.float32),
                                  confidences=np.full(17, 0.9, np.float32), person_index=0)]),
        "Frame": M.Frame(stamp_ns=T0, index=0, fps=24.0, image=rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)),
        "Instructions": instructions_from_arrays(targets=np.full((5, 2, 2), 0.5), joint_names=["nose", "left_hip"]),
    }


BASE = {name: codec.encode(msg) for name, msg in base_messages().items()}


def _paths(obj, prefix=()):
    """Every path into a nested msgpack body (maps and lists)."""
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj[:3]):
            yield from _paths(v, prefix + (i,))


def _replace(obj, path, value):
    if not path:
        return value
    head, rest = path[0], path[1:]
    if isinstance(obj, dict):
        return {**obj, head: _replace(obj[head], rest, value)}
    out = list(obj)
    out[head] = _replace(out[head], rest, value)
    return out


@st.composite
def mutated(draw, names=tuple(BASE)) -> bytes:
    """A valid payload of one type with one value somewhere in its header replaced by an odd one
    (or the header's type/version/body itself), or plain garbage bytes."""
    kind = draw(st.sampled_from(["mutate", "mutate", "extreme", "extreme", "extreme", "garbage", "truncate"]))
    name = draw(st.sampled_from(names))
    payload = BASE[name]
    if kind == "garbage":
        return draw(st.binary(max_size=600))
    if kind == "truncate":
        return payload[:draw(st.integers(0, len(payload)))]
    if kind == "extreme":  # type-preserving: decodes, and tests the handler instead of the codec
        def mutate(header):
            for _ in range(draw(st.integers(1, 3))):
                leaves = [p for p in _paths(header) if len(p) >= 2 and _same_type_extremes(_get(header, p)) is not None]
                path = draw(st.sampled_from(leaves))
                header = _replace(header, path, draw(_same_type_extremes(_get(header, path))))
            if header["t"] == "Command" and draw(st.booleans()):
                header = _replace(header, ("d", "args"), draw(command_args))
            return header

        return with_header(payload, mutate)
    value = draw(odd_values)

    def mutate(header):
        paths = list(_paths(header))
        return _replace(header, draw(st.sampled_from(paths)), value)

    return with_header(payload, mutate)


@st.composite
def odd_frames(draw) -> bytes:
    """Valid Frames of odd sizes (1x1 up to a thin strip) and contents (flat, noise)."""
    h, w = draw(st.integers(1, 64)), draw(st.integers(1, 700))
    fill = draw(st.sampled_from(["zeros", "full", "noise"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    img = {"zeros": np.zeros((h, w, 3), np.uint8), "full": np.full((h, w, 3), 255, np.uint8),
           "noise": rng.integers(0, 256, (h, w, 3), dtype=np.uint8)}[fill]
    return codec.encode(M.Frame(stamp_ns=T0, index=draw(st.integers(0, 2**40)), image=img,
                                fps=draw(st.sampled_from([float("nan"), 0.0, 24.0, 1e9]))))


def decode_or_none(payload: bytes, tp: type | None = None):
    try:
        return codec.decode(payload, tp)
    except codec.DecodeError:
        return None


# ----------------------------------------------------------------------------- the codec
def test_the_576_byte_deep_args_command_is_a_decode_error_not_a_recursion_error():
    payload = deep_args_command()
    assert len(payload) == 576
    with pytest.raises(codec.DecodeError, match="deeper than"):
        codec.decode(payload)
    # still a DecodeError with a stack already nearly full (a service decodes deep inside its loop)
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(150)
    try:
        with pytest.raises(codec.DecodeError):
            codec.decode(payload)
    finally:
        sys.setrecursionlimit(limit)


@pytest.mark.parametrize("value, match", [
    (_nest(codec.MAX_DEPTH + 5), "deeper than"),
    ([0] * (codec.MAX_ELEMENTS + 1), "more than"),
    ({"__nd__": "raw", "dt": "<f8", "sh": [2**31, 2**31], "o": 0, "n": 0}, "exceeds the limit"),
    ({"__nd__": "raw", "dt": "<f8", "sh": [1] * 40, "o": 0, "n": 8}, "dimensions"),
])
def test_limits_name_what_was_exceeded(value, match):
    key = "args" if not isinstance(value, dict) else None

    def mutate(h):
        d = dict(h["d"])
        if key:
            d["args"] = {"x": value}
        return {**h, "t": "Command" if key else "Frame", "d": d if key else {**d, "image": value}}

    base = BASE["Command"] if key else BASE["Frame"]
    with pytest.raises(codec.DecodeError, match=match):
        codec.decode(with_header(base, mutate))


def test_a_header_length_past_the_limit_is_refused_before_reading_it():
    payload = b"CTM\x01" + (codec.MAX_HEADER_BYTES + 1).to_bytes(4, "little") + b"\x80"
    with pytest.raises(codec.DecodeError, match="exceeds the limit"):
        codec.decode(payload)


def test_real_messages_stay_well_inside_the_limits():
    for name, payload in BASE.items():
        assert type(codec.decode(payload)).__name__ == name


@FUZZ
@given(payload=mutated())
def test_decode_returns_a_message_or_raises_decode_error(payload):
    try:
        msg = codec.decode(payload)
    except codec.DecodeError:
        return
    assert type(msg).__name__ in M.MESSAGE_TYPES


@FUZZ
@given(payload=mutated())
def test_decode_is_bounded_in_time(payload):
    """No payload of this size makes the decoder work for long (a bomb would show as seconds);
    generous bound, measured with process time so machine load does not count."""
    t = time.process_time()
    decode_or_none(payload)
    assert time.process_time() - t < 2.0


# ----------------------------------------------------------------------------- every node's handler
def test_bridge_core_handles_whatever_decodes():
    """Commands and setpoints that decode, however odd, go through the bridge core (argument
    checks, safety layer, tick) without raising."""
    core = BridgeCore(SafetyConfig())
    vehicle = base_messages()["VehicleState"]

    @HANDLER_FUZZ
    @given(payload=mutated(("Command", "Setpoint", "VehicleState")))
    def run(payload):
        msg = decode_or_none(payload)
        if isinstance(msg, M.Command):
            args, _ = core.command_args(msg)
            if args is not None:
                core.on_command(msg)
        elif isinstance(msg, M.Setpoint):
            core.on_setpoint(msg, 0.0, clock_ns=T0, vehicle=vehicle)
        veh = msg if isinstance(msg, M.VehicleState) else vehicle
        core.tick(0.02, vehicle=veh)

    run()


def test_planner_command_handles_whatever_decodes(tmp_path):
    from cinetransfer.services.planner import config as pc
    from cinetransfer.services.planner.core import Planner
    from cinetransfer.services.planner.solver import MpcSolver

    cfg = pc.PlannerConfig(max_solve_time_s=0.5)
    planner = Planner(cfg, solver=MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=0.5))

    @HANDLER_FUZZ
    @given(payload=mutated(("Command", "Instructions")))
    def run(payload):
        msg = decode_or_none(payload)
        if isinstance(msg, M.Command):
            assert planner.command(msg, T0) in (True, False)
        elif isinstance(msg, M.Instructions):
            assert isinstance(planner.refuse_instructions(msg), str)

    run()


def test_smoother_handles_whatever_decodes():
    from cinetransfer.services.smoother.config import SmootherConfig
    from cinetransfer.services.smoother.core import SmootherInputError
    from cinetransfer.services.smoother.stream import StreamState

    state = StreamState(SmootherConfig())

    @HANDLER_FUZZ
    @given(payload=mutated(("Measurement",)))
    def run(payload):
        msg = decode_or_none(payload, M.Measurement)
        if msg is None:
            return
        state.add(msg)
        try:
            state.window()
        except SmootherInputError:
            pass  # a documented refusal, counted by the service
        if len(state) > 20:
            state.reset()

    run()


@pytest.mark.slow
def test_detector_handles_whatever_decodes():
    """Frames that decode (any size down to 1x1) go through the real detector's `_process`
    (mediapipe): it measures or counts an error, and never raises."""
    from cinetransfer.services.detector.config import DetectorConfig
    from cinetransfer.services.detector.core import Detector
    from cinetransfer.services.detector.service import _process, _Stats

    class Sink:  # stands in for the node and the publisher: collects what _process reports
        def __init__(self):
            self.counters, self.errors, self.out = {}, [], []

        def error(self, msg, kind="error"):
            self.errors.append(msg)

        def record_latency_ms(self, ms):
            pass

        def put(self, m):
            self.out.append(m)

    sink, stats = Sink(), _Stats()
    with Detector(DetectorConfig(running_mode="image")) as det:
        @settings(HANDLER_FUZZ, max_examples=40)
        @given(payload=mutated(("Frame",)) | odd_frames())
        def run(payload):
            frame = decode_or_none(payload, M.Frame)
            if frame is not None:
                _process(sink, det, sink, stats, frame)

        run()
    assert stats.processed > 10  # the fuzz reached the detector, not only the codec


def test_a_jpeg_is_sized_from_its_header_before_it_is_decoded():
    import time

    import cv2

    from cinetransfer.shared import codec

    ok, buf = cv2.imencode(".jpg", np.full((10, 20, 3), 128, np.uint8))
    small = buf.tobytes()
    assert codec.jpeg_size(small) == (10, 20)
    assert codec._jpeg_array(memoryview(small), "uint8", [10, 20, 3], 600, "f").shape == (10, 20, 3)
    # a small file whose frame header declares 30000 x 30000 (what cost the detector 28 s and 5.4 GB)
    sof = next(i for i in range(2, len(small) - 1) if small[i] == 0xFF and small[i + 1] == 0xC0)
    bomb = small[:sof + 5] + (30000).to_bytes(2, "big") * 2 + small[sof + 9:]
    assert codec.jpeg_size(bomb) == (30000, 30000)
    t = time.thread_time()  # CPU, not wall: a loaded machine must not fail it
    with pytest.raises(codec.DecodeError, match="exceeds the limit of 40000000 pixels"):
        codec._jpeg_array(memoryview(bomb), "uint8", [30000, 30000, 3], 30000 * 30000 * 3, "f")
    with pytest.raises(codec.DecodeError, match="does not match the declared shape"):
        codec._jpeg_array(memoryview(bomb), "uint8", [10, 20, 3], 600, "f")  # the header lies about it
    assert time.thread_time() - t < 0.5  # nothing was decoded
    assert codec.jpeg_size(b"not a jpeg") is None
