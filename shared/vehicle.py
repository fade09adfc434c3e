"""The vehicle profile: one typed, validated description of the camera drone.

A profile (deploy/vehicles/NAME.yaml) says what the machine can do: camera sensor and image
size, lens ranges and rates, gimbal range and rates, speed and acceleration, and the envelope it
may fly in (geofence, altitude band, distance to the subject and to keep-out obstacles). The
planner's bounds (services/planner/config.Bounds.from_vehicle), the bridge's safety layer
(SafetyConfig.from_vehicle), the built-in simulator (DynamicsLimits.from_vehicle) and the MAVLink
sim-vehicle all take their limits from it, so that what the planner plans, the safety layer
accepts and the simulator flies are the same machine. `--vehicle NAME|PATH` selects one;
the default is DEFAULT_VEHICLE (CineMPC's camera, DESIGN §4).

The YAML states angles in degrees (rates in deg/s); the dataclasses hold radians.

`VehicleProfile.limits()` flattens a profile into the one spelling of each limit (the profile's
own names, a [min, max] pair split into `_min_` / `_max_`); shared/limits.py turns them into config
fields.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cinetransfer.shared.camera import coc_mm_for_sensor
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.paths import resolve_named_yaml, shipped_names

VEHICLES_DIR = Path(__file__).resolve().parents[1] / "deploy" / "vehicles"
DEFAULT_VEHICLE = "cinempc"
GEOFENCE_SHAPES = ("cylinder", "box")


def _num(where: str, v: Any, *, lo: float | None = None, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(f"{where} = {v!r}: must be a finite number")
    if positive and v <= 0:
        raise ConfigError(f"{where} = {v!r}: must be > 0")
    if lo is not None and v < lo:
        raise ConfigError(f"{where} = {v!r}: must be >= {lo}")
    return float(v)


def _pair(where: str, v: Any, *, positive: bool = False) -> tuple[float, float]:
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise ConfigError(f"{where} = {v!r}: must be [min, max]")
    lo, hi = _num(f"{where}[0]", v[0], positive=positive), _num(f"{where}[1]", v[1], positive=positive)
    if not lo < hi:
        raise ConfigError(f"{where} = {v!r}: min must be < max")
    return lo, hi


def _fields(where: str, d: Any, cls: type) -> dict[str, Any]:
    if not isinstance(d, dict):
        raise ConfigError(f"{where}: must be a mapping")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ConfigError(f"{where}: unknown field(s) {unknown}; allowed: {sorted(names)}")
    missing = sorted(f.name for f in dataclasses.fields(cls)
                     if f.name not in d and f.default is dataclasses.MISSING)
    if missing:
        raise ConfigError(f"{where}: missing field(s) {missing}")
    return d


@dataclass(frozen=True)
class CameraSpec:
    sensor_width_mm: float
    sensor_height_mm: float
    width_px: int
    height_px: int

    @property
    def coc_mm(self) -> float:
        """Circle of confusion for the depth of field [mm]: not a setting but the one definition of
        "in focus", derived from the sensor width (shared.camera.coc_mm_for_sensor)."""
        return coc_mm_for_sensor(self.sensor_width_mm)

    @classmethod
    def parse(cls, d: Any, where: str = "camera") -> "CameraSpec":
        if isinstance(d, dict) and "coc_mm" in d:
            raise ConfigError(f"{where}.coc_mm: not a setting any more: the circle of confusion is derived from "
                              "sensor_width_mm and the focus estimator (docs/configuration.md); remove the line")
        d = _fields(where, d, cls)
        vals = {k: _num(f"{where}.{k}", v, positive=True) for k, v in d.items()}
        for k in ("width_px", "height_px"):
            if vals[k] != int(vals[k]):
                raise ConfigError(f"{where}.{k} = {d[k]!r}: must be an integer")
            vals[k] = int(vals[k])
        return cls(**vals)


@dataclass(frozen=True)
class LensSpec:
    focal_length_mm: tuple[float, float]
    focal_rate_mmps: float
    focus_distance_m: tuple[float, float]  # [minimum focus distance, farthest focus setting]
    focus_rate_mps: float
    f_number: tuple[float, float]
    f_number_rate_ps: float

    @classmethod
    def parse(cls, d: Any, where: str = "lens") -> "LensSpec":
        d = _fields(where, d, cls)
        out = cls(focal_length_mm=_pair(f"{where}.focal_length_mm", d["focal_length_mm"], positive=True),
                  focal_rate_mmps=_num(f"{where}.focal_rate_mmps", d["focal_rate_mmps"], positive=True),
                  focus_distance_m=_pair(f"{where}.focus_distance_m", d["focus_distance_m"], positive=True),
                  focus_rate_mps=_num(f"{where}.focus_rate_mps", d["focus_rate_mps"], positive=True),
                  f_number=_pair(f"{where}.f_number", d["f_number"], positive=True),
                  f_number_rate_ps=_num(f"{where}.f_number_rate_ps", d["f_number_rate_ps"], positive=True))
        if out.f_number[0] < 0.5:
            raise ConfigError(f"{where}.f_number = {list(out.f_number)}: the minimum must be >= 0.5")
        if out.focus_distance_m[0] <= out.focal_length_mm[0] / 1000.0:
            raise ConfigError(f"{where}.focus_distance_m = {list(out.focus_distance_m)}: the minimum must exceed "
                              "the shortest focal length (no image closer than that)")
        return out


@dataclass(frozen=True)
class GimbalSpec:
    pitch_rad: tuple[float, float]  # (down, up), positive = looking up
    roll_max_rad: float
    yaw_rate_radps: float
    pitch_rate_radps: float
    roll_rate_radps: float

    @classmethod
    def parse(cls, d: Any, where: str = "gimbal") -> "GimbalSpec":
        keys = {"pitch_deg", "roll_max_deg", "yaw_rate_dps", "pitch_rate_dps", "roll_rate_dps"}
        if not isinstance(d, dict) or set(d) != keys:
            raise ConfigError(f"{where}: needs exactly the fields {sorted(keys)}, got "
                              f"{sorted(d) if isinstance(d, dict) else d!r}")
        lo, hi = _pair(f"{where}.pitch_deg", d["pitch_deg"])
        if lo < -90.0 or hi > 90.0:
            raise ConfigError(f"{where}.pitch_deg = {d['pitch_deg']!r}: must lie within [-90, 90]")
        roll = _num(f"{where}.roll_max_deg", d["roll_max_deg"], lo=0.0)
        if roll >= 90.0:
            raise ConfigError(f"{where}.roll_max_deg = {roll!r}: must be < 90")
        rates = {k: math.radians(_num(f"{where}.{k}", d[k], positive=True))
                 for k in ("yaw_rate_dps", "pitch_rate_dps", "roll_rate_dps")}
        return cls(pitch_rad=(math.radians(lo), math.radians(hi)), roll_max_rad=math.radians(roll),
                   yaw_rate_radps=rates["yaw_rate_dps"], pitch_rate_radps=rates["pitch_rate_dps"],
                   roll_rate_radps=rates["roll_rate_dps"])


@dataclass(frozen=True)
class MotionSpec:
    speed_max_mps: float  # horizontal speed limit (the planner: per axis; safety and simulator: norm)
    climb_max_mps: float  # vertical speed limit of the simulated autopilot
    accel_max_mps2: float

    @classmethod
    def parse(cls, d: Any, where: str = "motion") -> "MotionSpec":
        d = _fields(where, d, cls)
        return cls(**{k: _num(f"{where}.{k}", v, positive=True) for k, v in d.items()})


@dataclass(frozen=True)
class EnvelopeSpec:
    geofence_shape: str
    geofence_radius_m: float
    geofence_half_extent_m: tuple[float, float]
    altitude_m: tuple[float, float]  # band above home
    min_subject_distance_m: float  # horizontal, camera to subject
    min_obstacle_distance_m: float  # horizontal, camera to a keep-out obstacle's surface (shared/obstacles.py)

    @classmethod
    def parse(cls, d: Any, where: str = "envelope") -> "EnvelopeSpec":
        d = _fields(where, d, cls)
        if d["geofence_shape"] not in GEOFENCE_SHAPES:
            raise ConfigError(f"{where}.geofence_shape = {d['geofence_shape']!r}: must be one of {GEOFENCE_SHAPES}")
        half = d["geofence_half_extent_m"]
        if not isinstance(half, (list, tuple)) or len(half) != 2:
            raise ConfigError(f"{where}.geofence_half_extent_m = {half!r}: must be [x, y]")
        return cls(geofence_shape=d["geofence_shape"],
                   geofence_radius_m=_num(f"{where}.geofence_radius_m", d["geofence_radius_m"], positive=True),
                   geofence_half_extent_m=(_num(f"{where}.geofence_half_extent_m[0]", half[0], positive=True),
                                           _num(f"{where}.geofence_half_extent_m[1]", half[1], positive=True)),
                   altitude_m=_pair(f"{where}.altitude_m", d["altitude_m"]),
                   min_subject_distance_m=_num(f"{where}.min_subject_distance_m", d["min_subject_distance_m"], lo=0.0),
                   min_obstacle_distance_m=_num(f"{where}.min_obstacle_distance_m", d["min_obstacle_distance_m"],
                                                lo=0.0))


@dataclass(frozen=True)
class VehicleProfile:
    """One camera drone: camera, lens, gimbal, motion limits and envelope."""

    name: str
    description: str
    camera: CameraSpec
    lens: LensSpec
    gimbal: GimbalSpec
    motion: MotionSpec
    envelope: EnvelopeSpec
    path: str = ""

    def limits(self) -> dict[str, Any]:
        """Every limit under its one name (shared/limits.LIMIT_NAMES), in SI units and radians."""
        lens, gim, mo, env = self.lens, self.gimbal, self.motion, self.envelope
        return {"speed_max_mps": mo.speed_max_mps, "climb_max_mps": mo.climb_max_mps,
                "accel_max_mps2": mo.accel_max_mps2,
                "geofence_shape": env.geofence_shape, "geofence_radius_m": env.geofence_radius_m,
                "geofence_half_extent_m": env.geofence_half_extent_m,
                "altitude_min_m": env.altitude_m[0], "altitude_max_m": env.altitude_m[1],
                "min_subject_distance_m": env.min_subject_distance_m,
                "min_obstacle_distance_m": env.min_obstacle_distance_m,
                "pitch_min_rad": gim.pitch_rad[0], "pitch_max_rad": gim.pitch_rad[1], "roll_max_rad": gim.roll_max_rad,
                "yaw_rate_radps": gim.yaw_rate_radps, "pitch_rate_radps": gim.pitch_rate_radps,
                "roll_rate_radps": gim.roll_rate_radps,
                "focal_length_min_mm": lens.focal_length_mm[0], "focal_length_max_mm": lens.focal_length_mm[1],
                "focal_rate_mmps": lens.focal_rate_mmps,
                "focus_distance_min_m": lens.focus_distance_m[0], "focus_distance_max_m": lens.focus_distance_m[1],
                "focus_rate_mps": lens.focus_rate_mps,
                "f_number_min": lens.f_number[0], "f_number_max": lens.f_number[1],
                "f_number_rate_ps": lens.f_number_rate_ps}

    @classmethod
    def parse(cls, doc: Any, where: str = "vehicle") -> "VehicleProfile":
        sections = {"name", "description", "camera", "lens", "gimbal", "motion", "envelope"}
        if not isinstance(doc, dict):
            raise ConfigError(f"{where}: must be a mapping with {sorted(sections)}")
        unknown, missing = sorted(set(doc) - sections), sorted(sections - set(doc) - {"description"})
        if unknown or missing:
            raise ConfigError(f"{where}: unknown section(s) {unknown}, missing {missing}")
        return cls(name=str(doc["name"]), description=str(doc.get("description", "")),
                   camera=CameraSpec.parse(doc["camera"], f"{where}.camera"),
                   lens=LensSpec.parse(doc["lens"], f"{where}.lens"),
                   gimbal=GimbalSpec.parse(doc["gimbal"], f"{where}.gimbal"),
                   motion=MotionSpec.parse(doc["motion"], f"{where}.motion"),
                   envelope=EnvelopeSpec.parse(doc["envelope"], f"{where}.envelope"))


def vehicle_names() -> list[str]:
    return shipped_names(VEHICLES_DIR)


def resolve_vehicle(name_or_path: str) -> Path:
    return resolve_named_yaml(name_or_path, VEHICLES_DIR, missing="vehicle: profile {path} does not exist",
                              unknown="vehicle = {name}: no such profile; shipped: {shipped}")


_CACHE: dict[str, VehicleProfile] = {}


def load_vehicle(name_or_path: str | None = None) -> VehicleProfile:
    """The profile named (deploy/vehicles/NAME.yaml) or at PATH; None: DEFAULT_VEHICLE."""
    import yaml

    path = resolve_vehicle(name_or_path or DEFAULT_VEHICLE).resolve()
    key = str(path)
    if key not in _CACHE:
        try:
            doc = yaml.safe_load(path.read_text())
        except yaml.YAMLError as e:
            raise ConfigError(f"vehicle: {path} is not valid YAML ({e})") from None
        _CACHE[key] = dataclasses.replace(VehicleProfile.parse(doc, f"vehicle {path.stem}"), path=key)
    return _CACHE[key]


def _vehicle_arg(text: str) -> str:
    """--vehicle's type: the name or path as given, once the profile loads (argparse exits 2 otherwise)."""
    try:
        load_vehicle(text)
    except ConfigError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def add_vehicle_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", default=None, metavar="NAME|PATH", type=_vehicle_arg,
                   help=f"vehicle profile (deploy/vehicles: {', '.join(vehicle_names())}; default {DEFAULT_VEHICLE})")
