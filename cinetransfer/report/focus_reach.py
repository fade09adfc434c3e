"""Which asked focus labels any lens setting could have given, per frame and region (pure numpy).

The style asks each region (foreground, subject, background) to be sharp or soft. Whether a lens
can do it depends on the scene: where each region's pixels lie in depth, at the focal length and
distances the framing needs. For one filmed frame (its focal length and its regions' depths, both
from the simulator's truth) this module searches every focus distance and f-number in the vehicle's
lens range (thin lens, the one circle of confusion of shared/camera.py) for a setting that gives the
asked labels, and where there is none says why.

A region is in focus when at least half its pixels (camera.REGION_IN_FOCUS_SHARE) lie inside the
depth of field; a region's depths come as its n quantiles at (i + 1/2) / n (truth.depth_sample, the
inverted CDF). When k of them lie inside a depth of field, its true share of the region's pixels lies
strictly between (k - 1) / n and (k + 1) / n. A label counts as reachable with a setting when that
bound does not rule it out (sharp: (k + 1) / n > the threshold; soft: (k - 1) / n below it), so a
frame is excused only when the sample proves every setting wrong, never for being near the line.

The focus distances searched are, per f-number, those where a limit of the depth of field meets a
sample's depth and the ones between (the shares change only there), so no window of settings between
grid points is missed.

Combinations: regions are taken in the order subject, background, foreground (the subject is the
shot's point); a region is unreachable when no setting gives its label together with the labels
of the reachable regions before it. The reason names the first relaxation that would have made it
reachable: a wider aperture or a smaller one ("needs f/0.64"), focus beyond the lens's range
("needs focus at 4.0 m or beyond"), both, or none at all (the region lies at the depth of a region
asked otherwise: "foreground at the subject's depth").

The lens holds a wanted setting only to within shared.camera.LENS_HOLD (the bridge sends no smaller
change): a label counts as reachable only when some wanted setting gives it, together with the labels
granted before it, wherever inside that hold the lens settles. A combination that only a window
narrower than the hold gives is out of reach "on a knife edge" (kind 'hold'), the hold named in the
reason of every such frame.

Where the labels are reachable together, label_window says where (the settings' span) and how near the line: the
most blur the soft regions' medians keep at one setting that gives them all (blur_circles), in circles of the one
circle; the report names it for each frame the flight missed within reach.

Over time the lens moves its focus and f-number at most at the vehicle's rates. rate_min_misses counts
the fewest frames a grid lens so limited misses the asked labels (a dynamic programme over a grid of
settings: an upper bound on the fewest, for benchmarks). rate_least_misses is a proven lower bound (cells
that may give the labels, a lens anywhere in a cell, moving as many cells as a frame's travel spans).
rate_windows turns it into a verdict per frame (kind 'rate'): round the label switches, a window that
forces that many misses, and in it no more of the flight's own misses than the bound (docs/report.md,
"The lens's rates").
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cinetransfer.shared.camera import COC_MM, LENS_HOLD, REGION_IN_FOCUS_SHARE

REGIONS: tuple[str, ...] = ("foreground", "subject", "background")
#: the order in which asked labels are granted (indices into REGIONS)
PRIORITY: tuple[int, ...] = (1, 2, 0)
#: the search grid's f-numbers, log-spaced over the range searched (the focus distances are where a
#: limit meets a sample's depth: _focus_events)
N_APERTURE = 96
#: how far the reason's search relaxes the lens: any f-number in this range, focus out to this
RELAXED_F_NUMBER = (0.05, 256.0)
RELAXED_FOCUS_MAX_M = 1.0e5
BISECT_STEPS = 40
#: the finer grid of the other setting while bisecting one (the needed value to ~0.3 %)
N_FINE = 1000
#: the focus distances label_window refines its most blurring setting on, across the span that gives the labels
N_FINE_WINDOW = 400


@dataclass(frozen=True)
class Lens:
    """What the frame was filmed with and what the vehicle's lens can do."""

    focal_mm: float
    focus_m: tuple[float, float]  # nearest and farthest focus distance [m]
    f_number: tuple[float, float]  # smallest and largest f-number
    coc_mm: float = COC_MM
    #: how closely the lens holds a wanted focus (relative, x max(1, focus in m)) and f-number
    hold_focus: float = LENS_HOLD["focus_distance_m"]
    hold_f_number: float = LENS_HOLD["f_number"]


@dataclass(frozen=True)
class Unreachable:
    region: int
    kind: str  # 'depth' | 'f_number' | 'focus' | 'f_number_and_focus' | 'hold' | 'rate'
    reason: str
    needs_f_number: float | None = None
    needs_focus_m: float | None = None


