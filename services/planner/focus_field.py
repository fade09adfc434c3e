"""Where "only the foreground sharp" puts the depth of field: the ground the foreground band shows; and
how far in front of him "only the subject sharp" may put the focus (pure maths, inverse depths
x = 1/depth [1/m]).

The foreground is the band of rows below the subject's feet (shared/focus_regions.py). On open
ground it shows the ground from the feet, at the subject's own depth, down to the bottom row. A
camera `h` above a plane, pitched p (positive up), sees the ground at image row v (0 top, 1 bottom)
at depth along the optical axis x = h / (cos p t - sin p), t = (v - 1/2) h_s / f: the inverse depth
is linear in the row, so the band's rows are spread evenly in inverse depth between the feet and the
bottom row and its median is the mean of the two (ground_band).

In inverse depth the depth of field of the planning circle c_s spans 1/s +- sigma (cost.py), and a
circle `ratio` times larger spans 1/s +- ratio sigma: a subject beyond the larger field's far edge
is visibly soft while the band inside the small field is sharp (foreground_near_m).

The band starts at the subject's own depth, so whatever keeps the subject soft also loses the band's
far rows; the ground's median row is often only 3-5 m nearer than a subject 14 m away.
foreground_limits therefore puts the focus where the subject is blurred by SUBJECT_BLUR_CIRCLES of the
one circle c (1/s = 1/d + b sigma_c) and no more, with the narrowest field the planner uses: the band
from just in front of him is then inside the field of c. Where the band is shallow (a short lens close to
him) that field's edge, b - 1 circles in front of him, would cut off most of it: band_subject_blur then
asks less blur, down to LEAST_BAND_SUBJECT_BLUR, so that the edge lies a quarter of the way into the band.

With only the subject sharp and the field wider than he is deep (parkour at 50-60 mm and f/1), a field
centred on him leaves the background behind him only 1.0-1.35 circles soft: sharp to the focus
estimator, which reads a texture soft from 1.5 circles. A focus b circles in front of him adds b
circles to everything behind him and takes b from the foreground band's median (focus_ahead_inv_m).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: height of the ankle joint above the sole [m]: where the ground lies below the ankles
ANKLE_HEIGHT_M = 0.08
#: the subject's blur with only the foreground sharp, in circles of the one circle of confusion: above
#: every texture's flip of the focus estimator (0.88-1.22 circles, docs/report.md), below the 1.5 of the
#: visible circle, which left the band's median outside the field (parkour: truth foreground 0.13-0.24)
SUBJECT_BLUR_CIRCLES = 1.3
#: the least blur [circles] of the subject with only the foreground sharp where the band is shallow
#: (band_subject_blur): the one circle's field then ends 0.1 circles in front of him, so the truth, which
#: calls him soft once half his pixels lie outside it, still does. Below the 1.22 flip of the coarsest
#: texture measured (docs/report.md): a subject that coarse would read sharp to the focus estimator there;
#: the parkour runner flown at 1.09-1.10 circles read soft in every frame
LEAST_BAND_SUBJECT_BLUR = 1.1
#: where in the foreground band, as a share of its width in inverse depth from his feet, the one circle's
#: field may end with only the foreground sharp (band_subject_blur): three quarters of the band inside it
BAND_EDGE_SHARE = 0.25
#: the blur [circles of the one circle] a sharp subject may carry with only him sharp, so that the focus can stand in
#: front of him and blur the background more: at half the circle (0.6 wide open) the dancer read soft (extraction
#: 1.00 -> 0.93) and focus_hedge's hedge in front of her sharp (1.00 -> 0.60; docs/planner.md)
SHARP_SUBJECT_BLUR = 0.25
#: with only the background sharp, the least blur [circles] a settled soft subject is asked where the ground
#: behind him needs the sharp zone nearer (settled_subject_blur): the highest flip of the focus estimator over
#: the textures measured (1.22 circles, docs/report.md) with a margin, as SUBJECT_BLUR_CIRCLES
LEAST_SOFT_SUBJECT_BLUR = 1.3
#: the share of the background's rows that may show ground nearer than the one circle's sharp zone behind a
#: settled soft subject: the truth calls the background sharp from half its pixels inside the field, and the
#: rows beside and above him hold more than the ground right behind him
GROUND_BEHIND_SHARE = 0.35
#: the blur [circles of the one circle] both soft regions' medians share, with the focus where the scene's map
#: puts them equally soft (three_label_focus_inv_m), from which "only the subject sharp" starts to move the focus
#: there (LEAST_TOGETHER_BLUR) and from which it stands there wholly (FULL_TOGETHER_BLUR). The truth calls them soft
#: past 1 circle; parkour's frames 27-43 allow 1.09-1.37 circles at f/1, the frames before 1.0-1.07. In between the
#: focus goes part of the way, so that it has mostly travelled (4 frames at the lens's 15 m/s) when the window
#: opens: flown with 1.0-1.08 and 0.97-1.06 the plan's ramp straddled the window's edges (frames 27 and 43
#: missed), with 0.95-1.04 only frame 43 (docs/planner.md)
LEAST_TOGETHER_BLUR = 0.95
FULL_TOGETHER_BLUR = 1.04
#: the blur [circles] the foreground band's median keeps when the focus moves in front of a sharp subject: the
#: visible circle's 1.5, where the focus estimator reads every texture soft
SOFT_BAND_BLUR = 1.5
#: the least blur [circles] the focus balanced by the estimator's flips (three_label_focus_inv_m) leaves either soft
#: region: the truth calls a region soft past 1 circle
TRUTH_SOFT_BLUR = 1.03
#: the blur [circles] a sharp subject may carry with the three labels together (three_label_focus_inv_m): the focus
#: balanced by the flips stands behind him, where the parkour runner reads sharp to 1.33-1.68 circles (docs/report.md)
#: and the truth's rule (half his pixels inside the field) to 1; at the quarter circle of SHARP_SUBJECT_BLUR the
#: balance was cut short in frames 31-37 (flown 0.26-0.30 circles behind him; docs/planner.md)
TOGETHER_SUBJECT_BLUR = 0.35


@dataclass(frozen=True)
class Band:
    """The foreground band's ground in inverse depth [1/m]: at the feet's row and at the bottom row."""

    inv_top: float
    inv_bottom: float

    @property
    def inv_median(self) -> float:
        """The inverse depth half of the band's pixels lie nearer than (the rows are even in it)."""
        return 0.5 * (self.inv_top + self.inv_bottom)

    @property
    def bottom_m(self) -> float:
        """The depth of the ground at the bottom row [m]."""
        return 1.0 / self.inv_bottom


