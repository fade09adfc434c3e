"""The envelope holds on the vehicle, commands are bounded by it, and time is checked (
points 2 and 3): the bridge core driven against the real simulator backend's dynamics, in
simulated time (no wall clock, so the results do not depend on the machine's speed)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.services.autopilot_bridge.core import BREACH_REASON, BridgeCore
from cinetransfer.services.autopilot_bridge.safety import (
    check_command_args, clamp_outward_velocity, envelope_breach, return_point)
from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend
from cinetransfer.shared import messages as M

# the envelope of the issue: fence radius 60 m, altitude band 0.5..40 m, braking at 2 m/s^2
CFG = SafetyConfig(altitude_min_m=0.5, speed_max_mps=3.0, accel_max_mps2=2.0)
CLOCK = 1_700_000_000_000_000_000
S = 1_000_000_000


def sp(pos=(1.0, 2.0, 5.0), stamp=CLOCK, vel=(0.0, 0.0, 0.0), **kw):
    return M.Setpoint(stamp_ns=stamp, position_m=np.array(pos, float), velocity_mps=np.array(vel, float),
                      lens=M.LensState(focal_length_mm=35.0), **kw)


# ----------------------------------------------------------------------------- time
def test_given_a_setpoint_stamped_far_in_the_future_when_honest_ones_follow_then_they_are_accepted():
    c = BridgeCore(CFG)
    r = c.on_setpoint(sp(pos=(9.0, 0.0, 5.0), stamp=CLOCK + 3600 * S), 0.0, clock_ns=CLOCK)
    assert r is not None and not r.accepted and "ahead of the bridge clock" in r.reason
    assert c.counters["sp_future_stamp"] == 1 and c.last_stamp_ns is None
    for k in range(1, 4):  # the honest planner, stamping with the bridge's clock
        r = c.on_setpoint(sp(pos=(1.0, 0.0, 5.0), stamp=CLOCK + k * 40_000_000), 0.04 * k,
                          clock_ns=CLOCK + k * 40_000_000)
        assert r is not None and r.accepted
    assert c.counters["sp_out_of_order"] == 0
    assert not c.tick(0.2, vehicle=M.VehicleState(position_m=np.array([0.0, 0.0, 5.0]))).hold


@pytest.mark.parametrize("ahead_s, accepted", [(0.0, True), (0.99, True), (1.01, False), (-5.0, True)])
def test_the_stamp_tolerance_is_the_configured_one(ahead_s, accepted):
    c = BridgeCore(SafetyConfig(max_stamp_ahead_s=1.0))
    r = c.on_setpoint(sp(stamp=CLOCK + int(ahead_s * S)), 0.0, clock_ns=CLOCK)
    assert r.accepted is accepted


def test_a_rejected_setpoint_never_becomes_the_ordering_stamp():
    """A setpoint that fails the safety checks (NaN) carries a late stamp: it must not make the
    honest setpoints before that stamp 'out of order'."""
    c = BridgeCore(CFG)
    r = c.on_setpoint(sp(pos=(math.nan, 0.0, 5.0), stamp=CLOCK), 0.0, clock_ns=CLOCK)
    assert not r.accepted
    r = c.on_setpoint(sp(stamp=CLOCK - S), 0.01, clock_ns=CLOCK)
    assert r.accepted and c.last_stamp_ns == CLOCK - S


# ----------------------------------------------------------------------------- pure envelope helpers
@pytest.mark.parametrize("p, v, want", [
    # far inside: untouched
    ((0.0, 0.0, 20.0), (3.0, 0.0, 1.0), (3.0, 0.0, 1.0)),
    # on the fence (x = 60): no outward component left, the tangential one stays
    ((60.0, 0.0, 20.0), (3.0, 2.0, 0.0), (0.0, 2.0, 0.0)),
    # over the fence: inward motion is allowed
    ((61.0, 0.0, 20.0), (-3.0, 0.0, 0.0), (-3.0, 0.0, 0.0)),
    # at the ceiling and the floor: no further up / down
    ((0.0, 0.0, 40.0), (0.0, 0.0, 2.0), (0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.5), (0.0, 0.0, -2.0), (0.0, 0.0, 0.0)),
    # 1 m from the fence: at most the braking speed sqrt(2 a d) = 2 m/s outward
    ((59.0, 0.0, 20.0), (3.0, 0.0, 0.0), (2.0, 0.0, 0.0)),
])
def test_outward_velocity_is_clamped_directionally(p, v, want):
    out, _ = clamp_outward_velocity(np.array(p), np.array(v), CFG)
    np.testing.assert_allclose(out, want, atol=1e-9)


def test_outward_velocity_clamp_on_a_box_fence():
    cfg = SafetyConfig(geofence_shape="box", geofence_half_extent_m=(10.0, 5.0))
    out, hit = clamp_outward_velocity(np.array([10.0, -5.0, 3.0]), np.array([1.0, -1.0, 0.5]), cfg)
    assert hit
    np.testing.assert_allclose(out, [0.0, 0.0, 0.5])


def test_breach_and_return_point():
    assert not envelope_breach(np.array([60.2, 0.0, 40.2]), CFG)  # within the tolerance
    assert envelope_breach(np.array([62.45, 0.0, 20.0]), CFG)
    assert envelope_breach(np.array([0.0, 0.0, 41.73]), CFG)
    assert envelope_breach(np.array([np.nan, 0.0, 5.0]), CFG)
    assert not envelope_breach(np.array([0.0, 0.0, 0.0]), CFG)  # on the ground (below the band): landed, not a breach
    assert not envelope_breach(np.array([0.0, 0.0, 0.0]), CFG, tol_m=-0.5)  # and that holds for the exit check
    ret = return_point(np.array([44.16, 44.16, 41.73]), CFG)
    assert math.hypot(ret[0], ret[1]) == pytest.approx(60.0 - CFG.breach_return_margin_m)
    assert ret[2] == pytest.approx(40.0 - CFG.breach_return_margin_m)


# ----------------------------------------------------------------------------- command arguments
@pytest.mark.parametrize("action, args, ok", [
    ("takeoff", {"altitude_m": 5.0}, True),
    ("takeoff", {"altitude_m": 5}, True),
    ("takeoff", {}, True),  # the backend's configured altitude
    ("takeoff", {"altitude_m": 10000.0}, False),  # climbed past 73 m before
    ("takeoff", {"altitude_m": "abc"}, False),  # crashed the bridge with ValueError before
    ("takeoff", {"altitude_m": True}, False),
    ("takeoff", {"altitude_m": math.nan}, False),
    ("takeoff", {"altitude_m": -3.0}, False),
    ("takeoff", {"altitude_m": [5.0]}, False),
    ("takeoff", {"altitude_m": 5.0, "speed": 9}, False),
    ("arm", {}, True),
    ("arm", {"force": True}, False),
])
def test_command_arguments_are_checked_against_the_envelope(action, args, ok):
    out, why = check_command_args(action, args, CFG)
    assert (out is not None) is ok, why
    if not ok:
        assert why
    core = BridgeCore(CFG)
    got, _ = core.command_args(M.Command(action=action, args=args))
    assert (got is not None) is ok
    assert core.counters["commands_bad_args"] == (0 if ok else 1)


# ----------------------------------------------------------------------------- closed loop, real sim
def fly(core: BridgeCore, sim: SimBackend, setpoint_at, seconds: float, *, dt=0.01, sp_every=1):
    """Bridge loop in simulated time: setpoints from `setpoint_at(t)` every `sp_every` ticks,
    tick, drive the simulator. Returns the vehicle states and decisions, one per tick."""
    states, decisions = [], []
    vs = sim.vehicle_state()
    for k in range(int(round(seconds / dt))):
        t = k * dt
        if k % sp_every == 0:
            s = setpoint_at(t)
            if s is not None:
                core.on_setpoint(dataclass_stamp(s, CLOCK + int(t * S)), t, clock_ns=CLOCK + int(t * S), vehicle=vs)
        d = core.tick(t, vehicle=vs)
        d.drive(sim)
        sim.step(t)
        vs = sim.vehicle_state()
        states.append(vs)
        decisions.append(d)
    return states, decisions


def dataclass_stamp(s: M.Setpoint, stamp: int) -> M.Setpoint:
    import dataclasses

    return dataclasses.replace(s, stamp_ns=stamp)


def horizontal_and_alt(states):
    r = np.array([math.hypot(s.position_m[0], s.position_m[1]) for s in states])
    z = np.array([s.position_m[2] for s in states])
    return r, z


@pytest.fixture
def sim():
    s = SimBackend("open_country", render=False, truth=False, epoch_ns=0)
    s.start()
    yield s
    s.close()


@pytest.mark.parametrize("acc", [(0.0, 0.0, 0.0), (500.0, 500.0, 500.0)])
def test_given_100hz_setpoints_far_outside_with_a_large_feed_forward_then_the_vehicle_stays_inside(sim, acc):
    """The envelope attack: setpoints at (5000, 5000, 10000) with a large velocity (and
    acceleration) feed-forward, 100 Hz. Before: the vehicle settled at r = 62.45 m, z = 41.73 m
    against 60 / 40."""
    attack = sp(pos=(5000.0, 5000.0, 10000.0), vel=(500.0, 500.0, 500.0), acceleration_mps2=np.array(acc))
    core = BridgeCore(CFG)
    states, decisions = fly(core, sim, lambda t: attack, 60.0)
    r, z = horizontal_and_alt(states)
    assert r.max() <= 60.0 + CFG.breach_tolerance_m, r.max()
    assert z.max() <= 40.0 + CFG.breach_tolerance_m, z.max()
    assert r[-1] > 59.0 and z[-1] > 39.0  # it did go to the edge of the envelope (the test reached it)
    assert core.safety.counters["clamp_velocity_outward"] > 0
    assert not any(d.breach for d in decisions)


def test_given_the_vehicle_outside_the_envelope_then_the_breach_is_flagged_and_it_flies_back_inside(sim):
    """However it got there (wind, a bad estimate, an older bridge), a vehicle outside is flagged
    in VehicleState and Health and flown back inside while the plan keeps pulling outward."""
    sim.dyn.position = np.array([70.0, 0.0, 45.0])
    attack = sp(pos=(5000.0, 0.0, 10000.0), vel=(5.0, 0.0, 5.0))
    core = BridgeCore(CFG)
    states, decisions = fly(core, sim, lambda t: attack, 40.0)
    assert decisions[0].breach and not decisions[0].hold and decisions[0].reason == BREACH_REASON
    assert core.all_counters()["breaches"] == 1
    assert core.counters["breaches"] == 1  # no flapping at the fence
    r, z = horizontal_and_alt(states)
    first_inside = next(i for i, d in enumerate(decisions) if not d.breach)
    assert r[first_inside] <= 60.0 - 0.5 * CFG.breach_return_margin_m + 1e-6
    assert r[-1] <= 60.0 + CFG.breach_tolerance_m and z[-1] <= 40.0 + CFG.breach_tolerance_m
    assert not decisions[-1].breach and core.all_counters()["envelope_breach"] is False


def test_a_breach_outranks_an_operator_hold_but_not_a_lost_link(sim):
    sim.dyn.position = np.array([0.0, 0.0, 50.0])
    core = BridgeCore(CFG)
    core.on_command(M.Command(action="hold"))
    vs = sim.vehicle_state()
    d = core.tick(0.0, vehicle=vs)
    assert d.breach and not d.hold and d.setpoint is not None and d.setpoint.position_m[2] <= 40.0
    d = core.tick(0.02, vehicle=vs, connected=False)
    assert d.hold and d.reason == "link lost" and d.breach


def test_lens_values_reach_the_simulator_only_inside_the_safety_lens_ranges(sim):
    """Lens values get to a backend only inside setpoints, clamped to SafetyConfig's ranges."""
    wild = sp(pos=(0.0, 0.0, 5.0))
    wild = wild.__class__(**{**wild.__dict__, "lens": M.LensState(focal_length_mm=1e6, focus_distance_m=1e-9,
                                                                  f_number=0.01)})
    core = BridgeCore(CFG)
    states, _ = fly(core, sim, lambda t: wild, 10.0)
    lens = states[-1].lens
    assert CFG.focal_length_min_mm <= lens.focal_length_mm <= CFG.focal_length_max_mm
    assert CFG.focus_distance_min_m <= lens.focus_distance_m <= CFG.focus_distance_max_m
    assert CFG.f_number_min <= lens.f_number <= CFG.f_number_max
    assert core.safety.counters["clamp_lens"] > 0


def test_the_configured_take_off_altitude_must_lie_in_the_same_altitude_band():
    from cinetransfer.services.autopilot_bridge.config import BridgeConfig, ConfigError, MavlinkConfig

    with pytest.raises(ConfigError, match="takeoff_altitude_m"):
        BridgeConfig(mavlink=MavlinkConfig(takeoff_altitude_m=100.0))
    BridgeConfig(mavlink=MavlinkConfig(takeoff_altitude_m=3.0))
