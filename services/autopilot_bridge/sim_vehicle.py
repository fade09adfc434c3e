"""`cinetransfer sim-vehicle`: a simulated multirotor behind a real MAVLink 2 endpoint.

    cinetransfer sim-vehicle --mavlink udpin:127.0.0.1:14550          # wait for the bridge to call
    cinetransfer sim-vehicle --mavlink udpout:127.0.0.1:14540         # send to it (like PX4 SITL)
    cinetransfer sim-vehicle --autopilot ardupilot --start 0,0,0

It emulates just enough of PX4 (or ArduCopter with --autopilot ardupilot) for the bridge's
`mavlink` backend and independent ground stations (MAVProxy, MAVSDK) to fly it:

- sends HEARTBEAT (1 Hz; MAV_AUTOPILOT_PX4 / ARDUPILOTMEGA, custom mode, armed flag),
  LOCAL_POSITION_NED and ATTITUDE (50 Hz), GIMBAL_DEVICE_ATTITUDE_STATUS (20 Hz, earth-frame
  yaw), CAMERA_FOV_STATUS (5 Hz; the field of view of the current focal length), COMMAND_ACK;
  rates can be changed with MAV_CMD_SET_MESSAGE_INTERVAL;
- accepts SET_MODE and MAV_CMD_DO_SET_MODE, MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_NAV_TAKEOFF,
  MAV_CMD_NAV_LAND, SET_POSITION_TARGET_LOCAL_NED (position / velocity / yaw),
  GIMBAL_MANAGER_SET_ATTITUDE and MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, MAV_CMD_SET_CAMERA_ZOOM
  (ZOOM_TYPE_FOCAL_LENGTH), MAV_CMD_SET_CAMERA_FOCUS (FOCUS_TYPE_METERS),
  MAV_CMD_DO_DIGICAM_CONFIGURE (param3 = f-stop), MAV_CMD_GET_HOME_POSITION (-> HOME_POSITION);
  other commands get MAV_RESULT_UNSUPPORTED;
- the standard services of sim_vehicle_services.py: parameters, REQUEST_MESSAGE (HOME_POSITION,
  AUTOPILOT_VERSION, GIMBAL_MANAGER_INFORMATION), a camera component (100) and a gimbal manager;
- MAVLink 2 signing with --signing-key FILE (then unsigned messages are ignored);
- PX4 OFFBOARD semantics: switching into OFFBOARD is refused (TEMPORARILY_REJECTED) unless
  setpoints are streaming; in OFFBOARD, a stream that stops for `--offboard-timeout` (0.5 s,
  i.e. below 2 Hz) makes the vehicle leave OFFBOARD and hold (AUTO.LOITER);
- ArduCopter GUIDED semantics: position targets move it once it is flying (take-off first when
  landed); a velocity-only target stops after 3 s without update; no stream is required.

Dynamics: the built-in simulator's `shared.dynamics.VehicleDynamics` (the one model the sim backend
flies too; arming and the ground added by `vehicle_model.SimDynamicsAdapter`), with the limits,
lens ranges and camera sensor of the vehicle profile (--vehicle, shared/vehicle.py).
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import logging
import math
import select
import time
from typing import Any

import numpy as np

from cinetransfer.services.autopilot_bridge import enu_ned as F
from cinetransfer.services.autopilot_bridge.mavlink import connect, mavlink
from cinetransfer.services.autopilot_bridge.signing import enable_signing
from cinetransfer.services.autopilot_bridge.sim_vehicle_config import NODE, SimVehicleConfig
from cinetransfer.services.autopilot_bridge.sim_vehicle_services import CAMERA_COMPONENT, StandardServices
from cinetransfer.shared.dynamics import DynamicsLimits
from cinetransfer.shared.stopsignal import StopSignal
from cinetransfer.services.autopilot_bridge.vehicle_model import SimDynamicsAdapter
from cinetransfer.shared import nodeconfig
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.signing_key import read_signing_key
from cinetransfer.shared.vehicle import VehicleProfile, add_vehicle_argument, load_vehicle

log = logging.getLogger("cinetransfer.sim_vehicle")

R = mavlink  # short alias for constants
#: commands addressed to these are the autopilot's (it forwards lens commands to its camera)
AUTOPILOT_COMPONENTS = (0, R.MAV_COMP_ID_AUTOPILOT1, R.MAV_COMP_ID_GIMBAL)


class SimVehicle:
    """The simulated vehicle and its MAVLink endpoint. Drive it with `run()` or `step()`."""

    def __init__(self, url: str, *, autopilot: str = "px4", system_id: int = 1, start_enu=(0.0, 0.0, 0.0),
                 rate_hz: float = 100.0, telemetry_hz: float = 50.0, offboard_timeout_s: float = 0.5,
                 vehicle: VehicleProfile | None = None, signing_key: bytes | None = None) -> None:
        if autopilot not in ("px4", "ardupilot"):
            raise ValueError(f"autopilot {autopilot!r} must be 'px4' or 'ardupilot'")
        self.url, self.autopilot = url, autopilot
        self.rate_hz = rate_hz
        self.offboard_timeout_s = offboard_timeout_s
        vehicle = vehicle or load_vehicle()
        self.sensor_w, self.sensor_h = vehicle.camera.sensor_width_mm, vehicle.camera.sensor_height_mm
        self.conn = connect(url, source_system=system_id, source_component=R.MAV_COMP_ID_AUTOPILOT1)
        if signing_key is not None:
            enable_signing(self.conn, signing_key)
        self.model: Any = SimDynamicsAdapter(start_enu, limits=DynamicsLimits.from_vehicle(vehicle))
        self.home_enu = np.array([start_enu[0], start_enu[1], 0.0])
        self.mode = "LOITER"  # PX4 AUTO.LOITER ('Hold') / ArduCopter LOITER
        self.t0 = time.monotonic()
        self.last_t: float | None = None
        self.last_sp_s: float | None = None  # last SET_POSITION_TARGET_LOCAL_NED
        self.sp_velocity_only = False
        self.taking_off = False
        self.takeoff_alt_m: float | None = None
        self.last_gcs_heartbeat_s: float | None = None
        # message intervals [s] by name
        self.intervals: dict[str, float] = {"HEARTBEAT": 1.0, "LOCAL_POSITION_NED": 1.0 / telemetry_hz,
                                            "ATTITUDE": 1.0 / telemetry_hz, "GIMBAL_DEVICE_ATTITUDE_STATUS": 0.05,
                                            "CAMERA_FOV_STATUS": 0.2}
        self.next_send: dict[str, float] = {k: 0.0 for k in self.intervals}
        self.stats: collections.Counter[str] = collections.Counter()
        self.sp_times: collections.deque[float] = collections.deque(maxlen=2000)
        self.events: collections.deque[str] = collections.deque(maxlen=200)
        self.paused_link = False  # tests: drop all traffic in both directions
        self.services = StandardServices(self)
        self.last_sender = (0, 0)  # (system, component) of the COMMAND_LONG being handled

    # ------------------------------------------------------------------ helpers
    def _ms(self, now: float) -> int:
        return int((now - self.t0) * 1000) & 0xFFFFFFFF

    def _event(self, text: str) -> None:
        self.events.append(text)
        log.info("%s", text)

    @property
    def external_mode(self) -> str:
        return "OFFBOARD" if self.autopilot == "px4" else "GUIDED"

    def _custom_mode(self) -> int:
        if self.autopilot == "px4":
            if self.mode in F.PX4_AUTO_SUB:
                return F.px4_custom_mode(F.PX4_MAIN["AUTO"], F.PX4_AUTO_SUB[self.mode])
            return F.px4_custom_mode(F.PX4_MAIN.get(self.mode, F.PX4_MAIN["POSCTL"]))
        return F.ACM_MODES.get(self.mode, F.ACM_MODES["LOITER"])

    def _set_mode(self, name: str, now: float) -> int:
        """Switch mode; returns a MAV_RESULT."""
        if name == self.mode:
            return R.MAV_RESULT_ACCEPTED
        if self.autopilot == "px4" and name == "OFFBOARD":
            if self.last_sp_s is None or now - self.last_sp_s > self.offboard_timeout_s:
                self._event("OFFBOARD refused: no setpoint stream")
                return R.MAV_RESULT_TEMPORARILY_REJECTED
        allowed = (("OFFBOARD", "LOITER", "POSCTL", "LAND", "TAKEOFF", "RTL") if self.autopilot == "px4"
                   else ("GUIDED", "LOITER", "LAND", "RTL", "BRAKE", "STABILIZE"))
        if name not in allowed:
            return R.MAV_RESULT_UNSUPPORTED
        self._event(f"mode {self.mode} -> {name}")
        self.mode = name
        if name in ("LOITER", "BRAKE", "POSCTL"):
            self.model.hold_here()
        elif name == "LAND":
            self.model.track(np.array([*self.model.position_m[:2], self.model.ground_z_m]), np.zeros(3), None)
        return R.MAV_RESULT_ACCEPTED

    def _mode_from_custom(self, base_mode: int, main: int, sub: int) -> str | None:
        if not base_mode & R.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None
        if self.autopilot == "px4":
            return F.px4_mode_name(F.px4_custom_mode(main, sub))
        return F.acm_mode_name(main)

    # ------------------------------------------------------------------ receive
    def _handle(self, msg: Any, now: float) -> None:
        t = msg.get_type()
        if t == "BAD_DATA":
            return
        self.stats[f"rx_{t}"] += 1
        if t == "HEARTBEAT":
            if msg.get_srcSystem() != self.conn.mav.srcSystem:
                self.last_gcs_heartbeat_s = now
            return
        handler = {"SET_MODE": self._rx_set_mode, "COMMAND_LONG": self._rx_command,
                   "SET_POSITION_TARGET_LOCAL_NED": self._setpoint,
                   "GIMBAL_MANAGER_SET_ATTITUDE": self._rx_gimbal, "PARAM_REQUEST_LIST": self._rx_param,
                   "PARAM_REQUEST_READ": self._rx_param, "PARAM_SET": self._rx_param}.get(t)
        if handler is not None and msg.target_system in (0, self.conn.mav.srcSystem):
            # only COMMAND_LONG may be broadcast (target 0); the others must name this vehicle
            if msg.target_system == self.conn.mav.srcSystem or t == "COMMAND_LONG":
                handler(msg, now)

    def _rx_set_mode(self, msg: Any, now: float) -> None:
        cm = int(msg.custom_mode)
        name = self._mode_from_custom(msg.base_mode, (cm >> 16) & 0xFF if self.autopilot == "px4" else cm,
                                      (cm >> 24) & 0xFF)
        if name:
            self._set_mode(name, now)

    def _rx_param(self, msg: Any, now: float) -> None:
        if msg.target_component in AUTOPILOT_COMPONENTS:
            self.services.on_param_message(msg)

    def _rx_command(self, msg: Any, now: float) -> None:
        p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
        if msg.target_component == CAMERA_COMPONENT:
            self.services.ack_as_camera(msg, self.services.camera_command(int(msg.command), p, now))
            self.stats["acks_sent"] += 1
            return
        if msg.target_component not in AUTOPILOT_COMPONENTS:
            return
        self.last_sender = (msg.get_srcSystem(), msg.get_srcComponent())
        result = self._command(int(msg.command), p, now)
        self.conn.mav.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        self.stats["acks_sent"] += 1

    def _rx_gimbal(self, msg: Any, now: float) -> None:
        q = list(msg.q)
        if all(math.isfinite(c) for c in q):
            roll, pitch, yaw = F.quat_to_euler(q)
            if not msg.flags & R.GIMBAL_MANAGER_FLAGS_YAW_LOCK:
                yaw += F.yaw_enu_to_ned(self.model.yaw_rad)  # vehicle-relative yaw
            self.model.point_camera(np.array([F.yaw_ned_to_enu(yaw), pitch, roll]))

    def _setpoint(self, msg: Any, now: float) -> None:
        if msg.coordinate_frame != R.MAV_FRAME_LOCAL_NED:
            self.stats["sp_bad_frame"] += 1
            return
        self.last_sp_s = now
        self.sp_times.append(now)
        mask = int(msg.type_mask)
        if self.mode != self.external_mode:
            return
        if self.autopilot == "ardupilot" and self.model.landed and not self.taking_off:
            return  # ArduCopter: take off first
        pos_ok = not mask & (R.POSITION_TARGET_TYPEMASK_X_IGNORE | R.POSITION_TARGET_TYPEMASK_Y_IGNORE
                             | R.POSITION_TARGET_TYPEMASK_Z_IGNORE)
        vel_ok = not mask & (R.POSITION_TARGET_TYPEMASK_VX_IGNORE | R.POSITION_TARGET_TYPEMASK_VY_IGNORE
                             | R.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
        vel = F.ned_to_enu([msg.vx, msg.vy, msg.vz]) if vel_ok else np.zeros(3)
        yaw = None
        if not mask & R.POSITION_TARGET_TYPEMASK_YAW_IGNORE and math.isfinite(msg.yaw):
            yaw = F.yaw_ned_to_enu(msg.yaw)
        if not (pos_ok or vel_ok):
            return
        self.sp_velocity_only = not pos_ok
        self.model.track(F.ned_to_enu([msg.x, msg.y, msg.z]) if pos_ok else None, vel, yaw)

    def _command(self, cmd: int, p: list[float], now: float) -> int:
        """Carry out a COMMAND_LONG; returns its MAV_RESULT."""
        handlers = {
            R.MAV_CMD_DO_SET_MODE: self._cmd_set_mode, R.MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm,
            R.MAV_CMD_NAV_TAKEOFF: self._cmd_takeoff, R.MAV_CMD_NAV_LAND: self._cmd_land,
            R.MAV_CMD_GET_HOME_POSITION: self._cmd_home, R.MAV_CMD_SET_MESSAGE_INTERVAL: self._cmd_interval,
            R.MAV_CMD_SET_CAMERA_ZOOM: self._cmd_zoom, R.MAV_CMD_SET_CAMERA_FOCUS: self._cmd_focus,
            R.MAV_CMD_DO_DIGICAM_CONFIGURE: self._cmd_digicam, R.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW: self._cmd_pitchyaw,
            R.MAV_CMD_REQUEST_MESSAGE: lambda p, now: self.services.request_message(int(p[0]), now),
            R.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
                lambda p, now: self.services.request_message(R.MAVLINK_MSG_ID_AUTOPILOT_VERSION, now),
            R.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: lambda p, now: self.services.configure_gimbal(p, self.last_sender),
        }
        handler = handlers.get(cmd)
        return R.MAV_RESULT_UNSUPPORTED if handler is None else handler(p, now)

    def _cmd_set_mode(self, p: list[float], now: float) -> int:
        name = self._mode_from_custom(int(p[0]), int(p[1]), int(p[2]))
        return R.MAV_RESULT_DENIED if name is None else self._set_mode(name, now)

    def _cmd_arm(self, p: list[float], now: float) -> int:
        m = self.model
        if p[0] >= 0.5:
            if not m.armed:
                m.armed = True
                m.hold_here()
                self._event("armed")
            return R.MAV_RESULT_ACCEPTED
        if not m.landed and int(p[1]) != 21196:
            return R.MAV_RESULT_DENIED  # no disarm in flight unless forced
        m.armed = False
        self.taking_off = False
        self._event("disarmed")
        return R.MAV_RESULT_ACCEPTED

    def _cmd_takeoff(self, p: list[float], now: float) -> int:
        m = self.model
        if not m.armed:
            return R.MAV_RESULT_DENIED
        alt = float(p[6]) if math.isfinite(p[6]) and p[6] > 0 else self.services.takeoff_altitude_m
        m.track(np.array([m.position_m[0], m.position_m[1], m.ground_z_m + alt]), np.zeros(3), None)
        self.taking_off = True
        self.takeoff_alt_m = m.ground_z_m + alt
        if self.autopilot == "px4":
            self.mode = "TAKEOFF"
        self._event(f"take-off to {alt:.1f} m")
        return R.MAV_RESULT_ACCEPTED

    def _cmd_land(self, p: list[float], now: float) -> int:
        return self._set_mode("LAND", now) if self.mode != "LAND" else R.MAV_RESULT_ACCEPTED

    def _cmd_home(self, p: list[float], now: float) -> int:
        self._send_home(now)
        return R.MAV_RESULT_ACCEPTED

    def _cmd_interval(self, p: list[float], now: float) -> int:
        name = {R.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "LOCAL_POSITION_NED", R.MAVLINK_MSG_ID_ATTITUDE: "ATTITUDE",
                R.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS: "GIMBAL_DEVICE_ATTITUDE_STATUS",
                R.MAVLINK_MSG_ID_CAMERA_FOV_STATUS: "CAMERA_FOV_STATUS",
                R.MAVLINK_MSG_ID_HEARTBEAT: "HEARTBEAT"}.get(int(p[0]))
        if name is None:
            return R.MAV_RESULT_UNSUPPORTED
        if p[1] > 0:
            self.intervals[name] = max(p[1] * 1e-6, 0.005)
        return R.MAV_RESULT_ACCEPTED

    def _cmd_zoom(self, p: list[float], now: float) -> int:
        if int(p[0]) != R.ZOOM_TYPE_FOCAL_LENGTH:
            return R.MAV_RESULT_UNSUPPORTED
        return _set_lens_in_range(self.model, "focal_length_mm", p[1])

    def _cmd_focus(self, p: list[float], now: float) -> int:
        if int(p[0]) != R.FOCUS_TYPE_METERS:
            return R.MAV_RESULT_UNSUPPORTED
        return _set_lens_in_range(self.model, "focus_distance_m", p[1])

    def _cmd_digicam(self, p: list[float], now: float) -> int:
        # param3 = f-stop; 0 (or less) leaves the aperture alone, as the command's other fields are
        return _set_lens_in_range(self.model, "f_number", p[2]) if p[2] > 0 else R.MAV_RESULT_ACCEPTED

    def _cmd_pitchyaw(self, p: list[float], now: float) -> int:
        m = self.model
        pitch, yaw = math.radians(p[0]), math.radians(p[1])
        if not (math.isfinite(pitch) and math.isfinite(yaw)):
            return R.MAV_RESULT_DENIED
        flags = int(p[4])
        yaw_ned = yaw if flags & R.GIMBAL_MANAGER_FLAGS_YAW_LOCK else yaw + F.yaw_enu_to_ned(m.yaw_rad)
        m.point_camera(np.array([F.yaw_ned_to_enu(yaw_ned), pitch, 0.0]))
        return R.MAV_RESULT_ACCEPTED

    # ------------------------------------------------------------------ send
    def _send_home(self, now: float = 0.0) -> None:
        """HOME_POSITION: local NED of the start point (no GPS: lat/lon/alt 0)."""
        x, y, z = (float(v) for v in F.enu_to_ned(self.home_enu))
        self.conn.mav.home_position_send(0, 0, 0, x, y, z, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
                                         int(time.time() * 1e6))

    def _send_due(self, now: float) -> None:
        m, mav = self.model, self.conn.mav
        ms = self._ms(now)
        for name, interval in self.intervals.items():
            if now < self.next_send[name]:
                continue
            self.next_send[name] = max(self.next_send[name] + interval, now - interval)
            if name == "HEARTBEAT":
                base = R.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (R.MAV_MODE_FLAG_SAFETY_ARMED if m.armed else 0)
                ap = R.MAV_AUTOPILOT_PX4 if self.autopilot == "px4" else R.MAV_AUTOPILOT_ARDUPILOTMEGA
                state = R.MAV_STATE_ACTIVE if m.armed else R.MAV_STATE_STANDBY
                mav.heartbeat_send(R.MAV_TYPE_QUADROTOR, ap, base, self._custom_mode(), state)
            elif name == "LOCAL_POSITION_NED":
                p, v = F.enu_to_ned(m.position_m), F.enu_to_ned(m.velocity_mps)
                mav.local_position_ned_send(ms, *(float(x) for x in p), *(float(x) for x in v))
            elif name == "ATTITUDE":
                mav.attitude_send(ms, m.roll_rad, m.pitch_rad, F.yaw_enu_to_ned(m.yaw_rad), 0.0, 0.0, 0.0)
            elif name == "GIMBAL_DEVICE_ATTITUDE_STATUS":
                q = F.camera_ypr_to_quat_ned(m.camera_ypr_rad)
                flags = R.GIMBAL_DEVICE_FLAGS_YAW_LOCK | R.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME
                mav.gimbal_device_attitude_status_send(0, 0, ms, flags, q, math.nan, math.nan, math.nan, 0)
            elif name == "CAMERA_FOV_STATUS":
                hfov = math.degrees(2 * math.atan(self.sensor_w / (2 * m.focal_length_mm)))
                vfov = math.degrees(2 * math.atan(self.sensor_h / (2 * m.focal_length_mm)))
                q = F.camera_ypr_to_quat_ned(m.camera_ypr_rad)
                with self.services.as_camera() as cam:
                    cam.camera_fov_status_send(ms, 0, 0, 0, 0, 0, 0, q, hfov, vfov)
            self.stats[f"tx_{name}"] += 1
        self.services.send_periodic(now)

    # ------------------------------------------------------------------ loop
    def _failsafes(self, now: float) -> None:
        m = self.model
        if self.mode == self.external_mode and self.autopilot == "px4":
            if self.last_sp_s is None or now - self.last_sp_s > self.offboard_timeout_s:
                self._event("offboard setpoint stream lost: holding (AUTO.LOITER)")
                self.mode = "LOITER"
                m.hold_here()
        if self.autopilot == "ardupilot" and self.mode == "GUIDED" and self.sp_velocity_only:
            if self.last_sp_s is not None and now - self.last_sp_s > 3.0:
                m.hold_here()
                self.sp_velocity_only = False
        if self.taking_off and self.takeoff_alt_m is not None and abs(m.position_m[2] - self.takeoff_alt_m) < 0.1:
            self.taking_off = False
            if self.autopilot == "px4" and self.mode == "TAKEOFF":
                self.mode = "LOITER"
                m.hold_here()
        if self.mode == "LAND" and m.landed and m.armed:
            m.armed = False
            self._event("landed: disarmed")

    def step(self, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        for _ in range(2000):
            try:
                msg = self.conn.recv_match(blocking=False)
            except OSError as e:
                log.warning("receive failed: %s", e)
                break
            if msg is None:
                break
            if not self.paused_link:
                self._handle(msg, now)
        dt = 0.0 if self.last_t is None else min(now - self.last_t, 0.1)
        self.last_t = now
        self._failsafes(now)
        self.model.step(dt)
        if not self.paused_link:
            self._send_due(now)

    def run(self, stop: StopSignal) -> None:
        """Step at `rate_hz`, and at once whenever bytes arrive (commands are answered without
        waiting for the next physics tick)."""
        period = 1.0 / self.rate_hz
        nxt = time.monotonic()
        fd = getattr(self.conn, "fd", None)
        while not stop.is_set():
            self.step()
            now = time.monotonic()
            if now >= nxt:
                nxt += period
                if nxt < now - 0.5:
                    nxt = now + period
            delay = max(nxt - time.monotonic(), 0.0)
            if fd is not None:
                try:
                    select.select([fd], [], [], min(delay, 0.1))
                except (OSError, ValueError):
                    stop.wait(delay)
            else:
                stop.wait(delay)

    def setpoint_rate_hz(self, window_s: float = 2.0) -> float:
        """Rate of SET_POSITION_TARGET_LOCAL_NED over the last `window_s` seconds."""
        if len(self.sp_times) < 2:
            return 0.0
        t_end = self.sp_times[-1]
        ts = [t for t in self.sp_times if t >= t_end - window_s]
        return (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 and ts[-1] > ts[0] else 0.0

    def close(self) -> None:
        self.conn.close()


def _set_lens_in_range(model, name: str, value: float) -> int:
    """Apply a lens command if the value is inside the lens's range: ACCEPTED, else DENIED."""
    lo, hi = model.lens_ranges[name]
    if not (math.isfinite(value) and lo <= value <= hi):
        return R.MAV_RESULT_DENIED
    model.set_lens(name, value)
    return R.MAV_RESULT_ACCEPTED


