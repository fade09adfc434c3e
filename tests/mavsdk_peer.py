"""MAVSDK (the `mavsdk` PyPI package, C++ MAVSDK in-process) as the third party of the MAVLink tests.

`MavsdkAutopilot`: an autopilot written with MAVSDK's server plugins (TelemetryServer,
ActionServer, ParamServer, MavlinkDirectServer) and, on component 100, a CameraServer. Its
'vehicle' is kinematic on purpose: it jumps to each SET_POSITION_TARGET_LOCAL_NED it receives
while in OFFBOARD, so what the tests check is the protocol, not a controller. MAVSDK makes every
protocol decision itself (which commands it acknowledges, what it answers); this file only
records what arrived and publishes the state.
"""
from __future__ import annotations

import json
import threading
import time
from typing import Any

import mavsdk
from mavsdk.plugins.action_server import ActionServer, AllowableFlightModes, FlightMode
from mavsdk.plugins.camera_server import CameraFeedback, CameraServer, Information
from mavsdk.plugins.mavlink_direct_server import MavlinkDirectServer
from mavsdk.plugins.param_server import ParamServer
from mavsdk.plugins.telemetry_server import (PositionNed, PositionVelocityNed, TelemetryServer, VelocityNed)


class MavsdkAutopilot:
    """MAVSDK autopilot (system 1, component 1) with a MAVSDK camera (component 100)."""

    def __init__(self, url: str, *, start_ned=(0.0, 0.0, -3.0), camera: bool = True) -> None:
        self.mavsdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.AUTOPILOT))
        result = self.mavsdk.add_any_connection(url)
        if int(result) != 0:
            raise ConnectionError(f"MAVSDK could not open {url}: {result}")
        self.lock = threading.Lock()
        self.pos = list(start_ned)
        self.setpoints: list[dict] = []
        self.gimbal: list[dict] = []
        self.commands: list[tuple[str, float]] = []  # what MAVSDK handed to us, in order
        self.mode = FlightMode.HOLD
        self.armed = False
        ap = self.mavsdk.server_component()
        self.telemetry = TelemetryServer(ap)
        self.action = ActionServer(ap)
        self.params = ParamServer(ap)
        self.params.provide_param_float("MIS_TAKEOFF_ALT", 2.5)
        self.direct = MavlinkDirectServer(ap)
        self.action.set_armable(True, True)
        self.action.set_disarmable(True, True)
        self.action.set_allow_takeoff(True)
        self.action.set_allowable_flight_modes(AllowableFlightModes(True, True, True, True, True, True, True))
        self.action.subscribe_arm_disarm(self._on_arm)
        self.action.subscribe_flight_mode_change(self._on_mode)
        self.direct.subscribe_message("SET_POSITION_TARGET_LOCAL_NED", self._on_setpoint)
        self.direct.subscribe_message("GIMBAL_MANAGER_SET_ATTITUDE", self._on_gimbal)
        self.camera: CameraServer | None = None
        if camera:
            cam = self.mavsdk.server_component_by_type(mavsdk.ComponentType.CAMERA, 0)
            self.camera = CameraServer(cam)
            self.camera.set_information(Information(vendor_name="MAVSDK", model_name="CameraServer",
                                                    focal_length_mm=35.0, horizontal_sensor_size_mm=23.76,
                                                    vertical_sensor_size_mm=13.365, horizontal_resolution_px=1920,
                                                    vertical_resolution_px=1080))
            self.camera.subscribe_zoom_range(self._on_zoom_range)
            self.camera.subscribe_focus_meters(self._on_focus_meters)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._publish, daemon=True)
        self.thread.start()

    # MAVSDK calls these from its own threads
    def _on_arm(self, result: Any, arm: Any, _ud: Any) -> None:
        with self.lock:
            self.armed = bool(getattr(arm, "arm", False))
            self.commands.append(("arm", float(self.armed)))

    def _on_mode(self, result: Any, mode: int, _ud: Any) -> None:
        with self.lock:
            self.mode = FlightMode(mode)
            self.commands.append(("mode", float(mode)))

    def _on_setpoint(self, msg: Any, _ud: Any) -> None:
        f = json.loads(msg.fields_json)
        with self.lock:
            self.setpoints.append(f)
            if self.mode == FlightMode.OFFBOARD and self.armed:
                self.pos = [float(f["x"]), float(f["y"]), float(f["z"])]

    def _on_gimbal(self, msg: Any, _ud: Any) -> None:
        with self.lock:
            self.gimbal.append(json.loads(msg.fields_json))

    def _on_zoom_range(self, value: float, _ud: Any) -> None:
        with self.lock:
            self.commands.append(("zoom_range", float(value)))
        self.camera.respond_zoom_range(CameraFeedback.OK)

    def _on_focus_meters(self, value: float, _ud: Any) -> None:
        with self.lock:
            self.commands.append(("focus_meters", float(value)))
        self.camera.respond_focus_meters(CameraFeedback.OK)

    def _publish(self) -> None:
        while not self.stop.wait(0.05):
            with self.lock:
                n, e, d = self.pos
            self.telemetry.publish_position_velocity_ned(
                PositionVelocityNed(PositionNed(n, e, d), VelocityNed(0.0, 0.0, 0.0)))

    def count(self, name: str) -> int:
        with self.lock:
            return sum(1 for c in self.commands if c[0] == name)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2)
        self.mavsdk.destroy()


def wait_for(cond, timeout_s: float, what: str, poll=None) -> None:
    """Wait on a condition with a generous deadline; `poll()` runs in between (drives a backend)."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        if poll is not None:
            poll()
        time.sleep(0.01)
