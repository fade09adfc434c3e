"""Which focus labels within the lens's reach the extraction can read, given where the focus estimator
flips on each region (pure numpy).

focus_reach judges a label by the one circle of confusion: the blur at which the focus estimator flips
for the reference texture (shared.camera). On another texture it flips elsewhere (0.88-1.22 circles over
the textures measured, docs/report.md; focus_flip measures a region's flip on the filmed frame). The
extraction reads a region soft only once its blur passes that region's own flip, and sharp only below it,
so where physics lets a region be soft only just past one circle the truth can meet the label and the
extraction cannot: the verdict here says so (kind 'read'), for the extraction's side only.

A region whose flip is k circles reads as if its circle were k times the one circle: its field at focus s
and f-number n is the one circle's field at f-number k n (the field's half-width in inverse depth is linear
in n c, focus_reach.dof_inverse). So the search is focus_reach's with each region's f-number scaled by its
flip: per f-number of the lens's grid, the focus distances where any region's own limit meets one of its
samples and the ones between (its verdict changes only there), and focus_reach's own test of a setting
(`_feasible` given the flips; may_reach's rule: a label stays readable unless the region's quantiles prove
every setting wrong). No hold is asked (the reach has
judged it), so this verdict can only call fewer frames out of reach than a stricter one.
"""
from __future__ import annotations

import numpy as np

from cinetransfer.report import focus_reach as FR

KIND = "read"


def _settings(lens: FR.Lens, regions: list[int], inv_depth: np.ndarray,
              flips: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(f-numbers, focus distances) to search: N_APERTURE f-numbers over the lens's range, each with the focus
    distances where a region's own limit (its f-number times its flip) meets one of its samples, the range's
    ends, and the geometric midpoints between consecutive ones."""
    n = FR._grid(*lens.f_number, FR.N_APERTURE)
    lo, hi = lens.focus_m
    cols = [np.full((n.size, 1), lo), np.full((n.size, 1), hi)]
    for r in regions:
        x = np.asarray(inv_depth[r], float)
        x = np.unique(x[np.isfinite(x) & (x > 0)])
        cols.append(FR._focus_events(lens.focal_mm, n * flips[r], x, lens.coc_mm))
    ev = np.concatenate(cols, axis=1)
    return FR.with_midpoints(n, np.sort(np.where((ev >= lo) & (ev <= hi), ev, np.nan), axis=1))


def blur_range(lens: FR.Lens, r: int, others: list[int], asked: np.ndarray, inv_depth: np.ndarray,
               flips: np.ndarray) -> tuple[float, float] | None:
    """The least and most blur [circles] region r's median has at a setting of the lens that lets the regions
    `others` be read as asked (each by its flip); None where no setting does."""
    n, s = _settings(lens, others + [r], inv_depth, flips)
    fine_n = np.repeat(FR._grid(*lens.f_number, FR.N_APERTURE), FR.N_FINE_WINDOW // 4)
    fine_s = np.tile(FR._grid(*lens.focus_m, FR.N_FINE_WINDOW // 4), FR.N_APERTURE)
    n, s = np.append(n, fine_n), np.append(s, fine_s)
    ok = FR._feasible(lens, n, s, others, asked, inv_depth, flips)
    if not ok.any():
        return None
    b = FR.blur_circles(lens.focal_mm, n[ok], s[ok], float(np.median(inv_depth[r])), lens.coc_mm)
    return float(b.min()), float(b.max())


def focus_for_blur(focal_mm: float, f_number: float, x: float, b: float, behind: bool,
                   coc_mm: float = FR.COC_MM) -> float:
    """The focus distance [m] that leaves a point at inverse depth x [1/m] b circles soft, the point behind the
    focus when `behind` (1/s above x), else in front of it: 1/s = x -+ b sigma(s) with sigma = (1 - f/s) / (H - f)
    (focus_reach.blur_circles), solved for 1/s; FOCUS_FAR_M where 1/s would be 0 or less (beyond infinity)."""
    f = focal_mm / 1000.0
    hf = focal_mm * focal_mm / (f_number * coc_mm) / 1000.0  # H - f [m]
    sgn = 1.0 if behind else -1.0
    u = (x + sgn * b / hf) / (1.0 + sgn * b * f / hf)
    return 1.0 / u if u > 0 else FOCUS_FAR_M


#: focus_for_blur's answer where the blur asked needs a focus past infinity
FOCUS_FAR_M = 1.0e5


def unreadable_labels(lens: FR.Lens, asked: np.ndarray, judged: np.ndarray, inv_depth: np.ndarray,
                      flips: np.ndarray) -> list[FR.Unreachable]:
    """The labels of `judged` (3,) bool (present and within the reach) that no setting of the lens lets the
    extraction read, each region judged by its own flip `flips` (3,) [circles], in the order labels are granted
    (focus_reach.PRIORITY): a region is unreadable when no setting reads it together with the readable
    regions before it. The reason names the region's flip and the blur the lens can give it with the other
    labels read as asked."""
    asked, judged = np.asarray(asked, bool), np.asarray(judged, bool)
    inv_depth, flips = np.asarray(inv_depth, float), np.asarray(flips, float)
    regions = [r for r in FR.PRIORITY if judged[r] and inv_depth.shape[1] and np.isfinite(inv_depth[r]).all()]
    n, s = _settings(lens, regions, inv_depth, flips)
    kept: list[int] = []
    out: list[FR.Unreachable] = []
    for r in regions:
        if FR._feasible(lens, n, s, kept + [r], asked, inv_depth, flips).any():
            kept.append(r)
            continue
        out.append(_why(lens, r, kept, asked, inv_depth, flips))
    return out


def _why(lens: FR.Lens, r: int, kept: list[int], asked: np.ndarray, inv_depth: np.ndarray,
         flips: np.ndarray) -> FR.Unreachable:
    what = FR._label(r, asked) + (" with " + ", ".join(FR._label(k, asked) for k in kept) if kept else "")
    span = blur_range(lens, r, kept, asked, inv_depth, flips)
    if asked[r]:
        need = f"read sharp only under {flips[r]:.2f} circles (where the focus estimator flips on it in this frame)"
        gets = f"the lens leaves its median at least {span[0]:.2f} circles soft" if span else ""
    else:
        need = f"read soft only past {flips[r]:.2f} circles (where the focus estimator flips on it in this frame)"
        gets = f"the lens blurs its median at most {span[1]:.2f} circles" if span else ""
    with_others = " with the others read as asked" if kept else ""
    return FR.Unreachable(r, KIND, f"{what}: {need}; {gets}{with_others}, so no lens lets the extraction "
                                   "read it as asked")
