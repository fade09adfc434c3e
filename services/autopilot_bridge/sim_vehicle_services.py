"""The standard services a ground station expects of `cinetransfer sim-vehicle` besides flying.

- Parameters (PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET -> PARAM_VALUE) for the few
  values the simulation has: the take-off altitude, the offboard-loss timeout, the speed limits
  and the system id (read-only). Integers travel PX4-style byte-wise in the float field
  (ArduPilot: C cast), as AUTOPILOT_VERSION's capability flags say.
- MAV_CMD_REQUEST_MESSAGE for HOME_POSITION, AUTOPILOT_VERSION, GIMBAL_MANAGER_INFORMATION,
  GIMBAL_DEVICE_INFORMATION and, from
  the camera, CAMERA_INFORMATION and CAMERA_SETTINGS (also the older REQUEST_AUTOPILOT_CAPABILITIES
  and REQUEST_CAMERA_INFORMATION commands).
- A camera component (MAV_COMP_ID_CAMERA = 100): HEARTBEAT of type CAMERA, CAMERA_INFORMATION,
  zoom by focal length or by range, focus in metres, aperture (DO_DIGICAM_CONFIGURE param3),
  CAMERA_FOV_STATUS; commands addressed to it are acknowledged by it.
- A gimbal manager on the autopilot component: GIMBAL_MANAGER_INFORMATION (the profile's pitch and
  roll ranges), DO_GIMBAL_MANAGER_CONFIGURE (primary control) and GIMBAL_MANAGER_STATUS (5 Hz)
  for the gimbal device the vehicle carries (id 1, not a MAVLink component of its own).
"""
from __future__ import annotations

import contextlib
import math
import struct
import time
from dataclasses import dataclass
from typing import Any, Iterator

from cinetransfer.services.autopilot_bridge.mavlink import mavlink as R

CAMERA_COMPONENT = R.MAV_COMP_ID_CAMERA
GIMBAL_DEVICE_ID = 1  # a gimbal device without a MAVLink component of its own (ids 1..6)
FLIGHT_SW_VERSION = (1 << 24) | (15 << 16)  # reported as 1.15.0 (the PX4 release the emulation follows)


@dataclass
class Param:
    value: float
    is_int: bool = False
    read_only: bool = False
    lo: float = -math.inf
    hi: float = math.inf


def vehicle_params(autopilot: str, system_id: int, offboard_timeout_s: float, speed_mps: float,
                   climb_mps: float) -> dict[str, Param]:
    """The parameters the simulation has, named as the emulated autopilot names them."""
    if autopilot == "px4":
        return {"MIS_TAKEOFF_ALT": Param(2.5, lo=0.5, hi=100.0),
                "COM_OF_LOSS_T": Param(offboard_timeout_s, lo=0.05, hi=60.0),
                "MPC_XY_VEL_MAX": Param(speed_mps, read_only=True),
                "MPC_Z_VEL_MAX_UP": Param(climb_mps, read_only=True),
                "MAV_SYS_ID": Param(system_id, is_int=True, read_only=True)}
    return {"PILOT_TKOFF_ALT": Param(250.0, lo=0.0, hi=1000.0),
            "WPNAV_SPEED": Param(speed_mps * 100, read_only=True),
            "SYSID_THISMAV": Param(system_id, is_int=True, read_only=True)}