def ground_inverse_depth(v: float, *, height_m: float, pitch_rad: float, focal_mm: float,
                         sensor_height_mm: float) -> float:
    """Inverse depth along the optical axis [1/m] of the ground seen at normalised row `v` from a
    camera `height_m` above it (level roll); <= 0 where the row looks at or above the horizon."""
    t = (v - 0.5) * sensor_height_mm / focal_mm
    return (math.cos(pitch_rad) * t - math.sin(pitch_rad)) / height_m


def ground_band(v_feet: float, *, height_m: float, pitch_rad: float, focal_mm: float, sensor_height_mm: float,
                min_rows: float) -> Band | None:
    """The band below the feet's row `v_feet` as seen on the ground; None when it is under `min_rows`
    (a fraction of the frame) high, the camera is not above the ground or its bottom row sees no ground."""
    if not (math.isfinite(v_feet) and math.isfinite(height_m) and height_m > 0.1) or 1.0 - v_feet < min_rows:
        return None
    kw = {"height_m": height_m, "pitch_rad": pitch_rad, "focal_mm": focal_mm, "sensor_height_mm": sensor_height_mm}
    bottom = ground_inverse_depth(1.0, **kw)
    if not bottom > 0:
        return None
    return Band(max(ground_inverse_depth(max(v_feet, 0.0), **kw), 0.0), bottom)


def narrowest_spread(focal_mm: float, f_number: float, coc_mm: float) -> float:
    """Half the planning field's width in inverse depth [1/m] at the widest aperture: 1000 A c / f^2
    (the far-focus limit of (s - f) / (s (H - f)), cost.inverse_dof_limits)."""
    return 1000.0 * f_number * coc_mm / (focal_mm * focal_mm)