def dof_inverse(focal_mm: float, f_number: np.ndarray, focus_m: np.ndarray,
                coc_mm: float = COC_MM) -> tuple[np.ndarray, np.ndarray]:
    """(1/far, 1/near) [1/m] of the depth of field (thin lens, as camera.dof_limits_m); 1/far = 0
    when the depth of field reaches infinity (focus at or beyond the hyperfocal distance)."""
    f = focal_mm / 1000.0
    n, s = np.broadcast_arrays(np.asarray(f_number, float), np.asarray(focus_m, float))
    h = (focal_mm * focal_mm / (n * coc_mm) + focal_mm) / 1000.0
    inv_near = (h + s - 2.0 * f) / (s * (h - f))
    inv_far = np.maximum(h - s, 0.0) / (s * (h - f))
    return inv_far, inv_near


def in_focus_count(inv_depth: np.ndarray, inv_far: np.ndarray, inv_near: np.ndarray) -> np.ndarray:
    """How many of a region's depth samples lie inside each depth of field: (S,) samples, (G,) settings -> (G,)."""
    d = np.sort(np.asarray(inv_depth, float))
    return np.searchsorted(d, inv_near, side="right") - np.searchsorted(d, inv_far, side="left")


def in_focus_share(inv_depth: np.ndarray, inv_far: np.ndarray, inv_near: np.ndarray) -> np.ndarray:
    """Share of a region's depth sample inside each depth of field: (S,) samples, (G,) settings -> (G,)."""
    return in_focus_count(inv_depth, inv_far, inv_near) / np.asarray(inv_depth).size


def may_reach(inside: np.ndarray, n: int, sharp: bool) -> np.ndarray:
    """Whether `inside` of a region's n quantiles in the depth of field leaves its asked label possible:
    the true share lies strictly between (inside - 1) / n and (inside + 1) / n (module docstring)."""
    inside = np.asarray(inside)
    if sharp:
        return inside + 1 > REGION_IN_FOCUS_SHARE * n
    return inside - 1 < REGION_IN_FOCUS_SHARE * n


def _reaches(inv_depth: np.ndarray, inv_far: np.ndarray, inv_near: np.ndarray, sharp: bool) -> np.ndarray:
    return may_reach(in_focus_count(inv_depth, inv_far, inv_near), np.asarray(inv_depth).size, sharp)


def _grid(lo: float, hi: float, n: int) -> np.ndarray:
    return np.geomspace(lo, hi, n) if hi > lo else np.array([lo])


def _feasible(lens: Lens, n: np.ndarray, s: np.ndarray, regions: list[int], asked: np.ndarray,
              inv_depth: np.ndarray, flips: np.ndarray | None = None) -> np.ndarray:
    """Per setting (n, s broadcast together): every region in `regions` gets its asked label. With `flips`
    (3,) [circles of the one circle] each region is judged by its own circle (focus_read): a region flipping
    at k circles has the one circle's field at k times the f-number."""
    fields: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    ok = np.ones(np.broadcast(np.asarray(n), np.asarray(s)).shape, bool)
    for r in regions:
        k = 1.0 if flips is None else float(flips[r])
        if k not in fields:
            fields[k] = dof_inverse(lens.focal_mm, np.asarray(n, float) * k, s, lens.coc_mm)
        inv_far, inv_near = fields[k]
        ok &= _reaches(inv_depth[r], inv_far.ravel(), inv_near.ravel(), bool(asked[r])).reshape(ok.shape)
    return ok


def _focus_events(focal_mm: float, f_number: np.ndarray, x: np.ndarray, coc_mm: float) -> np.ndarray:
    """Per f-number (N,), the focus distances [m] (N, 2 M) at which the far and the near limit meet
    each inverse depth x (M,) > 0 (NaN where none does): from dof_inverse, 1/far = x at
    s = H / (1 + x (H - f)) and 1/near = x at s = (H - 2 f) / (x (H - f) - 1)."""
    f = focal_mm / 1000.0
    h = ((focal_mm * focal_mm / (np.asarray(f_number, float) * coc_mm) + focal_mm) / 1000.0)[:, None]
    x = np.asarray(x, float)[None, :]
    far = h / (1.0 + x * (h - f))
    den = x * (h - f) - 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        near = np.where(den > 0, (h - 2.0 * f) / den, np.nan)
    return np.concatenate([far, near], axis=1)


