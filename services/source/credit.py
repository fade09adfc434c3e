"""Credit flow control for a stream that must never drop an item (pure, no I/O).

The sender may have at most `window` items in flight: sent but not yet acknowledged by the
consumer (for the source: frames without a measurement yet). `may_send()` says whether the
next item may go; `ack(index)` records that the consumer has finished item `index`.
"""
from __future__ import annotations


class Credit:
    def __init__(self, window: int) -> None:
        if window < 1:
            raise ValueError("window must be >= 1")
        self.window = window
        self.sent = 0
        self._acked: set[int] = set()

    @property
    def acked(self) -> int:
        return len(self._acked)

    @property
    def in_flight(self) -> int:
        return self.sent - self.acked

    def may_send(self) -> bool:
        return self.in_flight < self.window

    def on_sent(self) -> None:
        self.sent += 1

    def ack(self, index: int) -> None:
        """A consumer finished item `index` (repeated acks count once)."""
        if 0 <= index:
            self._acked.add(index)

    def all_acked(self) -> bool:
        return self.acked >= self.sent
