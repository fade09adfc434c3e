"""Bridge logic without I/O: setpoints and commands in, 'track this' or 'hold' out.

`BridgeCore` owns the safety layer and the watchdog. The service feeds it decoded messages
and the monotonic time, asks `tick()` once per loop, and does what the returned `Decision`
says with the backend (VehiclePort). Nothing here touches Zenoh, a clock or a link.

Hold reasons, by priority: link lost > operator 'hold' command > no setpoint yet > the last
setpoint was 'hold' / invalid > watchdog (no accepted setpoint for `watchdog_timeout_s`).

Envelope breach (PX4's geofence failsafe as the model): every tick the *measured* vehicle
position is checked against the geofence and altitude band; when it is outside (by more than
`breach_tolerance_m`), the plan is ignored and the vehicle is sent to the nearest point
`breach_return_margin_m` inside, until it is back inside by half that margin. Only a lost link
(nothing can be commanded) ranks above it; an operator hold does not keep it outside.

Time: a setpoint stamped more than `max_stamp_ahead_s` after `clock_ns` (the bridge's "now" on
the stamp clock, passed in by the service) is rejected, and the ordering check only ever
remembers a stamp that passed that check — one forged future stamp used to lock out every
honest setpoint after it.
When tracking resumes, the commanded position restarts from where the vehicle is and moves
towards the plan within the speed/acceleration limits (`SafetyLayer.limit_motion`).
"""
from __future__ import annotations

import collections
import dataclasses
from dataclasses import dataclass

import numpy as np

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.services.autopilot_bridge.port import VehiclePort
from cinetransfer.services.autopilot_bridge.safety import (
    SafetyLayer, SafetyResult, check_command_args, envelope_breach, return_point, subject_centre_xy)
from cinetransfer.shared import messages as M

#: bridge commands handled here; everything else goes to the backend (VehiclePort.command)
CORE_ACTIONS = ("hold", "resume")
#: actions a backend may implement
BACKEND_ACTIONS = ("arm", "disarm", "engage", "takeoff", "land")

HOLD_COUNTERS = {
    "link lost": "holds_link",
    "operator hold": "holds_operator",
    "no setpoint yet": "holds_startup",
    "hold setpoint": "holds_hold_setpoint",
    "invalid plan": "holds_invalid_plan",
    "watchdog": "holds_watchdog",
}
BREACH_REASON = "envelope breach"


@dataclass(frozen=True)
class Decision:
    """What the service does with the backend this tick."""

    hold: bool  #: True: the vehicle must hold position
    setpoint: M.Setpoint | None = None  #: the safe, rate-limited setpoint to apply (when tracking)
    reason: str = ""  #: why it holds ('' when tracking)
    changed: bool = False  #: the hold/track state or hold reason changed this tick
    breach: bool = False  #: the measured vehicle is outside the envelope: `setpoint` flies it back

    def drive(self, backend: VehiclePort) -> None:
        """Do it with the backend: hold (commanded once, when the decision changes) or track the setpoint."""
        if self.hold:
            if self.changed:
                backend.hold()
        else:
            backend.apply(self.setpoint)


