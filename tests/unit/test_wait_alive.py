"""`job.wait_alive` on a real Zenoh session: it returns as soon as the named nodes' liveliness
tokens are up, and names the ones that never came."""
from __future__ import annotations

import threading
import time

import pytest

from cinetransfer.job import TransferError, wait_alive
from cinetransfer.shared import keys
from cinetransfer.shared.zenoh_config import ZenohOptions, open_session


@pytest.fixture
def session():
    with open_session(ZenohOptions(mode="peer")) as s:  # no endpoint, no scouting: this process alone
        yield s


def test_returns_once_every_named_token_is_up(session):
    # given one node alive already and another whose token comes a moment later
    tokens = [session.liveliness().declare_token(keys.alive("rig0", "source"))]
    detector = keys.alive("rig0", "detector")
    later = threading.Timer(0.3, lambda: tokens.append(session.liveliness().declare_token(detector)))
    later.start()
    try:
        # when waiting for both, then: it returns (the second token came)
        wait_alive(session, "rig0", {"source", "detector"}, timeout=60)
        assert len(tokens) == 2
    finally:
        later.join()
        for t in tokens:
            t.undeclare()


def test_names_the_nodes_that_never_came(session):
    # given only the source alive on rig0, and a detector alive on another rig
    tokens = [session.liveliness().declare_token(keys.alive("rig0", "source")),
              session.liveliness().declare_token(keys.alive("rig1", "detector"))]
    try:
        t = time.monotonic()
        with pytest.raises(TransferError, match=r"nodes not alive after 1s: detector, smoother$"):
            wait_alive(session, "rig0", {"source", "detector", "smoother"}, timeout=1.0)
        assert time.monotonic() - t >= 1.0  # it waited its whole timeout
    finally:
        for tk in tokens:
            tk.undeclare()
