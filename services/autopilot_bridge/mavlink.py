"""`MavlinkBackend`: the bridge's VehiclePort for a PX4 (OFFBOARD) or ArduPilot (GUIDED) vehicle.

Speaks MAVLink 2 (common dialect) through pymavlink. Everything runs in the caller's thread:
`step()` reads what arrived, detects link loss, and sends what is due.

Out (to the vehicle):
- HEARTBEAT (MAV_TYPE_ONBOARD_CONTROLLER) at `heartbeat_rate_hz`;
- a steady SET_POSITION_TARGET_LOCAL_NED stream (position + velocity + yaw, MAV_FRAME_LOCAL_NED)
  at `setpoint_rate_hz` — also while holding (the hold target is where the vehicle was), so PX4
  stays in OFFBOARD and can be switched into it at any time;
- gimbal: GIMBAL_MANAGER_SET_ATTITUDE, earth-frame quaternion with GIMBAL_MANAGER_FLAGS_YAW_LOCK;
- lens (DESIGN §5): the camera protocol (mav_camera.py): zoom, focus and aperture commands to the
  camera component, acknowledged or resent a bounded number of times, then the axis unsupported;
- mode and arming: MAV_CMD_DO_SET_MODE (PX4 OFFBOARD = main mode 6; ArduCopter GUIDED = 4),
  MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_NAV_TAKEOFF (ArduPilot, when landed), MAV_CMD_NAV_LAND
  (mav_ownership.py: who flies the vehicle, and the land's bounded retries);
- MAV_CMD_SET_MESSAGE_INTERVAL for the telemetry below (and REQUEST_DATA_STREAM for ArduPilot).

In (into VehicleState): HEARTBEAT (mode, armed, link), LOCAL_POSITION_NED, ATTITUDE,
GIMBAL_DEVICE_ATTITUDE_STATUS, CAMERA_INFORMATION / CAMERA_FOV_STATUS / CAMERA_SETTINGS (the lens,
mav_camera.py), COMMAND_ACK. Only from the configured vehicle (mav_lock.py: ids, the udpin source
address, MAVLink 2 signing when a key is configured); everything else is dropped and counted.

Frames: world ENU z-up <-> local NED (see enu_ned.py). The vehicle's yaw is set to the camera's
yaw (the multirotor faces the shot); the gimbal gets the full earth-frame attitude.

Link loss: no message at all from the vehicle (HEARTBEAT or telemetry) for `link_timeout_s`
-> `connected` is False (the service holds
and marks its state invalid); while lost, a TCP or serial connection is reopened every
`reopen_period_s` (a UDP socket is kept: the link resumes with the next HEARTBEAT).
After a link loss the backend does not re-enter OFFBOARD/GUIDED by itself unless
`reengage_after_link_loss`; if the vehicle leaves that mode while engaged (pilot or failsafe),
the backend never takes control back on its own.
"""
from __future__ import annotations

import collections
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from cinetransfer.services.autopilot_bridge import enu_ned as F
from cinetransfer.services.autopilot_bridge.config import MavlinkConfig
from cinetransfer.services.autopilot_bridge.mav_camera import LENS_AXES, CameraLink
from cinetransfer.services.autopilot_bridge.mav_commands import CommandRetries, InFlight
from cinetransfer.services.autopilot_bridge.mav_lock import VehicleLock
from cinetransfer.services.autopilot_bridge.mav_ownership import Ownership
from cinetransfer.services.autopilot_bridge.port import VehiclePort
from cinetransfer.services.autopilot_bridge.signing import enable_signing
from cinetransfer.shared import messages as M
from cinetransfer.shared.signing_key import read_signing_key

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

mavutil.set_dialect("common")
mavlink = mavutil.mavlink
if mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # pragma: no cover - env forced to v1 before import
    raise ImportError("cinetransfer's MAVLink code needs MAVLink 2 (unset MAVLINK09 / set MAVLINK20=1)")

