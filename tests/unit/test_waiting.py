"""The shared "wait while it moves" loop (cinetransfer/waiting.py), on a clock of its own: each wait
moves it on by what it was given, so no result depends on the machine's speed."""
import threading

import pytest

from cinetransfer.waiting import wait_while_moving


class Clock:
    """Seconds that pass only when a wait is made; `waits` records what each was given."""

    def __init__(self) -> None:
        self.t = 0.0
        self.waits: list[float] = []

    def __call__(self) -> float:
        return self.t

    def wait(self, s: float) -> None:
        self.waits.append(s)
        self.t += s


def test_work_longer_than_the_stall_limit_is_waited_for_while_it_moves():
    clock = Clock()
    # one step of progress every 2 s, done at 9 s: 9 s in all against a 3 s stall limit
    assert wait_while_moving(lambda: clock.t >= 9.0, lambda: int(clock.t // 2), 3.0, wait=clock.wait, clock=clock)
    assert clock.t == pytest.approx(9.0) and clock.waits == [1.0] * 9


def test_a_stall_counts_from_the_last_change_seen():
    clock = Clock()
    # progress 0, 1, 2 at 0, 1, 2 s, then none: stalled 3 s after the last change, at 5 s (not 3 s from the start)
    moved = wait_while_moving(lambda: False, lambda: min(int(clock.t), 2), 3.0, wait=clock.wait, clock=clock)
    assert moved is False and clock.t == pytest.approx(5.0)
    # a look of 2 s is cut to the time left before the stall: 2, then 1 (not 2 more, to 4 s)
    clock = Clock()
    assert not wait_while_moving(lambda: False, lambda: 0, 3.0, wait=clock.wait, look_s=2.0, clock=clock)
    assert clock.waits == [2.0, 1.0] and clock.t == pytest.approx(3.0)


def test_a_check_runs_after_every_wait_and_may_stop_it():
    clock = Clock()

    def check() -> None:
        if clock.t >= 2.0:
            raise RuntimeError("the node died")
    with pytest.raises(RuntimeError, match="the node died"):
        wait_while_moving(lambda: False, lambda: clock.t, 60.0, wait=clock.wait, check=check, clock=clock)
    assert clock.t == pytest.approx(2.0)


def test_a_worker_that_is_done_needs_no_wait():
    clock = Clock()
    assert wait_while_moving(lambda: True, lambda: 0, 0.0, wait=clock.wait, clock=clock) and clock.waits == []


def test_it_waits_for_a_real_thread_to_end():
    release = threading.Event()
    worker = threading.Thread(target=release.wait)
    worker.start()
    release.set()
    # the stall limit is far longer than any loaded machine needs to end a released thread
    assert wait_while_moving(lambda: not worker.is_alive(), lambda: 0, 3600.0, wait=worker.join)
    assert not worker.is_alive()
