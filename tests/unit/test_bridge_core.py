"""BridgeCore: watchdog hold, hold reasons and their priority, commands, and closed-loop setpoint
tracking within the speed/acceleration limits (core + the sim-vehicle's dynamics model)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.services.autopilot_bridge.core import BridgeCore
from cinetransfer.shared.dynamics import DynamicsLimits
from cinetransfer.services.autopilot_bridge.vehicle_model import SimDynamicsAdapter
from cinetransfer.shared import messages as M


def sp(pos=(1.0, 2.0, 5.0), stamp=1, **kw):
    return M.Setpoint(stamp_ns=stamp, position_m=np.array(pos, float), lens=M.LensState(focal_length_mm=35.0), **kw)


def vs(pos=(0.0, 0.0, 5.0), vel=(0.0, 0.0, 0.0)):
    return M.VehicleState(position_m=np.array(pos, float), velocity_mps=np.array(vel, float))


CLOCK = 10**18  # the bridge's "now" on the stamp clock: every stamp here lies in its past

CFG = SafetyConfig(watchdog_timeout_s=0.5, speed_max_mps=2.0, accel_max_mps2=1.5)


def test_given_no_setpoint_yet_when_ticking_then_holds_and_reports_the_change_once():
    c = BridgeCore(CFG)
    d = c.tick(0.0, vehicle=vs())
    assert d.hold and d.reason == "no setpoint yet" and d.changed
    d = c.tick(0.02, vehicle=vs())
    assert d.hold and not d.changed
    assert c.counters["holds_startup"] == 1


def test_given_setpoints_stop_when_watchdog_expires_then_hold_and_resume_on_fresh_setpoint():
    c = BridgeCore(CFG)
    c.on_setpoint(sp(stamp=1), 0.0, clock_ns=CLOCK, vehicle=vs())
    assert not c.tick(0.01, vehicle=vs()).hold
    assert not c.tick(0.49, vehicle=vs()).hold  # still within 0.5 s
    d = c.tick(0.51, vehicle=vs())
    assert d.hold and d.reason == "watchdog" and d.changed
    assert c.counters["holds_watchdog"] == 1 and c.all_counters()["hold_reason"] == "watchdog"
    c.on_setpoint(sp(stamp=2), 0.6, clock_ns=CLOCK, vehicle=vs())
    d = c.tick(0.61, vehicle=vs())
    assert not d.hold and d.changed and d.setpoint is not None


def test_rejected_setpoints_do_not_feed_the_watchdog():
    c = BridgeCore(CFG)
    c.on_setpoint(sp(stamp=1), 0.0, clock_ns=CLOCK)
    for i, t in enumerate(np.arange(0.05, 1.0, 0.05)):
        r = c.on_setpoint(sp(pos=(math.nan, 0.0, 5.0), stamp=2 + i), float(t), clock_ns=CLOCK)
        assert r is not None and not r.accepted
    assert c.tick(1.0, vehicle=vs()).reason == "watchdog"
    assert c.safety.counters["sp_rejected_nonfinite"] == 19


@pytest.mark.parametrize("kw,reason", [({"valid": False}, "invalid plan"), ({"mode": "hold"}, "hold setpoint")])
def test_given_invalid_or_hold_setpoint_then_hold(kw, reason):
    c = BridgeCore(CFG)
    c.on_setpoint(sp(stamp=1), 0.0, clock_ns=CLOCK)
    assert not c.tick(0.02, vehicle=vs()).hold
    c.on_setpoint(sp(stamp=2, **kw), 0.03, clock_ns=CLOCK)
    d = c.tick(0.04, vehicle=vs())
    assert d.hold and d.reason == reason


def test_hold_priority_and_operator_commands():
    c = BridgeCore(CFG)
    c.on_setpoint(sp(stamp=1), 0.0, clock_ns=CLOCK)
    assert c.on_command(M.Command(action="hold")) == "hold"
    assert c.tick(0.01, vehicle=vs()).reason == "operator hold"
    assert c.tick(0.02, vehicle=vs(), connected=False).reason == "link lost"  # link beats everything
    assert c.on_command(M.Command(action="resume")) is None
    c.on_setpoint(sp(stamp=2), 0.03, clock_ns=CLOCK)
    assert not c.tick(0.04, vehicle=vs()).hold
    assert c.on_command(M.Command(action="engage")) == "engage"
    assert c.on_command(M.Command(action="self-destruct")) is None
    assert c.counters["commands_unknown"] == 1 and c.counters["holds_link"] == 1


def test_out_of_order_setpoints_are_rejected_and_counted():
    c = BridgeCore(CFG)
    c.on_setpoint(sp(pos=(1.0, 0.0, 5.0), stamp=10), 0.0, clock_ns=CLOCK)
    r = c.on_setpoint(sp(pos=(9.0, 0.0, 5.0), stamp=5), 0.01, clock_ns=CLOCK)
    assert r is not None and not r.accepted and "out of order" in r.reason
    assert c.counters["sp_out_of_order"] == 1
    np.testing.assert_allclose(c.target.position_m, [1.0, 0.0, 5.0])


def test_closed_loop_tracking_stays_within_limits_and_reaches_the_setpoints():
    """Given a plan that jumps 20 m then follows a 1.5 m/s line, the vehicle (sim-vehicle's model)
    tracks it without exceeding the bridge's speed limit, and ends on the line."""
    c = BridgeCore(CFG)
    fast = DynamicsLimits(speed_max_mps=8.0, climb_max_mps=8.0, accel_max_mps2=6.0)  # faster than allowed
    m = SimDynamicsAdapter((0.0, 0.0, 5.0), limits=fast)
    m.armed = True
    m.hold_here()
    dt, t = 0.02, 0.0
    speeds = []
    for k in range(int(30 / dt)):
        t = k * dt
        if k % 2 == 0:  # planner at 25 Hz
            if t < 15:
                target, vel = (20.0, 0.0, 8.0), (0.0, 0.0, 0.0)
            else:
                target, vel = (20.0, 1.5 * (t - 15), 8.0), (0.0, 1.5, 0.0)
            c.on_setpoint(M.Setpoint(stamp_ns=k + 1, position_m=np.array(target), velocity_mps=np.array(vel),
                                     lens=M.LensState()), t, clock_ns=CLOCK, vehicle=vs(m.position_m, m.velocity_mps))
        d = c.tick(t, vehicle=vs(m.position_m, m.velocity_mps))
        assert not d.hold or k == 0
        if not d.hold:
            m.track(d.setpoint.position_m, d.setpoint.velocity_mps, None)
        m.step(dt)
        speeds.append(float(np.linalg.norm(m.velocity_mps)))
        if t == pytest.approx(14.0):
            np.testing.assert_allclose(m.position_m, [20.0, 0.0, 8.0], atol=0.05)
    assert max(speeds) <= CFG.speed_max_mps * 1.05  # the commanded transfer is rate limited
    np.testing.assert_allclose(m.position_m, [20.0, 1.5 * 15, 8.0], atol=0.1)
    assert c.safety.counters["clamp_position_rate"] > 100
