"""The MAVLink side against an implementation we did not write: MAVSDK 4.1.0 (C++, in-process).

1. The bridge's backend flies a MAVSDK autopilot that has a MAVSDK CameraServer (component 100):
   setpoints and gimbal decoded right, camera found by its HEARTBEAT, zoom (by range: MAVSDK
   refuses zoom by focal length) and focus accepted and read back, aperture (which MAVSDK never
   acknowledges) resent a bounded number of times and then unsupported, land taken (MAVSDK
   ignores NAV_LAND; the land mode it takes) and never followed by a switch back to OFFBOARD.
2. MAVSDK as a ground station flies `cinetransfer sim-vehicle` (a real process): parameters,
   version, camera and gimbal listed, the gimbal pointed, arm, take-off, offboard, land.
All over real UDP on 127.0.0.1.
"""
from __future__ import annotations

import math
import subprocess
import sys
import time

import numpy as np
import pytest

mavsdk = pytest.importorskip("mavsdk", reason="mavsdk==4.1.0 is in the test extra (pip install -e .[test])")

from mavsdk_peer import MavsdkAutopilot, wait_for  # noqa: E402

from cinetransfer.services.autopilot_bridge import enu_ned as F  # noqa: E402
from cinetransfer.services.autopilot_bridge.config import MavlinkConfig  # noqa: E402
from cinetransfer.services.autopilot_bridge.mavlink import TYPEMASK_POS_VEL_YAW, MavlinkBackend, mavlink  # noqa: E402
from cinetransfer.shared import messages as M  # noqa: E402

pytestmark = pytest.mark.timeout(180)


def free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Driver:
    """The bridge's control step without Zenoh: one setpoint into the backend, one step."""

    def __init__(self, backend: MavlinkBackend) -> None:
        self.backend = backend
        self.sp: M.Setpoint | None = None

    def poll(self) -> None:
        if self.sp is not None:
            self.backend.apply(self.sp)
        self.backend.step(time.monotonic())


def test_bridge_flies_a_mavsdk_autopilot_with_a_camera_server():
    port = free_udp_port()
    ap = MavsdkAutopilot(f"udpin://127.0.0.1:{port}")
    backend = MavlinkBackend(MavlinkConfig(url=f"udpout:127.0.0.1:{port}", connect_timeout_s=30.0,
                                           focal_length_range_mm=(30.0, 500.0)))
    drv = Driver(backend)
    try:
        backend.start()
        backend.command("engage", {})
        lens = M.LensState(focal_length_mm=85.0, focus_distance_m=12.0, f_number=2.8)
        drv.sp = M.Setpoint(position_m=np.array([2.0, 1.0, 4.0]), camera_ypr_rad=np.array([0.5, -0.3, 0.0]),
                            lens=lens)
        wait_for(lambda: backend.engaged, 30, "OFFBOARD and armed", drv.poll)
        # the vehicle (MAVSDK decoded our setpoints) is where we sent it: world ENU (2, 1, 4) = NED (1, 2, -4)
        wait_for(lambda: np.allclose(backend.vehicle_state().position_m, [2.0, 1.0, 4.0], atol=1e-3), 30,
                 "position tracked", drv.poll)
        with ap.lock:
            sp = dict(ap.setpoints[-1])
            gimbal = dict(ap.gimbal[-1])
        assert sp["coordinate_frame"] == mavlink.MAV_FRAME_LOCAL_NED and sp["type_mask"] == TYPEMASK_POS_VEL_YAW == 2496
        assert (sp["x"], sp["y"], sp["z"]) == pytest.approx((1.0, 2.0, -4.0))
        assert sp["yaw"] == pytest.approx(F.yaw_enu_to_ned(0.5), abs=1e-6)
        assert gimbal["flags"] == mavlink.GIMBAL_MANAGER_FLAGS_YAW_LOCK
        np.testing.assert_allclose(F.quat_to_euler(gimbal["q"]), (0.0, -0.3, F.yaw_enu_to_ned(0.5)), atol=1e-5)

        # the lens: the camera found by its HEARTBEAT; focus in metres accepted; zoom by focal length
        # DENIED by MAVSDK, so by range over the profile's 30-500 mm: (85 - 30) / 470 = 11.70 %
        wait_for(lambda: backend.vehicle_state().lens_unsupported == ["f_number"], 60,
                 "aperture given up after its retries", drv.poll)
        st = backend.vehicle_state()
        h = backend.health_counters()
        assert h["mav_camera_component"] == 100 and h["mav_zoom_by_range"]
        assert st.lens.focal_length_mm == pytest.approx(85.0) and st.lens.focus_distance_m == pytest.approx(12.0)
        assert math.isnan(st.lens.f_number) and h["mav_lens_unsupported"] == "f_number"
        assert ap.count("focus_meters") == 1 and ap.count("zoom_range") == 1
        with ap.lock:
            zoom = next(v for name, v in ap.commands if name == "zoom_range")
        assert zoom == pytest.approx((85.0 - 30.0) / 470.0 * 100.0, abs=1e-3)
        # nothing is resent unboundedly: 1 + command_retries DIGICAM commands, then silence
        assert h["mav_commands_given_up"] == 1
        sent = h["mav_commands_sent"]
        drv.sp = M.Setpoint(position_m=np.array([2.0, 1.0, 4.0]), camera_ypr_rad=np.array([0.5, -0.3, 0.0]),
                            lens=M.LensState(focal_length_mm=85.0, focus_distance_m=12.0, f_number=4.0))
        t_end = time.monotonic() + 3.0
        wait_for(lambda: time.monotonic() > t_end, 60, "3 s of flight", drv.poll)
        assert backend.health_counters()["mav_commands_sent"] == sent  # a new f-number is not sent either

        # land: MAVSDK neither acks nor acts on NAV_LAND; after the retries the land mode is asked for
        assert backend.command("land", {})
        wait_for(lambda: backend.health_counters()["mav_land"] == "landing", 60, "land taken", drv.poll)
        assert backend.vehicle_state().mode == "LAND" and backend.health_counters()["mav_owner"] == "landing"
        # ... and never handed back to OFFBOARD by the bridge, nor the plan flown
        drv.sp = M.Setpoint(position_m=np.array([5.0, 5.0, 5.0]), camera_ypr_rad=np.array([0.5, -0.3, 0.0]))
        n_modes = ap.count("mode")
        t_end = time.monotonic() + 3.0
        wait_for(lambda: time.monotonic() > t_end, 60, "3 s after the land", drv.poll)
        assert ap.count("mode") == n_modes and backend.vehicle_state().mode == "LAND"
        assert backend.health_counters()["mav_foreign_system"] == 0
    finally:
        backend.close()
        ap.close()