def build_parser() -> argparse.ArgumentParser:
    ap = nodeconfig.settings_parser(SimVehicleConfig, NODE, "cinetransfer sim-vehicle", __doc__.split("\n\n")[0])
    add_vehicle_argument(ap)
    return ap


def config_from_args(args: argparse.Namespace) -> SimVehicleConfig:
    """Defaults, then the settings (`--config`), then the flags; --vehicle over the settings' `vehicle`."""
    cfg = nodeconfig.config_from_args(SimVehicleConfig, args, NODE)
    return dataclasses.replace(cfg, vehicle=args.vehicle) if args.vehicle else cfg


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = config_from_args(args)
        vehicle = load_vehicle(cfg.vehicle or None)
        key = read_signing_key(cfg.signing_key) if cfg.signing_key else None
    except ConfigError as e:
        return report_config_error(e, "cinetransfer sim-vehicle")
    logging.basicConfig(level=getattr(logging, cfg.log_level),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    stop = StopSignal().install()  # a handler that sets an Event can deadlock (stopsignal.py)
    veh = SimVehicle(cfg.mavlink, autopilot=cfg.autopilot, system_id=cfg.system_id, start_enu=cfg.start,
                     rate_hz=cfg.rate_hz, telemetry_hz=cfg.telemetry_rate_hz,
                     offboard_timeout_s=cfg.offboard_timeout_s, vehicle=vehicle, signing_key=key)
    log.info("sim-vehicle (%s) on %s, start %s%s", cfg.autopilot, cfg.mavlink, cfg.start,
             ", MAVLink 2 signed" if key else "")
    try:
        veh.run(stop)
        log.info("received %s, stopping", stop.name())
    finally:
        veh.close()
        log.info("stopped (rx setpoints %d, acks sent %d)", veh.stats["rx_SET_POSITION_TARGET_LOCAL_NED"],
                 veh.stats["acks_sent"])
    return 0
