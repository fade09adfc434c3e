"""The known upright surfaces of a scene: its fixed photo layers as the map hands them to the planner.

Each layer that stands where the scene puts it (not a camera-facing one, which follows the camera, and not
the sky) is the rectangle its quad spans (world_meshes.layer_quad): focus_hedge's hedge 3 m in front of the
camera's start and its backdrop 30 m behind the subject. A cut-out's transparent pixels (the hedge's
irregular top) are inside the rectangle: the map is the quad, not its silhouette. Solid objects are left
out: a tree or a pillar is a keep-out (sim/obstacles.py), a box no flat picture.

Each rectangle carries its texture's flip: the blur [circles of the one circle] from which the focus estimator
reads the texture soft as this renderer draws defocus (READ_FLIP_CIRCLES, measured; docs/report.md, "Read soft
by the extraction"), so that the planner can ask each region for blur
past its own flip; a texture not measured has the one circle's own, 1.
"""
from __future__ import annotations

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.sim.scene import LayerSpec, Scene
from cinetransfer.services.autopilot_bridge.sim.world_meshes import layer_quad
from cinetransfer.shared.surfaces import Surface

#: the focus estimator's flip [circles] on each measured texture as this renderer draws defocus (docs/report.md),
#: each measured alone (one texture at 960 px), not on a flight's frames: the frames a flight is judged on must
#: not tune what the planner asks of them; the crisp hedge needs the most blur to be read soft
READ_FLIP_CIRCLES = {"hedge.png": 1.27, "lawn_backdrop.jpg": 1.10, "forest_backdrop.png": 1.20}


def layer_surface(spec: LayerSpec) -> Surface | None:
    """The rectangle a fixed layer spans; None for the sky and camera-facing layers."""
    if spec.region == "sky" or spec.facing == "camera":
        return None
    size = (1, 1)
    if spec.extent_m is None:
        img = cv2.imread(str(spec.texture), cv2.IMREAD_UNCHANGED)
        if img is None:
            return None
        size = (int(img.shape[1]), int(img.shape[0]))
    corners, _ = layer_quad(spec, size, np.zeros(3), 0.0)
    z = corners[:, 2]
    return Surface(float(corners[0, 0]), float(corners[0, 1]), float(corners[1, 0]), float(corners[1, 1]),
                   float(z.min()), float(z.max()), READ_FLIP_CIRCLES.get(spec.texture.name, 1.0))


def scene_surfaces(scene: Scene) -> tuple[Surface, ...]:
    """Every fixed layer's rectangle of `scene`."""
    return tuple(s for s in (layer_surface(spec) for spec in scene.layers) if s is not None)