def foreground_near_m(band: Band, keep_out_m: float, *, spread_min: float, soft_ratio: float) -> float:
    """D_n* [m] of the planning circle for a row with the foreground sharp: the ground at the bottom
    row, or, with the subject kept out by the far limit of the visible-defocus field at `keep_out_m`
    (`soft_ratio` times the circle; inf: nothing kept out), no farther than the lens's narrowest field
    puts it: 1 / (1/keep_out + (soft_ratio + 1) `spread_min`). A nearer target asks for a field the
    lens cannot make, and the least-squares plan then let the subject back into it (parkour, only the
    foreground sharp: the runner sharp in 16 % of the frames)."""
    x_n = band.inv_bottom
    if math.isfinite(keep_out_m) and keep_out_m > 0:
        x_n = max(x_n, 1.0 / keep_out_m + (soft_ratio + 1.0) * spread_min)
    return 1.0 / x_n


def foreground_limits(depth_m: float, *, spread: float, sharp_ratio: float, far_ratio: float,
                      subject_blur: float = SUBJECT_BLUR_CIRCLES) -> tuple[float, float] | None:
    """(D_n*, D_f*) [m] of the planning circle c_s for a row with only the foreground sharp: the focus
    where the subject `depth_m` away is blurred by `subject_blur` circles c = c_s / `sharp_ratio`,
    1/s = 1/d + subject_blur sigma / sharp_ratio, with the field `spread` = sigma (the planning
    circle's half-width at the aperture planned for, narrowest_spread): the far limit of the circle
    `far_ratio` c_s (the far limit's, cost.defocus_ratio) at 1/s - far_ratio sigma and the near limit
    of c_s at 1/s + sigma: a field the lens makes, so the least-squares plan meets both. A nearer near
    target (the band's bottom row) asks for a deeper field, which at the same far limit moves the focus
    nearer and the field's far edge off the band's far rows. None (the caller keeps its targets) when
    `far_ratio` c_s is smaller than the asked blur: the far limit is then the sharpness circle's, which
    previews a switch still ahead (cost.switched_out) or follows a borderline label, and those keep the
    lens's move for after the switch; or when the far limit would lie at or beyond infinity."""
    if not (depth_m > 0 and spread > 0 and sharp_ratio > 0) or far_ratio * sharp_ratio < subject_blur:
        return None
    x_s = 1.0 / depth_m + subject_blur * spread / sharp_ratio
    x_far = x_s - far_ratio * spread
    if x_far <= 0:
        return None
    return 1.0 / (x_s + spread), 1.0 / x_far


def band_subject_blur(depth_m: float, band: Band | None, *, spread: float, most: float = SUBJECT_BLUR_CIRCLES,
                      least: float = LEAST_BAND_SUBJECT_BLUR, share: float = BAND_EDGE_SHARE) -> float:
    """The subject's blur [circles of the one circle] to ask with only the foreground sharp, from how deep the
    band below his feet is: with the focus where he is b circles soft, the one circle's field (half-width
    `spread` in inverse depth) ends (b - 1) circles in front of him, and the band runs from his depth to its
    bottom row, so b = 1 + `share` w puts the edge `share` of the way into a band w circles deep. Within
    [`least`, `most`]; `most` with no band known. A short lens near the subject makes the band shallow: the
    parkour runner at 30-35 mm and 10.5-11 m showed ground 0.4-0.5 circles deep in front of him at f/1.2, its
    median 0.14-0.37 circles (0.32-0.44 at 37-46 mm and 11-12 m), and at 1.3 circles the field's edge 0.3
    circles in front of him left 17-49 % of it sharp (truth foreground 0.78)."""
    if band is None or not (depth_m > 0 and spread > 0):
        return most
    width = (band.inv_bottom - 1.0 / depth_m) / spread
    return min(max(1.0 + share * width, least), most)


def focus_ahead_inv_m(depth_m: float, band: Band | None, *, fg_absent: bool, spread: float,
                      subject_blur: float = SHARP_SUBJECT_BLUR, band_blur: float = SOFT_BAND_BLUR) -> float:
    """How far in front of a sharp subject `depth_m` away the focus stands [1/m, inverse depth] with only
    him sharp. The foreground band (ground_band) tells how wide the field is against the depths round him:
    with its median inside the one circle's field while the focus is on him (under 1 circle), what lies as
    far behind him is inside it too and sharp to the focus estimator (parkour: the backdrop 1.0-1.35
    circles), and the band is out of reach anyway with the background soft, as the report judges it; the
    focus then stands `subject_blur` circles in front of him, which adds that much blur to everything behind
    him while he stays sharp. From there to `band_blur` circles (where the estimator reads every texture
    soft) the move shrinks linearly to nothing: the band keeps its blur, and the background, as far behind,
    is soft already (the dancer's, 1.5-1.7 circles). Nothing with no band known or no foreground in the source:
    the move then only blurs the subject. `spread` is the one circle's half-width at the aperture planned for
    (narrowest_spread with the one circle at 1.2 x the widest f-number): wide open his blur is up to
    1.2 `subject_blur`, 0.3 circles (parkour: 0.29-0.31, the dancer 0.32, both read sharp)."""
    if fg_absent or band is None or not (depth_m > 0 and spread > 0 and band_blur > 1.0):
        return 0.0
    band_circles = (band.inv_median - 1.0 / depth_m) / spread
    share = min(max((band_blur - band_circles) / (band_blur - 1.0), 0.0), 1.0)
    return share * subject_blur * spread


