"""Known upright surfaces of the scene: flat rectangles standing in the world (a hedge, a backdrop), the
part of the scene's map the planner uses to know how deep what the camera sees lies (pure geometry).

A `Surface` is a vertical rectangle over the ground segment from (x0, y0) to (x1, y1), filling the height
band [z_min, z_max]. Settings files write one as the list `[x0_m, y0_m, x1_m, y1_m, z_min_m, z_max_m]`, or with a
seventh number, the blur [circles of the one circle] from which the focus estimator reads its texture soft (its
flip; 1, the one circle's own definition, when not given) (`surfaces_from`); a scene of the built-in simulator
derives its own from its fixed photo layers (services/autopilot_bridge/sim/surfaces.py). They are a map, as the
keep-out obstacles are (shared/obstacles.py), not a measurement: what moves is not among them.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from cinetransfer.shared.errors import ConfigError


@dataclass(frozen=True)
class Surface:
    """An upright rectangle of world space (metres, z up) over the segment (x0, y0) - (x1, y1)."""

    x0_m: float
    y0_m: float
    x1_m: float
    y1_m: float
    z_min_m: float
    z_max_m: float
    #: the blur [circles] from which the focus estimator reads this surface's texture soft
    flip_circles: float = 1.0

    def as_list(self) -> list[float]:
        """The settings-file spelling: [x0_m, y0_m, x1_m, y1_m, z_min_m, z_max_m], the flip appended when not 1."""
        out = [self.x0_m, self.y0_m, self.x1_m, self.y1_m, self.z_min_m, self.z_max_m]
        return out if self.flip_circles == 1.0 else [*out, self.flip_circles]


def surfaces_from(values: Iterable[Sequence[float]], where: str = "surfaces_m") -> tuple[Surface, ...]:
    """Surfaces from their settings spelling (each [x0, y0, x1, y1, z_min, z_max] in metres, optionally the flip
    [circles]); ConfigError naming the entry when one is not six or seven finite numbers, its two ends apart,
    z_min < z_max and a flip above 0."""
    out = []
    for i, v in enumerate(values):
        nums = tuple(v) if isinstance(v, (list, tuple)) else ()
        if len(nums) not in (6, 7) or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                     and math.isfinite(x) for x in nums):
            raise ConfigError(f"{where}[{i}] = {v!r}: must be [x0_m, y0_m, x1_m, y1_m, z_min_m, z_max_m] and "
                              f"optionally flip_circles, finite")
        s = Surface(*(float(x) for x in nums))
        if math.hypot(s.x1_m - s.x0_m, s.y1_m - s.y0_m) <= 0 or not s.z_min_m < s.z_max_m or not s.flip_circles > 0:
            raise ConfigError(f"{where}[{i}] = {v!r}: needs two distinct ends, z_min_m < z_max_m and flip_circles > 0")
        out.append(s)
    return tuple(out)


def surfaces_setting(values: Iterable[Sequence[float]], where: str = "surfaces_m") -> tuple[tuple[float, ...], ...]:
    """A config's `surfaces_m` checked (surfaces_from, ConfigError naming `where`) and held as tuples of floats."""
    return tuple(tuple(s.as_list()) for s in surfaces_from(values, where))
