"""Keep-out obstacles: upright cylinders the camera drone must not fly into (pure geometry).

A `Obstacle` is the obstacle's own extent (a trunk, a pillar, a tree's crown): its axis at world
(x, y), its radius, and the height band [z_min, z_max] it fills. The clearance a vehicle keeps
from its surface is a limit of the vehicle (the profile's `envelope.min_obstacle_distance_m`,
shared/vehicle.py), not of the obstacle, so the planner's soft constraint and the bridge's
envelope check add the same number. Settings files write one as the list
`[x_m, y_m, radius_m, z_min_m, z_max_m]` (`obstacles_from`); a scene of the built-in simulator
derives its own (services/autopilot_bridge/sim/obstacles.py).

The clearance is round: a vehicle a height h under or over the band keeps its horizontal distance
from the axis at least r + sqrt(c^2 - h^2) (`keep_out_radius_m`), none once h >= c. A tree's crown
is given as a stack of such cylinders, each as wide as the crown within its band, so the clearance
follows the crown's rounded underside (sim/obstacles.py).
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


def obstacles_setting(values: Iterable[Sequence[float]], where: str = "obstacles_m") -> tuple[tuple[float, ...], ...]:
    """A config's `obstacles_m` checked (obstacles_from, ConfigError naming `where`) and held as tuples of floats:
    a settings file gives lists, and the config stays hashable."""
    return tuple(tuple(k.as_list()) for k in obstacles_from(values, where))


def keep_out_radius_m(k: Obstacle, z_m: float, clearance_m: float) -> float | None:
    """Horizontal radius [m] a vehicle at height `z_m` keeps from the cylinder's axis with a round
    clearance: r + sqrt(c^2 - h^2), h the vertical gap from `z_m` to the height band (0 within it);
    None when h > c (it passes over or under)."""
    h = max(k.z_min_m - z_m, z_m - k.z_max_m, 0.0)
    if h > clearance_m:
        return None
    return k.radius_m + math.sqrt(clearance_m * clearance_m - h * h)


def _axis_distance_m(k: Obstacle, xy: Sequence[float]) -> float:
    return math.hypot(float(xy[0]) - k.x_m, float(xy[1]) - k.y_m)


def intrusion_m(obstacles: Iterable[Obstacle], p: Sequence[float], clearance_m: float) -> float:
    """How far [m] position `p` (x, y, z) lies inside the clearance of the obstacle it is deepest in
    (keep_out_radius_m minus its distance from the axis): negative when it keeps every clearance (by
    that much), -inf when it is beside none."""
    worst = -math.inf
    for k in obstacles:
        r = keep_out_radius_m(k, float(p[2]), clearance_m)
        if r is not None:
            worst = max(worst, r - _axis_distance_m(k, p))
    return worst


def towards(k: Obstacle, p: Sequence[float]) -> tuple[tuple[float, float, float], float]:
    """(unit vector from `p` (x, y, z) to the nearest point of the obstacle's own cylinder, the distance [m]
    to that point); ((0, 0, 0), 0) inside it. The keep-out is every point within the clearance of the
    cylinder (keep_out_radius_m's round clearance is that distance), so the distance less the clearance
    is how far `p` is from the keep-out, and the vector is the way into it."""
    dx, dy = k.x_m - float(p[0]), k.y_m - float(p[1])
    rho = math.hypot(dx, dy)
    gap = max(rho - k.radius_m, 0.0)
    gx, gy = (dx * gap / rho, dy * gap / rho) if rho > 1e-12 else (0.0, 0.0)
    z = float(p[2])
    gz = k.z_min_m - z if z < k.z_min_m else (k.z_max_m - z if z > k.z_max_m else 0.0)
    d = math.sqrt(gx * gx + gy * gy + gz * gz)
    if d < 1e-12:
        return (0.0, 0.0, 0.0), 0.0
    return (gx / d, gy / d, gz / d), d


def push_out(obstacles: Iterable[Obstacle], p: Sequence[float], distance_m: float) -> np.ndarray:
    """`p` moved radially (horizontally) out of every obstacle's clearance `distance_m`, the nearest
    axis first; a point on an axis moves along +x."""
    out = np.array(p, dtype=float)
    for k in sorted(obstacles, key=lambda k: _axis_distance_m(k, out)):
        r = keep_out_radius_m(k, float(out[2]), distance_m)
        if r is None or _axis_distance_m(k, out) >= r:
            continue
        d = out[:2] - (k.x_m, k.y_m)
        n = float(np.linalg.norm(d))
        d = d / n if n > 1e-9 else np.array([1.0, 0.0])
        out[:2] = np.array([k.x_m, k.y_m]) + d * r
    return out


#: passes of push_out before a point is judged unclearable (keep-outs that overlap bounce it between them)
CLEAR_PASSES = 8


def push_clear(obstacles: Iterable[Obstacle], p: Sequence[float], distance_m: float,
               passes: int = CLEAR_PASSES) -> tuple[np.ndarray, bool]:
    """`p` pushed out (push_out) again and again until it keeps every clearance `distance_m`, and whether it
    does after `passes`: one pass out of one keep-out can land in a neighbour's (two pillars, a trunk beside a
    crown's slice); a point on the line between two overlapping ones bounces between them and stays inside."""
    obstacles = tuple(obstacles)
    out = np.array(p, dtype=float)
    for _ in range(passes):
        if intrusion_m(obstacles, out, distance_m) <= 1e-9:
            return out, True
        out = push_out(obstacles, out, distance_m)
    return out, intrusion_m(obstacles, out, distance_m) <= 1e-9


def nearest_keep_outs(obstacles: Iterable[Obstacle], p: Sequence[float], *, clearance_m: float, reach_m: float,
                      count: int) -> list[tuple[Obstacle, float]]:
    """At most `count` (obstacle, keep-out radius at `p`'s height: keep_out_radius_m) whose keep-out
    circle lies within `reach_m` of `p` horizontally, nearest first (ties by the order given); one whose
    keep-out circle lies inside a nearer one's is left out (a trunk under its crown, a crown's slices)."""
    near = []
    for i, k in enumerate(obstacles):
        r = keep_out_radius_m(k, float(p[2]), clearance_m)
        if r is not None and _axis_distance_m(k, p) - r <= reach_m:
            near.append((_axis_distance_m(k, p) - r, i, k, r))
    out: list[tuple[Obstacle, float]] = []
    for _, _, k, r in sorted(near, key=lambda t: (t[0], t[1])):
        if len(out) < count and not any(_circle_inside(k, r, o, ro) for o, ro in out):
            out.append((k, r))
    return out


def _circle_inside(a: Obstacle, ra: float, b: Obstacle, rb: float) -> bool:
    """Whether the circle of radius `ra` round `a`'s axis lies inside that of `rb` round `b`'s."""
    return math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) + ra <= rb
