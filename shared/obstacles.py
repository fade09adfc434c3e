"""Keep-out obstacles: upright cylinders the camera drone must not fly into (pure geometry).

A `Obstacle` is the obstacle's own extent (a trunk, a pillar, a tree's crown): its axis at world
(x, y), its radius, and the height band [z_min, z_max] it fills. The clearance a vehicle keeps
from its surface is a limit of the vehicle (the profile's `envelope.min_obstacle_distance_m`,
shared/vehicle.py), not of the obstacle, so the planner's soft constraint and the bridge's
envelope check add the same number. Settings files write one as the list
`[x_m, y_m, radius_m, z_min_m, z_max_m]` (`obstacles_from`); a scene of the built-in simulator
derives its own (services/autopilot_bridge/sim/obstacles.py).

The height band counts for a vehicle at height z when z lies within the clearance of it: a camera
flying under a crown (or over a pillar) by less than the clearance is as near as one beside it.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from cinetransfer.shared.errors import ConfigError


@dataclass(frozen=True)
class Obstacle:
    """An upright cylinder of world space (metres, z up) the vehicle keeps out of."""

    x_m: float
    y_m: float
    radius_m: float
    z_min_m: float
    z_max_m: float

    def as_list(self) -> list[float]:
        """The settings-file spelling: [x_m, y_m, radius_m, z_min_m, z_max_m]."""
        return [self.x_m, self.y_m, self.radius_m, self.z_min_m, self.z_max_m]


def obstacles_from(values: Iterable[Sequence[float]], where: str = "obstacles_m") -> tuple[Obstacle, ...]:
    """Keep-outs from their settings spelling (each [x, y, radius, z_min, z_max] in metres);
    ConfigError naming the entry when one is not five finite numbers, a radius > 0 and z_min < z_max."""
    out = []
    for i, v in enumerate(values):
        nums = tuple(v) if isinstance(v, (list, tuple)) else ()
        if len(nums) != 5 or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                     and math.isfinite(x) for x in nums):
            raise ConfigError(f"{where}[{i}] = {v!r}: must be [x_m, y_m, radius_m, z_min_m, z_max_m], finite")
        k = Obstacle(*(float(x) for x in nums))
        if k.radius_m <= 0 or not k.z_min_m < k.z_max_m:
            raise ConfigError(f"{where}[{i}] = {v!r}: needs radius_m > 0 and z_min_m < z_max_m")
        out.append(k)
    return tuple(out)


def surface_distance_m(k: Obstacle, xy: Sequence[float]) -> float:
    """Horizontal distance [m] from `xy` to the cylinder's surface (negative inside)."""
    return math.hypot(float(xy[0]) - k.x_m, float(xy[1]) - k.y_m) - k.radius_m


def covers_height(k: Obstacle, z_m: float, clearance_m: float) -> bool:
    """Whether a vehicle at height `z_m` is within `clearance_m` of the cylinder's height band."""
    return k.z_min_m - clearance_m <= z_m <= k.z_max_m + clearance_m


def intrusion_m(obstacles: Iterable[Obstacle], p: Sequence[float], clearance_m: float) -> float:
    """How far [m] position `p` (x, y, z) lies inside the clearance of the nearest obstacle whose
    height band it is beside (clearance minus surface distance): negative when it keeps every
    clearance (by that much), -inf when it is beside none."""
    beside = [k for k in obstacles if covers_height(k, float(p[2]), clearance_m)]
    return max((clearance_m - surface_distance_m(k, p) for k in beside), default=-math.inf)


def push_out(obstacles: Iterable[Obstacle], p: Sequence[float], distance_m: float) -> np.ndarray:
    """`p` moved radially (horizontally) out of every keep-out it is beside until `distance_m`
    from its surface, the nearest cylinder's axis first; a point on an axis moves along +x."""
    out = np.array(p, dtype=float)
    for k in sorted(obstacles, key=lambda k: surface_distance_m(k, out)):
        if not covers_height(k, float(out[2]), distance_m) or surface_distance_m(k, out) >= distance_m:
            continue
        d = out[:2] - (k.x_m, k.y_m)
        n = float(np.linalg.norm(d))
        d = d / n if n > 1e-9 else np.array([1.0, 0.0])
        out[:2] = np.array([k.x_m, k.y_m]) + d * (k.radius_m + distance_m)
    return out


def nearest_obstacles(obstacles: Iterable[Obstacle], p: Sequence[float], *, clearance_m: float, reach_m: float,
                      count: int) -> list[Obstacle]:
    """At most `count` obstacles whose height band `p` is beside and whose surface lies within
    `reach_m` of it horizontally, nearest first (ties by the order given); one whose circle lies
    inside a nearer one's is left out (a trunk under its crown: the crown keeps it clear)."""
    near = sorted(((surface_distance_m(k, p), i, k) for i, k in enumerate(obstacles)
                   if covers_height(k, float(p[2]), clearance_m) and surface_distance_m(k, p) <= reach_m),
                  key=lambda t: (t[0], t[1]))
    out: list[Obstacle] = []
    for _, _, k in near:
        if len(out) < count and not any(circle_inside(k, o) for o in out):
            out.append(k)
    return out


def circle_inside(a: Obstacle, b: Obstacle) -> bool:
    """Whether `a`'s horizontal circle lies inside `b`'s."""
    return math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) + a.radius_m <= b.radius_m
