"""One take at a time per rig: a take holds a lease, a liveliness token `ct/{rig}/lease/{holder}`
on the deployment's bus, from before its extraction until its nodes are told to stop.

A second transfer on the same rig sees the first one's token and is refused (TransferError, exit 1)
before it sends anything: never a silent takeover. The token goes with its session, so a transfer
that dies (even killed outright) frees the rig as soon as the router notices. Two transfers that
declare at the same instant both see the other and both refuse: a refusal, never two owners.
"""
from __future__ import annotations

import os
import socket
import time
from typing import Any

from cinetransfer.job import TransferError
from cinetransfer.shared import keys

LOOK_S = 2.0  #: how long the take waits for the router's answer about other leases


def holder_id() -> str:
    """This process's lease name: host, pid and start time (key-safe)."""
    host = "".join(c if c.isalnum() or c in "-_" else "-" for c in socket.gethostname())[:40] or "host"
    return f"{host}-{os.getpid()}-{time.time_ns()}"


class TakeLease:
    """`with TakeLease(session, rig):` the rig is this take's, or TransferError says whose it is."""

    def __init__(self, session: Any, rig: str) -> None:
        self.session, self.rig, self.holder = session, rig, holder_id()
        self._token: Any = None

    def __enter__(self) -> "TakeLease":
        self._token = self.session.liveliness().declare_token(keys.lease(self.rig, self.holder))
        others = sorted(h for h in self.holders() if h != self.holder)
        if others:
            self.release()
            raise TransferError(f"rig {self.rig} is busy: another take holds it ({others[0]}); "
                                "one take at a time per deployment, run this one when it has ended")
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def holders(self) -> list[str]:
        replies = self.session.liveliness().get(keys.lease(self.rig), timeout=LOOK_S)
        return [str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None]

    def release(self) -> None:
        if self._token is not None:
            self._token.undeclare()
            self._token = None
