"""Which way the scripted subject faces: a walk's direction, else the scene's `facing_deg` (or where the
last walk left it), turned into at TURN_RATE. A pure function of the script and time."""
from __future__ import annotations

import math

import numpy as np

from cinetransfer.services.autopilot_bridge.sim.scene import MOVING
from cinetransfer.services.autopilot_bridge.sim.subject import SubjectScript

#: how fast the body turns to a new heading [rad/s] (a person turns round in under a second)
TURN_RATE = 4.0


def wrap(a: float) -> float:
    return float((a + math.pi) % (2 * math.pi) - math.pi)


class ScriptHeading:
    """heading_at(t): the subject's heading [rad, world yaw: 0 faces +x] under a script."""

    def __init__(self, script: SubjectScript, facing_rad: float):
        self.script = script
        self._ends: list[tuple[float, float]] = []
        h = facing_rad
        for _t0, _t1, kind, a, b, _ in script.segments:
            start = h
            if kind in MOVING and float(np.hypot(*(b - a))) > 1e-9:
                h = math.atan2(b[1] - a[1], b[0] - a[0])
            self._ends.append((start, h))

    def segment_at(self, t_s: float) -> tuple[float, int]:
        """(script-local time, index of the segment) at t_s."""
        sc = self.script
        t = t_s % sc.period_s if sc.spec.loop and sc.period_s > 0 else min(max(t_s, 0.0), sc.period_s)
        for k, seg in enumerate(sc.segments):
            if t <= seg[1]:
                return t, k
        return t, len(sc.segments) - 1

    def heading_at(self, t_s: float) -> float:
        t, k = self.segment_at(t_s)
        start, goal = self._ends[k]
        turn = wrap(goal - start)
        done = min(abs(turn), TURN_RATE * max(t - self.script.segments[k][0], 0.0))
        return wrap(start + math.copysign(done, turn))
