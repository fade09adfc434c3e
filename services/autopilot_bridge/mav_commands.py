"""Commands that wait for their COMMAND_ACK, resent a bounded number of times.

A MAVLink command is answered by a COMMAND_ACK or by nothing (a component that does not know
it, a lost datagram). `CommandRetries` keeps each command in flight under a key (the lens axis,
'land', ...), resends it every `interval_s` with `confirmation` counting up, and gives it up
after `retries` resends: the caller learns that from `step()` and decides what it means (a lens
axis becomes unsupported, a land is reported as not taken). Nothing is ever resent forever.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

#: send(command, params, component, confirmation)
Sender = Callable[[int, tuple[float, ...], int, int], None]


@dataclass
class InFlight:
    """One command waiting for its acknowledgement."""

    key: str
    command: int
    params: tuple[float, ...]
    component: int
    first_s: float
    sent_s: float
    tries: int = 1


class CommandRetries:
    """The commands in flight, by key (one per key: a newer value replaces the older)."""

    def __init__(self, send: Sender, *, retries: int, interval_s: float) -> None:
        self.send_raw = send
        self.retries = retries
        self.interval_s = interval_s
        self.in_flight: dict[str, InFlight] = {}

    def send(self, key: str, command: int, params: tuple[float, ...], component: int, now: float) -> None:
        p = tuple(float(x) for x in params) + (0.0,) * (7 - len(params))
        self.in_flight[key] = InFlight(key, command, p, component, now, now)
        self.send_raw(command, p, component, 0)

    def pending(self, key: str) -> InFlight | None:
        return self.in_flight.get(key)

    def on_ack(self, command: int, src_component: int) -> InFlight | None:
        """The command in flight this COMMAND_ACK answers (removed), or None.

        An ack from another component than the one addressed is not an answer (a broadcast
        component-0 command is answered by whoever handles it)."""
        for key, f in self.in_flight.items():
            if f.command == command and f.component in (0, src_component):
                return self.in_flight.pop(key)
        return None

    def cancel(self, key: str) -> None:
        self.in_flight.pop(key, None)

    def step(self, now: float) -> list[InFlight]:
        """Resend what is due; returns the commands given up (no ack after all retries)."""
        gave_up = []
        for key, f in list(self.in_flight.items()):
            if now - f.sent_s < self.interval_s:
                continue
            if f.tries > self.retries:
                gave_up.append(self.in_flight.pop(key))
                continue
            self.send_raw(f.command, f.params, f.component, min(f.tries, 255))
            f.tries += 1
            f.sent_s = now
        return gave_up
