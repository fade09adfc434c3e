"""The smoother node over real Zenoh: Measurements in, streaming windows and the final result out."""
from __future__ import annotations

import random
import threading
import time

import pytest
import zenoh

from cinetransfer.services.smoother.synthetic import walking_sequence
from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M
from conftest import connect_flags, spawn, stop, wait_for

RIG = "sm"


class Bus:
    """The test's own session: publishes measurements/commands, collects instructions in arrival order."""

    def __init__(self, opts):
        self.session = zenoh_config.open_session(opts)
        self.lock = threading.Lock()
        self.instructions: list[M.Instructions] = []
        self.alive: set[str] = set()
        self._decl = [
            self.session.declare_subscriber(keys.INSTRUCTIONS.key(RIG), self._on),
            self.session.liveliness().declare_subscriber(keys.all_alive(RIG), self._on_alive, history=True),
        ]
        self.meas = self.session.declare_publisher(keys.MEASUREMENT.key(RIG),
                                                   congestion_control=zenoh.CongestionControl.BLOCK)
        self.cmd = self.session.declare_publisher(keys.SMOOTHER_COMMAND.key(RIG),
                                                  congestion_control=zenoh.CongestionControl.BLOCK)

    def _on(self, s):
        msg = codec.decode(s.payload.to_bytes(), M.Instructions)
        with self.lock:
            self.instructions.append(msg)

    def _on_alive(self, s):
        with self.lock:
            name = str(s.key_expr).split("/")[-1]
            (self.alive.add if s.kind == zenoh.SampleKind.PUT else self.alive.discard)(name)

    def got(self):
        with self.lock:
            return list(self.instructions)

    def close(self):
        for d in (*self._decl, self.meas, self.cmd):
            d.undeclare()
        self.session.close()


@pytest.fixture
def bus(listener_opts):
    b = Bus(listener_opts)
    yield b
    b.close()


@pytest.fixture
def smoother(port, bus, tmp_path):
    log = tmp_path / "smoother.log"
    proc = spawn("smoother", "--rig", RIG, "--end-idle", "0", "--publish-period", "0.2", "--window", "1.0",
                 *connect_flags(port), log=log)
    wait_for(lambda: "smoother" in bus.alive or proc.poll() is not None, timeout=60, what="smoother liveliness")
    assert proc.poll() is None, log.read_text()
    yield proc, log
    rc = stop(proc)
    assert rc == 0, log.read_text()


def _last_frame(ins: M.Instructions) -> int:
    return ins.first_frame + ins.image_targets.shape[0] - 1


def test_streaming_windows_then_final_result(bus, smoother):
    proc, log = smoother
    n = 72  # 3 s at 24 fps
    ms = walking_sequence(n, flicker=True)
    # Out of order within small blocks, plus duplicates; the newest frame is held back.
    order = list(range(n - 1))
    for k in range(0, n - 1, 6):
        blk = order[k:k + 6]
        random.Random(k).shuffle(blk)
        order[k:k + 6] = blk
    for j, i in enumerate(order):
        bus.meas.put(codec.encode(ms[i]))
        if j % 10 == 0:
            bus.meas.put(codec.encode(ms[i]))  # a duplicate
        time.sleep(0.01)

    # The windows keep up with the stream: one ends at the newest frame with every frame before it
    # (valid: no gap), so the node has all it was sent and nothing is due (it publishes only on news).
    def caught_up():  # how many messages had come up to that window (with it)
        return next((k + 1 for k, ins in enumerate(bus.got()) if not ins.final and ins.valid
                     and _last_frame(ins) == n - 2), None)

    seen = wait_for(caught_up, timeout=60, what="a window with every frame up to the newest")
    # The lag bound, counted in windows rather than seconds (a loaded machine stretches the publish
    # period and the solve, never their order): a frame that comes is in the very next window. The
    # pause leaves room for windows without news (none may come); any length of it passes.
    time.sleep(3 * 0.2)
    bus.meas.put(codec.encode(ms[n - 1]))
    bus.meas.put(codec.encode(ms[n - 1]))  # a duplicate
    wait_for(lambda: len(bus.got()) > seen, timeout=30, what="the window after the newest frame")
    win = bus.got()[seen]
    assert (win.final, _last_frame(win)) == (False, n - 1)
    assert win.image_targets.shape[0] == 24  # 1 s window at 24 fps
    assert win.subject_visible.all()
    windows = [ins for ins in bus.got() if not ins.final]
    assert all(w.image_targets.shape[1:] == (4, 2) for w in windows)
    # End of stream: the whole sequence, with every frame once.
    bus.cmd.put(codec.encode(M.Command(action="end")))
    final = wait_for(lambda: next((i for i in bus.got() if i.final), None), timeout=30, what="final instructions")
    assert final.first_frame == 0 and final.image_targets.shape == (n, 4, 2)
    assert final.subject_visible.all() and final.valid
    # The flickering bystander (x0 = 480 px) is never followed.
    assert float(final.subject_box[:, 0].max()) < 300 / 640
    assert proc.poll() is None
