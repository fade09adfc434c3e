"""The vehicle profile: one set of limits for the planner, the safety layer and the simulators."""
import argparse
import dataclasses
import math
from pathlib import Path

import pytest

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.shared.dynamics import DynamicsLimits
from cinetransfer.services.autopilot_bridge.vehicle_model import SimDynamicsAdapter
from cinetransfer.services.planner import config as pc
from cinetransfer.shared.errors import CinetransferError, ConfigError
from cinetransfer.shared import limits as limits_module
from cinetransfer.shared import vehicle as vehicle_module
from cinetransfer.shared.nodeconfig import settings_from
from cinetransfer.shared.limits import LIMIT_NAMES, vehicle_fields
from cinetransfer.shared.vehicle import VehicleProfile, load_vehicle, vehicle_names


CONFIGS = (pc.Bounds, SafetyConfig, DynamicsLimits)


def limit_fields(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if f.name in LIMIT_NAMES]


def test_each_limit_has_one_spelling_the_profiles():
    """The three configs name a limit as the profile does; no earlier spelling is a field any more."""
    assert set(load_vehicle().limits()) == set(LIMIT_NAMES)
    retired = {old for cls in CONFIGS for old in cls.SETTING_ALIASES}
    for cls in CONFIGS:
        names = {f.name for f in dataclasses.fields(cls)}
        assert not names & retired, f"{cls.__name__}: {sorted(names & retired)}"
        assert set(cls.SETTING_ALIASES.values()) <= names, cls.__name__  # an alias leads to a field
    # what each one bounds: the planner everything but the geofence, the safety layer no rates,
    # the simulator no envelope
    assert set(limit_fields(pc.Bounds)) == set(LIMIT_NAMES) - {"geofence_shape", "geofence_radius_m",
                                                               "geofence_half_extent_m"}
    assert set(limit_fields(SafetyConfig)) == set(LIMIT_NAMES) - {n for n in LIMIT_NAMES if "rate" in n}
    assert set(limit_fields(DynamicsLimits)) == set(LIMIT_NAMES) - {
        "geofence_shape", "geofence_radius_m", "geofence_half_extent_m", "altitude_min_m", "altitude_max_m",
        "min_subject_distance_m", "min_obstacle_distance_m"}


def odd_profile(tmp_path) -> VehicleProfile:
    """A profile no code default could match: every number of cinempc's changed."""
    import yaml

    doc = yaml.safe_load(Path(load_vehicle("cinempc").path).read_text())
    doc["name"] = "odd"
    doc["lens"] = {"focal_length_mm": [21, 77], "focal_rate_mmps": 7.5, "focus_distance_m": [0.7, 61],
                   "focus_rate_mps": 4.5, "f_number": [1.8, 13], "f_number_rate_ps": 1.25}
    doc["gimbal"] = {"pitch_deg": [-70, 20], "roll_max_deg": 11, "yaw_rate_dps": 41, "pitch_rate_dps": 33,
                     "roll_rate_dps": 29}
    doc["motion"] = {"speed_max_mps": 3.3, "climb_max_mps": 1.7, "accel_max_mps2": 0.9}
    doc["envelope"] = {"geofence_shape": "box", "geofence_radius_m": 33, "geofence_half_extent_m": [44, 55],
                       "altitude_m": [2.5, 31], "min_subject_distance_m": 4.25,
                       "min_obstacle_distance_m": 0.75}
    p = tmp_path / "odd.yaml"
    p.write_text(yaml.safe_dump(doc))
    return load_vehicle(str(p))


def test_planner_safety_and_simulator_follow_a_non_default_profile(tmp_path):
    v = odd_profile(tmp_path)
    want, default = v.limits(), load_vehicle().limits()
    for cfg in (pc.Bounds.from_vehicle(v), SafetyConfig.from_vehicle(v), DynamicsLimits.from_vehicle(v)):
        for name in limit_fields(type(cfg)):
            got = getattr(cfg, name)
            assert got == want[name] != default[name], f"{type(cfg).__name__}.{name}: {got}"
    assert pc.Bounds.from_vehicle(v).pitch_max_rad == pytest.approx(math.radians(20))
    # the MAVLink sim-vehicle flies the same dynamics with the same lens ranges
    adapter = SimDynamicsAdapter(limits=DynamicsLimits.from_vehicle(v))
    assert adapter.lens_ranges["focus_distance_m"] == (0.7, 61.0)


