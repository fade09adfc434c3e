"""Ctrl-C while the take is being closed: held, not lost, and not cutting the stop short."""
from __future__ import annotations

import os
import signal
import time

from cinetransfer.flight import HeldInterrupt


def test_a_ctrl_c_while_the_take_closes_is_remembered_and_the_handler_restored(capsys):
    before = signal.getsignal(signal.SIGINT)
    with HeldInterrupt() as held:
        assert not held.pressed
        os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt: the block runs to its end
        deadline = time.monotonic() + 5
        while not held.pressed and time.monotonic() < deadline:
            time.sleep(0.01)  # the handler runs in the main thread, between bytecodes
        assert held.pressed
    assert signal.getsignal(signal.SIGINT) is before
    assert "already stopping" in capsys.readouterr().err


def test_without_a_ctrl_c_nothing_is_pressed():
    with HeldInterrupt() as held:
        pass
    assert not held.pressed
