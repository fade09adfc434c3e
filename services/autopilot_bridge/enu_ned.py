"""Frame conversions between cinetransfer's world frame and MAVLink's local NED frame.

World (cinetransfer.shared.messages): ENU, x east, y north, z up; camera/vehicle attitude as
(yaw about +z from +x counter-clockwise, pitch positive looking up, roll about the forward axis).
MAVLink local frame: NED, x north, y east, z down; attitude as aerospace Euler angles of a
forward-right-down body (roll, pitch nose-up positive, yaw from north clockwise).

    x_ned = y_enu,  y_ned = x_enu,  z_ned = -z_enu       (the same swap maps NED back to ENU)
    yaw_ned = pi/2 - yaw_enu                              (and back: yaw_enu = pi/2 - yaw_ned)
    pitch and roll keep their sign: 'nose up' and 'right side down' are the same physical
    rotations in a forward-left-up and a forward-right-down body.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from cinetransfer.shared.angles import wrap_angle as wrap


def enu_to_ned(v: Sequence[float]) -> np.ndarray:
    """A position/velocity vector from world ENU to NED."""
    return np.array([v[1], v[0], -v[2]], dtype=float)


def ned_to_enu(v: Sequence[float]) -> np.ndarray:
    """A position/velocity vector from NED to world ENU."""
    return np.array([v[1], v[0], -v[2]], dtype=float)


def yaw_enu_to_ned(yaw_enu: float) -> float:
    return wrap(math.pi / 2 - yaw_enu)


def yaw_ned_to_enu(yaw_ned: float) -> float:
    return wrap(math.pi / 2 - yaw_ned)


def euler_to_quat(roll: float, pitch: float, yaw: float) -> list[float]:
    """Quaternion [w, x, y, z] of aerospace ZYX Euler angles (NED / FRD, MAVLink's order)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]


def quat_to_euler(q: Sequence[float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a quaternion [w, x, y, z] (aerospace ZYX)."""
    w, x, y, z = (float(c) for c in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if n == 0 or not math.isfinite(n):
        raise ValueError(f"invalid quaternion {list(q)!r}")
    w, x, y, z = w / n, x / n, y / n, z / n
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def camera_ypr_to_quat_ned(ypr_enu: Sequence[float]) -> list[float]:
    """World camera (yaw, pitch, roll) -> earth-frame NED quaternion for the gimbal manager."""
    yaw, pitch, roll = (float(a) for a in ypr_enu)
    return euler_to_quat(roll, pitch, yaw_enu_to_ned(yaw))


def quat_ned_to_camera_ypr(q: Sequence[float]) -> np.ndarray:
    """Earth-frame NED quaternion -> world camera (yaw, pitch, roll)."""
    roll, pitch, yaw = quat_to_euler(q)
    return np.array([yaw_ned_to_enu(yaw), pitch, roll])


# --------------------------------------------------------------------------- PX4 modes
#: PX4 custom main modes and AUTO sub modes (px4/src/modules/commander/px4_custom_mode.h)
PX4_MAIN = {"MANUAL": 1, "ALTCTL": 2, "POSCTL": 3, "AUTO": 4, "ACRO": 5, "OFFBOARD": 6, "STABILIZED": 7}
PX4_AUTO_SUB = {"READY": 1, "TAKEOFF": 2, "LOITER": 3, "MISSION": 4, "RTL": 5, "LAND": 6}

#: ArduCopter custom modes used here
ACM_MODES = {"STABILIZE": 0, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9, "BRAKE": 17}


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """HEARTBEAT.custom_mode of a PX4 mode (main mode in byte 2, sub mode in byte 3)."""
    return (main << 16) | (sub << 24)


def px4_mode_name(custom_mode: int) -> str:
    """'OFFBOARD', 'LOITER' (AUTO.LOITER, 'Hold'), 'POSCTL', ... of a PX4 custom_mode."""
    main = (custom_mode >> 16) & 0xFF
    sub = (custom_mode >> 24) & 0xFF
    if main == PX4_MAIN["AUTO"]:
        for name, s in PX4_AUTO_SUB.items():
            if s == sub:
                return name
        return f"AUTO_{sub}"
    for name, m in PX4_MAIN.items():
        if m == main:
            return name
    return f"MODE_{main}_{sub}"


def acm_mode_name(custom_mode: int) -> str:
    for name, m in ACM_MODES.items():
        if m == custom_mode:
            return name
    return f"MODE_{custom_mode}"
