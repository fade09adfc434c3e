"""`cinetransfer monitor --foxglove`: a real WebSocket client (the Foxglove WebSocket protocol)
connects, sees the rig's channels advertised and receives their messages, images and transforms
included, while real messages cross a real Zenoh session."""
import base64
import json
import struct
import threading
import time

import numpy as np

from cinetransfer import runlog
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M
from cinetransfer.shared.zenoh_config import open_session
from conftest import connect_flags, free_port, spawn, stop, wait_for

WANT = ("ct/live/vehicle/state", "ct/live/camera/frame", "ct/live/tf/camera", "ct/live/camera/frame/calibration")


def _publish_until(session, done: threading.Event) -> None:
    state = session.declare_publisher("ct/live/vehicle/state")
    frame = session.declare_publisher("ct/live/camera/frame")
    img = np.zeros((54, 96, 3), np.uint8)
    img[:, 40:60] = (0, 0, 255)
    lens = M.LensState(focal_length_mm=35.0, sensor_width_mm=23.76, sensor_height_mm=13.365)
    i = 0
    while not done.wait(0.05):
        state.put(codec.encode(M.VehicleState(stamp_ns=i, seq=i, position_m=np.array([1.0, 2.0, 3.0]), backend="sim")))
        frame.put(codec.encode(M.Frame(stamp_ns=i, seq=i, index=i, image=img, lens=lens)))
        i += 1
    state.undeclare()
    frame.undeclare()


def _connect(url: str):
    from websockets.sync.client import connect

    def attempt():
        try:
            return connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=5, max_size=None)
        except OSError:
            return None
    return wait_for(attempt, timeout=60, interval=0.2, what=f"the Foxglove server at {url}")


def test_monitor_serves_the_rig_to_a_foxglove_websocket_client(port, listener_opts, tmp_path):
    ws_port = free_port()
    done = threading.Event()
    with open_session(listener_opts) as s:
        pub = threading.Thread(target=_publish_until, args=(s, done), daemon=True)
        pub.start()
        proc = spawn("monitor", "ct/live/**", "--foxglove", "--port", str(ws_port), *connect_flags(port),
                     log=tmp_path / "monitor.log")
        try:
            ws = _connect(f"ws://127.0.0.1:{ws_port}")
            channels: dict[str, dict] = {}
            with ws:
                # the server advertises a channel per topic, with its schema
                deadline = time.monotonic() + 60
                while not set(WANT) <= set(channels):
                    assert time.monotonic() < deadline, f"not advertised: {set(WANT) - set(channels)}"
                    msg = ws.recv(timeout=30)
                    if isinstance(msg, str):
                        op = json.loads(msg)
                        if op.get("op") == "advertise":
                            channels.update({c["topic"]: c for c in op["channels"]})
                subs: dict[int, str] = {}

                def subscribe(topics) -> None:
                    new = {len(subs) + 1 + n: t for n, t in enumerate(topics)}
                    subs.update(new)
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": i, "channelId": channels[t]["id"]} for i, t in new.items()]}))

                subscribe(WANT)
                got: dict[str, bytes] = {}
                deadline, retry = time.monotonic() + 60, time.monotonic() + 5
                while len(got) < len(WANT):
                    assert time.monotonic() < deadline, f"nothing on {set(WANT) - set(got)}; {channels}"
                    if time.monotonic() > retry:
                        # foxglove-sdk 0.30.3 advertises a new channel to connected clients a moment before
                        # it accepts subscriptions to it (it answers status "Unknown channel ID: N"; seen
                        # in about 1 run in 6 when the client connects while channels are being created):
                        # like a viewer, subscribe again
                        subscribe([t for t in WANT if t not in got])
                        retry = time.monotonic() + 5
                    msg = ws.recv(timeout=30)
                    if isinstance(msg, bytes) and msg[0] == 0x01:  # MessageData
                        sub_id, = struct.unpack_from("<I", msg, 1)
                        got.setdefault(subs[sub_id], msg[1 + 4 + 8:])
        finally:
            done.set()
            pub.join()
            rc = stop(proc)
    assert rc == 0, (tmp_path / "monitor.log").read_text()[-3000:]
    # then the vehicle state is our JSON form, with the schema generated from shared/messages.py
    st = channels["ct/live/vehicle/state"]
    assert st["encoding"] == "json" and st["schemaName"] == "cinetransfer.VehicleState"
    assert json.loads(st["schema"])["properties"]["position_m"]["items"]["type"] == "number"
    assert json.loads(got["ct/live/vehicle/state"])["position_m"] == [1.0, 2.0, 3.0]
    # and the frame is a foxglove.CompressedImage (JPEG), the pose a FrameTransform, the lens a calibration
    for topic, name in (("ct/live/camera/frame", "foxglove.CompressedImage"),
                        ("ct/live/tf/camera", "foxglove.FrameTransform"),
                        ("ct/live/camera/frame/calibration", "foxglove.CameraCalibration")):
        ch = channels[topic]
        assert ch["encoding"] == "protobuf" and ch["schemaName"] == name, ch
    image_cls = runlog._protobuf_class(type("S", (), {"name": "foxglove.CompressedImage", "data": base64.b64decode(
        channels["ct/live/camera/frame"]["schema"])}))
    img = image_cls.FromString(got["ct/live/camera/frame"])
    assert img.format == "jpeg" and img.data[:2] == b"\xff\xd8"
