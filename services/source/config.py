"""Parameters of the source node: one frozen dataclass, each field with its flag, unit and range
(shared/nodeconfig.py). Settings keys in a deploy config are the field names."""
from __future__ import annotations

from dataclasses import dataclass

from cinetransfer.shared.nodeconfig import setting


@dataclass(frozen=True)
class SourceConfig:
    """How far the source may run ahead of the detector, and how long it waits for it."""

    window: int = setting(8, flag="--window", unit="frames", range=">= 1",
                          help="frames that may be ahead of the detector's measurements")
    wait_detector_s: float = setting(120.0, flag="--wait-detector", unit="s", range=">= 0", metavar="S",
                                     help="wait this long for a detector before giving up on a play")
    stall_s: float = setting(300.0, flag="--stall", unit="s", range="> 0", metavar="S",
                             help="end a play with an error when the detector acknowledges nothing for this long")
