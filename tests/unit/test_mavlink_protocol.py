"""The bridge's MAVLink protocol pieces on their own: bounded retries, mode ownership, the camera's
zoom fallback, the signing key and the signature check (real MAVLink 2 frames from pymavlink)."""
from __future__ import annotations

import math
import os

import pytest

from cinetransfer.services.autopilot_bridge.mav_camera import CameraLink
from cinetransfer.services.autopilot_bridge.mav_commands import CommandRetries
from cinetransfer.services.autopilot_bridge.mav_ownership import Ownership
from cinetransfer.services.autopilot_bridge.mavlink import mavlink
from cinetransfer.services.autopilot_bridge.signing import enable_signing
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.signing_key import read_signing_key, write_signing_key

R = mavlink


def test_a_command_without_ack_is_resent_retries_times_then_given_up():
    sent = []
    rc = CommandRetries(lambda c, p, comp, conf: sent.append((c, comp, conf)), retries=3, interval_s=1.0)
    rc.send("land", R.MAV_CMD_NAV_LAND, (0, 0), 1, now=10.0)
    given_up = []
    for t in (10.5, 11.0, 11.9, 12.0, 13.0, 14.0, 15.0, 16.0):
        given_up += rc.step(t)
    # first send at 10, resends at 11, 12, 13 (confirmation 1, 2, 3); given up at 14; nothing after
    assert sent == [(21, 1, 0), (21, 1, 1), (21, 1, 2), (21, 1, 3)]
    assert [f.key for f in given_up] == ["land"] and given_up[0].tries == 4
    assert rc.pending("land") is None


def test_an_ack_answers_only_the_component_that_was_addressed():
    rc = CommandRetries(lambda *a: None, retries=3, interval_s=1.0)
    rc.send("focus_distance_m", R.MAV_CMD_SET_CAMERA_FOCUS, (3, 12.0), 100, now=0.0)
    assert rc.on_ack(R.MAV_CMD_SET_CAMERA_FOCUS, 1) is None  # the autopilot's ack is not the camera's
    f = rc.on_ack(R.MAV_CMD_SET_CAMERA_FOCUS, 100)
    assert f is not None and f.params[:2] == (3.0, 12.0) and rc.pending("focus_distance_m") is None


def test_ownership_never_takes_the_vehicle_back_by_itself():
    o = Ownership(engage_on_start=False, reengage_after_link_loss=False)
    assert o.state == "idle"
    assert not o.on_vehicle("OFFBOARD", True, "OFFBOARD") and o.state == "idle"  # someone else's OFFBOARD
    o.engage()
    o.on_vehicle("OFFBOARD", True, "OFFBOARD")
    assert o.engaged
    assert o.on_vehicle("POSCTL", True, "OFFBOARD") and o.state == "released"
    o.on_vehicle("OFFBOARD", True, "OFFBOARD")  # back in OFFBOARD (a pilot's doing): still released
    assert o.state == "released"
    o.engage()
    o.on_vehicle("OFFBOARD", True, "OFFBOARD")
    o.start_land()
    o.on_vehicle("OFFBOARD", True, "OFFBOARD")
    assert o.state == "landing" and o.land == "sent"
    o.on_vehicle("AUTO.LAND", True, "OFFBOARD")
    assert o.land == "landing"
    o.on_vehicle("OFFBOARD", True, "OFFBOARD")
    o.disarm()
    assert o.state == "landing"  # only an engage command ends a land
    o2 = Ownership(engage_on_start=True, reengage_after_link_loss=True)
    o2.on_link_lost()
    assert o2.engaging
    o3 = Ownership(engage_on_start=True, reengage_after_link_loss=False)
    o3.on_link_lost()
    assert o3.state == "released" and o3.reason == "link lost"


def test_engaging_is_given_up_after_a_bounded_number_of_attempts():
    from cinetransfer.services.autopilot_bridge.mav_ownership import ENGAGE_ATTEMPTS

    o = Ownership(engage_on_start=True, reengage_after_link_loss=False)
    for _ in range(ENGAGE_ATTEMPTS):
        o.attempted()
    assert o.engaging
    o.attempted()
    assert o.state == "released" and o.reason == f"engage not taken after {ENGAGE_ATTEMPTS} attempts"
    o.engage()
    o.attempted()
    assert o.engaging and o.attempts == 1


def camera(sent):
    rc = CommandRetries(lambda c, p, comp, conf: sent.append((c, p[:3], comp)), retries=2, interval_s=1.0)
    return rc, CameraLink(R, rc, component=100, focal_range_mm=(30.0, 500.0), sensor_width_mm=23.76,
                          min_gap_s=0.2, request=lambda msg_id, comp: sent.append(("request", msg_id, comp)))


def test_zoom_falls_back_to_range_over_the_profiles_focal_lengths():
    sent = []
    rc, cam = camera(sent)
    cam.want("focal_length_mm", 85.0, now=0.0)
    assert sent[-1] == (R.MAV_CMD_SET_CAMERA_ZOOM, (R.ZOOM_TYPE_FOCAL_LENGTH, 85.0, 0.0), 100)
    cam.on_ack(rc.on_ack(R.MAV_CMD_SET_CAMERA_ZOOM, 100), R.MAV_RESULT_DENIED, now=0.1)
    # (85 - 30) / (500 - 30) = 11.702 %
    assert sent[-1][0] == R.MAV_CMD_SET_CAMERA_ZOOM and sent[-1][1][0] == R.ZOOM_TYPE_RANGE
    assert sent[-1][1][1] == pytest.approx(11.7021, abs=1e-4) and cam.zoom_by_range
    assert ("request", R.MAVLINK_MSG_ID_CAMERA_SETTINGS, 100) in sent
    cam.on_ack(rc.on_ack(R.MAV_CMD_SET_CAMERA_ZOOM, 100), R.MAV_RESULT_ACCEPTED, now=0.2)
    assert cam.lens()[0] == 85.0  # the accepted value until the camera reports its zoom
    settings = R.MAVLink_camera_settings_message(0, R.CAMERA_MODE_VIDEO, 50.0, math.nan)
    cam.on_settings(settings)
    assert cam.lens()[0] == pytest.approx(265.0)  # 30 + 0.5 x 470
    fov = R.MAVLink_camera_fov_status_message(0, 0, 0, 0, 0, 0, 0, [1, 0, 0, 0], 15.91, 8.99)
    cam.on_fov(fov)
    assert cam.lens()[0] == pytest.approx(23.76 / (2 * math.tan(math.radians(15.91) / 2)))  # 85.0 mm


