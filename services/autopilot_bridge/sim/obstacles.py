"""The keep-out obstacles of a scene: the cylinders the camera drone must not fly into.

Derived once from the scene's solid objects (the 3-D world's `objects:`), so the flight keeps
clear of what the renderer draws: a pillar is its own cylinder; a tree is two, its trunk (from
the ground to the trunk's top) and its crown (the crown ellipsoid's widest circle over the
ellipsoid's height band, sim/world_meshes.tree_crown). Boxes (walls, buildings) and moving
objects (the courtyard's van) give none: a wall is no cylinder, and a keep-out is declared
once, not followed. The clearance the vehicle keeps from them is the vehicle profile's
`min_obstacle_distance_m`; the transfer hands the cylinders to the planner and to the bridge's
safety layer (shared/obstacles.py).
"""
from __future__ import annotations

from cinetransfer.services.autopilot_bridge.sim.scene import ObjectSpec, Scene
from cinetransfer.services.autopilot_bridge.sim.world_meshes import tree_crown
from cinetransfer.shared.obstacles import Obstacle


def object_obstacles(spec: ObjectSpec, ground_z_m: float = 0.0) -> tuple[Obstacle, ...]:
    """The keep-out cylinders of one solid object standing on the ground at `ground_z_m`."""
    if spec.kind == "box" or spec.path_m:
        return ()
    x, y = spec.position_m
    out = [Obstacle(x, y, spec.size_m[0] / 2, ground_z_m, ground_z_m + spec.size_m[2])]
    if spec.kind == "tree" and min(spec.crown_m) > 0:
        (cx, cy, cz), (rx, _, rz) = tree_crown(spec, (x, y), ground_z_m)
        out.append(Obstacle(cx, cy, rx, cz - rz, cz + rz))
    return tuple(out)


def scene_obstacles(scene: Scene) -> tuple[Obstacle, ...]:
    """Every keep-out cylinder of `scene` (none in a scene without solid objects)."""
    z0 = scene.ground.z_m if scene.ground is not None else 0.0
    return tuple(k for spec in scene.objects for k in object_obstacles(spec, z0))
