"""The lens over MAVLink, as cameras speak the camera protocol.

- Which component is the camera: `camera_component` when configured, else the first HEARTBEAT of
  type MAV_TYPE_CAMERA from the vehicle's system; until one is heard, lens commands go to the
  autopilot (which may forward them). CAMERA_INFORMATION is requested from it (REQUEST_MESSAGE).
- Zoom: MAV_CMD_SET_CAMERA_ZOOM by focal length (ZOOM_TYPE_FOCAL_LENGTH) first; a camera that
  refuses it (DENIED / UNSUPPORTED) is zoomed by range (ZOOM_TYPE_RANGE, 0..100 %) over the
  vehicle profile's focal-length range (CAMERA_INFORMATION carries one focal length, no range).
- Focus: MAV_CMD_SET_CAMERA_FOCUS in metres (FOCUS_TYPE_METERS). Aperture: MAV_CMD_DO_DIGICAM_CONFIGURE
  param3 = f-stop (MAVLink has no dedicated aperture command).
- Read back: CAMERA_FOV_STATUS (focal length from the horizontal field of view) and
  CAMERA_SETTINGS (zoomLevel in %, when zooming by range), requested from the camera itself;
  else the value of the last accepted command.
- A command with no acknowledgement is resent a bounded number of times (mav_commands.py); then,
  or when the camera answers UNSUPPORTED, its axis is unsupported: never commanded again, and
  listed in VehicleState.lens_unsupported so that the planner keeps that axis fixed.
"""
from __future__ import annotations

import logging
import math
from typing import Any, Callable

from cinetransfer.services.autopilot_bridge.mav_commands import CommandRetries, InFlight
from cinetransfer.shared.camera import LENS_HOLD

LENS_AXES = ("focal_length_mm", "focus_distance_m", "f_number")
#: a change smaller than this is not sent (focus: relative, x max(1, value)): the lens's hold, which the
#: report's reach search also uses
LENS_EPS = LENS_HOLD