#: SET_POSITION_TARGET_LOCAL_NED type mask: use position, velocity and yaw; ignore accel, yaw rate
TYPEMASK_POS_VEL_YAW = (mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
                        | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
                        | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE)
RESULT_NAMES = {v: k for k, v in vars(mavlink).items() if k.startswith("MAV_RESULT_") and isinstance(v, int)}


def parse_url(url: str, baud: int) -> tuple[str, int]:
    """pymavlink device string and baud rate; also accepts 'serial:/dev/ttyX[:BAUD]'."""
    if url.startswith("serial:"):
        rest = url[len("serial:"):]
        path, _, b = rest.rpartition(":") if rest.rsplit(":", 1)[-1].isdigit() else (rest, "", "")
        return path, int(b) if b else baud
    return url, baud


def connect(url: str, *, source_system: int, source_component: int, baud: int = 921600) -> Any:
    """A pymavlink connection speaking MAVLink 2 with the common dialect."""
    url, baud = parse_url(url, baud)
    conn = mavutil.mavlink_connection(url, baud=baud, source_system=source_system,
                                      source_component=source_component, dialect="common")
    conn.mav.WIRE_PROTOCOL_VERSION = "2.0"
    return conn


@dataclass(frozen=True)
class Ack:
    """A COMMAND_ACK matched to the command we sent."""

    command: int
    result: int
    sent_s: float
    acked_s: float
    params: tuple[float, ...]

    @property
    def accepted(self) -> bool:
        return self.result == mavlink.MAV_RESULT_ACCEPTED

    @property
    def rtt_ms(self) -> float:
        return (self.acked_s - self.sent_s) * 1e3

    @property
    def result_name(self) -> str:
        return RESULT_NAMES.get(self.result, str(self.result))


