"""SIGINT/SIGTERM as a stop request that is safe to raise at any instant.

A Python signal handler runs in the main thread between two bytecodes, possibly while that
thread holds a lock. A handler that sets a `threading.Event` takes the Event's own lock, which
is not reentrant: when the signal lands inside the main thread's own `Event.wait()` (between
taking that lock and waiting, or after waking), the handler blocks on a lock its thread holds
and the process hangs for good after logging "received SIGINT". So the handler here only
stores the signal number (no lock, no I/O), and waiting polls that flag in short slices.
"""
from __future__ import annotations

import signal
import time
from typing import Any

POLL_S = 0.05  # longest delay between a signal and a waiter noticing it


class StopSignal:
    """Event-like stop flag (`is_set`, `set`, `wait`) that SIGINT/SIGTERM set once installed."""

    def __init__(self) -> None:
        self.signum: int | None = None  # the signal that asked to stop (None: none, or set() by code)
        self._set = False
        self._old: dict[int, Any] = {}

    def install(self, signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)) -> "StopSignal":
        """Handle `signals` (main thread only); `restore()` puts the previous handlers back."""
        for sig in signals:
            self._old[sig] = signal.signal(sig, self._on_signal)
        return self

    def restore(self) -> None:
        for sig, h in self._old.items():
            signal.signal(sig, h)
        self._old.clear()

    def _on_signal(self, signum: int, _frame: object) -> None:
        self.signum = signum  # a plain store: nothing here may take a lock or write to a stream
        self._set = True

    def set(self) -> None:
        self._set = True

    def is_set(self) -> bool:
        return self._set

    def wait(self, timeout: float | None = None) -> bool:
        """Until set, or `timeout` seconds (None: for ever); returns `is_set()`."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._set:
            left = POLL_S if deadline is None else min(POLL_S, deadline - time.monotonic())
            if left <= 0:
                break
            time.sleep(left)
        return self._set

    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else "stop"
