"""How far back the camera stands so that a subject can be soft before a sharp background (pure maths).

Keeping the framing, the focal length grows with the distance (f = k d, k in mm per metre), and the
hyperfocal distance with its square. Only the background in focus asks for the far limit of the
sharpness circle c at infinity (focus s >= H = f^2 / (A c)) while the near limit of the visible-defocus
circle r c lies beyond the subject (D_n >= d + mu; the planner's subject_keep_out_m when given). With s = H
that near limit is H / (1 + r), so

    k^2 d^2 / (1000 A c) >= (1 + r) (d + mu)   ->   d >= (a + sqrt(a^2 + 4 a mu)) / 2,  a = 1000 A c (1 + r) / k^2

(f and c in mm, d, mu and H in m). The focus cannot go past its maximum, so the subject is softest at
d* = sqrt(1000 A c s_max) / k (best_separation_m); farther is worse, as beyond the longest focal
length (k d <= f_max). From too near no lens setting gives the choice: the planner then raises its
minimum distance to the subject to this standoff, over a look-ahead longer than its horizon, and the
image term lengthens the lens to keep the framing.

The other half of a rack focus, the subject sharp before a soft background, wants the same move: at a
fixed framing the depth of field reaches a = 1000 A r c / k^2 behind a subject focused at d by
a d / (d - a) (the far limit of r c: d H / (H - d) with H = d^2 / a), which shrinks towards a as the
camera backs off. A background `beta` behind the subject is beyond it from

    d >= a beta / (beta - a)     (beta > a; a background at infinity: d >= a)

(background_soft_standoff_m); nearer, its blur is under r c whatever the lens does.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

#: the f-number the standoff is computed for, as a multiple of the widest the lens opens to: the
#: plan then does not sit at the aperture's limit
APERTURE_MARGIN = 1.2


def standoff_m(k_mm_per_m: float, *, f_number: float, coc_mm: float, defocus_ratio: float, mu_m: float) -> float:
    """The least subject distance [m] at which a subject `mu_m` deep can lie beyond the near limit of
    the circle `defocus_ratio` x `coc_mm` with the far limit of `coc_mm` at infinity, at `f_number`
    and with the framing f = k d; NaN for a framing that says nothing (k <= 0 or not finite)."""
    if not (math.isfinite(k_mm_per_m) and k_mm_per_m > 0):
        return math.nan
    a = 1000.0 * f_number * coc_mm * (1.0 + defocus_ratio) / (k_mm_per_m * k_mm_per_m)
    mu = max(mu_m, 0.0)
    return 0.5 * (a + math.sqrt(a * a + 4.0 * a * mu))


def background_soft_standoff_m(k_mm_per_m: float, *, f_number: float, coc_mm: float, defocus_ratio: float,
                                behind_m: float) -> float:
    """The least subject distance [m] at which a background `behind_m` behind a subject focused at its
    own distance lies beyond the far limit of the circle `defocus_ratio` x `coc_mm`, at `f_number`
    and with the framing f = k d; inf when no distance gives it (the background within a of the
    subject), NaN for a framing that says nothing."""
    if not (math.isfinite(k_mm_per_m) and k_mm_per_m > 0):
        return math.nan
    a = 1000.0 * f_number * coc_mm * defocus_ratio / (k_mm_per_m * k_mm_per_m)
    if math.isinf(behind_m):
        return a
    return a * behind_m / (behind_m - a) if behind_m > a else math.inf


def best_separation_m(k_mm_per_m: float, *, f_number_min: float, coc_mm: float, focus_max_m: float) -> float:
    """The subject distance [m] at which the subject is softest with the far limit at infinity: the
    blur of a point at d focused at H is c (H / d - 1), and H = k^2 d^2 / (1000 A c) grows with d until
    it reaches the longest focus; beyond, the focus stays there, the aperture closes to keep the far
    limit at infinity and the blur falls as c (s_max / d - 1). So d* = sqrt(1000 A_min c s_max) / k."""
    if not (math.isfinite(k_mm_per_m) and k_mm_per_m > 0):
        return math.nan
    return math.sqrt(1000.0 * f_number_min * coc_mm * focus_max_m) / k_mm_per_m


def framing_k(target_v: np.ndarray, joints_z_m: np.ndarray, sensor_height_mm: float) -> float:
    """Focal length per metre of distance [mm/m] a style row's framing asks for: the vertical image
    extent of the joints' targets (normalised, on the sensor) over the subject's own vertical extent
    between those joints; NaN with fewer than two joints or under 0.1 m of extent. Foreshortening only
    shortens the image extent, so this errs towards a looser framing (a farther standoff)."""
    v, z = np.asarray(target_v, float), np.asarray(joints_z_m, float)
    ok = np.isfinite(v) & np.isfinite(z)
    if ok.sum() < 2 or np.ptp(z[ok]) < 0.1:
        return math.nan
    return float(np.ptp(v[ok]) * sensor_height_mm / np.ptp(z[ok]))


def separation_distance_m(ks: Sequence[float], ratios: Sequence[float], *, f_number_min: float, coc_mm: float,
                          mu_m: float | Sequence[float], focus_max_m: float, focal_max_mm: float) -> float:
    """The minimum subject distance [m] the planner keeps for the rows ahead that want the subject
    soft and the background sharp (per row: its framing `ks`, framing_k, its visible-defocus circle
    ratio `ratios` and how far past his centre it keeps him out, `mu_m`: one for all rows or one per
    row); 0 when no row does or no framing is known. Per row never beyond the
    distance of the softest subject (best_separation_m) nor the longest focal length's: past them the
    choice is out of the lens's reach, and the report says so per frame."""
    best = 0.0
    mus = np.broadcast_to(np.asarray(mu_m, dtype=float), (len(ks),))
    for k, r, mu in zip(ks, ratios, mus):
        need = standoff_m(k, f_number=APERTURE_MARGIN * f_number_min, coc_mm=coc_mm, defocus_ratio=r, mu_m=float(mu))
        if not math.isfinite(need):
            continue
        cap = min(best_separation_m(k, f_number_min=f_number_min, coc_mm=coc_mm, focus_max_m=focus_max_m),
                  focal_max_mm / k)
        best = max(best, min(need, cap))
    return best


def background_soft_distance_m(ks: Sequence[float], ratios: Sequence[float], *, f_number_min: float,
                               coc_mm: float, behind_m: float, focal_max_mm: float) -> float:
    """The minimum subject distance [m] the planner keeps for the rows ahead that want the subject
    sharp and the background soft (per row: its framing `ks` and visible-defocus circle ratio
    `ratios`, as separation_distance_m), for a background `behind_m` behind the subject; 0 when no
    row does, no framing is known or no distance gives the choice (the report says so per frame).
    Farther always blurs the background more, so only the longest focal length caps it."""
    best = 0.0
    for k, r in zip(ks, ratios):
        need = background_soft_standoff_m(k, f_number=APERTURE_MARGIN * f_number_min, coc_mm=coc_mm,
                                          defocus_ratio=r, behind_m=behind_m)
        if math.isfinite(need):
            best = max(best, min(need, focal_max_mm / k))
    return best