def _settings(lens: Lens, n_range: tuple[float, float], s_range: tuple[float, float],
              inv_depth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(f-numbers, focus distances) to search: N_APERTURE f-numbers, each with the focus distances in
    s_range where a limit meets one of the samples `inv_depth` (any shape; NaN and 0 ignored), the
    range's ends and the geometric midpoints between consecutive ones (every share they give)."""
    n = _grid(*n_range, N_APERTURE)
    x = np.asarray(inv_depth if inv_depth is not None else [], float).ravel()
    x = np.unique(x[np.isfinite(x) & (x > 0)])
    ev = _focus_events(lens.focal_mm, n, x, lens.coc_mm)
    lo, hi = s_range
    ev = np.where((ev >= lo) & (ev <= hi), ev, np.nan)
    ev = np.sort(np.concatenate([ev, np.full((n.size, 1), lo), np.full((n.size, 1), hi)], axis=1), axis=1)
    return with_midpoints(n, ev)


def with_midpoints(n: np.ndarray, events: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(f-numbers, focus distances) of each f-number `n` (N,) with its sorted focus `events` (N, K; NaN
    where none) and the geometric midpoints between consecutive ones: every share the events bound."""
    with np.errstate(invalid="ignore"):
        mid = np.sqrt(events[:, 1:] * events[:, :-1])
    s = np.concatenate([events, mid], axis=1)
    nn = np.broadcast_to(n[:, None], s.shape)
    keep = np.isfinite(s)
    return nn[keep], s[keep]


def _any(lens: Lens, n_range, s_range, regions, asked, inv_depth) -> tuple[np.ndarray, np.ndarray]:
    """The settings over n_range x s_range that give every label: (f-numbers, focus)."""
    n, s = _settings(lens, n_range, s_range, inv_depth[regions])
    ok = _feasible(lens, n, s, regions, asked, inv_depth)
    return n[ok], s[ok]


def _bisect(ok_at, good: float, bad: float) -> float:
    """The boundary between a value that works and one that does not (geometric bisection)."""
    for _ in range(BISECT_STEPS):
        mid = math.sqrt(good * bad)
        good, bad = (mid, bad) if ok_at(mid) else (good, mid)
    return good


def _needed_f_number(lens: Lens, regions, asked, inv_depth, s_range) -> float | None:
    """The f-number nearest the lens's range that gives the labels with focus in range, or None."""
    n_ok, _ = _any(lens, RELAXED_F_NUMBER, s_range, regions, asked, inv_depth)
    if n_ok.size == 0:
        return None
    lo, hi = lens.f_number
    s = _grid(*s_range, N_FINE)

    def ok_at(n: float) -> bool:
        return bool(_feasible(lens, np.full_like(s, n), s, regions, asked, inv_depth).any())

    below, above = n_ok[n_ok < lo], n_ok[n_ok > hi]
    if below.size and (not above.size or math.log(lo / below.max()) <= math.log(above.min() / hi)):
        return _bisect(ok_at, float(below.max()), lo)
    return _bisect(ok_at, float(above.min()), hi) if above.size else None


def _needed_focus(lens: Lens, regions, asked, inv_depth) -> float | None:
    """The focus distance nearest the lens's range that gives the labels with an f-number in range."""
    s_lo = max(lens.focal_mm / 1000.0 * 1.001, 1e-3)
    _, s_ok = _any(lens, lens.f_number, (s_lo, RELAXED_FOCUS_MAX_M), regions, asked, inv_depth)
    if s_ok.size == 0:
        return None
    n = _grid(*lens.f_number, N_FINE)

    def ok_at(s: float) -> bool:
        return bool(_feasible(lens, n, np.full_like(n, s), regions, asked, inv_depth).any())

    near, far = s_ok[s_ok < lens.focus_m[0]], s_ok[s_ok > lens.focus_m[1]]
    if far.size and (not near.size or math.log(far.min() / lens.focus_m[1]) <= math.log(lens.focus_m[0] / near.max())):
        return _bisect(ok_at, float(far.min()), lens.focus_m[1])
    return _bisect(ok_at, float(near.max()), lens.focus_m[0]) if near.size else None


def _held_focus_fits(a: float, b: float, lens: Lens) -> bool:
    """Whether some wanted focus puts every focus the lens may settle at (within the hold) inside [a, b];
    an end of [a, b] at an end of the lens's range is open (the lens goes no further)."""
    lo, hi = lens.focus_m
    rel = lens.hold_focus
    # the least wanted focus whose hold starts at a or later: a settled focus x holds s when |s - x| <= rel max(1, x)
    s0 = lo if a <= lo else (a * (1.0 + rel) if a >= 1.0 else a + rel)
    if s0 > hi:
        return False
    top = s0 / (1.0 - rel) if s0 >= 1.0 - rel else s0 + rel
    return b >= hi or top <= b


def _held_reaches(lens: Lens, regions: list[int], asked: np.ndarray, inv_depth: np.ndarray) -> bool:
    """Whether a wanted setting gives every label of `regions` over its whole hold (module docstring).

    Per wanted f-number n the lens settles within [n - h, n + h] (clipped to its range): the depth of field
    is narrowest at the smallest and widest at the largest, and every other one lies between them, so a
    sharp label is judged at the smallest, a soft one at the largest. Over focus the shares change only
    where a limit meets a sample; between those the verdict is constant, and a wanted focus works when its
    hold lies within one run of good stretches."""
    lo_n, hi_n = lens.f_number
    n0 = _grid(lo_n, hi_n, N_APERTURE)
    n_at = {True: np.maximum(lo_n, n0 - lens.hold_f_number), False: np.minimum(hi_n, n0 + lens.hold_f_number)}
    events = []
    for sharp in (True, False):
        x = inv_depth[[r for r in regions if bool(asked[r]) == sharp]].ravel()
        x = np.unique(x[np.isfinite(x) & (x >= 0)])
        events.append(_focus_events(lens.focal_mm, n_at[sharp], x, lens.coc_mm))
    lo, hi = lens.focus_m
    ev = np.concatenate(events, axis=1)
    ev = np.where((ev > lo) & (ev < hi), ev, np.nan)
    ends = np.ones((n0.size, 1))
    ev = np.sort(np.concatenate([lo * ends, ev, hi * ends], axis=1), axis=1)
    with np.errstate(invalid="ignore"):
        mid = np.sqrt(ev[:, 1:] * ev[:, :-1])
    good = np.isfinite(mid)
    mid = np.where(good, mid, lo)
    for r in regions:
        sharp = bool(asked[r])
        inv_far, inv_near = dof_inverse(lens.focal_mm, n_at[sharp][:, None], mid, lens.coc_mm)
        good &= _reaches(inv_depth[r], inv_far.ravel(), inv_near.ravel(), sharp).reshape(good.shape)
    for g in np.flatnonzero(good.any(axis=1)):
        idx = np.flatnonzero(good[g])
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            if _held_focus_fits(float(ev[g, run[0]]), float(ev[g, run[-1] + 1]), lens):
                return True
    return False


def _knife_edge(lens: Lens, r: int, kept: list[int], asked: np.ndarray) -> Unreachable:
    what = _label(r, asked) + (" with " + ", ".join(_label(k, asked) for k in kept) if kept else "")
    return Unreachable(r, "hold", f"{what}: only on a knife edge, narrower than the lens holds "
                                  f"(focus ±{100 * lens.hold_focus:g} %, f-number ±{lens.hold_f_number:g})")


def _label(r: int, asked: np.ndarray) -> str:
    return f"{REGIONS[r]} {'sharp' if asked[r] else 'soft'}"


def _depth_twin(r: int, kept: list[int], asked: np.ndarray, inv_depth: np.ndarray) -> int | None:
    """The region granted before `r`, asked otherwise, whose depths overlap r's the most."""
    best, best_share = None, 0.0
    for k in kept:
        if bool(asked[k]) == bool(asked[r]):
            continue
        lo, hi = np.nanmin(inv_depth[k]), np.nanmax(inv_depth[k])
        share = float(np.mean((inv_depth[r] >= lo) & (inv_depth[r] <= hi)))
        if share > best_share:
            best, best_share = k, share
    return best


def _why(lens: Lens, r: int, kept: list[int], asked: np.ndarray, inv_depth: np.ndarray) -> Unreachable:
    regions = kept + [r]
    what = _label(r, asked) + (" with " + ", ".join(_label(k, asked) for k in kept) if kept else "")
    n_need = _needed_f_number(lens, regions, asked, inv_depth, lens.focus_m)
    if n_need is not None:
        edge = (f"the lens opens to f/{lens.f_number[0]:g}" if n_need < lens.f_number[0]
                else f"the lens stops down to f/{lens.f_number[1]:g}")
        return Unreachable(r, "f_number", f"{what}: needs f/{n_need:.2g} ({edge})", needs_f_number=n_need)
    s_need = _needed_focus(lens, regions, asked, inv_depth)
    if s_need is not None:
        if s_need > lens.focus_m[1]:
            text = f"needs focus at {s_need:.3g} m or beyond (the lens focuses to {lens.focus_m[1]:g} m)"
        else:
            text = f"needs focus at {s_need:.3g} m or nearer (the lens focuses from {lens.focus_m[0]:g} m)"
        return Unreachable(r, "focus", f"{what}: {text}", needs_focus_m=s_need)
    wide = (max(lens.focal_mm / 1000.0 * 1.001, 1e-3), RELAXED_FOCUS_MAX_M)
    n_ok, s_ok = _any(lens, RELAXED_F_NUMBER, wide, regions, asked, inv_depth)
    if n_ok.size:
        i = int(np.argmin(np.abs(np.log(n_ok / np.clip(n_ok, *lens.f_number)))
                          + np.abs(np.log(s_ok / np.clip(s_ok, *lens.focus_m)))))
        return Unreachable(r, "f_number_and_focus", f"{what}: needs f/{n_ok[i]:.2g} with focus at {s_ok[i]:.3g} m "
                           "(outside the lens's range in both)", needs_f_number=float(n_ok[i]),
                           needs_focus_m=float(s_ok[i]))
    twin = _depth_twin(r, kept, asked, inv_depth)
    where = f"at the {REGIONS[twin]}'s depth" if twin is not None else "at the depths of the regions asked otherwise"
    return Unreachable(r, "depth", f"{REGIONS[r]} {where}: no lens gives {what}")


def unreachable_labels(lens: Lens, asked: np.ndarray, present: np.ndarray,
                       inv_depth: np.ndarray) -> list[Unreachable]:
    """The asked labels of one frame that no focus distance and f-number in the lens's range gives.

    asked, present: (3,) bool per region (foreground, subject, background); inv_depth: (3, S) each
    region's inverse depths [1/m] (0 = infinity). Regions absent or without depths are skipped."""
    asked = np.asarray(asked, bool)
    inv_depth = np.asarray(inv_depth, float)
    present = np.asarray(present, bool)
    n, s = _settings(lens, lens.f_number, lens.focus_m, inv_depth[present])
    inv_far, inv_near = dof_inverse(lens.focal_mm, n, s, lens.coc_mm)
    granted = np.ones(n.shape, bool)  # the settings that give every label granted so far
    kept: list[int] = []
    out: list[Unreachable] = []
    for r in PRIORITY:
        if not present[r] or inv_depth.shape[1] == 0 or not np.isfinite(inv_depth[r]).all():
            continue
        with_r = granted & _reaches(inv_depth[r], inv_far, inv_near, bool(asked[r]))
        if not with_r.any():
            out.append(_why(lens, r, kept, asked, inv_depth))
        elif not _held_reaches(lens, kept + [r], asked, inv_depth):
            out.append(_knife_edge(lens, r, kept, asked))
        else:
            kept.append(r)
            granted = with_r
    return out


@dataclass(frozen=True)
class Window:
    """The settings in the lens's range that give a frame's labels together, and how far from the line they are."""

    f_number: tuple[float, float]  # the span of f-numbers that give them
    focus_m: tuple[float, float]  # the span of focus distances [m] that give them
    best: tuple[float, float]  # (f-number, focus [m]) of the setting that blurs the soft regions most
    #: the blur [circles of the one circle] of the least blurred soft region's median at `best`; None: none soft
    soft_circles: float | None


def blur_circles(focal_mm: float, f_number: np.ndarray, focus_m: np.ndarray, inv_depth: np.ndarray,
                 coc_mm: float = COC_MM) -> np.ndarray:
    """The blur [circles of `coc_mm`] of a point at inverse depth `inv_depth` [1/m] with the lens at each
    setting: |1/s - x| over the field's half-width in inverse depth, (s - f) / (s (H - f)) (dof_inverse), which is
    the thin lens's blur diameter f^2 s |1/s - x| / (N (s - f)) over the circle."""
    f = focal_mm / 1000.0
    n, s = np.broadcast_arrays(np.asarray(f_number, float), np.asarray(focus_m, float))
    h = (focal_mm * focal_mm / (n * coc_mm) + focal_mm) / 1000.0
    return np.abs(1.0 / s - inv_depth) * s * (h - f) / (s - f)


def label_window(lens: Lens, asked: np.ndarray, present: np.ndarray, inv_depth: np.ndarray) -> Window | None:
    """Where the lens gives every present label of one frame together (the may_reach rule, exact, no hold), None
    where nothing does or no region has depths. Per combination the one number that says how far from the line it
    is: the most blur the soft regions' medians keep at one setting that gives them all (the least of them), so a
    frame within reach only at about 1 circle is seen as the knife edge it is, whatever the flight did."""
    asked, present, inv_depth = np.asarray(asked, bool), np.asarray(present, bool), np.asarray(inv_depth, float)
    regions = [r for r in PRIORITY if present[r] and inv_depth.shape[1] and np.isfinite(inv_depth[r]).all()]
    if not regions:
        return None
    n, s = _settings(lens, lens.f_number, lens.focus_m, inv_depth[regions])
    ok = _feasible(lens, n, s, regions, asked, inv_depth)
    if not ok.any():
        return None
    n, s = n[ok], s[ok]
    span = (float(n.min()), float(n.max())), (float(s.min()), float(s.max()))
    soft = [r for r in regions if not asked[r]]
    if not soft:
        return Window(*span, (float(n[0]), float(s[0])), None)

    def least_blur(n_: np.ndarray, s_: np.ndarray) -> np.ndarray:
        return np.min([blur_circles(lens.focal_mm, n_, s_, float(np.median(inv_depth[r])), lens.coc_mm)
                       for r in soft], axis=0)

    # the candidates' best, then a fine focus grid over the span at its f-number and at the widest that gives
    # the labels (the narrowest field), so the most blur is found to ~N_FINE_WINDOW steps of the span
    i = int(np.argmax(least_blur(n, s)))
    fine_s = np.tile(_grid(*span[1], N_FINE_WINDOW), 2)
    fine_n = np.repeat([n[i], span[0][0]], N_FINE_WINDOW)
    ok = _feasible(lens, fine_n, fine_s, regions, asked, inv_depth)
    n, s = np.append(n[i], fine_n[ok]), np.append(s[i], fine_s[ok])
    blur = least_blur(n, s)
    j = int(np.argmax(blur))
    return Window(*span, (float(n[j]), float(s[j])), float(blur[j]))


#: the rate grid's cells per frame of travel (focus, f-number): a move of the lens's rate over one frame
#: is RATE_SUBSTEPS cells, so the grid's moves are exactly the ones the rates allow at the nominal frame step
RATE_SUBSTEPS = (8, 4)


@dataclass(frozen=True)
class LensRates:
    """How fast the vehicle's lens moves (the vehicle profile's lens rates)."""

    focus_mps: float
    f_number_ps: float


def _rate_grid(lens: Lens, rates: LensRates, dt_s: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """(focus distances, f-numbers) of the rate grid, uniform in metres and in f-number, and the cells
    one frame step's move spans: each step is the rate's move over dt_s / RATE_SUBSTEPS."""
    steps = (rates.focus_mps * dt_s / RATE_SUBSTEPS[0], rates.f_number_ps * dt_s / RATE_SUBSTEPS[1])
    axes = [np.append(np.arange(lo, hi, st), hi) for (lo, hi), st in zip((lens.focus_m, lens.f_number), steps)]
    return axes[0], axes[1], RATE_SUBSTEPS


def _spread_min(cost: np.ndarray, cells: tuple[int, int]) -> np.ndarray:
    """Per grid setting, the least cost of a setting within `cells` of it (per axis): where a lens that
    ended the last frame anywhere may be now (the box the rates allow)."""
    out = cost
    for axis, k in enumerate(cells):
        src, out = out, out.copy()
        n = src.shape[axis]
        for shift in range(1, min(k, n - 1) + 1):
            lo, hi = [slice(None)] * src.ndim, [slice(None)] * src.ndim
            lo[axis], hi[axis] = slice(shift, None), slice(None, n - shift)
            np.minimum(out[tuple(lo)], src[tuple(hi)], out=out[tuple(lo)])
            np.minimum(out[tuple(hi)], src[tuple(lo)], out=out[tuple(hi)])
    return out


def _grid_feasible(lens: Lens, s: np.ndarray, n: np.ndarray, r: int, asked: np.ndarray,
                   inv_depth: np.ndarray) -> np.ndarray:
    """(S, N) grid: the setting gives region r its asked label (the may_reach rule)."""
    inv_far, inv_near = dof_inverse(lens.focal_mm, n[None, :], s[:, None], lens.coc_mm)
    return _reaches(inv_depth[r], inv_far.ravel(), inv_near.ravel(), bool(asked[r])).reshape(inv_far.shape)


def rate_min_misses(lenses: list[Lens | None], asked: np.ndarray, judged: np.ndarray, inv_depth: np.ndarray,
                    rates: LensRates, dt_s: float, regions: tuple[int, ...]) -> int:
    """The fewest frames in which a lens moving at most at `rates` misses a judged label of `regions`.

    lenses: one per frame (None = nothing judged; the lens moves on); asked, judged: (N, 3) bool, the
    asked labels and where they count (the region present and within each frame's own reach,
    unreachable_labels); inv_depth: (N, 3, S); frames dt_s apart. A dynamic programme over the frames:
    per lens setting, the fewest misses of any path ending there, the path moving at most a frame's
    travel of focus and f-number between frames. The settings are a grid uniform in metres of focus and
    in f-number whose cells are a frame's travel / RATE_SUBSTEPS, so every grid path is one the rates
    allow. The focal length is taken as filmed (it is the framing's)."""
    asked, judged = np.asarray(asked, bool), np.asarray(judged, bool)
    cost: np.ndarray | None = None
    cells = RATE_SUBSTEPS
    for i, lens in enumerate(lenses):
        if lens is None:  # nothing judged, the lens moves on at its rates
            cost = _spread_min(cost, cells) if cost is not None else None
            continue
        s, n, cells = _rate_grid(lens, rates, dt_s)
        ok = np.ones((s.size, n.size), bool)
        for r in regions:
            if judged[i, r]:
                ok &= _grid_feasible(lens, s, n, r, asked[i], inv_depth[i])
        here = np.where(ok, 0, 1) if ok.any() else np.zeros(ok.shape, int)  # none on the grid: not judged
        cost = here if cost is None else _spread_min(cost, cells) + here
    return int(cost.min()) if cost is not None else 0


# --- a lower bound on the misses the lens's rates force, and the frames it excuses -----------------
#: the lower bound's cells per frame's travel (focus, f-number): finer is tighter and costs more
RATE_BOUND_CELLS = (2, 2)
#: the pieces a focus cell is judged in, at most this far apart in 1/focus [1/m]
RATE_SUB_INVERSE_M = 0.008


@dataclass(frozen=True)
class RateGrid:
    """Cells of focus [m] and f-number, uniform, each a frame's travel at the rates / RATE_BOUND_CELLS."""

    focus_edges: np.ndarray
    f_number_edges: np.ndarray
    rates: LensRates
    #: the focus cells cut into pieces (_sub_edges): their edges, and the first piece of every cell
    pieces: np.ndarray = field(default_factory=lambda: np.zeros(0))
    piece_of: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    #: how much longer than its stamps say a step between frames may be (the stamps' rounding)
    slack_s: float = 0.0

    def reach(self, dt_s: float) -> tuple[int, int]:
        """How many cells away a lens may be dt_s later: ceil(m) for a move of m cells.

        Cells are half-open, [e_i, e_i + w): a lens in cell i moved by at most m w lands below e_i + (1 + m) w,
        so in cell i + ceil(m) at most (i + m for a whole m, where the edge itself is the next cell's); the same
        downwards. A move within ROUNDING_CELLS of a whole number of cells counts as that number (float
        rounding of the product, not a physical move: 1e-9 of a cell is a third of a nanometre of focus)."""
        w = (self.focus_edges[1] - self.focus_edges[0], self.f_number_edges[1] - self.f_number_edges[0])
        dt = dt_s + self.slack_s
        moves = (self.rates.focus_mps * dt / w[0], self.rates.f_number_ps * dt / w[1])
        return (max(math.ceil(moves[0] - ROUNDING_CELLS), 0), max(math.ceil(moves[1] - ROUNDING_CELLS), 0))


#: RateGrid.reach: a move this close above a whole number of cells is float rounding
ROUNDING_CELLS = 1e-9


def rate_grid(focus_m: tuple[float, float], f_number: tuple[float, float], rates: LensRates, dt_s: float,
              cells: tuple[int, int] = RATE_BOUND_CELLS, slack_s: float = 0.0) -> RateGrid:
    """Cells of a move over dt_s + slack_s / `cells` (per axis): a step of up to dt_s moves a lens that many
    cells at most (RateGrid.reach), none more."""
    def edges(lo: float, hi: float, step: float) -> np.ndarray:
        return np.append(np.arange(lo, hi, step), hi) if hi > lo else np.array([lo, lo + step])

    dt = dt_s + slack_s
    focus = edges(*focus_m, rates.focus_mps * dt / cells[0])
    return RateGrid(focus, edges(*f_number, rates.f_number_ps * dt / cells[1]), rates, *_sub_edges(focus),
                    slack_s=slack_s)


@dataclass(frozen=True)
class RateFrame:
    """One frame as the lower bound sees it: when (simulation time), and per cell of the grid whether some
    setting in it may give every judged label (None: nothing judged)."""

    t_s: float
    possible: np.ndarray | None
    #: after a gap in the frames (a new take, frames lost): the lens may be anywhere, not only where the rates
    #: take it (a take may set the lens as it starts)
    fresh: bool = False


@dataclass(frozen=True)
class RateWindow:
    """Round the label switches `switches`: frames first..last force at least `least` misses on any lens
    moving at most at the rates; `missed` the flight's misses there, `excused` the ones excused."""

    switches: tuple[int, ...]
    first: int
    last: int
    least: int
    missed: tuple[int, ...]
    excused: tuple[int, ...] = field(default=())


def _count_in(inv_depth: np.ndarray, inv_far: np.ndarray, inv_near: np.ndarray) -> np.ndarray:
    return np.maximum(in_focus_count(inv_depth, inv_far.ravel(), inv_near.ravel()), 0).reshape(inv_far.shape)


def possible_cells(grid: RateGrid, lens: Lens, asked: np.ndarray, judged: np.ndarray,
                   inv_depth: np.ndarray) -> np.ndarray:
    """(S, N) cells of focus [s_a, s_b] x f-number [n_a, n_b] where some setting may give every judged label
    (a superset: no cell holding a setting that gives them is left out; settings outside the lens's range
    are clipped to it).

    Both limits of the field (as inverse depths) fall as the focus grows and as the f-number falls, so every
    field in a cell lies inside [1/far(n_b, s_b), 1/near(n_b, s_a)] and holds [1/far(n_a, s_a),
    1/near(n_a, s_b)]: a sharp label may be given in the cell when the outer interval may give it, a soft
    one when the inner may (the may_reach rule), each region alone."""
    s = np.clip(grid.pieces, *lens.focus_m)
    f = lens.focal_mm / 1000.0
    # the field in inverse depth is 1/s -+ (1 - f/s) n c / f^2 (dof_inverse: 1/far + 1/near = 2/s), the far
    # end clipped at 0: separable in focus and f-number
    u, a = 1.0 / s, 1.0 - f / s
    b = np.clip(grid.f_number_edges, *lens.f_number) * lens.coc_mm / 1000.0 / (f * f)
    ua, ub, aa, ab, na, nb = u[:-1, None], u[1:, None], a[:-1, None], a[1:, None], b[None, :-1], b[None, 1:]
    out_far, out_near = np.maximum(ub - ab * nb, 0.0), ua + aa * nb
    in_far, in_near = np.maximum(ua - aa * na, 0.0), ub + ab * na
    ok = np.ones(out_far.shape, bool)
    for r in np.flatnonzero(judged):
        sharp = bool(asked[r])
        count = _count_in(inv_depth[r], out_far, out_near) if sharp else _count_in(inv_depth[r], in_far, in_near)
        ok &= may_reach(count, inv_depth[r].size, sharp)
    return np.logical_or.reduceat(ok, grid.piece_of, axis=0)


def _sub_edges(edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The focus cells cut into pieces at most RATE_SUB_INVERSE_M apart in 1/focus (the field's centre), and
    where each cell's first piece starts. Where a frame's travel sweeps the field far (a short focus), a
    whole cell would let one region's label be judged at one end and another's at the other."""
    inv = 1.0 / edges
    k = np.maximum(np.ceil((inv[:-1] - inv[1:]) / RATE_SUB_INVERSE_M), 1).astype(int)
    pieces = [np.linspace(a, b, m + 1)[:-1] for a, b, m in zip(edges[:-1], edges[1:], k)]
    return np.append(np.concatenate(pieces), edges[-1]), np.concatenate([[0], np.cumsum(k)[:-1]])


def _spread(cost: np.ndarray, cells: tuple[int, int]) -> np.ndarray:
    """_spread_min, with a reach across a whole axis taken at once (a gap between takes)."""
    for axis, k in enumerate(cells):
        if k >= cost.shape[axis] - 1:
            cost = np.broadcast_to(cost.min(axis=axis, keepdims=True), cost.shape).copy()
            cells = (0, cells[1]) if axis == 0 else (cells[0], 0)
    return _spread_min(cost, cells)


def rate_least_misses(frames: list[RateFrame], grid: RateGrid) -> int:
    """A lower bound on the frames any lens moving at most at the grid's rates misses.

    The relaxation: a frame's labels given anywhere in its possible cells (a superset), a lens anywhere in
    a cell, so between frames it may reach every cell a move at the rates can end in (RateGrid.reach), the
    start anywhere. Over the cells the fewest misses are counted exactly (a dynamic
    programme), so no lens misses fewer. A frame with nothing judged, or no possible cell at all (nothing
    gives its labels, not the rate: the reach per frame's business), costs nothing."""
    if not frames:
        return 0
    cost = np.zeros((grid.focus_edges.size - 1, grid.f_number_edges.size - 1), np.int32)
    t_prev = frames[0].t_s
    for f in frames:
        cost = np.full_like(cost, cost.min()) if f.fresh else _spread(cost, grid.reach(max(f.t_s - t_prev, 0.0)))
        t_prev = f.t_s
        if f.possible is not None and f.possible.any():
            cost += ~f.possible
    return int(cost.min())


def label_switches(asked: np.ndarray) -> list[int]:
    return [int(i) for i in np.flatnonzero((asked[1:] != asked[:-1]).any(axis=1)) + 1]


def _parts(frames: list[RateFrame], grid: RateGrid, switches: list[int]) -> list[tuple[int, int, list[int], int]]:
    """Parts [a, b) of the timeline with their switches and least misses: cut halfway between two switches
    only where the parts' bounds add up to the whole's (a cut through a lens's travel would lose forced
    misses)."""
    out, a, group = [], 0, switches[:1]
    rest = rate_least_misses(frames, grid)  # the bound of frames[a:]
    for nxt in switches[1:]:
        c = (group[-1] + nxt) // 2
        left, right = rate_least_misses(frames[a:c], grid), rate_least_misses(frames[c:], grid)
        if left + right == rest:
            out.append((a, c, group, left))
            a, group, rest = c, [], right
        group.append(nxt)
    out.append((a, len(frames), group, rest))
    return out


def rate_windows(frames: list[RateFrame], grid: RateGrid, asked: np.ndarray, missed: np.ndarray,
                 switches: list[int] | None = None) -> list[RateWindow]:
    """Per switch of the asked labels (N, 3), or run of switches a lens travels through, the frames the lens's
    rates force any lens to miss there, and which of the flight's misses `missed` (N,) bool that excuses.

    The timeline is cut into parts (_parts). A part's least misses k (rate_least_misses) set the window: k
    frames before its first switch to k after its last, inside the part. The window's own bound holds for
    it alone, and the windows do not overlap, so they add up to no more than the run's. In a window at most
    its bound of the flight's own misses are excused, the nearest a switch first. `switches`: the ones to
    judge (default every switch of `asked`; leaving one out can only excuse less)."""
    out: list[RateWindow] = []
    switches = label_switches(np.asarray(asked, bool)) if switches is None else switches
    for a, b, sw, part in _parts(frames, grid, switches) if switches else []:
        if part == 0:
            continue
        first, end = max(a, sw[0] - part), min(b, sw[-1] + part)
        least = rate_least_misses(frames[first:end], grid)
        miss = [i for i in range(first, end) if missed[i]]
        near = sorted(miss, key=lambda i: (min(abs(i - s + 0.5) for s in sw), i))[:least]
        if least:
            out.append(RateWindow(tuple(sw), first, end - 1, least, tuple(miss), tuple(sorted(near))))
    return out