class BridgeCore:
    """Safety layer + watchdog + hold logic."""

    def __init__(self, safety_cfg: SafetyConfig) -> None:
        self.cfg = safety_cfg
        self.safety = SafetyLayer(safety_cfg)
        self.counters: collections.Counter[str] = collections.Counter(
            {"sp_out_of_order": 0, "sp_future_stamp": 0, "sp_invalid": 0, "commands": 0, "commands_unknown": 0,
             "commands_bad_args": 0, "breaches": 0,
             **{v: 0 for v in HOLD_COUNTERS.values()}})
        self.target: M.Setpoint | None = None  # last accepted safe setpoint
        self.last_ok_s: float | None = None  # monotonic time it was accepted
        self.last_stamp_ns: int | None = None
        self.plan_hold_reason = ""  # 'hold setpoint' / 'invalid plan' from the newest setpoint
        self.operator_hold = False
        self.hold_reason = ""  # the first tick reports the start-up hold as a change
        self.holding = False
        self.cmd_pos: np.ndarray | None = None
        self.cmd_vel: np.ndarray | None = None
        self.last_tick_s: float | None = None
        self.last_result: SafetyResult | None = None
        self.lens_cmd: M.LensState | None = None
        self.breach = False
        self.breach_target: np.ndarray | None = None

    # ------------------------------------------------------------------ inputs
    def on_setpoint(self, sp: M.Setpoint, now_s: float, *, clock_ns: int, vehicle: M.VehicleState | None = None,
                    subject: M.SubjectState | None = None) -> SafetyResult | None:
        """Take one decoded setpoint. Returns the safety result (None if not checked).

        `clock_ns`: the bridge's "now" on the clock setpoints are stamped with. A rejected
        result (stamped in the future, out of order, or failing the safety checks) is for the
        service to count as a rejection.
        """
        ahead_ns = sp.stamp_ns - clock_ns
        if ahead_ns > self.cfg.max_stamp_ahead_s * 1e9:
            self.counters["sp_future_stamp"] += 1
            return SafetyResult(None, f"stamped {ahead_ns / 1e9:.3g} s ahead of the bridge clock "
                                      f"(limit {self.cfg.max_stamp_ahead_s:g} s)")
        if self.last_stamp_ns is not None and sp.stamp_ns < self.last_stamp_ns:
            self.counters["sp_out_of_order"] += 1
            return SafetyResult(None, "stamped before the last accepted setpoint (out of order)")
        if not sp.valid:
            self.counters["sp_invalid"] += 1
            self.plan_hold_reason = "invalid plan"
            self.last_ok_s = now_s
            self.last_stamp_ns = sp.stamp_ns
            return None
        if sp.mode == "hold":
            self.plan_hold_reason = "hold setpoint"
            self.last_ok_s = now_s
            self.last_stamp_ns = sp.stamp_ns
            return None
        vehicle_xy = None if vehicle is None else np.asarray(vehicle.position_m[:2], float)
        lens_now = self.lens_cmd or (vehicle.lens if vehicle is not None else None)
        res = self.safety.check(sp, subject_xy=subject_centre_xy(subject), vehicle_xy=vehicle_xy,
                                lens_now=lens_now)
        self.last_result = res
        if res.accepted:
            self.last_stamp_ns = sp.stamp_ns  # only a stamp that passed every check orders later ones
            self.target = res.setpoint
            self.last_ok_s = now_s
            self.plan_hold_reason = ""
            self.lens_cmd = res.setpoint.lens
        return res

    def command_args(self, cmd: M.Command) -> tuple[dict | None, str]:
        """(arguments to pass to the backend, '') or (None, why they are refused), checked
        against the envelope (`safety.check_command_args`)."""
        args, why = check_command_args(cmd.action, dict(cmd.args), self.cfg)
        if args is None:
            self.counters["commands_bad_args"] += 1
        return args, why

    def on_command(self, cmd: M.Command) -> str | None:
        """Handle 'hold' / 'resume' here; return the action to pass to the backend, or None."""
        self.counters["commands"] += 1
        action = cmd.action
        if action == "hold":
            self.operator_hold = True
            return "hold"
        if action == "resume":
            self.operator_hold = False
            return None
        if action in BACKEND_ACTIONS:
            return action
        self.counters["commands_unknown"] += 1
        return None

    # ------------------------------------------------------------------ per tick
    def _reason(self, now_s: float, connected: bool) -> str:
        if not connected:
            return "link lost"
        if self.operator_hold:
            return "operator hold"
        if self.last_ok_s is None:
            return "no setpoint yet"
        if now_s - self.last_ok_s > self.cfg.watchdog_timeout_s:
            return "watchdog"
        if self.plan_hold_reason:
            return self.plan_hold_reason
        if self.target is None:
            return "no setpoint yet"
        return ""

    def _update_breach(self, vehicle: M.VehicleState | None) -> None:
        """Enter the breach state when the measured vehicle is outside the envelope; leave it
        once the vehicle is half the return margin inside (hysteresis: no flapping at the fence)."""
        if vehicle is None:
            return
        pos = np.asarray(vehicle.position_m, float)
        if not self.breach:
            if envelope_breach(pos, self.cfg):
                self.breach = True
                self.counters["breaches"] += 1
                self.breach_target = return_point(pos, self.cfg) if np.all(np.isfinite(pos)) else None
        elif not envelope_breach(pos, self.cfg, tol_m=-0.5 * self.cfg.breach_return_margin_m):
            self.breach = False
            self.breach_target = None

    def _breach_setpoint(self, vehicle: M.VehicleState | None) -> M.Setpoint | None:
        if self.breach_target is None:
            return None
        cam = (np.asarray(vehicle.camera_ypr_rad, float).copy() if vehicle is not None
               else np.zeros(3))
        return M.Setpoint(stamp_ns=self.last_stamp_ns or 0, mode="track", position_m=self.breach_target.copy(),
                          velocity_mps=np.zeros(3), acceleration_mps2=np.zeros(3),
                          camera_ypr_rad=np.where(np.isfinite(cam), cam, 0.0), lens=M.LensState(),
                          solver_status="envelope breach: return inside")

    def tick(self, now_s: float, *, vehicle: M.VehicleState | None, connected: bool = True) -> Decision:
        """Decide for this tick. `vehicle` is the backend's latest state (None if unknown)."""
        dt = 0.0 if self.last_tick_s is None else min(max(now_s - self.last_tick_s, 0.0), 0.2)
        self.last_tick_s = now_s
        self._update_breach(vehicle)
        if self.breach and connected:
            was_breach = self.hold_reason == BREACH_REASON
            sp = self._breach_setpoint(vehicle)  # None: position unknown, so hold is all that is left
            self.holding, self.hold_reason = sp is None, BREACH_REASON
            self.cmd_pos = self.cmd_vel = None  # tracking resumes from the vehicle afterwards
            return Decision(sp is None, sp, BREACH_REASON, not was_breach, breach=True)
        reason = self._reason(now_s, connected)
        was_holding, old_reason = self.holding, self.hold_reason
        self.holding, self.hold_reason = bool(reason), reason
        changed = (self.holding != was_holding) or (reason != old_reason)
        if reason:
            if changed:
                self.counters[HOLD_COUNTERS[reason]] += 1
            self.cmd_pos = self.cmd_vel = None  # restart from the vehicle when tracking resumes
            return Decision(True, None, reason, changed, breach=self.breach)
        assert self.target is not None
        if self.cmd_pos is None or self.cmd_vel is None:
            if vehicle is not None:
                self.cmd_pos = np.asarray(vehicle.position_m, float).copy()
                self.cmd_vel = np.asarray(vehicle.velocity_mps, float).copy()
            else:
                self.cmd_pos = np.asarray(self.target.position_m, float).copy()
                self.cmd_vel = np.zeros(3)
        mc = self.safety.limit_motion(target_pos=self.target.position_m, target_vel=self.target.velocity_mps,
                                      prev_pos=self.cmd_pos, prev_vel=self.cmd_vel, dt_s=dt)
        self.cmd_pos, self.cmd_vel = mc.position_m, mc.velocity_mps
        sp = dataclasses.replace(self.target, position_m=mc.position_m.copy(), velocity_mps=mc.velocity_mps.copy())
        return Decision(False, sp, "", changed)

    def all_counters(self) -> dict[str, int | str | bool]:
        out: dict[str, int | str | bool] = dict(self.safety.counters)
        out.update(self.counters)
        out["holding"] = self.holding
        out["hold_reason"] = self.hold_reason
        out["envelope_breach"] = self.breach
        return out