def spawn_vehicle(port: int) -> subprocess.Popen:
    # a generous offboard failsafe (default 0.5 s of wall time): a loaded machine can stall MAVSDK's
    # setpoint stream that long, and the vehicle then rightly leaves OFFBOARD; not what is tested here
    return subprocess.Popen([sys.executable, "-m", "cinetransfer", "sim-vehicle", "--offboard-timeout", "5",
                             "--mavlink", f"udpin:127.0.0.1:{port}"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)


def test_mavsdk_ground_station_flies_the_sim_vehicle():
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.camera import Camera
    from mavsdk.plugins.gimbal import Gimbal
    from mavsdk.plugins.info import Info
    from mavsdk.plugins.offboard import Offboard, PositionNedYaw
    from mavsdk.plugins.param import Param
    from mavsdk.plugins.telemetry import Telemetry

    port = free_udp_port()
    proc = spawn_vehicle(port)
    gcs = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION))
    try:
        assert int(gcs.add_any_connection(f"udpout://127.0.0.1:{port}")) == 0
        system = gcs.first_autopilot(60.0)
        assert system is not None
        param, camera, gimbal = Param(system), Camera(system), Gimbal(system)
        assert param.get_param_float("MIS_TAKEOFF_ALT") == pytest.approx(2.5)
        assert param.get_param_int("MAV_SYS_ID") == 1
        param.set_param_float("MIS_TAKEOFF_ALT", 3.0)
        assert param.get_param_float("MIS_TAKEOFF_ALT") == pytest.approx(3.0)
        names = {p.name for p in param.get_all_params().float_params}
        assert {"MIS_TAKEOFF_ALT", "COM_OF_LOSS_T", "MPC_XY_VEL_MAX"} <= names
        assert Info(system).get_version().flight_sw_major == 1
        wait_for(lambda: len(camera.camera_list().cameras) == 1 and len(gimbal.gimbal_list().gimbals) == 1, 60,
                 "camera and gimbal listed")
        cam = camera.camera_list().cameras[0]
        assert cam.component_id == 100 and cam.model_name == "sim-vehicle camera"
        # the gimbal, as a ground station points it: take control, pitch -30 deg, yaw 45 deg (north-east)
        from mavsdk.plugins.gimbal import ControlMode, GimbalMode, SendMode

        gid = gimbal.gimbal_list().gimbals[0].gimbal_id
        gimbal.take_control(gid, ControlMode.PRIMARY)
        gimbal.set_angles(gid, 0.0, -30.0, 45.0, GimbalMode.YAW_LOCK, SendMode.ONCE)
        wait_for(lambda: abs(gimbal.get_attitude(gid).euler_angle_forward.pitch_deg + 30.0) < 0.5
                 and abs(gimbal.get_attitude(gid).euler_angle_north.yaw_deg - 45.0) < 0.5, 60, "gimbal pointed")

        telemetry, action, offboard = Telemetry(system), Action(system), Offboard(system)
        action.arm()
        action.takeoff()
        wait_for(lambda: telemetry.position_velocity_ned().position.down_m < -2.8, 60, "take-off to 3 m")
        offboard.set_position_ned(PositionNedYaw(1.0, 2.0, -4.0, 90.0))
        offboard.start()
        wait_for(lambda: abs(telemetry.position_velocity_ned().position.east_m - 2.0) < 0.2, 60, "offboard target",
                 lambda: offboard.set_position_ned(PositionNedYaw(1.0, 2.0, -4.0, 90.0)))
        action.land()
        wait_for(lambda: not telemetry.armed(), 90, "landed and disarmed")
    finally:
        gcs.destroy()
        proc.send_signal(2)
        out, _ = proc.communicate(timeout=20)
    text = out.decode(errors="replace")
    assert proc.returncode == 0, text
    assert "param MIS_TAKEOFF_ALT = 3" in text and "take-off to 3.0 m" in text and "-> OFFBOARD" in text
    assert "landed: disarmed" in text