class StandardServices:
    """Parameters, requested messages, the camera and the gimbal manager of one SimVehicle."""

    def __init__(self, veh: Any) -> None:
        self.veh = veh
        self.params = vehicle_params(veh.autopilot, veh.conn.mav.srcSystem, veh.offboard_timeout_s,
                                     veh.model.dyn.limits.speed_max_mps, veh.model.dyn.limits.climb_max_mps)
        self.next_camera_hb = 0.0
        self.next_gimbal_status = 0.0
        self.gimbal_primary = (0, 0)  # (system, component) in control of the gimbal; (0, 0) = nobody

    # ------------------------------------------------------------------ helpers
    @contextlib.contextmanager
    def as_camera(self) -> Iterator[Any]:
        """Send as the camera component (same system, same link)."""
        mav = self.veh.conn.mav
        comp, mav.srcComponent = mav.srcComponent, CAMERA_COMPONENT
        try:
            yield mav
        finally:
            mav.srcComponent = comp

    def _ms(self) -> int:
        return self.veh._ms(time.monotonic())

    @property
    def takeoff_altitude_m(self) -> float:
        p = self.params.get("MIS_TAKEOFF_ALT")
        return p.value if p is not None else self.params["PILOT_TKOFF_ALT"].value / 100.0

    # ------------------------------------------------------------------ parameters
    def _wire(self, p: Param) -> tuple[float, int]:
        if not p.is_int:
            return float(p.value), R.MAV_PARAM_TYPE_REAL32
        if self.veh.autopilot == "px4":
            return struct.unpack("<f", struct.pack("<i", int(p.value)))[0], R.MAV_PARAM_TYPE_INT32
        return float(int(p.value)), R.MAV_PARAM_TYPE_INT32

    def _from_wire(self, p: Param, value: float) -> float:
        if p.is_int and self.veh.autopilot == "px4":
            return float(struct.unpack("<i", struct.pack("<f", value))[0])
        return float(value)

    def send_param(self, name: str) -> None:
        names = list(self.params)
        value, ptype = self._wire(self.params[name])
        self.veh.conn.mav.param_value_send(name.encode(), value, ptype, len(names), names.index(name))
        self.veh.stats["tx_PARAM_VALUE"] += 1

    def on_param_message(self, msg: Any) -> None:
        t = msg.get_type()
        if t == "PARAM_REQUEST_LIST":
            for name in self.params:
                self.send_param(name)
            return
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="replace")
        if t == "PARAM_REQUEST_READ" and name not in self.params and 0 <= msg.param_index < len(self.params):
            name = list(self.params)[msg.param_index]
        p = self.params.get(name)
        if p is None:
            return  # the protocol's answer to an unknown parameter is silence
        if t == "PARAM_SET" and not p.read_only:
            v = self._from_wire(p, msg.param_value)
            if math.isfinite(v) and p.lo <= v <= p.hi:
                p.value = v
                if name == "COM_OF_LOSS_T":
                    self.veh.offboard_timeout_s = v
                self.veh._event(f"param {name} = {v:g}")
        self.send_param(name)  # PARAM_SET is answered with the value now in force

    # ------------------------------------------------------------------ requested messages
    def request_message(self, msg_id: int, now: float) -> int:
        """MAV_CMD_REQUEST_MESSAGE addressed to the autopilot; returns its MAV_RESULT."""
        senders = {R.MAVLINK_MSG_ID_HOME_POSITION: self.veh._send_home,
                   R.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.send_autopilot_version,
                   R.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION: self.send_gimbal_manager_information,
                   R.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION: self.send_gimbal_device_information}
        send = senders.get(msg_id)
        if send is None:
            return R.MAV_RESULT_UNSUPPORTED
        send(now)
        return R.MAV_RESULT_ACCEPTED

    def send_autopilot_version(self, _now: float) -> None:
        caps = (R.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | R.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | R.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | (R.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE if self.veh.autopilot == "px4"
                   else R.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST))
        self.veh.conn.mav.autopilot_version_send(caps, FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
                                                 0x5EED0000 + self.veh.conn.mav.srcSystem)

    def send_gimbal_manager_information(self, _now: float) -> None:
        lim = self.veh.model.dyn.limits
        caps = (R.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS | R.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS
                | R.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_LOCK | R.GIMBAL_MANAGER_CAP_FLAGS_HAS_ROLL_AXIS)
        self.veh.conn.mav.gimbal_manager_information_send(
            self._ms(), caps, GIMBAL_DEVICE_ID, -lim.roll_max_rad, lim.roll_max_rad, lim.pitch_min_rad,
            lim.pitch_max_rad, -math.pi, math.pi)

    def send_gimbal_device_information(self, _now: float) -> None:
        """On behalf of the gimbal device, which has no MAVLink component of its own (as PX4 does)."""
        lim = self.veh.model.dyn.limits
        caps = (R.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_AXIS | R.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS
                | R.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS | R.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_LOCK)
        self.veh.conn.mav.gimbal_device_information_send(
            self._ms(), b"cinetransfer", b"sim-vehicle gimbal", b"", 0, 0, 0, caps, 0, -lim.roll_max_rad,
            lim.roll_max_rad, lim.pitch_min_rad, lim.pitch_max_rad, -math.pi, math.pi, GIMBAL_DEVICE_ID)

    def configure_gimbal(self, p: list[float], sender: tuple[int, int]) -> int:
        """MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: who has primary control (-1 unchanged, -2 the
        sender, -3 nobody); secondary control is not emulated."""
        sysid, compid = int(p[0]), int(p[1])
        if sysid == -2 or compid == -2:
            self.gimbal_primary = sender
        elif sysid == -3 or compid == -3:
            self.gimbal_primary = (0, 0)
        elif sysid >= 0 and compid >= 0:
            self.gimbal_primary = (sysid, compid)
        return R.MAV_RESULT_ACCEPTED

    # ------------------------------------------------------------------ camera component
    def camera_command(self, cmd: int, p: list[float], now: float) -> int:
        """A COMMAND_LONG addressed to the camera; returns its MAV_RESULT."""
        veh = self.veh
        if cmd == R.MAV_CMD_REQUEST_MESSAGE:
            return self._camera_request(int(p[0]))
        if cmd == R.MAV_CMD_REQUEST_CAMERA_INFORMATION:
            return self._camera_request(R.MAVLINK_MSG_ID_CAMERA_INFORMATION)
        if cmd == R.MAV_CMD_SET_CAMERA_ZOOM and int(p[0]) == R.ZOOM_TYPE_RANGE:
            lo, hi = veh.model.lens_ranges["focal_length_mm"]
            if not (math.isfinite(p[1]) and 0.0 <= p[1] <= 100.0):
                return R.MAV_RESULT_DENIED
            veh.model.set_lens("focal_length_mm", lo + p[1] / 100.0 * (hi - lo))
            return R.MAV_RESULT_ACCEPTED
        if cmd in (R.MAV_CMD_SET_CAMERA_ZOOM, R.MAV_CMD_SET_CAMERA_FOCUS, R.MAV_CMD_DO_DIGICAM_CONFIGURE,
                   R.MAV_CMD_SET_MESSAGE_INTERVAL):
            return veh._command(cmd, p, now)
        return R.MAV_RESULT_UNSUPPORTED

    def _camera_request(self, msg_id: int) -> int:
        if msg_id == R.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            self.send_camera_information()
        elif msg_id == R.MAVLINK_MSG_ID_CAMERA_SETTINGS:
            self.send_camera_settings()
        else:
            return R.MAV_RESULT_UNSUPPORTED
        return R.MAV_RESULT_ACCEPTED

    def send_camera_information(self) -> None:
        veh = self.veh
        flags = (R.CAMERA_CAP_FLAGS_CAPTURE_VIDEO | R.CAMERA_CAP_FLAGS_HAS_BASIC_ZOOM
                 | R.CAMERA_CAP_FLAGS_HAS_BASIC_FOCUS)
        with self.as_camera() as mav:
            mav.camera_information_send(self._ms(), list(b"cinetransfer".ljust(32, b"\0")),
                                        list(b"sim-vehicle camera".ljust(32, b"\0")), 0,
                                        float(veh.model.focal_length_mm), veh.sensor_w, veh.sensor_h, 1920, 1080, 0,
                                        flags, 0, b"", GIMBAL_DEVICE_ID)
        veh.stats["tx_CAMERA_INFORMATION"] += 1

    def send_camera_settings(self) -> None:
        lo, hi = self.veh.model.lens_ranges["focal_length_mm"]
        zoom = (float(self.veh.model.focal_length_mm) - lo) / (hi - lo) * 100.0
        with self.as_camera() as mav:
            mav.camera_settings_send(self._ms(), R.CAMERA_MODE_VIDEO, zoom, math.nan)

    def ack_as_camera(self, msg: Any, result: int) -> None:
        with self.as_camera() as mav:
            mav.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def send_periodic(self, now: float) -> None:
        """The camera's HEARTBEAT (1 Hz) and the gimbal manager's status (5 Hz)."""
        veh = self.veh
        if now >= self.next_camera_hb:
            self.next_camera_hb = now + 1.0
            with self.as_camera() as mav:
                mav.heartbeat_send(R.MAV_TYPE_CAMERA, R.MAV_AUTOPILOT_INVALID, 0, 0, R.MAV_STATE_ACTIVE)
            veh.stats["tx_camera_HEARTBEAT"] += 1
        if now >= self.next_gimbal_status:
            self.next_gimbal_status = now + 0.2
            veh.conn.mav.gimbal_manager_status_send(self._ms(), R.GIMBAL_MANAGER_FLAGS_YAW_LOCK, GIMBAL_DEVICE_ID,
                                                    *self.gimbal_primary, 0, 0)
