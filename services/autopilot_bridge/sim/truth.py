"""The simulator's focus truth from a depth map and the subject's mask, one definition for both renderers.

The regions are the style's (shared.focus_regions: image-space, from the subject's mask); a region is
present when it covers REGION_MIN_FRACTION of the image, and in focus when REGION_IN_FOCUS_FRACTION of
its pixels lie inside the lens's depth of field (shared.camera.dof_limits_m with the sensor's circle of
confusion). Its depths are kept as DEPTH_SAMPLES inverse depths for the report's reachability, a band
below the feet too short to be a foreground's too (an extraction may read it as one).
"""
from __future__ import annotations

import math

import numpy as np

from cinetransfer.shared import camera as cam
from cinetransfer.shared.focus_regions import feet_row, foreground_present, region_masks

#: a region counts as present when it covers at least this fraction of the image.
REGION_MIN_FRACTION = 0.002
#: a region is "in focus" when at least this fraction of its pixels lies inside the DoF.
REGION_IN_FOCUS_FRACTION = cam.REGION_IN_FOCUS_SHARE
#: how many depths describe a region in the truth (its 2.5, 7.5, ..., 97.5 % points)
DEPTH_SAMPLES = 20


def depth_sample(depth_m: np.ndarray) -> np.ndarray:
    """A region's pixel depths [m] (inf = sky) as DEPTH_SAMPLES inverse depths [1/m] at equally spaced
    quantiles: what the report needs to tell which focus labels any lens setting could give it."""
    inv = 1.0 / np.asarray(depth_m, dtype=float)  # inf -> 0: the sky is at infinity
    probs = (np.arange(DEPTH_SAMPLES) + 0.5) / DEPTH_SAMPLES
    return np.quantile(inv, probs, method="inverted_cdf")


def region_truth(depth_m: np.ndarray, subject: np.ndarray, focal_mm: float, f_number: float, focus_m: float,
                 coc_mm: float, foreground: bool | None = None) -> dict:
    """Focus truth of the three regions from per-pixel depths [m] (inf = sky) and the subject's mask.
    `foreground`: whether the band below the feet is one, judged on the full-resolution mask
    (focus_regions.foreground_present) when these are a subsample of it; None = judged on `subject`."""
    near, far = cam.dof_limits_m(focal_mm, f_number, focus_m, coc_mm)
    feet = feet_row(subject)
    if foreground is None:
        foreground = foreground_present(feet, subject.shape[0])
    subj = subject if subject.any() else None
    regions = region_masks(subj, feet, foreground, subject.shape)
    # a band too short to be a foreground keeps its depths: an extraction whose mask ends a pixel or two
    # above the true feet reads it as one, and the report judges its reach from them (docs/report.md)
    sampled = (region_masks(subj, feet, True, subject.shape)[0], *regions[1:])
    infocus = (depth_m >= near) & (depth_m <= far)
    present, frac, inv_depth = [], [], []
    for region, pixels in zip(regions, sampled):
        n = int(region.sum())
        ok = n >= REGION_MIN_FRACTION * region.size
        present.append(ok)
        frac.append(float((infocus & region).sum()) / n if ok else math.nan)
        inv_depth.append(depth_sample(depth_m[pixels]) if pixels.any() else np.full(DEPTH_SAMPLES, np.nan))
    in_focus = np.array([p and f >= REGION_IN_FOCUS_FRACTION for p, f in zip(present, frac)], bool)
    return {"dof_near_m": near, "dof_far_m": far if math.isfinite(far) else math.nan,
            "region_present": np.array(present, bool), "region_in_focus": in_focus,
            "region_focus_fraction": np.array(frac, np.float32),
            "region_inverse_depth": np.array(inv_depth, np.float32)}
