"""Built-in simulator: vehicle, gimbal and lens dynamics (shared/dynamics.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cinetransfer.shared.dynamics import DynamicsLimits, VehicleDynamics, ramp_angles

LIM = DynamicsLimits()


def run(dyn: VehicleDynamics, seconds: float, dt: float = 0.005) -> dict[str, np.ndarray]:
    """Advance in steps of dt and record position, velocity, acceleration."""
    rec: dict[str, list] = {"p": [], "v": [], "a": [], "ypr": [], "lens": []}
    for _ in range(int(round(seconds / dt))):
        dyn.advance(dt)
        rec["p"].append(dyn.position.copy())
        rec["v"].append(dyn.velocity.copy())
        rec["a"].append(dyn.acceleration.copy())
        rec["ypr"].append(dyn.camera_ypr.copy())
        rec["lens"].append((dyn.focal_mm, dyn.focus_m, dyn.f_number))
    return {k: np.array(v) for k, v in rec.items()}


def test_position_step_respects_speed_and_acceleration_limits_and_converges():
    # given a vehicle at rest and a target 30 m away, diagonal and up
    dyn = VehicleDynamics(limits=LIM)
    dyn.set_target(position=np.array([20.0, 20.0, 5.0]))
    # when it flies there
    r = run(dyn, 60.0)
    # then horizontal/vertical speed and acceleration stay within the limits...
    assert np.hypot(r["v"][:, 0], r["v"][:, 1]).max() <= LIM.speed_max_mps + 1e-9
    assert np.abs(r["v"][:, 2]).max() <= LIM.climb_max_mps + 1e-9
    assert np.linalg.norm(r["a"], axis=1).max() <= LIM.accel_max_mps2 + 1e-9
    dv = np.diff(r["v"], axis=0) / 0.005  # achieved acceleration
    assert np.linalg.norm(dv, axis=1).max() <= LIM.accel_max_mps2 + 1e-6
    # ...it cruised at the speed limit, and it arrives without overshooting much
    assert np.hypot(r["v"][:, 0], r["v"][:, 1]).max() > 0.99 * LIM.speed_max_mps
    np.testing.assert_allclose(dyn.position, [20, 20, 5], atol=0.02)
    assert r["p"][:, 0].max() < 20.0 + 0.05


def test_velocity_follows_a_first_order_lag():
    # given a small velocity step (below the acceleration limit: 0.2/0.25 = 0.8 m/s^2)
    dyn = VehicleDynamics(limits=LIM)
    v_sp = np.array([0.2, 0.0, 0.0])
    t, dt, vs = 0.0, 0.005, []
    while t < 1.0:
        # position setpoint moves with the vehicle: only the velocity term acts
        dyn.set_target(position=dyn.position.copy(), velocity=v_sp)
        dyn.advance(dt)
        t += dt
        vs.append(dyn.velocity[0])
    vs = np.array(vs)
    tau = LIM.lag_tau_s
    # then v(tau) = 63 % and v(3 tau) = 95 % of the step (first-order response)
    i_tau = int(round(tau / dt)) - 1
    assert vs[i_tau] == pytest.approx(0.2 * (1 - math.exp(-1)), rel=0.03)
    assert vs[3 * (i_tau + 1) - 1] == pytest.approx(0.2 * (1 - math.exp(-3)), rel=0.03)
    assert np.all(np.diff(vs) >= -1e-12) and vs.max() <= 0.2 + 1e-9


def test_gimbal_rates_and_ranges_are_limited_and_yaw_takes_the_short_way():
    dyn = VehicleDynamics(limits=LIM, camera_ypr=np.array([math.radians(170), 0.0, 0.0]))
    dyn.set_target(position=dyn.position, camera_ypr=np.array([math.radians(-170), math.radians(-120),
                                                               math.radians(80)]))
    r = run(dyn, 0.2)
    # yaw went up through 180 deg (20 deg the short way), at its rate limit
    yaw_deg = math.degrees(dyn.camera_ypr[0]) % 360
    assert yaw_deg == pytest.approx(170 + math.degrees(LIM.yaw_rate_radps) * 0.2, abs=0.1)
    # pitch and roll moved at their own rate limits
    assert dyn.camera_ypr[1] == pytest.approx(-LIM.pitch_rate_radps * 0.2, abs=1e-6)
    assert dyn.camera_ypr[2] == pytest.approx(LIM.roll_rate_radps * 0.2, abs=1e-6)
    run(dyn, 5.0)
    assert math.degrees(dyn.camera_ypr[0]) == pytest.approx(-170, abs=1e-6)
    assert dyn.camera_ypr[1] == pytest.approx(LIM.pitch_min_rad)  # clamped to the mechanical range
    assert dyn.camera_ypr[2] == pytest.approx(LIM.roll_max_rad)
    steps = np.abs(np.diff(np.unwrap(r["ypr"][:, 0])))
    assert steps.max() <= LIM.yaw_rate_radps * 0.005 + 1e-9


def test_lens_rates_and_ranges_are_limited_and_nan_keeps_a_target():
    dyn = VehicleDynamics(limits=LIM, focal_mm=30.0, focus_m=5.0, f_number=4.0)
    dyn.set_target(position=dyn.position, lens=(100.0, 50.0, 1.0))
    run(dyn, 1.0)
    assert dyn.focal_mm == pytest.approx(30 + 20 * 1.0, abs=1e-6)
    assert dyn.focus_m == pytest.approx(5 + 15 * 1.0, abs=1e-6)
    assert dyn.f_number == pytest.approx(1.0, abs=1e-6)  # 3/s: reached after 1 s
    dyn.set_target(position=dyn.position, lens=(1000.0, float("nan"), 50.0))
    run(dyn, 60.0)
    assert dyn.focal_mm == pytest.approx(LIM.focal_length_max_mm)
    assert dyn.focus_m == pytest.approx(50.0)  # NaN kept the previous target
    assert dyn.f_number == pytest.approx(LIM.f_number_max)


def test_hold_decelerates_within_limits_and_stays_put():
    dyn = VehicleDynamics(limits=LIM)
    dyn.set_target(position=np.array([100.0, 0.0, 0.0]))
    run(dyn, 8.0)
    assert dyn.velocity[0] == pytest.approx(2.0, abs=0.01)
    p_hold = dyn.position.copy()
    dyn.hold()
    r = run(dyn, 6.0)
    # decelerates at the limit: stopping distance about v^2 / (2 a) plus the lag
    travelled = dyn.position[0] - p_hold[0]
    assert 2.0 ** 2 / (2 * LIM.accel_max_mps2) * 0.9 < travelled < 2.0 ** 2 / (2 * LIM.accel_max_mps2) + 1.0
    assert np.linalg.norm(r["a"], axis=1).max() <= LIM.accel_max_mps2 + 1e-9
    assert np.linalg.norm(dyn.velocity) < 0.01
    p_stop = dyn.position.copy()
    run(dyn, 3.0)
    assert np.linalg.norm(dyn.position - p_stop) < 0.01
    assert dyn.holding


def test_limits_validate_with_clear_errors():
    with pytest.raises(ValueError, match="speed_max_mps"):
        DynamicsLimits(speed_max_mps=-1.0)
    with pytest.raises(ValueError, match="focal_length_min_mm must be < focal_length_max_mm"):
        DynamicsLimits(focal_length_min_mm=100.0, focal_length_max_mm=50.0)
    with pytest.raises(ValueError, match="unknown field"):
        DynamicsLimits.from_dict({"max_sped": 3})


def test_ramp_angles_moves_a_share_of_the_way_yaw_the_short_way():
    out = ramp_angles(np.array([0.1, 0.2, 0.0]), np.array([0.3, -0.2, 0.1]), 0.25)
    np.testing.assert_allclose(out, [0.15, 0.1, 0.025], atol=1e-12)
    # 3.0 -> -3.0 the short way is +0.2832 (through pi); a quarter of it: 3.0708
    out = ramp_angles(np.array([3.0, 0.0, 0.0]), np.array([-3.0, 0.0, 0.0]), 0.25)
    assert out[0] == pytest.approx(3.0 + 0.25 * (2 * math.pi - 6.0), abs=1e-12)
    np.testing.assert_allclose(ramp_angles(np.zeros(3), np.ones(3), 1.7), np.ones(3))  # share clamped to 1


def test_a_pan_commanded_in_steps_turns_at_a_steady_rate_between_them():
    # given a 1 deg/s pan commanded every 0.05 s (the planner's 20 Hz), each command 0.1 s ahead
    rate = math.radians(1.0)
    dyn = VehicleDynamics(limits=LIM)
    yaws = []
    for k in range(20):
        dyn.set_target(position=dyn.position, camera_ypr=np.array([rate * (k * 0.05 + 0.1), 0.0, 0.0]))
        for _ in range(10):
            dyn.advance(0.005)
            yaws.append(float(dyn.camera_ypr[0]))
    # then after the first command every 5 ms sub-step turns 0.005 deg: no jump-and-hold staircase
    steps = np.degrees(np.diff(yaws[10:]))
    np.testing.assert_allclose(steps, 0.005, atol=1e-9)
    # and at each command's end the gimbal is where it was commanded (as before the ramp)
    assert yaws[-1] == pytest.approx(rate * (19 * 0.05 + 0.1), abs=1e-12)


def test_hold_ends_a_gimbal_ramp_where_the_gimbal_is():
    dyn = VehicleDynamics(limits=LIM)
    dyn.set_target(position=dyn.position, camera_ypr=np.array([0.1, 0.0, 0.0]))
    dyn.advance(0.02)
    here = dyn.camera_ypr.copy()
    dyn.hold()
    dyn.advance(0.1)
    np.testing.assert_allclose(dyn.camera_ypr, here)


def test_pose_now_carries_the_last_sub_step_over_the_remainder():
    # given a 0.05 rad yaw command (ramped over 0.05 s: 1 rad/s) and a 35 -> 36 mm zoom (20 mm/s)
    dyn = VehicleDynamics(limits=LIM, focal_mm=35.0)
    dyn.set_target(position=dyn.position, camera_ypr=np.array([0.05, 0.0, 0.0]), lens=(36.0, 10.0, 4.0))
    # when asked for 7.5 ms: one 5 ms sub-step is integrated, 2.5 ms carried
    dyn.advance(0.0075)
    assert dyn.camera_ypr[0] == pytest.approx(0.005, abs=1e-12) and dyn.focal_mm == pytest.approx(35.1)
    # then the pose at 7.5 ms: yaw 7.5 mrad, focal 35.15 mm, still where it stood
    position, ypr, focal = dyn.pose_now()
    assert ypr[0] == pytest.approx(0.0075, abs=1e-12) and focal == pytest.approx(35.15)
    np.testing.assert_allclose(position, 0.0)