class MavlinkBackend(VehiclePort):
    """PX4 / ArduPilot vehicle over MAVLink (see the module docstring)."""

    name = "mavlink"

    def __init__(self, cfg: MavlinkConfig, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.clock = clock
        self.log = logging.getLogger("cinetransfer.autopilot_bridge.mavlink")
        self.conn: Any = None
        self.t0 = clock()
        self.lock = VehicleLock(cfg.target_system, cfg.target_component)
        self.signing_key = read_signing_key(cfg.signing_key_file) if cfg.signing_key_file else None
        self.autopilot = cfg.autopilot if cfg.autopilot != "auto" else ""
        self.origin = np.asarray(cfg.local_origin_m, dtype=float)
        # link
        self.link_up = False
        self.last_heartbeat_s: float | None = None
        self.last_rx_s: float | None = None  # last message of any kind from the vehicle
        self.last_reopen_s = self.t0
        # vehicle state from telemetry
        self.mode = ""
        self.armed = False
        self.pos_ned: np.ndarray | None = None
        self.vel_ned = np.zeros(3)
        self.pos_rx_s: float | None = None
        self.pos_stamp_ns = 0
        self.rpy_ned = np.zeros(3)  # roll, pitch, yaw (NED)
        self.gimbal_ypr: np.ndarray | None = None  # world camera yaw, pitch, roll
        # what we command
        self.sp_pos_ned: np.ndarray | None = None
        self.sp_vel_ned = np.zeros(3)
        self.sp_yaw_ned = 0.0
        self.gimbal_target: np.ndarray | None = None
        self.gimbal_sent: np.ndarray | None = None
        self.gimbal_sent_s = -1e9
        self.holding = True
        self.stream_since_s: float | None = None
        self.owner = Ownership(cfg.engage_on_start, cfg.reengage_after_link_loss)
        self.takeoff_sent = False
        self._next_hb = self._next_sp = self._next_engage = self._next_arm = 0.0
        # commands and acks
        self.pending: dict[int, tuple[float, tuple[float, ...]]] = {}
        self.retries = CommandRetries(self._send_command_long, retries=cfg.command_retries,
                                      interval_s=cfg.command_retry_s)
        self.camera = CameraLink(mavlink, self.retries, component=cfg.camera_component,
                                 focal_range_mm=cfg.focal_length_range_mm, sensor_width_mm=cfg.sensor_width_mm,
                                 min_gap_s=1.0 / cfg.lens_command_rate_hz, request=self._request_message)
        self.acks: dict[int, Ack] = {}
        self.ack_rtts_ms: collections.deque[float] = collections.deque(maxlen=200)
        self.counters: collections.Counter[str] = collections.Counter(
            {"mav_setpoints_sent": 0, "mav_commands_sent": 0, "mav_acks_accepted": 0, "mav_acks_failed": 0,
             "mav_link_losses": 0, "mav_reopens": 0, "mav_mode_lost": 0, "mav_heartbeats_rx": 0,
             "mav_commands_given_up": 0})

    @property
    def target_system(self) -> int:
        return self.lock.system

    @property
    def target_component(self) -> int:
        return self.lock.component

    @property
    def engaged(self) -> bool:
        return self.owner.engaged

    # ------------------------------------------------------------------ lifecycle
    def _open(self) -> None:
        self.close()
        self.conn = connect(self.cfg.url, source_system=self.cfg.source_system,
                            source_component=self.cfg.source_component, baud=self.cfg.baud_rate)
        self.lock.attach(self.conn)
        if self.signing_key is not None:
            enable_signing(self.conn, self.signing_key)

    def start(self) -> None:
        self._open()
        deadline = self.clock() + self.cfg.connect_timeout_s
        while not self.link_up:
            now = self.clock()
            if now > deadline:
                self.close()
                raise ConnectionError(f"no autopilot HEARTBEAT on {self.cfg.url} within "
                                      f"{self.cfg.connect_timeout_s:.1f} s")
            self._send_heartbeat()
            t_end = now + 0.2
            while self.clock() < t_end and not self.link_up:
                self._poll(self.clock())
                time.sleep(0.005)
        self.log.info("connected to %s autopilot sys %d comp %d on %s (mode %s, %s)", self.autopilot,
                      self.target_system, self.target_component, self.cfg.url, self.mode,
                      "armed" if self.armed else "disarmed")

    def close(self) -> None:
        if self.conn is not None:
            try:
                self.conn.close()
            except OSError:
                pass
            self.conn = None

    @property
    def reopens_link(self) -> bool:
        """Stream links (TCP, serial) are reopened after a loss; a UDP socket has nothing to
        reopen (reopening would only drop datagrams in flight): it resumes on the next HEARTBEAT."""
        return not self.cfg.url.startswith(("udpin:", "udpout:", "udp:", "udpbcast:"))

    @property
    def connected(self) -> bool:
        return self.link_up

    # ------------------------------------------------------------------ receive
    def _poll(self, now: float) -> int:
        n = 0
        if self.conn is None:
            return 0
        while n < 1000:
            try:
                msg = self.conn.recv_match(blocking=False)
            except (OSError, ConnectionError) as e:
                self.log.warning("MAVLink receive failed: %s", e)
                break
            if msg is None:
                break
            n += 1
            self._handle(msg, now)
        return n

    def _handle(self, msg: Any, now: float) -> None:
        t = msg.get_type()
        if t == "BAD_DATA":
            return
        src, comp = msg.get_srcSystem(), msg.get_srcComponent()
        if t == "HEARTBEAT" and self._is_vehicle_heartbeat(msg, src, comp):
            self.lock.lock_address()
            self._on_heartbeat(msg, now)
            return
        if t == "HEARTBEAT" and src == self.lock.system and msg.type == mavlink.MAV_TYPE_CAMERA:
            self.camera.on_heartbeat(msg, comp)  # the camera of the vehicle (first one heard)
        if not self.lock.accepts(src, comp, self.camera.component) or t == "HEARTBEAT":
            return
        if self.link_up:
            self.last_rx_s = now  # any message from the vehicle keeps the link alive
        handler = self._TELEMETRY.get(t)
        if handler is not None:
            getattr(self, handler)(msg, now)

    #: the handler of each message type the bridge reads from the vehicle (besides HEARTBEAT)
    _TELEMETRY = {"LOCAL_POSITION_NED": "_on_position", "ATTITUDE": "_on_attitude",
                  "GIMBAL_DEVICE_ATTITUDE_STATUS": "_on_gimbal_status", "CAMERA_FOV_STATUS": "_on_fov",
                  "CAMERA_INFORMATION": "_on_camera_information", "CAMERA_SETTINGS": "_on_camera_settings",
                  "COMMAND_ACK": "_on_ack", "STATUSTEXT": "_on_statustext"}

    def _is_vehicle_heartbeat(self, msg: Any, src: int, comp: int) -> bool:
        """A HEARTBEAT of the vehicle (the first autopilot heard becomes the target); not one of a
        ground station, another companion, a gimbal or a camera."""
        if msg.type in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_TYPE_CAMERA,
                        mavlink.MAV_TYPE_GIMBAL) or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
            return False
        return self.lock.is_vehicle_heartbeat(src, comp)

    def _on_position(self, msg: Any, now: float) -> None:
        self.pos_ned = np.array([msg.x, msg.y, msg.z], dtype=float)
        self.vel_ned = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
        self.pos_rx_s = now
        self.pos_stamp_ns = M.now_ns()

    def _on_attitude(self, msg: Any, _now: float) -> None:
        self.rpy_ned = np.array([msg.roll, msg.pitch, msg.yaw], dtype=float)

    def _on_fov(self, msg: Any, _now: float) -> None:
        self.camera.on_fov(msg)

    def _on_camera_information(self, msg: Any, _now: float) -> None:
        self.camera.on_information(msg)

    def _on_camera_settings(self, msg: Any, _now: float) -> None:
        self.camera.on_settings(msg)

    def _on_statustext(self, msg: Any, _now: float) -> None:
        self.log.info("vehicle: %s", msg.text)

    def _on_heartbeat(self, msg: Any, now: float) -> None:
        self.counters["mav_heartbeats_rx"] += 1
        if not self.autopilot:
            if msg.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
                self.autopilot = "ardupilot"
            else:
                if msg.autopilot != mavlink.MAV_AUTOPILOT_PX4:
                    self.log.warning("autopilot type %d: treating it as PX4", msg.autopilot)
                self.autopilot = "px4"
        self.last_heartbeat_s = self.last_rx_s = now
        self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            self.mode = (F.px4_mode_name(msg.custom_mode) if self.autopilot == "px4"
                         else F.acm_mode_name(msg.custom_mode))
        else:
            self.mode = "UNKNOWN"
        if not self.link_up:
            self.link_up = True
            self.log.info("link up (mode %s, %s)", self.mode, "armed" if self.armed else "disarmed")
            self._request_telemetry()
        was_engaged = self.owner.engaged
        if self.owner.on_vehicle(self.mode, self.armed, self.external_mode):
            self.counters["mav_mode_lost"] += 1
            self.log.warning("vehicle left %s (now %s, %s): not taking control back", self.external_mode,
                             self.mode, "armed" if self.armed else "disarmed")
        elif self.owner.engaged and not was_engaged:
            self.log.info("engaged: %s, armed", self.external_mode)

    def _on_gimbal_status(self, msg: Any, _now: float) -> None:
        try:
            roll, pitch, yaw = F.quat_to_euler(msg.q)
        except ValueError:
            return
        flags = int(msg.flags)
        earth = bool(flags & mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME) or (
            bool(flags & mavlink.GIMBAL_DEVICE_FLAGS_YAW_LOCK)
            and not flags & mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)
        if not earth:
            yaw += float(self.rpy_ned[2])
        self.gimbal_ypr = np.array([F.yaw_ned_to_enu(yaw), pitch, roll])

    def _on_ack(self, msg: Any, now: float) -> None:
        cmd, result = int(msg.command), int(msg.result)
        if result == mavlink.MAV_RESULT_IN_PROGRESS:
            return
        f = self.retries.on_ack(cmd, msg.get_srcComponent())
        if f is not None:
            self._on_retried_ack(f, result, now)
            return
        sent = self.pending.pop(cmd, None)
        if sent is None:
            return
        ack = Ack(cmd, result, sent[0], self.clock(), sent[1])  # the receive time, not the poll's start
        self.acks[cmd] = ack
        self.ack_rtts_ms.append(ack.rtt_ms)
        if ack.accepted:
            self.counters["mav_acks_accepted"] += 1
            p = sent[1]
            # provisional until the next HEARTBEAT confirms it (saves a second when engaging)
            if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                self.armed = p[0] >= 0.5
            elif cmd == mavlink.MAV_CMD_DO_SET_MODE and self.autopilot == "px4":
                self.mode = F.px4_mode_name(F.px4_custom_mode(int(p[1]), int(p[2])))
            elif cmd == mavlink.MAV_CMD_DO_SET_MODE:
                self.mode = F.acm_mode_name(int(p[1]))
        else:
            self.counters["mav_acks_failed"] += 1
            self.log.warning("command %d refused: %s", cmd, ack.result_name)

    def _on_retried_ack(self, f: InFlight, result: int, now: float) -> None:
        """The answer to a lens or land command (sent with bounded retries)."""
        ok = result == mavlink.MAV_RESULT_ACCEPTED
        self.counters["mav_acks_accepted" if ok else "mav_acks_failed"] += 1
        ack = self.acks[f.command] = Ack(f.command, result, f.sent_s, self.clock(), f.params)
        self.ack_rtts_ms.append(ack.rtt_ms)
        if f.key in LENS_AXES:
            self.camera.on_ack(f, result, now)
        elif ok and self.owner.land in ("sent", "mode sent"):
            self.owner.land = "accepted"
        elif not ok:
            self.log.warning("%s refused: %s", f.key, RESULT_NAMES.get(result, result))
            self._land_fallback(f, f"refused: {RESULT_NAMES.get(result, result)}", now)

    def _on_given_up(self, f: InFlight, now: float) -> None:
        self.counters["mav_commands_given_up"] += 1
        self.log.warning("command %d (%s) not acknowledged after %d tries: giving up", f.command, f.key, f.tries)
        if f.key in LENS_AXES:
            self.camera.on_gave_up(f)
        else:
            self._land_fallback(f, f"not acknowledged after {f.tries} tries", now)

    def _land_fallback(self, f: InFlight, why: str, now: float) -> None:
        """NAV_LAND was not taken: ask for the land mode instead; that not taken either, report it."""
        if not self.owner.landing or self.owner.land == "landing":
            return
        if f.key == "land":
            self.owner.land = "mode sent"
            ardu = self.autopilot == "ardupilot"
            mode = (F.ACM_MODES["LAND"], 0) if ardu else (F.PX4_MAIN["AUTO"], F.PX4_AUTO_SUB["LAND"])
            self.retries.send("land_mode", mavlink.MAV_CMD_DO_SET_MODE,
                              (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, *mode), self.target_component, now)
            self.log.warning("NAV_LAND %s: asking for the land mode", why)
        else:
            self.owner.land = f"not taken: NAV_LAND and the land mode {why}"
            self.log.error("land not taken: %s", self.owner.land)

    # ------------------------------------------------------------------ send
    def _ms(self) -> int:
        return int((self.clock() - self.t0) * 1000) & 0xFFFFFFFF

    def _send_heartbeat(self) -> None:
        self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                     mavlink.MAV_STATE_ACTIVE)

    def send_command(self, command: int, *params: float, component: int | None = None) -> None:
        """COMMAND_LONG to the vehicle (7 params; missing ones are 0); the ack is matched later."""
        p = tuple(float(x) for x in params) + (0.0,) * (7 - len(params))
        comp = self.target_component if component is None else component
        self._send_command_long(command, p, comp, 0)
        self.pending[command] = (self.clock(), p)

    def _send_command_long(self, command: int, params: tuple[float, ...], component: int, confirmation: int) -> None:
        if self.conn is None:
            return
        comp = component or self.target_component
        self.conn.mav.command_long_send(self.target_system, comp, command, confirmation, *params)
        self.counters["mav_commands_sent"] += 1

    def _request_message(self, msg_id: int, component: int) -> None:
        """MAV_CMD_REQUEST_MESSAGE (its ack is not tracked: several share one command id)."""
        self._send_command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, (msg_id, 0, 0, 0, 0, 0, 0), component, 0)

    def wait_ack(self, command: int, timeout_s: float = 2.0) -> Ack | None:
        """Poll until the COMMAND_ACK of `command` arrives (tests, benchmarks, start-up)."""
        deadline = self.clock() + timeout_s
        while self.clock() < deadline:
            self._poll(self.clock())
            if command not in self.pending and command in self.acks:
                return self.acks[command]
            time.sleep(0.0002)
        return None

    def _request_telemetry(self) -> None:
        hz = self.cfg.telemetry_rate_hz
        if hz <= 0 or self.conn is None:
            return
        for msg_id, rate in ((mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, hz), (mavlink.MAVLINK_MSG_ID_ATTITUDE, hz),
                             (mavlink.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS, min(hz, 20.0)),
                             (mavlink.MAVLINK_MSG_ID_CAMERA_FOV_STATUS, min(hz, 5.0))):
            # several SET_MESSAGE_INTERVALs share one command id: don't track their acks
            self.conn.mav.command_long_send(self.target_system, self.target_component,
                                            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 1e6 / rate,
                                            0, 0, 0, 0, 0)
        if self.autopilot == "ardupilot":
            self.conn.mav.request_data_stream_send(self.target_system, self.target_component,
                                                   mavlink.MAV_DATA_STREAM_ALL, int(hz), 1)
        self._request_camera_telemetry()

    def _request_camera_telemetry(self) -> None:
        """The lens read-back comes from the camera itself (when it is not the autopilot)."""
        comp = self.camera.component
        if not comp or comp == self.target_component or self.conn is None:
            return
        self.conn.mav.command_long_send(self.target_system, comp, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                        mavlink.MAVLINK_MSG_ID_CAMERA_FOV_STATUS, 2e5, 0, 0, 0, 0, 0)
        self.camera.on_link_up()

    def _send_setpoint(self) -> None:
        assert self.sp_pos_ned is not None
        p, v = self.sp_pos_ned, self.sp_vel_ned
        self.conn.mav.set_position_target_local_ned_send(
            self._ms(), self.target_system, self.target_component, mavlink.MAV_FRAME_LOCAL_NED,
            TYPEMASK_POS_VEL_YAW, float(p[0]), float(p[1]), float(p[2]), float(v[0]), float(v[1]), float(v[2]),
            0.0, 0.0, 0.0, float(self.sp_yaw_ned), 0.0)
        self.counters["mav_setpoints_sent"] += 1

    def _send_gimbal(self, now: float) -> None:
        assert self.gimbal_target is not None
        q = F.camera_ypr_to_quat_ned(self.gimbal_target)
        nan = float("nan")
        self.conn.mav.gimbal_manager_set_attitude_send(
            self.target_system, self.target_component, mavlink.GIMBAL_MANAGER_FLAGS_YAW_LOCK,
            self.cfg.gimbal_device_id, q, nan, nan, nan)
        self.gimbal_sent = self.gimbal_target.copy()
        self.gimbal_sent_s = now

    @property
    def external_mode(self) -> str:
        return "GUIDED" if self.autopilot == "ardupilot" else "OFFBOARD"

    def _engage_step(self, now: float) -> None:
        """Mode and arming commands while engaging; a step that sent any is one bounded attempt."""
        sent = self.counters["mav_commands_sent"]
        self._engage_commands(now)
        if self.counters["mav_commands_sent"] > sent:
            self.owner.attempted()

    def _engage_commands(self, now: float) -> None:
        if now < self._next_engage:
            return
        self._next_engage = now + 1.0
        if self.autopilot == "ardupilot":
            if self.mode != "GUIDED":
                self.send_command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                  F.ACM_MODES["GUIDED"])
            elif not self.armed:
                self.send_command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            elif self._landed() and not self.takeoff_sent:
                self.send_command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, self.cfg.takeoff_altitude_m)
                self.takeoff_sent = True
            return
        if self.engaged:
            return
        # PX4 refuses OFFBOARD unless setpoints already stream (> 2 Hz): stream first, then switch
        if self.mode != "OFFBOARD":
            if self.stream_since_s is not None and now - self.stream_since_s >= 0.5:
                self.send_command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                  F.PX4_MAIN["OFFBOARD"], 0)
            else:
                self._next_engage = now + 0.1
        if not self.armed and now >= self._next_arm:
            self._next_arm = now + 1.0
            self.send_command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def _taking_off_while_holding(self) -> bool:
        """ArduPilot: a 'stay here' target sent during NAV_TAKEOFF would cancel the climb."""
        return (self.autopilot == "ardupilot" and self.holding and self.takeoff_sent and self.pos_ned is not None
                and -self.pos_ned[2] < 0.9 * self.cfg.takeoff_altitude_m)

    def _landed(self) -> bool:
        return self.pos_ned is None or -self.pos_ned[2] < 0.3

    # ------------------------------------------------------------------ VehiclePort
    def apply(self, setpoint: M.Setpoint) -> None:
        if self.owner.landing:
            self.hold()  # a land was asked for: never fly the plan again on our own
            return
        self.holding = False
        self.sp_pos_ned = F.enu_to_ned(np.asarray(setpoint.position_m, float) - self.origin)
        self.sp_vel_ned = F.enu_to_ned(setpoint.velocity_mps)
        ypr = np.asarray(setpoint.camera_ypr_rad, float)
        self.sp_yaw_ned = F.yaw_enu_to_ned(float(ypr[0]))
        self.gimbal_target = ypr.copy()
        if self.link_up:
            now = self.clock()
            for axis in LENS_AXES:
                self.camera.want(axis, float(getattr(setpoint.lens, axis)), now)

    def hold(self) -> None:
        self.holding = True
        if self.pos_ned is not None:
            self.sp_pos_ned = self.pos_ned.copy()
            self.sp_yaw_ned = float(self.rpy_ned[2])
        self.sp_vel_ned = np.zeros(3)

    def command(self, action: str, args: dict) -> bool:
        if self.conn is None:
            return False
        if action == "engage":
            self.owner.engage()
            self.takeoff_sent = False
            self._next_engage = 0.0
        elif action == "arm":
            self.send_command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        elif action == "disarm":
            self.owner.disarm()
            self.send_command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        elif action == "takeoff":
            alt = float(args.get("altitude_m", self.cfg.takeoff_altitude_m))
            self.send_command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, alt)
        elif action == "land":
            self.owner.start_land()
            self.retries.cancel("land_mode")
            self.retries.send("land", mavlink.MAV_CMD_NAV_LAND, (0, 0, 0, math.nan, 0, 0, 0), self.target_component,
                              self.clock())
            self.hold()
        else:
            return False
        return True

    def step(self, now_s: float) -> None:
        now = now_s
        if self.conn is None and not self._reopen(now):  # (a failed reopen left no link: retried in turn)
            return
        self._poll(now)
        if not self._keep_link(now) or self.conn is None:
            return
        if now >= self._next_hb:
            self._next_hb = now + 1.0 / self.cfg.heartbeat_rate_hz
            self._send_heartbeat()
        if not self.link_up:
            return
        self._stream(now)
        for f in self.retries.step(now):
            self._on_given_up(f, now)
        # ArduCopter is GUIDED and armed before its take-off: engaging ends with the climb
        if self.owner.engaging or (self.owner.engaged and self.autopilot == "ardupilot"):
            self._engage_step(now)

    def _keep_link(self, now: float) -> bool:
        """Notice a lost link (nothing from the vehicle for link_timeout_s) and reopen a stream link
        now and then; False when a reopen failed (nothing more to do this step)."""
        if self.link_up and (self.last_rx_s is None or now - self.last_rx_s > self.cfg.link_timeout_s):
            self.link_up = False
            self.counters["mav_link_losses"] += 1
            self.owner.on_link_lost()
            self.stream_since_s = None
            self.last_reopen_s = now
            self.log.warning("link lost: nothing from the vehicle for %.1f s", self.cfg.link_timeout_s)
        if not self.link_up and self.reopens_link:
            return self._reopen(now)
        return True

    def _reopen(self, now: float) -> bool:
        """Open the link again, at most once per reopen_period_s; False while there is none. A
        vehicle that is not listening yet (rebooting) is a warning, never an exception out of step."""
        if now - self.last_reopen_s <= self.cfg.reopen_period_s:
            return self.conn is not None
        self.last_reopen_s = now
        self.counters["mav_reopens"] += 1
        self.log.info("reopening %s", self.cfg.url)
        try:
            self._open()
        except (OSError, ConnectionError) as e:
            self.log.warning("reopen failed: %s", e)
            self.conn = None
            return False
        return True

    def _stream(self, now: float) -> None:
        """What flows while the link is up: the position setpoint at its rate, the gimbal target
        when it changed (or once a second)."""
        if self.sp_pos_ned is None and self.pos_ned is not None:
            self.hold()  # stream 'stay here' from the start
        if self.sp_pos_ned is not None and now >= self._next_sp and not self._taking_off_while_holding():
            self._next_sp = max(self._next_sp + 1.0 / self.cfg.setpoint_rate_hz, now - 0.5 / self.cfg.setpoint_rate_hz)
            self._send_setpoint()
            if self.stream_since_s is None:
                self.stream_since_s = now
        if self.gimbal_target is not None and (
                self.gimbal_sent is None or now - self.gimbal_sent_s > 1.0
                or (np.max(np.abs(self.gimbal_target - self.gimbal_sent)) > 1e-3 and now - self.gimbal_sent_s > 0.05)):
            self._send_gimbal(now)

    def vehicle_state(self) -> M.VehicleState:
        now = self.clock()
        fresh = self.pos_rx_s is not None and now - self.pos_rx_s < self.cfg.link_timeout_s
        pos = self.origin + F.ned_to_enu(self.pos_ned) if self.pos_ned is not None else self.origin.copy()
        vel = F.ned_to_enu(self.vel_ned)
        roll, pitch, yaw = (float(x) for x in self.rpy_ned)
        att = np.array([F.yaw_ned_to_enu(yaw), pitch, roll])
        cam = self.gimbal_ypr if self.gimbal_ypr is not None else np.array([att[0], 0.0, 0.0])
        focal, focus, f_number = self.camera.lens()
        lens = M.LensState(focal_length_mm=focal, focus_distance_m=focus, f_number=f_number,
                           sensor_width_mm=self.cfg.sensor_width_mm, sensor_height_mm=self.cfg.sensor_height_mm,
                           coc_mm=self.cfg.coc_mm)
        return M.VehicleState(stamp_ns=self.pos_stamp_ns or M.now_ns(), valid=bool(self.link_up and fresh),
                              position_m=pos, velocity_mps=vel, attitude_ypr_rad=att, camera_ypr_rad=cam.copy(),
                              lens=lens, mode=self.mode, armed=self.armed, holding=self.holding, backend="mavlink",
                              lens_unsupported=sorted(self.camera.unsupported))

    def health_counters(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self.counters)
        out.update(mav_link=self.link_up, mav_mode=self.mode, mav_armed=self.armed, mav_engaged=self.engaged,
                   mav_autopilot=self.autopilot, mav_owner=self.owner.state, mav_owner_reason=self.owner.reason,
                   mav_land=self.owner.land, mav_signing=self.signing_key is not None)
        out.update(self.camera.counters())
        out.update(self.lock.counters(self.conn))
        if self.ack_rtts_ms:
            out["mav_ack_rtt_ms_median"] = float(np.median(self.ack_rtts_ms))
        return out
