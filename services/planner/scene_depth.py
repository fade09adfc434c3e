"""How deep what the camera frames lies, from the scene's map: the ground plane and the known upright surfaces
(shared/surfaces.py) seen along the rays of a planned camera (pure geometry, inverse depths x = 1/depth [1/m]
along the optical axis).

The foreground band's ground alone (focus_field.ground_band) misses what stands on it: focus_hedge's hedge
6.8 m from the camera filled parkour's band while the ground below the runner's feet lay 7.3-9.4 m away, so
the planner could not tell the frames where the hedge and the backdrop can both be soft round a sharp runner
(docs/planner.md, "Only the subject sharp: the three labels together"). A region's median inverse depth is
the one the truth's definition turns on: it calls a region in focus from half its pixels inside the field.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cinetransfer.shared import camera as cam
from cinetransfer.shared.surfaces import Surface

#: rays cast per region: rows x columns, at the cells' centres
GRID = (24, 32)


def ray_hits(uv: np.ndarray, position: Sequence[float], ypr: Sequence[float], *, focal_mm: float,
             sensor: cam.Sensor, ground_z_m: float, surfaces: Sequence[Surface]) -> tuple[np.ndarray, np.ndarray]:
    """(inverse depths, flips), each (N,): the inverse depth along the optical axis [1/m] of what each normalised
    image point `uv` (N, 2) sees from a camera at `position` with attitude `ypr` (the nearest of the ground plane at
    `ground_z_m` and the surfaces; 0 where the ray meets none of them: the sky, or beyond the map), and the focus
    estimator's flip [circles] on it (the surface's own; 1, the one circle's, on the ground and where it meets
    nothing)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    c = np.asarray(position, float)
    ray_c = np.column_stack([np.ones(len(uv)), (0.5 - uv[:, 0]) * sensor.width_mm / focal_mm,
                             (0.5 - uv[:, 1]) * sensor.height_mm / focal_mm])
    # camera x = 1 along every ray, so its parameter at a hit is that point's depth along the optical axis
    d = ray_c @ cam.rotation_ypr(*(float(a) for a in ypr)).T
    t = np.full(len(uv), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        tg = (ground_z_m - c[2]) / d[:, 2]
    t = np.where((d[:, 2] < 0) & (tg > 0), tg, t)
    flip = np.ones(len(uv))
    for s in surfaces:
        ts = _surface_hits(s, c, d)
        flip = np.where(ts < t, s.flip_circles, flip)
        t = np.minimum(t, ts)
    return np.where(np.isfinite(t), 1.0 / t, 0.0), flip


def _surface_hits(s: Surface, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(N,) ray parameter where each ray c + t d meets the rectangle `s`; inf where it misses."""
    ex, ey = s.x1_m - s.x0_m, s.y1_m - s.y0_m
    ax, ay = s.x0_m - c[0], s.y0_m - c[1]
    den = d[:, 0] * ey - d[:, 1] * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ax * ey - ay * ex) / den
        u = (ax * d[:, 1] - ay * d[:, 0]) / den
    z = c[2] + t * d[:, 2]
    hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1) & (z >= s.z_min_m) & (z <= s.z_max_m)
    return np.where(hit, t, np.inf)


def grid_points(v_top: float, v_bottom: float, grid: tuple[int, int] = GRID) -> np.ndarray:
    """(rows * columns, 2) normalised image points at the centres of a grid over the rows [v_top, v_bottom] and
    the frame's width."""
    rows, cols = grid
    v = v_top + (np.arange(rows) + 0.5) * (v_bottom - v_top) / rows
    u = (np.arange(cols) + 0.5) / cols
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def region_medians_and_flips(v_feet: float, hits_of) -> tuple[float, float, float, float]:
    """(foreground band, background) median inverse depths [1/m], then each region's flip [circles]: the band the
    rows below the subject's feet `v_feet` (shared/focus_regions.py), the background the rows above them; a flip that
    of what the region's median ray meets, the pixels the truth's and the extraction's rules turn on. `hits_of` maps
    (N, 2) image points to (inverse depths, flips) (ray_hits). NaN for a region with no rows. The map holds no
    subject, so the rays he hides see what stands behind him: the box of his joints left out instead (twice his
    silhouette with a runner's limbs spread) flipped parkour's background median between the lawn 31 m away and
    the backdrop 40 m away, where the truth's stayed at 40 m."""
    v_feet = min(max(v_feet, 0.0), 1.0)
    fg = _median_and_flip(*hits_of(grid_points(v_feet, 1.0))) if v_feet < 1.0 else (float("nan"),) * 2
    bg = _median_and_flip(*hits_of(grid_points(0.0, v_feet))) if v_feet > 0.0 else (float("nan"),) * 2
    return fg[0], bg[0], fg[1], bg[1]


def _median_and_flip(inv: np.ndarray, flip: np.ndarray) -> tuple[float, float]:
    """The median of `inv` and the flip of the ray at its upper middle (the median itself for an odd count)."""
    k = int(np.argsort(inv, kind="stable")[len(inv) // 2])
    return float(np.median(inv)), float(flip[k])
