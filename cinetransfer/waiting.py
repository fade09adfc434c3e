"""Waiting for work that takes as long as it takes while it moves on, and not past a stall.

A loaded machine makes every worker slow, so the transfer never limits how long a worker may take
in all; it limits how long it may go without progress (a frame recorded, a message written, a frame
measured). `wait_while_moving` is that loop, for the recorder's close, the live output reading's
finish and the flight's take.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Hashable

#: how often a wait looks again when nothing wakes it (the worker's end, a condition) sooner
LOOK_S = 1.0


def wait_while_moving(done: Callable[[], bool], progress: Callable[[], Hashable], stall_s: float, *,
                      wait: Callable[[float], object], look_s: float = LOOK_S,
                      check: Callable[[], None] | None = None,
                      clock: Callable[[], float] = time.monotonic) -> bool:
    """Wait until `done()`: True then; False once `progress()` has kept one value for `stall_s` seconds
    of `clock` (the stall counts from the last change seen, not from the start).

    `wait(s)` blocks for at most s seconds and may return sooner (a thread's join, a condition's wait
    for a change); it is given no more than `look_s` nor the time left before the stall. `check()`, if
    given, runs after every wait and may raise to stop waiting (a node died)."""
    seen, since = progress(), clock()
    while not done():
        now, p = clock(), progress()
        if p != seen:
            seen, since = p, now
        elif now - since >= stall_s:
            return False
        wait(max(min(look_s, since + stall_s - now), 0.0))
        if check is not None:
            check()
    return True
