"""The frames of a simulated run where the source's focus label was out of any lens's reach.

Per compared output frame and region: the label the source asks (its `focus_in`), the region's
depths and the filmed focal length from the simulator's truth (`GroundTruth.region_inverse_depth`,
`focal_length_mm`, `lens_limits`), judged by focus_reach.unreachable_labels. Frames whose truth
predates those fields (an older recording) are never called unreachable.

Given the lens's rates, misses the flight made round a switch of the asked labels are excused (kind
'rate') where the rates force them, never more than focus_reach's proven lower bound
(focus_reach.rate_windows); the windows, with the flight's misses against the bound, are kept.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from cinetransfer.report import focus_reach as FR
from cinetransfer.shared import messages as M


@dataclass(frozen=True, eq=False)
class Reach:
    """Per frame of the compared timeline and region: unreachable, and why ('' when reachable)."""

    unreachable: np.ndarray  # (N, 3) bool
    reasons: np.ndarray  # (N, 3) object (str)
    judged: np.ndarray  # (N,) the frame had what the judgement needs (truth with depths and lens)
    kinds: np.ndarray  # (N, 3) object (str): the kind of each verdict (focus_reach.Unreachable.kind; '' reachable)
    rate_windows: list[FR.RateWindow] = field(default_factory=list)

    @classmethod
    def none(cls, n: int) -> "Reach":
        return cls(np.zeros((n, 3), bool), np.full((n, 3), "", dtype=object), np.zeros(n, bool),
                   np.full((n, 3), "", dtype=object))


def lens_of(t: M.GroundTruth) -> FR.Lens | None:
    lim = np.asarray(t.lens_limits, dtype=float)
    inv = np.asarray(t.region_inverse_depth)
    if lim.shape != (4,) or not np.isfinite(lim).all() or not np.isfinite(t.focal_length_mm) \
            or inv.ndim != 2 or inv.shape[1] == 0:
        return None
    return FR.Lens(float(t.focal_length_mm), (float(lim[0]), float(lim[1])), (float(lim[2]), float(lim[3])))


def truths_by_frame(truths: Sequence[M.GroundTruth], n: int, offset: int) -> list[M.GroundTruth | None]:
    """The truth of each output frame 0..n-1 (the first one of duplicates), as fidelity.truth_track."""
    out: list[M.GroundTruth | None] = [None] * n
    for t in truths:
        i = int(t.frame_index) - offset
        if 0 <= i < n and out[i] is None:
            out[i] = t
    return out


#: a frame's verdicts by what they are computed from (`frame_key`): see `reach`'s `memo`
Memo = dict[tuple, list[FR.Unreachable]]


def frame_key(lens: FR.Lens, asked: np.ndarray, present: np.ndarray, inv_depth: np.ndarray) -> tuple:
    """Everything `unreachable_labels` reads of one frame, as a dictionary key (exact values)."""
    return (lens, np.asarray(asked, bool).tobytes(), np.asarray(present, bool).tobytes(), inv_depth.shape,
            inv_depth.tobytes())


def reach(asked: np.ndarray, present: np.ndarray, truths: Sequence[M.GroundTruth | None],
          memo: Memo | None = None, rates: FR.LensRates | None = None, also: np.ndarray | None = None) -> Reach:
    """Reach of the asked labels `asked` (N, 3) where `present` (N, 3) (the region present on both
    sides), one truth (or None) per frame; with the lens's `rates`, the misses they force too.
    `memo`: verdicts of frames judged before (filled here), so that one report judges each frame
    once (its shots compare the same frames again). `also` (N, 3): regions judged per frame besides
    (the extraction's where the truth has none but kept its depths), never for the rates."""
    n = len(truths)
    out = Reach.none(n)
    judge = present if also is None else np.asarray(present, bool) | np.asarray(also, bool)
    for i, t in enumerate(truths):
        lens = lens_of(t) if t is not None else None
        if lens is None:
            continue
        out.judged[i] = True
        if not judge[i].any():
            continue
        inv = np.asarray(t.region_inverse_depth, float)
        key = frame_key(lens, asked[i], judge[i], inv) if memo is not None else None
        found = memo.get(key) if key is not None else None
        if found is None:
            found = FR.unreachable_labels(lens, asked[i], judge[i], inv)
            if key is not None:
                memo[key] = found
        for u in found:
            out.unreachable[i, u.region] = True
            out.reasons[i, u.region] = u.reason
            out.kinds[i, u.region] = u.kind
    if rates is not None and out.judged.any():
        _excuse_rate_misses(out, np.asarray(asked, bool), np.asarray(present, bool), truths, rates)
    return out


def rate_frames(asked: np.ndarray, judged: np.ndarray, truths: Sequence[M.GroundTruth | None],
                rates: FR.LensRates, only: Sequence[int] | None = None,
                cells: tuple[int, int] = FR.RATE_BOUND_CELLS) -> tuple[list[FR.RateFrame], FR.RateGrid]:
    """Each frame for the rates' lower bound, at its truth's simulation time, with the cells that may give its
    judged labels (only for the frames `only`, if given), and the grid (over every lens range filmed, a
    frame's travel at the frames' usual step); a frame without a judged truth keeps the last one's time (no
    time is assumed to pass), one after a gap (GAP_STEPS) starts afresh."""
    lenses = [lens_of(t) if t is not None else None for t in truths]
    have = [(t, lens) for t, lens in zip(truths, lenses) if lens is not None]
    steps = np.diff([t.stamp_ns for t, _ in have]) * 1e-9
    dt = float(np.median(steps)) if len(have) > 1 else 1.0
    # the cells are a move over the longest step between consecutive frames (not a gap), so that every such
    # step moves the lens `cells` cells at most, however the stamps round
    regular = steps[(steps > 0) & (steps <= GAP_STEPS * dt)]
    grid = FR.rate_grid((min(x.focus_m[0] for _, x in have), max(x.focus_m[1] for _, x in have)),
                        (min(x.f_number[0] for _, x in have), max(x.f_number[1] for _, x in have)), rates,
                        float(regular.max()) if regular.size else dt, cells, slack_s=STAMP_SLACK_S)
    wanted = set(range(len(truths)) if only is None else only)
    # times from the first stamp, in whole nanoseconds first: a stamp since the epoch (1.8e18 ns) in float
    # seconds keeps only about 0.2 microseconds: half the parkour rack's steps read as 2.000004 cells
    t0 = int(have[0][0].stamp_ns)
    t_s, out = 0.0, []
    for i, (t, lens) in enumerate(zip(truths, lenses)):
        possible, fresh = None, False
        if lens is not None:
            now = (int(t.stamp_ns) - t0) * 1e-9
            fresh, t_s = now - t_s > GAP_STEPS * dt, now
            if judged[i].any() and i in wanted:
                possible = FR.possible_cells(grid, lens, asked[i], judged[i], np.asarray(t.region_inverse_depth, float))
        out.append(FR.RateFrame(t_s, possible, fresh))
    return out, grid


#: a step between two frames may be this much longer than their stamps say (each stamp rounded to the
#: nanosecond)
STAMP_SLACK_S = 1e-9
#: more time than this many frames' steps between two truths is a gap (a new take, frames lost): after it
#: the lens may be anywhere
GAP_STEPS = 1.5
#: the frames either side of a switch (or of a run of switches closer than twice that) the first look judges
FIRST_LOOK = 12
#: its cells per frame's travel (coarser than the verdict's: a looser bound, found for less)
FIRST_LOOK_CELLS = (1, 1)


def _binding_switches(asked: np.ndarray, judged: np.ndarray, truths: Sequence[M.GroundTruth | None],
                      rates: FR.LensRates, missed: np.ndarray) -> list[int]:
    """The label switches, judged on both sides, round which any lens misses a frame and the flight did: a
    first look at FIRST_LOOK frames either side of each run of them (a switch left out is only excused
    less)."""
    sw = np.asarray(FR.label_switches(asked), int)
    sw = [int(s) for s in sw[((asked[sw] != asked[sw - 1]) & judged[sw] & judged[sw - 1]).any(axis=1)]]
    if not sw:
        return []
    runs = np.split(np.asarray(sw), np.flatnonzero(np.diff(sw) > 2 * FIRST_LOOK) + 1)  # switches a lens may race
    spans = [(max(0, int(r[0]) - FIRST_LOOK), min(len(truths), int(r[-1]) + FIRST_LOOK)) for r in runs]
    keep = [k for k, (a, b) in enumerate(spans) if missed[a:b].any()]
    runs, spans = [runs[k] for k in keep], [spans[k] for k in keep]
    frames, grid = rate_frames(asked, judged, truths, rates, only=[i for a, b in spans for i in range(a, b)],
                               cells=FIRST_LOOK_CELLS)
    return [int(s) for r, (a, b) in zip(runs, spans) if FR.rate_least_misses(frames[a:b], grid) > 0 for s in r]


def _excuse_rate_misses(out: Reach, asked: np.ndarray, present: np.ndarray, truths: Sequence[M.GroundTruth | None],
                        rates: FR.LensRates) -> None:
    """Mark the misses rate_windows excuses: per excused frame one region the flight missed, of those whose
    label the switch changed if any, the last in the order labels are granted (as a combination out of reach
    is reported), with the rates and the bound."""
    stamps = [t.stamp_ns for t in truths if t is not None and lens_of(t) is not None]
    if np.any(np.diff(stamps) <= 0):  # no time between frames would stop the lens: no bound without a clock
        return
    depths = np.array([np.isfinite(np.asarray(t.region_inverse_depth, float)).all(axis=1)
                       if j else np.zeros(3, bool) for t, j in zip(truths, out.judged)], bool).reshape(-1, 3)
    judged = present & ~out.unreachable & depths
    got = np.array([t.region_in_focus if t is not None else np.zeros(3, bool) for t in truths], bool).reshape(-1, 3)
    wrong = judged & (got != asked)
    binding = _binding_switches(asked, judged, truths, rates, wrong.any(axis=1))
    if not binding:
        return  # no switch round which a lens must miss and this flight did: no cells to build
    frames, grid = rate_frames(asked, judged, truths, rates)
    out.rate_windows.extend(FR.rate_windows(frames, grid, asked, wrong.any(axis=1), binding))
    for w in out.rate_windows:
        for i in w.excused:
            r = _excused_region(i, w.switches, asked, wrong[i])
            out.unreachable[i, r] = True
            out.kinds[i, r] = "rate"
            out.reasons[i, r] = (f"{FR.REGIONS[r]} {'sharp' if asked[i, r] else 'soft'}: the focus moves at most "
                                 f"{rates.focus_mps:g} m/s and the f-number {rates.f_number_ps:g}/s, so any lens "
                                 f"misses at least {w.least} of frames {w.first}-{w.last} round the "
                                 f"{_switch_words(w.switches)} (this flight missed {len(w.missed)} of them)")


def _excused_region(i: int, switches: tuple[int, ...], asked: np.ndarray, wrong: np.ndarray) -> int:
    """Of the regions the flight missed in frame i, one the nearest switch racked if any, the last granted."""
    at = min(switches, key=lambda s: abs(i - s + 0.5))
    racked = [r for r in reversed(FR.PRIORITY) if wrong[r] and asked[at, r] != asked[at - 1, r]]
    return racked[0] if racked else next(r for r in reversed(FR.PRIORITY) if wrong[r])


def _switch_words(switches: tuple[int, ...]) -> str:
    if len(switches) == 1:
        return f"switch at frame {switches[0]}"
    return f"switches at frames {', '.join(map(str, switches[:-1]))} and {switches[-1]}"


def runs(rch: Reach, t_s: np.ndarray, rows: np.ndarray, shot_rows: Sequence[int] = ()) -> list[dict[str, Any]]:
    """Consecutive unreachable frames per region (and shot) of one kind of verdict as report rows: region, shot
    (by the source row `rows` each frame follows; `shot_rows`: the first row of every shot after the first),
    kind (focus_reach.Unreachable.kind), first and last output frame, frames, time span, and the
    reason at its first and last frame. Cut where the kind changes: a run of frames needing a wider aperture with a
    knife edge at each end read as knife edges throughout when only its ends' reasons were shown."""
    bounds = [0, *sorted(int(r) for r in shot_rows)]
    out = []
    for r, name in enumerate(FR.REGIONS):
        idx = np.flatnonzero(rch.unreachable[:, r])
        if idx.size == 0:
            continue
        shot = np.searchsorted(bounds, np.asarray(rows)[idx], side="right") - 1
        kind = rch.kinds[idx, r]
        cut = np.flatnonzero((np.diff(idx) > 1) | (np.diff(shot) != 0) | (kind[1:] != kind[:-1])) + 1
        for seg in np.split(np.arange(idx.size), cut):
            a, b = int(idx[seg[0]]), int(idx[seg[-1]])
            first, last = str(rch.reasons[a, r]), str(rch.reasons[b, r])
            out.append({"region": name, "shot": int(shot[seg[0]]), "kind": str(kind[seg[0]]),
                        "first_frame": a, "last_frame": b,
                        "frames": int(seg.size), "t_s": [float(t_s[a]), float(t_s[b])],
                        "reason": first, "reason_last": last if last != first else None})
    return out


def window_rows(rch: Reach, t_s: np.ndarray) -> list[dict[str, Any]]:
    """The rate windows as report rows: the switch, the window's frames and time span, the least misses any
    lens at the rates makes there against the flight's misses, and how many of those are excused."""
    return [{"switch_frames": list(w.switches), "first_frame": w.first, "last_frame": w.last,
             "t_s": [float(t_s[w.first]), float(t_s[w.last])], "least_misses": w.least,
             "flown_misses": len(w.missed), "excused": len(w.excused)} for w in rch.rate_windows]