def test_an_axis_never_acknowledged_becomes_unsupported_and_is_not_sent_again():
    sent = []
    rc, cam = camera(sent)
    cam.want("f_number", 2.8, now=0.0)
    for t in (1.0, 2.0, 3.0):
        for f in rc.step(t):
            cam.on_gave_up(f)
    assert [s[0] for s in sent] == [R.MAV_CMD_DO_DIGICAM_CONFIGURE] * 3  # 1 + 2 retries
    assert cam.unsupported == {"f_number": "no acknowledgement after 3 tries"}
    cam.want("f_number", 4.0, now=5.0)
    assert len(sent) == 3 and math.isnan(cam.lens()[2])
    cam.want("focus_distance_m", 12.0, now=5.0)
    cam.on_ack(rc.on_ack(R.MAV_CMD_SET_CAMERA_FOCUS, 100), R.MAV_RESULT_UNSUPPORTED, now=5.1)
    assert set(cam.unsupported) == {"f_number", "focus_distance_m"}


def test_deploy_certs_writes_a_signing_key(tmp_path):
    from cinetransfer.deploy.certs import generate

    files = generate(tmp_path / "secrets", identities=())
    key = tmp_path / "secrets" / "mavlink-signing.key"
    assert key in files and key.stat().st_mode & 0o777 == 0o600 and len(read_signing_key(key)) == 32


def test_signing_key_file_round_trip_and_errors(tmp_path):
    path = write_signing_key(tmp_path)
    assert oct(path.stat().st_mode & 0o777) == "0o600" and len(read_signing_key(path)) == 32
    (tmp_path / "short.key").write_text("abcd\n")
    with pytest.raises(ConfigError, match="64 hexadecimal"):
        read_signing_key(tmp_path / "short.key")
    with pytest.raises(ConfigError, match="cannot be read"):
        read_signing_key(tmp_path / "missing.key")


class _Conn:
    """What enable_signing needs of a pymavlink connection, around a real MAVLink object."""

    def __init__(self, mav) -> None:
        self.mav = mav

    def setup_signing(self, key, sign_outgoing, allow_unsigned_callback, link_id):
        s = self.mav.signing
        s.secret_key, s.sign_outgoing, s.allow_unsigned_callback, s.link_id = key, sign_outgoing, \
            allow_unsigned_callback, link_id
        s.timestamp = 10**12


def _frame(key: bytes, timestamp: int, lat: float) -> bytes:
    tx = R.MAVLink(None, srcSystem=1, srcComponent=1)
    tx.signing.secret_key, tx.signing.sign_outgoing, tx.signing.timestamp = key, True, timestamp
    return R.MAVLink_local_position_ned_message(0, lat, 0, 0, 0, 0, 0).pack(tx)


def test_a_forged_future_timestamp_does_not_lock_out_the_genuine_stream():
    good, bad = os.urandom(32), os.urandom(32)
    rx = R.MAVLink(None)
    rx.robust_parsing = True  # as on every mavutil connection: a refused frame becomes BAD_DATA
    enable_signing(_Conn(rx), good)
    ok = rx.parse_buffer(_frame(good, 10**12 + 1, 1.0))
    assert ok and ok[0].x == 1.0
    forged = rx.parse_buffer(_frame(bad, 10**15, 150.0)) or []  # wrong key, far-future timestamp
    assert all(m.get_type() == "BAD_DATA" for m in forged)
    later = rx.parse_buffer(_frame(good, 10**12 + 2, 2.0))  # pymavlink alone would call this 'old'
    assert later and later[0].get_type() == "LOCAL_POSITION_NED" and later[0].x == 2.0
    replay = rx.parse_buffer(_frame(good, 10**12 + 2, 3.0)) or []  # same timestamp again: a replay
    assert all(m.get_type() == "BAD_DATA" for m in replay)
    assert rx.signing.reject_count == 2


def test_mavlink_config_refuses_a_bad_key_and_bad_retries(tmp_path):
    from cinetransfer.services.autopilot_bridge.config import MavlinkConfig

    with pytest.raises(ConfigError, match="cannot be read"):
        MavlinkConfig(signing_key_file=str(tmp_path / "missing.key"))
    with pytest.raises(ConfigError, match="command_retries"):
        MavlinkConfig(command_retries=-1)
    with pytest.raises(ConfigError, match="focal_length_range_mm"):
        MavlinkConfig(focal_length_range_mm=(500.0, 30.0))
    assert MavlinkConfig(signing_key_file=str(write_signing_key(tmp_path))).command_retries == 3



def test_the_bridge_zooms_by_range_over_its_vehicle_profiles_focal_lengths():
    from cinetransfer.services.autopilot_bridge.service import build_parser, config_from_args

    cfg = config_from_args(build_parser().parse_args(["--backend", "mavlink", "--vehicle", "inspire3"]))
    assert cfg.mavlink.focal_length_range_mm == (17.0, 28.0)  # deploy/vehicles/inspire3.yaml's zoom lens
