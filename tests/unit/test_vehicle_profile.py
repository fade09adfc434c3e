"""The vehicle profile: one set of limits for the planner, the safety layer and the simulators."""
import math

import pytest

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.shared.dynamics import DynamicsLimits
from cinetransfer.services.autopilot_bridge.vehicle_model import SimDynamicsAdapter
from cinetransfer.services.planner import config as pc
from cinetransfer.shared.errors import CinetransferError, ConfigError
from cinetransfer.shared.vehicle import VehicleProfile, load_vehicle, vehicle_names


def limits(b: pc.Bounds, s: SafetyConfig, d: DynamicsLimits) -> dict[str, tuple]:
    """name -> (planner, safety layer, simulator) of every limit the three share."""
    return {
        "focal_min": (b.focal_min_mm, s.focal_length_min_mm, d.focal_min_mm),
        "focal_max": (b.focal_max_mm, s.focal_length_max_mm, d.focal_max_mm),
        "focus_min": (b.focus_min_m, s.focus_min_m, d.focus_min_m),
        "focus_max": (b.focus_max_m, s.focus_max_m, d.focus_max_m),
        "fnumber_min": (b.fnumber_min, s.f_number_min, d.f_number_min),
        "fnumber_max": (b.fnumber_max, s.f_number_max, d.f_number_max),
        "pitch_min": (b.pitch_min_rad, s.gimbal_pitch_min_rad, d.pitch_min_rad),
        "pitch_max": (b.pitch_max_rad, s.gimbal_pitch_max_rad, d.pitch_max_rad),
        "roll_max": (b.roll_max_rad, s.gimbal_roll_max_rad, d.roll_max_rad),
        "speed": (b.speed_max_mps, s.max_speed_mps, d.max_speed_xy_mps),
        "climb": (b.climb_max_mps, s.max_climb_mps, d.max_speed_z_mps),
        "accel": (b.accel_max_mps2, s.max_accel_mps2, d.max_accel_mps2),
    }


@pytest.mark.parametrize("name", vehicle_names())
def test_planner_safety_and_simulator_read_identical_limits_from_the_profile(name):
    v = load_vehicle(name)
    got = limits(pc.Bounds.from_vehicle(v), SafetyConfig.from_vehicle(v), DynamicsLimits.from_vehicle(v))
    for what, (planner, safety, sim) in got.items():
        assert planner == safety == sim, f"{name}: {what} differs: planner {planner}, safety {safety}, sim {sim}"
    assert got["focus_min"][0] == v.lens.focus_distance_m[0]  # the camera's own minimum focus distance
    # the rates the planner plans with are the ones the simulator flies
    b, d = pc.Bounds.from_vehicle(v), DynamicsLimits.from_vehicle(v)
    assert (b.yaw_rate_max_radps, b.pitch_rate_max_radps, b.focal_rate_max_mmps, b.focus_rate_max_mps,
            b.fnumber_rate_max_ps) == (d.yaw_rate_rps, d.pitch_rate_rps, d.focal_rate_mmps, d.focus_rate_mps,
                                       d.f_number_rate_ps)
    # the MAVLink sim-vehicle flies the same dynamics with the same lens ranges
    adapter = SimDynamicsAdapter(limits=d)
    assert adapter.lens_ranges["focus_distance_m"] == v.lens.focus_distance_m


def test_the_code_defaults_are_the_default_profile():
    """Bounds(), SafetyConfig() and DynamicsLimits() with no profile are CineMPC's camera too."""
    got = limits(pc.Bounds(), SafetyConfig(), DynamicsLimits())
    want = limits(*(f(load_vehicle("cinempc")) for f in (pc.Bounds.from_vehicle, SafetyConfig.from_vehicle,
                                                          DynamicsLimits.from_vehicle)))
    for what in got:
        assert got[what] == pytest.approx(want[what], abs=1e-12), what


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