def shifted_limits(near_m: float, far_m: float, shift_inv_m: float) -> tuple[float, float]:
    """(D_n*, D_f*) [m] moved nearer by `shift_inv_m` in inverse depth, their width in it kept: where the
    lens cannot make them, the least-squares plan centres its field on their midpoint. A far limit moved to
    or past infinity is infinity."""
    x_n, x_f = 1.0 / near_m + shift_inv_m, 1.0 / far_m + shift_inv_m
    return 1.0 / x_n, (1.0 / x_f if x_f > 0 else math.inf)


def ground_behind_inv_m(v_feet: float, share: float, *, height_m: float, pitch_rad: float, focal_mm: float,
                        sensor_height_mm: float) -> float:
    """The inverse depth [1/m] of the ground nearer than which `share` of the background's rows (those above
    the feet's row `v_feet`) lie: the rows from the feet up see the ground behind the subject ever farther,
    linearly in inverse depth (ground_inverse_depth), up to the horizon. 0 when that row sees no ground (at or
    above the horizon: the sky, or whatever stands far behind) or the view is unknown."""
    if not (math.isfinite(v_feet) and math.isfinite(height_m) and height_m > 0.1 and 0.0 <= share <= 1.0):
        return 0.0
    v = (1.0 - share) * min(max(v_feet, 0.0), 1.0)
    return max(ground_inverse_depth(v, height_m=height_m, pitch_rad=pitch_rad, focal_mm=focal_mm,
                                    sensor_height_mm=sensor_height_mm), 0.0)


def rack_lead_cap_s(depth_m: float, background_inv_m: float, *, spread: float, rate_mps: float) -> float:
    """How long [s] before a rack away from the subject the focus may leave him, at the lens's rate `rate_mps`,
    without bringing the background (inverse depth `background_inv_m`, ground_behind_inv_m) into the one
    circle's field before the switch: the field's far limit 1/s - `spread` stays nearer than the background while
    s < 1 / (background_inv_m + `spread`), so the focus may travel from him `depth_m` away to there. inf where the
    background lies inside the field with the focus on him already: it is sharp before the switch whatever the
    lead (parkour's lawn 6-10 m behind the runner), and a background at infinity (0) gives the hyperfocal
    distance 1 / `spread`."""
    if not (depth_m > 0 and spread > 0 and rate_mps > 0 and math.isfinite(background_inv_m)):
        return 0.0
    x_b = max(background_inv_m, 0.0)
    if 1.0 / depth_m - spread <= x_b:
        return math.inf
    return (1.0 / (x_b + spread) - depth_m) / rate_mps


def settled_subject_blur(back_m: float, ground_inv_m: float, *, spread: float, most: float,
                         least: float = LEAST_SOFT_SUBJECT_BLUR) -> float:
    """The blur [circles of the one circle] to ask of a soft subject whose back lies `back_m` away, with only the
    background sharp, so that the one circle's sharp zone starts at the ground `ground_inv_m` [1/m]
    (ground_behind_inv_m): with the focus behind him and his back b circles soft, the zone starts at
    1/back - (b - 1) `spread` (the one circle's half-width in inverse depth), so b = 1 + (1/back -
    ground_inv_m) / `spread`, within [least, most]. A ground beyond what `most` gives (or none: 0) asks `most`."""
    if not (back_m > 0 and spread > 0 and math.isfinite(ground_inv_m)) or ground_inv_m <= 0:
        return most
    b = 1.0 + (1.0 / back_m - ground_inv_m) / spread
    return min(max(b, least), most)


