"""Who flies the vehicle: the bridge's mode-ownership state machine (docs/mavlink.md draws it).

    idle ──engage──▶ engaging ──HEARTBEAT: OFFBOARD/GUIDED + armed──▶ engaged
      ▲                 ▲  │                                             │
      │ disarm          │  └──link lost (no --reengage)──▶ released ◀────┤ vehicle left the mode
      │                 │                                    │          │ (pilot, failsafe, RTL),
      │                 └──────────────engage────────────────┘          │ link lost
      │                                                                 │
      └───────────── any state ──land──▶ landing (never left by itself) ◀┘

Only an `engage` command (or --engage at start, --reengage after a link loss) puts the bridge in
`engaging`, the one state in which it switches modes and arms; after ENGAGE_ATTEMPTS rounds of
those commands without success it gives up (`released`, reason 'engage not taken'). From `released` and `landing` it
never switches the vehicle back to OFFBOARD/GUIDED on its own, whatever the HEARTBEAT says.

Landing: MAV_CMD_NAV_LAND, resent a bounded number of times without an acknowledgement; refused
or never acknowledged, the bridge asks for the autopilot's land mode (MAV_CMD_DO_SET_MODE: PX4
AUTO.LAND, ArduCopter LAND), bounded the same way; `land` (Health `mav_land`) says what happened:
'sent', 'accepted', 'landing' (the vehicle left OFFBOARD/GUIDED or reports LAND), 'refused: ...',
'not taken: ...'. While landing the bridge streams a hold at the vehicle's position, never the plan.
"""
from __future__ import annotations

import logging

IDLE, ENGAGING, ENGAGED, RELEASED, LANDING = "idle", "engaging", "engaged", "released", "landing"
#: engaging sends its mode / arming commands at most this many times (about once a second)
ENGAGE_ATTEMPTS = 15


class Ownership:
    """The state (one of the five above), why it was entered, and the land's progress."""

    def __init__(self, engage_on_start: bool, reengage_after_link_loss: bool) -> None:
        self.state = ENGAGING if engage_on_start else IDLE
        self.reason = "--engage" if engage_on_start else ""
        self.land = ""
        self.attempts = 0
        self.reengage = reengage_after_link_loss
        self.log = logging.getLogger("cinetransfer.autopilot_bridge.mavlink")

    def _to(self, state: str, reason: str) -> None:
        if state != self.state:
            self.log.info("ownership: %s -> %s (%s)", self.state, state, reason)
        self.state, self.reason = state, reason

    def engage(self) -> None:
        self.attempts = 0
        self._to(ENGAGING, "engage command")

    def attempted(self) -> None:
        """One round of mode / arming commands sent while engaging; too many and the bridge gives up."""
        if self.state != ENGAGING:
            return
        self.attempts += 1
        if self.attempts > ENGAGE_ATTEMPTS:
            self._to(RELEASED, f"engage not taken after {ENGAGE_ATTEMPTS} attempts")
            self.log.error("the vehicle did not enter OFFBOARD/GUIDED armed after %d attempts: released",
                           ENGAGE_ATTEMPTS)

    def disarm(self) -> None:
        if self.state != LANDING:
            self._to(IDLE, "disarm command")

    def start_land(self) -> None:
        self.land = "sent"
        self._to(LANDING, "land command")

    def on_vehicle(self, mode: str, armed: bool, external_mode: str) -> bool:
        """A HEARTBEAT's mode and arming; True when the vehicle just left our control."""
        in_control = mode == external_mode and armed
        if self.state == ENGAGING and in_control:
            self._to(ENGAGED, f"{mode}, armed")
        elif self.state == ENGAGED and not in_control:
            self._to(RELEASED, f"vehicle left {external_mode} (now {mode}, {'armed' if armed else 'disarmed'})")
            return True
        elif self.state == LANDING and mode != external_mode and self.land != "landing":
            self.land = "landing"
            self.log.info("land taken: vehicle in %s", mode)
        return False

    def on_link_lost(self) -> None:
        if self.state in (ENGAGING, ENGAGED):
            if self.reengage:
                self._to(ENGAGING, "link lost; --reengage")
            else:
                self._to(RELEASED, "link lost")

    @property
    def engaged(self) -> bool:
        return self.state == ENGAGED

    @property
    def engaging(self) -> bool:
        return self.state == ENGAGING

    @property
    def landing(self) -> bool:
        return self.state == LANDING
