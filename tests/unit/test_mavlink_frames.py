"""ENU <-> NED conversions, yaw and quaternions, PX4/ArduPilot mode encoding, and the MAVLink
messages the backend sends, decoded from their real bytes."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cinetransfer.services.autopilot_bridge import enu_ned as F
from cinetransfer.services.autopilot_bridge.mavlink import TYPEMASK_POS_VEL_YAW, mavlink
from cinetransfer.shared.camera import rotation_ypr


def test_position_swap_and_sign():
    np.testing.assert_array_equal(F.enu_to_ned([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])  # east 1, north 2, up 3
    np.testing.assert_array_equal(F.ned_to_enu([2.0, 1.0, -3.0]), [1.0, 2.0, 3.0])


@pytest.mark.parametrize("yaw_enu,yaw_ned", [
    (0.0, math.pi / 2),  # facing east
    (math.pi / 2, 0.0),  # facing north
    (math.pi, -math.pi / 2),  # facing west
    (-math.pi / 2, math.pi),  # facing south
])
def test_yaw_conversion(yaw_enu, yaw_ned):
    assert F.wrap(F.yaw_enu_to_ned(yaw_enu) - yaw_ned) == pytest.approx(0.0, abs=1e-12)
    assert F.wrap(F.yaw_ned_to_enu(yaw_ned) - yaw_enu) == pytest.approx(0.0, abs=1e-12)


angles = st.floats(-3.1, 3.1)


@settings(max_examples=200, deadline=None)
@given(yaw=angles, pitch=st.floats(-1.5, 1.5), roll=angles)
def test_quaternion_round_trip(yaw, pitch, roll):
    ypr = F.quat_ned_to_camera_ypr(F.camera_ypr_to_quat_ned([yaw, pitch, roll]))
    assert F.wrap(ypr[0] - yaw) == pytest.approx(0.0, abs=1e-9)
    assert ypr[1] == pytest.approx(pitch, abs=1e-9) and F.wrap(ypr[2] - roll) == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=100, deadline=None)
@given(yaw=angles, pitch=st.floats(-1.5, 1.5), roll=st.floats(-1.0, 1.0))
def test_gimbal_quaternion_points_the_optical_axis_where_the_world_camera_model_does(yaw, pitch, roll):
    """The NED quaternion rotates the body x axis to the same physical direction as
    shared.camera.rotation_ypr does in ENU (the optical axis), and body y (right) to -left."""
    w, x, y, z = F.camera_ypr_to_quat_ned([yaw, pitch, roll])
    r_ned = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    r_enu = rotation_ypr(yaw, pitch, roll)
    np.testing.assert_allclose(F.ned_to_enu(r_ned[:, 0]), r_enu[:, 0], atol=1e-9)  # forward
    np.testing.assert_allclose(F.ned_to_enu(r_ned[:, 1]), -r_enu[:, 1], atol=1e-9)  # right = -left


def test_px4_and_ardupilot_mode_names():
    assert F.px4_mode_name(F.px4_custom_mode(6)) == "OFFBOARD"
    assert F.px4_mode_name(F.px4_custom_mode(4, 3)) == "LOITER"
    assert F.px4_mode_name(F.px4_custom_mode(4, 6)) == "LAND"
    assert F.acm_mode_name(4) == "GUIDED" and F.acm_mode_name(99) == "MODE_99"
    # the same numbers pymavlink uses
    from pymavlink import mavutil
    assert mavutil.px4_map["OFFBOARD"][1:] == (6, 0) and mavutil.px4_map["LOITER"][1:] == (4, 3)
    assert mavutil.mode_mapping_acm[4] == "GUIDED"


def test_setpoint_and_lens_messages_round_trip_through_real_mavlink2_bytes():
    enc = mavlink.MAVLink(None, srcSystem=245, srcComponent=191)
    dec = mavlink.MAVLink(None)
    p = F.enu_to_ned([3.0, 4.0, 5.0])
    msg = enc.set_position_target_local_ned_encode(12, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, TYPEMASK_POS_VEL_YAW,
                                                   *p, 0, 0, 0, 0, 0, 0, F.yaw_enu_to_ned(0.0), 0)
    buf = msg.pack(enc)
    assert buf[0] == 0xFD  # MAVLink 2 frame
    out = dec.parse_char(buf)
    assert out.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
    assert (out.x, out.y, out.z) == (4.0, 3.0, -5.0) and out.yaw == pytest.approx(math.pi / 2)
    assert out.type_mask & mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    assert not out.type_mask & (mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE)
    zoom = enc.command_long_encode(1, 100, mavlink.MAV_CMD_SET_CAMERA_ZOOM, 0, mavlink.ZOOM_TYPE_FOCAL_LENGTH,
                                   85.0, 0, 0, 0, 0, 0)
    out = dec.parse_char(zoom.pack(enc))
    assert out.command == 531 and out.param1 == 3 and out.param2 == 85.0
    focus = enc.command_long_encode(1, 100, mavlink.MAV_CMD_SET_CAMERA_FOCUS, 0, mavlink.FOCUS_TYPE_METERS,
                                    12.5, 0, 0, 0, 0, 0)
    out = dec.parse_char(focus.pack(enc))
    assert out.command == 532 and out.param1 == 3 and out.param2 == 12.5


@pytest.mark.parametrize("url,baud,expect", [
    ("serial:/dev/ttyTHS1:921600", 57600, ("/dev/ttyTHS1", 921600)),
    ("serial:/dev/ttyACM0", 57600, ("/dev/ttyACM0", 57600)),
    ("udpin:0.0.0.0:14540", 57600, ("udpin:0.0.0.0:14540", 57600)),
    ("tcp:127.0.0.1:5760", 57600, ("tcp:127.0.0.1:5760", 57600)),
])
def test_connection_strings(url, baud, expect):
    from cinetransfer.services.autopilot_bridge.mavlink import parse_url
    assert parse_url(url, baud) == expect
