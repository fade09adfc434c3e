"""The vehicle interface every backend implements (built-in simulator, MAVLink, ...).

The bridge service owns the Zenoh side and the safety layer; a backend only talks to a
vehicle. The service calls, from one thread:

    backend.start()
    loop at the bridge rate:
        backend.apply(setpoint)      # already checked and clamped by the safety layer
        or backend.hold()            # watchdog / 'hold' setpoint / invalid plan
        backend.step(now_s)          # advance the simulation or poll the link
        publish backend.vehicle_state(), backend.subject_state(), backend.frames(), backend.truths()
    backend.close()

All quantities are in the world frame of cinetransfer.shared.messages (z up, metres, radians).
"""
from __future__ import annotations

import abc

from cinetransfer.shared import messages as M


class VehiclePort(abc.ABC):
    """A vehicle with a gimbal and a controllable lens."""

    name: str = "abstract"

    @abc.abstractmethod
    def start(self) -> None:
        """Connect / initialise. May block until the vehicle answers; raise on failure."""

    @abc.abstractmethod
    def apply(self, setpoint: M.Setpoint) -> None:
        """Track this (safe) setpoint until the next call."""

    @abc.abstractmethod
    def hold(self) -> None:
        """Stop and hover in place (position hold / loiter), keep the lens as it is."""

    @abc.abstractmethod
    def step(self, now_s: float) -> None:
        """Advance to `now_s` (monotonic seconds): integrate the sim or poll the link."""

    @abc.abstractmethod
    def vehicle_state(self) -> M.VehicleState:
        """Latest vehicle/gimbal/lens state."""

    def subject_state(self) -> M.SubjectState | None:
        """Latest 3-D subject state if this backend knows it (the simulator does)."""
        return None

    def frames(self) -> list[M.Frame]:
        """Camera frames produced since the last call (the simulator renders them)."""
        return []

    def truths(self) -> list[M.GroundTruth]:
        """Ground truth of the frames returned by `frames()` (simulator only)."""
        return []

    def command(self, action: str, args: dict) -> bool:
        """Operator request from the bridge command key: 'arm', 'disarm', 'engage' (arm and
        enter the autopilot's external-control mode), 'takeoff' (args: altitude_m), 'land'.
        Returns False when this backend does not support the action (the default)."""
        return False

    @property
    def connected(self) -> bool:
        """False while the link to the vehicle is lost."""
        return True

    def close(self) -> None:
        """Release the link / resources."""