def rack_ahead_inv_m(depth_m: float, background_inv_m: float, *, spread: float, background_blur: float,
                     most: float) -> float:
    """How far in front of a sharp subject `depth_m` away the focus stands [1/m, inverse depth] before a rack away
    from him, so that the background (inverse depth `background_inv_m`, ground_behind_inv_m) is `background_blur`
    circles soft: with the focus on him it is (1/d - x_b) / `spread` circles soft, and a focus b circles in front adds
    b; b within [0, `most`], so he stays sharp. 0 for a background unknown (0: none seen) or farther than the blur."""
    if not (depth_m > 0 and spread > 0 and math.isfinite(background_inv_m)) or background_inv_m <= 0:
        return 0.0
    behind = (1.0 / depth_m - background_inv_m) / spread
    return min(max(background_blur - behind, 0.0), most) * spread


def three_label_focus_inv_m(depth_m: float, fg_inv_m: float, bg_inv_m: float, *, spread: float, otherwise_inv_m: float,
                            subject_blur: float = SHARP_SUBJECT_BLUR, least_blur: float = LEAST_TOGETHER_BLUR,
                            full_blur: float = FULL_TOGETHER_BLUR,
                            flips: tuple[float, float] = (1.0, 1.0)) -> float:
    """How far in front of a sharp subject `depth_m` away the focus stands [1/m, inverse depth; negative: behind
    him] with only him sharp, from the foreground's and the background's median inverse depths (`fg_inv_m`,
    `bg_inv_m`; scene_depth.region_medians_and_flips): the focus where the two soft regions lie equally far past
    the focus estimator's flips on them (`flips`, circles: foreground, background; _read_balanced_inv_m), held
    within TOGETHER_SUBJECT_BLUR circles of him (`spread`: the one circle's half-width in inverse depth at the widest
    aperture), so both are read soft as far as the lens can make them together while he stays sharp. With equal
    flips that is where they are equally blurred, 1/s = (x_fg + x_bg) / 2, held within `subject_blur` circles of
    him; the reach below is judged there.
    Where, so placed, the less blurred of the two is under `least_blur` circles no lens gives the three labels and
    the caller's own move `otherwise_inv_m` stands (the band is lost whatever the focus, and the background's blur
    matters more); from `full_blur` on the focus stands there; in between it lies part of the way, linearly in that
    blur. Parkour, frames 27-43: the hedge 6.8 m, the runner 10.6 m, the backdrop 40 m: the focus 11.6 m, 1 m
    behind him, both 1.09-1.37 circles soft at f/1. The caller's move where a depth is unknown or out of order."""
    values = (depth_m, fg_inv_m, bg_inv_m, spread)
    if not (all(np.isfinite(values)) and depth_m > 0 and spread > 0) or not fg_inv_m > 1.0 / depth_m > bg_inv_m:
        return otherwise_inv_m
    x_s = 1.0 / depth_m
    x = min(max(0.5 * (fg_inv_m + bg_inv_m), x_s - subject_blur * spread), x_s + subject_blur * spread)
    shared = min(fg_inv_m - x, x - bg_inv_m) / spread
    x = _read_balanced_inv_m(x, fg_inv_m, bg_inv_m, x_s, spread=spread, flips=flips)
    w = min(max((shared - least_blur) / (full_blur - least_blur), 0.0), 1.0) if full_blur > least_blur \
        else float(shared >= least_blur)
    return w * (x - x_s) + (1.0 - w) * otherwise_inv_m


def _read_balanced_inv_m(x_equal: float, fg_inv_m: float, bg_inv_m: float, x_s: float, *, spread: float,
                         flips: tuple[float, float]) -> float:
    """The focus [1/m] moved from the equal-circle focus `x_equal` by (k_fg - k_bg) `spread` / 2 towards the region
    flipping earlier (`flips`: the focus estimator's flips on the foreground and the background, in circles), so
    that both lie equally far past their flips, only as far as keeps each region TRUTH_SOFT_BLUR circles soft and
    the subject within TOGETHER_SUBJECT_BLUR circles; `x_equal` itself with equal flips or where that leaves no
    room."""
    step = -0.5 * (flips[0] - flips[1]) * spread
    lo = max(bg_inv_m + TRUTH_SOFT_BLUR * spread, x_s - TOGETHER_SUBJECT_BLUR * spread)
    hi = min(fg_inv_m - TRUTH_SOFT_BLUR * spread, x_s + TOGETHER_SUBJECT_BLUR * spread)
    x = min(max(x_equal + step, lo), hi)
    return x if (x - x_equal) * step > 0 else x_equal