def test_the_bridge_service_reports_the_unsupported_aperture_and_the_land_over_zenoh(port, listener_opts, tmp_path):
    """The same MAVSDK autopilot under the real `autopilot_bridge` process: what the backend found
    reaches VehicleState and Health on the bus."""
    import threading

    from conftest import connect_flags, spawn, stop

    from cinetransfer.shared import codec, keys, zenoh_config

    rig, udp = "mv", free_udp_port()
    ap = MavsdkAutopilot(f"udpin://127.0.0.1:{udp}")
    session = zenoh_config.open_session(listener_opts)
    seen: dict[str, object] = {}
    lock = threading.Lock()

    def keep(name, cls):
        def cb(sample):
            msg = codec.decode(sample.payload.to_bytes(), cls)
            with lock:
                seen[name] = msg
        return cb

    subs = [session.declare_subscriber(keys.VEHICLE_STATE.key(rig), keep("state", M.VehicleState)),
            session.declare_subscriber(keys.health(rig, "autopilot_bridge"), keep("health", M.Health))]
    sp_pub = session.declare_publisher(keys.SETPOINT.key(rig))
    cmd_pub = session.declare_publisher(keys.BRIDGE_COMMAND.key(rig))
    br = spawn("autopilot_bridge", "--rig", rig, "--backend", "mavlink", "--mavlink", f"udpout:127.0.0.1:{udp}",
               "--engage", "--health-period", "0.2", "--connect-timeout", "60", *connect_flags(port),
               log=tmp_path / "bridge.log")

    def latest(name):
        with lock:
            return seen.get(name)

    def stream() -> None:
        sp = M.Setpoint(stamp_ns=time.time_ns(), position_m=np.array([1.0, 1.0, 4.0]), camera_ypr_rad=np.zeros(3),
                        lens=M.LensState(focal_length_mm=50.0, focus_distance_m=8.0, f_number=4.0))
        sp_pub.put(codec.encode(sp))

    def counters() -> dict:
        h = latest("health")
        return dict(h.counters) if h is not None else {}

    try:
        wait_for(lambda: (latest("state") is not None and latest("state").lens_unsupported == ["f_number"]
                          and counters().get("mav_lens_unsupported") == "f_number"), 120,
                 "aperture unsupported in VehicleState and Health", stream)
        st = latest("state")
        assert st.lens.focal_length_mm == pytest.approx(50.0) and st.lens.focus_distance_m == pytest.approx(8.0)
        cmd_pub.put(codec.encode(M.Command(stamp_ns=time.time_ns(), action="land")))
        wait_for(lambda: counters().get("mav_land") == "landing" and latest("state").mode == "LAND", 120,
                 "the land taken, in Health", stream)
        assert counters()["mav_owner"] == "landing" and counters()["mav_commands_given_up"] == 2
    finally:
        rc = stop(br)
        for d in (*subs, sp_pub, cmd_pub):
            d.undeclare()
        session.close()
        ap.close()
    assert rc == 0, (tmp_path / "bridge.log").read_text()[-3000:]