class CameraLink:
    """Lens commands, their acknowledgements and the lens state read back (see the module docstring)."""

    def __init__(self, mav: Any, commands: CommandRetries, *, component: int, focal_range_mm: tuple[float, float],
                 sensor_width_mm: float, min_gap_s: float, request: Callable[[int, int], None]) -> None:
        self.R = mav  # the pymavlink dialect module (constants)
        self.commands = commands
        self.configured = component
        self.component = component  # 0 = not known: the autopilot's component is addressed
        self.focal_range = focal_range_mm
        self.sensor_width_mm = sensor_width_mm
        self.min_gap_s = min_gap_s
        self.request = request  # request(message id, component)
        self.log = logging.getLogger("cinetransfer.autopilot_bridge.camera")
        self.info: dict[str, Any] = {}
        self.zoom_by_range = False
        self.unsupported: dict[str, str] = {}
        self.sent: dict[str, float] = {}
        self.sent_s: dict[str, float] = {}
        self.wanted: dict[str, float] = {}
        self.acked = {a: math.nan for a in LENS_AXES}
        self.focal_from_fov = math.nan
        self.focal_from_zoom = math.nan
        self.refused = 0

    # ------------------------------------------------------------------ discovery and read-back
    def on_heartbeat(self, msg: Any, src_component: int) -> None:
        if self.component or msg.type != self.R.MAV_TYPE_CAMERA:
            return
        self.component = src_component
        self.log.info("camera found: component %d", src_component)
        self.request(self.R.MAVLINK_MSG_ID_CAMERA_INFORMATION, src_component)

    def on_link_up(self) -> None:
        if self.component:
            self.request(self.R.MAVLINK_MSG_ID_CAMERA_INFORMATION, self.component)

    def on_information(self, msg: Any) -> None:
        flags = int(msg.flags)
        self.info = {"vendor": bytes(msg.vendor_name).rstrip(b"\0").decode(errors="replace"),
                     "model": bytes(msg.model_name).rstrip(b"\0").decode(errors="replace"),
                     "focal_length_mm": float(msg.focal_length), "flags": flags}
        self.log.info("camera %s %s, focal length %.1f mm, flags 0x%x", self.info["vendor"], self.info["model"],
                      self.info["focal_length_mm"], flags)

    def on_fov(self, msg: Any) -> None:
        hfov = float(msg.hfov)
        if math.isfinite(hfov) and 0.0 < hfov < 180.0:
            self.focal_from_fov = self.sensor_width_mm / (2.0 * math.tan(math.radians(hfov) / 2.0))

    def on_settings(self, msg: Any) -> None:
        z = float(msg.zoomLevel)
        if self.zoom_by_range and math.isfinite(z) and 0.0 <= z <= 100.0:
            lo, hi = self.focal_range
            self.focal_from_zoom = lo + z / 100.0 * (hi - lo)

    def lens(self) -> tuple[float, float, float]:
        """(focal length, focus distance, f-number) as read back, NaN where unknown."""
        focal = next((f for f in (self.focal_from_fov, self.focal_from_zoom, self.acked["focal_length_mm"])
                      if math.isfinite(f)), math.nan)
        return focal, self.acked["focus_distance_m"], self.acked["f_number"]

    # ------------------------------------------------------------------ commands
    def want(self, axis: str, value: float, now: float) -> None:
        """The planner's lens value: sent when it changed enough and the axis's rate allows."""
        if axis in self.unsupported or not math.isfinite(value):
            return
        self.wanted[axis] = value
        last = self.sent.get(axis)
        scale = max(1.0, last) if axis == "focus_distance_m" and last is not None else 1.0
        if last is not None and abs(value - last) <= LENS_EPS[axis] * scale:
            return
        if now - self.sent_s.get(axis, -1e9) < self.min_gap_s or self.commands.pending(axis) is not None:
            return  # the next call sends the newest value
        self._send(axis, value, now)

    def _send(self, axis: str, value: float, now: float) -> None:
        R = self.R
        if axis == "focal_length_mm" and self.zoom_by_range:
            lo, hi = self.focal_range
            pct = min(max((value - lo) / (hi - lo) * 100.0, 0.0), 100.0)
            cmd, params = R.MAV_CMD_SET_CAMERA_ZOOM, (R.ZOOM_TYPE_RANGE, pct)
        elif axis == "focal_length_mm":
            cmd, params = R.MAV_CMD_SET_CAMERA_ZOOM, (R.ZOOM_TYPE_FOCAL_LENGTH, value)
        elif axis == "focus_distance_m":
            cmd, params = R.MAV_CMD_SET_CAMERA_FOCUS, (R.FOCUS_TYPE_METERS, value)
        else:  # param1 mode, param2 shutter, param3 aperture (f-stop); 0 = unchanged
            cmd, params = R.MAV_CMD_DO_DIGICAM_CONFIGURE, (0, 0, value)
        self.commands.send(axis, cmd, params, self.component, now)
        self.sent[axis] = value
        self.sent_s[axis] = now

    def on_ack(self, f: InFlight, result: int, now: float) -> None:
        """The camera's answer to a lens command."""
        R, axis = self.R, f.key
        if result == R.MAV_RESULT_ACCEPTED:
            self.acked[axis] = self.sent[axis]
            return
        if axis == "focal_length_mm" and not self.zoom_by_range and \
                result in (R.MAV_RESULT_DENIED, R.MAV_RESULT_UNSUPPORTED):
            self.zoom_by_range = True
            self.log.info("camera refuses zoom by focal length: zooming by range over %.0f-%.0f mm",
                          *self.focal_range)
            if self.component:
                self.request(R.MAVLINK_MSG_ID_CAMERA_SETTINGS, self.component)
            self._send(axis, self.sent[axis], now)
        elif result == R.MAV_RESULT_UNSUPPORTED:
            self.mark_unsupported(axis, "camera answered UNSUPPORTED")
        else:
            self.refused += 1
            self.log.warning("camera refused %s = %g: result %d", axis, self.sent[axis], result)

    def on_gave_up(self, f: InFlight) -> None:
        self.mark_unsupported(f.key, f"no acknowledgement after {f.tries} tries")

    def mark_unsupported(self, axis: str, why: str) -> None:
        if axis not in self.unsupported:
            self.unsupported[axis] = why
            self.log.warning("lens %s unsupported by the camera (component %d): %s; holding it fixed",
                             axis, self.component, why)

    def counters(self) -> dict[str, Any]:
        return {"mav_camera_component": self.component, "mav_zoom_by_range": self.zoom_by_range,
                "mav_lens_unsupported": ",".join(sorted(self.unsupported)), "mav_lens_refused": self.refused}
