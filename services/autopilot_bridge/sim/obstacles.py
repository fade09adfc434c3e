"""The keep-out obstacles of a scene: the cylinders the camera drone must not fly into.

Derived once from the scene's solid objects (the 3-D world's `objects:`), so the flight keeps
clear of what the renderer draws: a pillar is its own cylinder; a tree is its trunk (from
the ground to the trunk's top) and its crown, a stack of CROWN_SLICES cylinders, each as wide as
the crown ellipsoid (sim/world_meshes.tree_crown) within its band: the clearance then follows the
crown's rounded underside (one cylinder of its widest circle kept a camera at 1.7 m, 6 cm under the
lowest leaf, 2.3 m from tree_3's axis, where the nearest leaves are 1.4 m away). Boxes (walls,
buildings) and moving objects (the courtyard's van) give none: a wall is no cylinder, and a keep-out is declared
once, not followed. The clearance the vehicle keeps from them is the vehicle profile's
`min_obstacle_distance_m`; the transfer hands the cylinders to the planner and to the bridge's
safety layer (shared/obstacles.py).
"""
from __future__ import annotations

import math

from cinetransfer.services.autopilot_bridge.sim.scene import ObjectSpec, Scene
from cinetransfer.services.autopilot_bridge.sim.world_meshes import tree_crown
from cinetransfer.shared.obstacles import Obstacle

#: horizontal slices a tree's crown is kept out of as: each is as wide as the crown at its widest, so
#: the stack overstates the crown by up to one slice (0.125 m of tree_3's 3 m); six kept a camera at
#: 1.6 m 1.99 m from tree_3's axis, 24 keep it 1.82 m
CROWN_SLICES = 24


def object_obstacles(spec: ObjectSpec, ground_z_m: float = 0.0) -> tuple[Obstacle, ...]:
    """The keep-out cylinders of one solid object standing on the ground at `ground_z_m`."""
    if spec.kind == "box" or spec.path_m:
        return ()
    x, y = spec.position_m
    out = [Obstacle(x, y, spec.size_m[0] / 2, ground_z_m, ground_z_m + spec.size_m[2])]
    if spec.kind == "tree" and min(spec.crown_m) > 0:
        out += crown_slices(*tree_crown(spec, (x, y), ground_z_m))
    return tuple(out)


def crown_slices(centre: tuple[float, float, float], radii: tuple[float, float, float],
                 n: int = CROWN_SLICES) -> list[Obstacle]:
    """An upright ellipsoid (centre, radii; the two horizontal radii equal) as `n` stacked cylinders,
    each as wide as the ellipsoid at its band's height nearest the centre."""
    (cx, cy, cz), (rx, _, rz) = centre, radii
    edges = [cz - rz + 2 * rz * i / n for i in range(n + 1)]
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        gap = 0.0 if lo <= cz <= hi else min(abs(lo - cz), abs(hi - cz))
        out.append(Obstacle(cx, cy, rx * math.sqrt(max(1.0 - (gap / rz) ** 2, 0.0)), lo, hi))
    return out


def scene_obstacles(scene: Scene) -> tuple[Obstacle, ...]:
    """Every keep-out cylinder of `scene` (none in a scene without solid objects)."""
    z0 = scene.ground.z_m if scene.ground is not None else 0.0
    return tuple(k for spec in scene.objects for k in object_obstacles(spec, z0))
