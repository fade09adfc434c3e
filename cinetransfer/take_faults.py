"""What happened during each take, read back from the run's own recording, and whether the take
is degraded: a take whose vehicle held for more than `MAX_HOLD_SHARE` of its time, or whose planner
restarted, is not a flight of the instructions, and its goals are not reported as met however its
frames score. (A planner that dies and stays dead leaves the vehicle holding: the hold share says
so. Its longest silence between two Health reports is reported, never judged: it is wall time, and
a loaded machine stretches it.)

A take's window is the receive time of its first to its last ground-truth record (one per frame,
after the simulation's reset); every other fact is taken from the messages received in it.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable

from cinetransfer.runlog import RunReader
from cinetransfer.shared import keys
from cinetransfer.shared import messages as M

MAX_HOLD_SHARE = 0.10  #: a take that held for more of its time than this is degraded


@dataclass
class TakeFaults:
    take: int
    hold_share: float = 0.0  #: share of the take's vehicle states that were holding
    hold_s: float = 0.0  #: that share of the take's duration [simulated s]
    planner_restarts: int = 0
    planner_silence_s: float = 0.0  #: longest gap between two planner Health reports [wall s]
    over_budget_solves: int = 0
    watchdog_holds: int = 0
    degraded: bool = False
    reasons: list[str] = field(default_factory=list)


def counter_increase(values: Iterable[Any]) -> int:
    """How much a counter went up across a series of reports; a drop (the node restarted and
    counts from 0 again) starts a new run whose whole value counts."""
    total, last = 0, None
    for v in values:
        v = int(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else 0
        total += v if last is None or v < last else v - last
        last = v
    return total


def restarts(uptimes: list[float]) -> int:
    """Restarts of a node seen in its Health reports: its uptime went down."""
    return sum(1 for a, b in zip(uptimes, uptimes[1:]) if b < a)


def judge(facts: TakeFaults, duration_s: float) -> TakeFaults:
    """Mark the take degraded, with its reasons, from its facts."""
    facts.hold_s = round(facts.hold_share * duration_s, 3)
    if facts.hold_share > MAX_HOLD_SHARE:
        facts.reasons.append(f"the vehicle held for {facts.hold_share:.0%} of the take "
                             f"(more than {MAX_HOLD_SHARE:.0%})")
    if facts.planner_restarts:
        facts.reasons.append(f"the planner restarted {facts.planner_restarts} time(s)")
    facts.degraded = bool(facts.reasons)
    return facts


def _window(truths: list[tuple[int, M.GroundTruth]], take: dict, epoch_ns: int) -> tuple[int, int] | None:
    lo, hi = int(take["first_index"]), int(take["first_index"]) + int(take["end_row"]) - int(take["first_row"])
    times = [t for t, g in truths if g.stamp_ns >= epoch_ns and lo <= g.frame_index < hi]
    return (min(times), max(times)) if times else None


def _in(msgs: list[tuple[int, Any]], w: tuple[int, int]) -> list[Any]:
    return [m for t, m in msgs if w[0] <= t <= w[1]]


def _before(msgs: list[tuple[int, Any]], t0: int) -> list[Any]:
    earlier = [m for t, m in msgs if t < t0]
    return earlier[-1:]


def read_facts(recording: Path, rig: str) -> dict[str, list[tuple[int, Any]]]:
    """(receive time, message) of every message of the keys the faults are read from (truth, vehicle
    state, the planner's and the bridge's Health), in recording order, by key."""
    want = {keys.SIM_TRUTH.key(rig): M.GroundTruth, keys.VEHICLE_STATE.key(rig): M.VehicleState,
            keys.health(rig, "planner"): M.Health, keys.health(rig, "autopilot_bridge"): M.Health}
    got: dict[str, list[tuple[int, Any]]] = {k: [] for k in want}
    # not the camera frames (decoding them cost ~2 CPU s), and the objects themselves: no codec round trip
    for t, key, msg in RunReader(recording).typed(want):
        if isinstance(msg, want[key]):
            got[key].append((t, msg))
    return got


def take_faults(recording: Path, rig: str, takes: list[dict], *, epoch_ns: int, fps: float,
                facts: dict[str, list[tuple[int, Any]]] | None = None) -> list[TakeFaults]:
    """Each take's faults, from the recording `recording` of rig `rig` (meta.json's takes and epoch);
    `facts`: what `read_facts` read from it already (the transfer keeps its vehicle states for the
    report: the recording is read once)."""
    got = read_facts(recording, rig) if facts is None else facts
    truths, states = got[keys.SIM_TRUTH.key(rig)], got[keys.VEHICLE_STATE.key(rig)]
    planner, bridge = got[keys.health(rig, "planner")], got[keys.health(rig, "autopilot_bridge")]
    out = []
    for i, tk in enumerate(takes):
        f = TakeFaults(take=i)
        w = _window(truths, tk, epoch_ns)
        if w is not None:
            held = [s.holding for s in _in(states, w)]
            f.hold_share = round(sum(held) / len(held), 4) if held else 0.0
            ph = _before(planner, w[0]) + _in(planner, w)
            f.planner_restarts = restarts([h.uptime_s for h in ph])
            f.over_budget_solves = counter_increase(h.counters.get("over_budget", 0) for h in ph)
            f.over_budget_solves -= counter_increase(h.counters.get("over_budget", 0) for h in ph[:1])
            pt = [w[0]] + [t for t, _ in planner if w[0] <= t <= w[1]] + [w[1]]
            f.planner_silence_s = round(max(b - a for a, b in zip(pt, pt[1:])) * 1e-9, 2)
            bh = _before(bridge, w[0]) + _in(bridge, w)
            f.watchdog_holds = counter_increase(h.counters.get("holds_watchdog", 0) for h in bh) - \
                counter_increase(h.counters.get("holds_watchdog", 0) for h in bh[:1])
        out.append(judge(f, (int(tk["end_row"]) - int(tk["first_row"])) / fps))
    return out


def summary(faults: list[TakeFaults]) -> dict[str, Any]:
    """The flight's faults for meta.json and the report's headline."""
    return {"degraded": any(f.degraded for f in faults),
            "reasons": [f"take {f.take}: {r}" for f in faults for r in f.reasons],
            "hold_s": round(sum(f.hold_s for f in faults), 3),
            "planner_restarts": sum(f.planner_restarts for f in faults),
            "over_budget_solves": sum(f.over_budget_solves for f in faults),
            "watchdog_holds": sum(f.watchdog_holds for f in faults),
            "max_hold_share": MAX_HOLD_SHARE, "takes": [asdict(f) for f in faults]}
