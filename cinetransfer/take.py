"""Assembling a take: which recorded item (frame, truth) goes into which slot of the output.

Pure logic, no I/O. Slot k of a take is instruction frame k. Two modes:

- exact (simulation time): every slot must get its own item. Items may arrive out of order
  (held back until the slots before them are filled), a second item for a slot is a counted
  duplicate and ignored; `require_complete` raises `MissingFramesError` naming missing slots.
  Nothing is ever repeated.
- real time (wall clock): items arrive in time order; a slot nobody filled repeats the
  previous item (counted and flagged per slot), an item for a slot already written is late
  (counted, dropped). The tail is never padded: `finish()` reports which slots are missing.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


class MissingFramesError(RuntimeError):
    """A take in simulation time lacks frames: the run is not what the instructions asked for."""


@dataclass(frozen=True)
class Placed:
    slot: int
    item: Any
    repeat: bool = False  #: True: this slot shows the previous item again (real time only)


@dataclass
class TakeSummary:
    n_slots: int
    written: int = 0
    repeated_slots: list[int] = field(default_factory=list)
    missing_slots: list[int] = field(default_factory=list)
    duplicates: int = 0
    late: int = 0
    out_of_range: int = 0

    @property
    def complete(self) -> bool:
        return self.written == self.n_slots and not self.missing_slots


def describe_slots(slots: list[int], limit: int = 8) -> str:
    shown = ", ".join(str(s) for s in slots[:limit])
    return shown + (f", ... ({len(slots)} in all)" if len(slots) > limit else "")


class TakeAssembler:
    """Places items into slots 0..n_slots-1 in order (see the module doc)."""

    def __init__(self, n_slots: int, *, exact: bool) -> None:
        if n_slots < 0:
            raise ValueError("n_slots must be >= 0")
        self.exact = exact
        self.summary = TakeSummary(n_slots)
        self._next = 0  # the next slot to write
        self._held: dict[int, Any] = {}  # exact mode: items waiting for earlier slots
        self._last: Any = None

    @property
    def next_slot(self) -> int:
        return self._next

    @property
    def done(self) -> bool:
        return self._next >= self.summary.n_slots

    def add(self, slot: int, item: Any) -> list[Placed]:
        """Offer the item of `slot`; returns what can be written now, in slot order."""
        s = self.summary
        if not 0 <= slot < s.n_slots:
            s.out_of_range += 1
            return []
        if slot < self._next or slot in self._held:
            if self.exact:
                s.duplicates += 1
            else:
                s.late += 1
            return []
        if self.exact:
            self._held[slot] = item
            return self._release()
        return self._fill_to(slot, item)

    def _release(self) -> list[Placed]:
        out = []
        while self._next in self._held:
            out.append(self._write(self._held.pop(self._next), repeat=False))
        return out

    def _fill_to(self, slot: int, item: Any) -> list[Placed]:
        out = []
        if self._last is None:
            self._last = item  # a take that opens between two frames starts on the first one
        while self._next < slot:
            self.summary.repeated_slots.append(self._next)
            out.append(self._write(self._last, repeat=True))
        out.append(self._write(item, repeat=False))
        return out

    def _write(self, item: Any, *, repeat: bool) -> Placed:
        p = Placed(self._next, item, repeat)
        self._last = item
        self._next += 1
        self.summary.written += 1
        return p

    def finish(self) -> TakeSummary:
        """Close the take: the summary, with the slots that never got an item."""
        s = self.summary
        s.missing_slots = [k for k in range(self._next, s.n_slots) if k not in self._held]
        return s


def require_complete(summary: TakeSummary, what: str = "frames") -> None:
    """Simulation time: a take missing any slot is an error (MissingFramesError), never padded."""
    if summary.missing_slots or summary.written < summary.n_slots:
        raise MissingFramesError(f"{len(summary.missing_slots)} of {summary.n_slots} {what} of the take never "
                                 f"arrived (slots {describe_slots(summary.missing_slots)}); "
                                 f"{summary.written} were recorded")
