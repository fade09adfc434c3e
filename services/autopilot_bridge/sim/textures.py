"""Procedural textures of the 3-D world: made from a fixed seed at load time (deterministic, nothing shipped).

Each is a BGR uint8 tile that repeats without a seam (the noise is periodic), fine enough to put at
least one texel on every output pixel at the closest distance a scene lets the camera come (the
`period_m` a scene gives divided by the tile's size). Surfaces need texture: flat colour reads as
soft to the detector's focus estimate.
"""
from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

TILE_PX = 512
#: the names a scene's object may use as `texture:`
NAMES = ("brick", "stone", "plaster", "bark", "leaves", "detail", "paving")


def periodic_noise(size: int, cells: int, seed: int) -> np.ndarray:
    """Smooth noise in [0, 1] on a (size, size) tile that wraps: a random (cells x cells) grid, tiled 3x3,
    upsampled bicubically, the middle kept."""
    rng = np.random.default_rng(seed)
    g = rng.random((cells, cells), dtype=np.float32)
    big = cv2.resize(np.tile(g, (3, 3)), (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
    return np.clip(big[size:2 * size, size:2 * size], 0.0, 1.0)


def fbm(size: int, seed: int, octaves: int = 6, base_cells: int = 4, gain: float = 0.55) -> np.ndarray:
    """Fractal noise in [0, 1]: octaves of periodic noise, each twice as fine and `gain` as strong."""
    out = np.zeros((size, size), np.float32)
    amp, total = 1.0, 0.0
    for k in range(octaves):
        cells = min(base_cells * 2 ** k, size)
        out += amp * periodic_noise(size, cells, seed * 101 + k)
        total += amp
        amp *= gain
    out /= total
    lo, hi = np.percentile(out, (1, 99))
    return np.clip((out - lo) / max(hi - lo, 1e-6), 0.0, 1.0)


def _colourise(shade: np.ndarray, dark_bgr: tuple[float, float, float], light_bgr: tuple[float, float, float]
               ) -> np.ndarray:
    d, li = np.array(dark_bgr, np.float32), np.array(light_bgr, np.float32)
    return np.clip(d + shade[..., None] * (li - d), 0, 255).astype(np.uint8)


def _courses(size: int, rows: int, cols: int, mortar: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(mortar mask, per-block tint in [0, 1]) of a running-bond pattern (every other course shifted by half)."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    r = np.floor(y * rows)
    xs = x * cols + 0.5 * (r % 2)
    c = np.floor(xs) % cols
    fy, fx = y * rows - r, xs - np.floor(xs)
    joint = (fy < mortar * rows / cols * 2) | (fx < mortar)
    tint = np.random.default_rng(seed).random((rows, cols), dtype=np.float32)[r.astype(int) % rows, c.astype(int)]
    return joint, tint


@lru_cache(maxsize=None)
def texture(name: str, size: int = TILE_PX) -> np.ndarray:
    """The named procedural texture, (size, size, 3) BGR uint8 (cached)."""
    if name not in NAMES:
        raise ValueError(f"unknown procedural texture {name!r}; textures: {list(NAMES)}")
    seed = NAMES.index(name) + 1
    n = fbm(size, seed)
    grain = fbm(size, seed + 50, octaves=3, base_cells=size // 8)
    if name == "detail":
        return cv2.cvtColor((grain * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    if name == "brick":
        joint, tint = _courses(size, 16, 8, 0.05, seed)
        img = _colourise(0.55 * tint + 0.25 * n + 0.2 * grain, (30, 45, 110), (80, 110, 190))
        img[joint] = _colourise(0.5 * grain[joint] + 0.3, (150, 160, 165), (200, 205, 210))
        return img
    if name == "paving":
        joint, tint = _courses(size, 8, 8, 0.03, seed)
        img = _colourise(0.4 * tint + 0.35 * n + 0.25 * grain, (95, 105, 115), (170, 180, 190))
        img[joint] = _colourise(0.6 * grain[joint], (40, 45, 50), (90, 95, 100))
        return img
    if name == "stone":
        return _colourise(0.6 * n + 0.4 * grain, (110, 120, 125), (200, 205, 210))
    if name == "plaster":
        return _colourise(0.5 * n + 0.5 * grain, (150, 185, 205), (205, 230, 245))
    if name == "bark":
        y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
        ridges = 0.5 + 0.5 * np.sin(2 * np.pi * (12 * x + 1.5 * n))
        return _colourise(0.5 * ridges + 0.3 * grain + 0.2 * n, (20, 35, 50), (70, 95, 115))
    # leaves: dark gaps between lit clumps
    clumps = fbm(size, seed + 7, octaves=4, base_cells=32)
    return _colourise(0.55 * clumps + 0.25 * grain + 0.2 * n, (15, 45, 20), (60, 150, 80))