def test_the_code_defaults_are_read_from_the_default_profile(monkeypatch):
    """Bounds(), SafetyConfig() and DynamicsLimits() take the default profile's numbers: with
    another default profile they follow it (no number is typed in the code)."""
    for cls in CONFIGS:
        assert {n: getattr(cls(), n) for n in limit_fields(cls)} == vehicle_fields(cls, load_vehicle("cinempc"))
    monkeypatch.setattr(vehicle_module, "DEFAULT_VEHICLE", "inspire3")
    limits_module._default_limits.cache_clear()
    try:
        for cls in CONFIGS:
            got = {n: getattr(cls(), n) for n in limit_fields(cls)}
            assert got == vehicle_fields(cls, load_vehicle("inspire3")), cls.__name__
    finally:
        monkeypatch.undo()
        limits_module._default_limits.cache_clear()


@pytest.mark.parametrize("cls, old, new", [(cls, old, new) for cls in CONFIGS
                                           for old, new in cls.SETTING_ALIASES.items()])
def test_earlier_spellings_in_settings_files_set_the_one_field(cls, old, new):
    base = cls()
    value = getattr(base, new) * (1.1 if "min" in new and getattr(base, new) > 0 else 0.9)  # inside its range
    if cls is DynamicsLimits:
        got = DynamicsLimits.from_dict({old: value})
    else:
        got = settings_from(cls, {old: value}, "node")
    assert getattr(got, new) == pytest.approx(value)
    with pytest.raises(ConfigError, match=f"{new} is given twice"):
        settings_from(cls, {old: value, new: value}, "node") if cls is not DynamicsLimits else \
            DynamicsLimits.from_dict({new: value, old: value})


def test_a_deploy_config_with_earlier_spellings_still_configures_planner_and_bridge(tmp_path):
    from cinetransfer.services.autopilot_bridge import service as bridge
    from cinetransfer.services.planner import service as planner

    cfg = tmp_path / "rig.yaml"
    cfg.write_text("nodes:\n"
                   "  - {name: planner, command: planner, settings: {bounds: {min_distance_m: 2.5, fnumber_max: 16}}}\n"
                   "  - name: autopilot_bridge\n    command: autopilot_bridge\n"
                   "    settings: {safety: {max_speed_mps: 1.5, gimbal_roll_max_rad: 0.2, focus_min_m: 0.8}}\n")
    ap = argparse.ArgumentParser()
    planner.add_config_arguments(ap)
    p = planner.config_from_args(ap.parse_args(["--config", str(cfg)]))
    assert (p.bounds.min_subject_distance_m, p.bounds.f_number_max) == (2.5, 16.0)
    b = bridge.config_from_args(bridge.build_parser().parse_args(["--config", str(cfg)])).safety
    assert (b.speed_max_mps, b.roll_max_rad, b.focus_distance_min_m) == (1.5, 0.2, 0.8)
    assert pc.from_dict({"bounds": {"focal_min_mm": 40}}).bounds.focal_length_min_mm == 40.0


def test_cinempc_profile_matches_the_published_camera():
    v = load_vehicle("cinempc")
    assert (v.camera.sensor_width_mm, v.camera.sensor_height_mm) == (23.76, 13.365)
    assert v.lens.focal_length_mm == (30.0, 500.0) and v.lens.f_number == (1.0, 22.0)
    assert (v.camera.width_px, v.camera.height_px) == (960, 540)
    assert v.gimbal.pitch_rad == pytest.approx((-math.pi / 2, math.radians(30)))


def test_a_broken_profile_is_refused_naming_the_field(tmp_path):
    import yaml

    from pathlib import Path

    doc = yaml.safe_load(Path(load_vehicle("cinempc").path).read_text())
    doc["lens"]["f_number"] = [8, 2]
    with pytest.raises(ConfigError, match=r"lens\.f_number"):
        VehicleProfile.parse(doc)
    doc["lens"]["f_number"] = [1, 22]
    doc["gimbal"]["pitch_deg"] = [-120, 30]
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(CinetransferError, match=r"gimbal\.pitch_deg"):
        load_vehicle(str(p))
    with pytest.raises(ConfigError, match="no such profile"):
        load_vehicle("no_such_drone")


@pytest.mark.parametrize("name", vehicle_names())
def test_planner_harness_and_sim_vehicle_fly_one_dynamics_model(name):
    """The planner's closed-loop harness and the MAVLink sim-vehicle integrate the simulator's
    VehicleDynamics with the same limits (one dynamics model)."""
    from cinetransfer.services.planner.kinematic_sim import KinematicSim
    from cinetransfer.shared.dynamics import VehicleDynamics

    v = load_vehicle(name)
    harness = KinematicSim(vehicle=v).dyn
    sim_vehicle = SimDynamicsAdapter(limits=DynamicsLimits.from_vehicle(v)).dyn
    assert type(harness) is VehicleDynamics and type(sim_vehicle) is VehicleDynamics
    assert harness.limits == sim_vehicle.limits == DynamicsLimits.from_vehicle(v)
