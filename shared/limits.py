"""The vehicle's limits as config fields: each declared once, under the profile's name, with the
default profile's number as its default.

`VehicleProfile.limits()` gives every limit under its one name (LIMIT_NAMES: the profile's own
names, a [min, max] pair split into `_min_` / `_max_`, angles in radians). The groups below
(MotionLimits, EnvelopeLimits, GimbalLimits, GimbalRateLimits, LensLimits, LensRateLimits) declare
each as a field whose default is read from the default profile (`profile_field`). The planner's
Bounds, the bridge's SafetyConfig and the simulator's DynamicsLimits inherit the groups they bound
and `from_vehicle` fills them (`vehicle_fields`): no number and no name is typed twice.
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any, Callable

from cinetransfer.shared.vehicle import VehicleProfile, load_vehicle

LIMIT_NAMES: tuple[str, ...] = (
    "speed_max_mps", "climb_max_mps", "accel_max_mps2", "geofence_shape", "geofence_radius_m",
    "geofence_half_extent_m", "altitude_min_m", "altitude_max_m", "min_subject_distance_m", "min_obstacle_distance_m",
    "pitch_min_rad", "pitch_max_rad", "roll_max_rad", "yaw_rate_radps", "pitch_rate_radps", "roll_rate_radps",
    "focal_length_min_mm", "focal_length_max_mm", "focal_rate_mmps", "focus_distance_min_m",
    "focus_distance_max_m", "focus_rate_mps", "f_number_min", "f_number_max", "f_number_rate_ps")


def vehicle_fields(cls: type, v: VehicleProfile) -> dict[str, Any]:
    """The limits of `v` that config dataclass `cls` has a field for, by field name."""
    limits = v.limits()
    return {f.name: limits[f.name] for f in dataclasses.fields(cls) if f.name in limits}


def profile_default(name: str) -> Callable[[], Any]:
    """A dataclass default_factory: limit `name` of the default profile (read when first needed)."""
    if name not in LIMIT_NAMES:
        raise ValueError(f"{name!r} is not a vehicle limit; the limits: {', '.join(LIMIT_NAMES)}")
    return lambda: _default_limits()[name]


def profile_field(name: str) -> Any:
    """A dataclass field whose default is limit `name` of the default profile."""
    return dataclasses.field(default_factory=profile_default(name))


@functools.cache
def _default_limits() -> dict[str, Any]:
    return load_vehicle().limits()


# -- the limits as config fields, each declared once under its one name ------------------------
# The planner's Bounds, the bridge's SafetyConfig and the simulator's DynamicsLimits are built from
# the groups they bound; a field's default is the default profile's number.

@dataclass(frozen=True)
class MotionLimits:
    speed_max_mps: float = profile_field("speed_max_mps")  # horizontal speed [m/s]
    climb_max_mps: float = profile_field("climb_max_mps")  # vertical speed [m/s]
    accel_max_mps2: float = profile_field("accel_max_mps2")  # [m/s^2]


@dataclass(frozen=True)
class EnvelopeLimits:
    altitude_min_m: float = profile_field("altitude_min_m")  # camera height band above home [m]
    altitude_max_m: float = profile_field("altitude_max_m")
    min_subject_distance_m: float = profile_field("min_subject_distance_m")  # horizontal, camera to subject [m]
    #: horizontal, camera to the surface of a keep-out obstacle [m] (shared/obstacles.py)
    min_obstacle_distance_m: float = profile_field("min_obstacle_distance_m")


@dataclass(frozen=True)
class GimbalLimits:
    pitch_min_rad: float = profile_field("pitch_min_rad")  # camera pitch band [rad], positive = looking up
    pitch_max_rad: float = profile_field("pitch_max_rad")
    roll_max_rad: float = profile_field("roll_max_rad")  # |roll| [rad]


@dataclass(frozen=True)
class GimbalRateLimits:
    yaw_rate_radps: float = profile_field("yaw_rate_radps")  # [rad/s]
    pitch_rate_radps: float = profile_field("pitch_rate_radps")
    roll_rate_radps: float = profile_field("roll_rate_radps")


@dataclass(frozen=True)
class LensLimits:
    focal_length_min_mm: float = profile_field("focal_length_min_mm")  # focal length range [mm]
    focal_length_max_mm: float = profile_field("focal_length_max_mm")
    focus_distance_min_m: float = profile_field("focus_distance_min_m")  # minimum focus distance to "infinity" [m]
    focus_distance_max_m: float = profile_field("focus_distance_max_m")
    f_number_min: float = profile_field("f_number_min")
    f_number_max: float = profile_field("f_number_max")


@dataclass(frozen=True)
class LensRateLimits:
    focal_rate_mmps: float = profile_field("focal_rate_mmps")  # [mm/s]
    focus_rate_mps: float = profile_field("focus_rate_mps")  # [m/s]
    f_number_rate_ps: float = profile_field("f_number_rate_ps")  # [1/s]

