"""The 3-D world renderer (scenes with `world: 3d`): meshes drawn by OpenGL, depth of field from depth.

Per frame: the scene's meshes (world_meshes.py: ground, photo layers, solid objects) and the person's
skinned body (actor.py) are drawn by gl_canvas.GLCanvas through the camera model; the read-back depth
gives every pixel its blur (dof.py, the lens model of shared/camera.py) and the truth: the subject's
mask and depths for the focus regions (truth.py), the joints projected with camera.project_world and
judged hidden when something other than the person lies in front of them in the depth buffer.
Same view and time, same bytes: nothing random at run time, one GL context drawing in order.
"""
from __future__ import annotations

import math

import numpy as np

from cinetransfer.services.autopilot_bridge.sim import textures
from cinetransfer.services.autopilot_bridge.sim.actor import Actor, Body
from cinetransfer.services.autopilot_bridge.sim.dof import apply_dof, sigma_px
from cinetransfer.services.autopilot_bridge.sim.gl_canvas import SURFACE_SUBJECT, GLCanvas, MeshData
from cinetransfer.services.autopilot_bridge.sim.renderer import View
from cinetransfer.services.autopilot_bridge.sim.scene import Scene
from cinetransfer.services.autopilot_bridge.sim.truth import region_truth
from cinetransfer.services.autopilot_bridge.sim.world_meshes import (ground_mesh, ground_texture, layer_mesh,
                                                                     object_meshes, object_position, read_texture)
from cinetransfer.shared import camera as cam
from cinetransfer.shared.focus_regions import feet_row, foreground_present

#: the truth's region masks and depths are read from every TRUTH_STRIDE-th pixel (the 2.5-D label pass: 1/6)
TRUTH_STRIDE = 4
#: a joint counts as hidden when something other than the person is this much nearer at its pixel [m]
OCCLUSION_MARGIN_M = 0.05


class WorldRenderer:
    """Draws a 3-D scene for one camera view and time and computes its truth (SceneRenderer's interface)."""

    world = "3d"

    def __init__(self, scene: Scene, width: int | None = None, height: int | None = None):
        self.scene = scene
        self.width = int(width or scene.camera.width)
        self.height = int(height or scene.camera.height)
        self.sensor = cam.Sensor(scene.camera.sensor_width_mm, scene.camera.sensor_height_mm, scene.camera.coc_mm)
        self.ground_z = scene.ground.z_m if scene.ground else 0.0
        self.actor = Actor(scene.subject, ground_z_m=self.ground_z)
        self.subject = self.actor  # the subject with a heading of its own (heading_at), as the 2.5-D renderer's
        self.script = self.actor.script
        self.canvas = GLCanvas(self.width, self.height)
        self.canvas.add_texture("detail", textures.texture("detail"))
        self._static: list[MeshData] = []
        self._layers: list[tuple[int, object, tuple[int, int], bool]] = []
        if scene.ground is not None:
            g = ground_texture(scene.ground.texture)
            self.canvas.add_texture("ground", g)
            self._static.append(ground_mesh(scene, (g.shape[1], g.shape[0])))
        for i, spec in enumerate(scene.layers):
            img = read_texture(spec.texture, spec.wrap)
            tile = 2 if spec.wrap == "reflect" else 1
            self.canvas.add_texture(f"layer{i}", img, repeat=spec.wrap == "reflect")
            size = (img.shape[1] // tile, img.shape[0] // tile)
            cut_out = bool(img[..., 3].min() < 128)
            if spec.facing == "camera":
                self._layers.append((i, spec, size, cut_out))
            else:
                self._static.append(layer_mesh(i, spec, size, np.zeros(3), 0.0, cut_out))
        for name in sorted({o.texture for o in scene.objects} | ({"leaves"} if scene.objects else set())):
            self.canvas.add_texture(name, textures.texture(name))
        self._moving = [(i, o) for i, o in enumerate(scene.objects) if o.path_m and o.speed_mps > 0]
        for i, o in enumerate(scene.objects):
            if not (o.path_m and o.speed_mps > 0):
                self._static.extend(object_meshes(i, o, o.position_m, self.ground_z))
        self._static_names = {m.name for m in self._static}
        # the ground's centre is under the camera whatever its extent: sorted after every object
        self._centres = [np.array([0.0, 0.0, -1e6]) if m.name == "ground" else m.vertices.mean(axis=0)
                         for m in self._static]

    # -- the subject ------------------------------------------------------------------------
    def body_at(self, t_s: float) -> Body:
        return self.actor.body_at(t_s)

    def subject_joints(self, t_s: float, camera_pos_m: np.ndarray) -> np.ndarray:
        """The person's COCO-17 joints [m, world] at t_s (the same whatever the camera: a real body)."""
        return self.actor.joints_at(t_s)

    def subject_heading(self, t_s: float) -> float:
        return self.actor.heading_at(t_s)

    # -- drawing ----------------------------------------------------------------------------
    def meshes(self, view: View, body: Body, t_s: float) -> list[MeshData]:
        """Everything to draw at t_s, nearest first (llvmpipe then skips the shading of hidden pixels):
        the person, moving objects, the static scene by distance, the ground, the sky last."""
        out = [MeshData("subject", body.vertices_m, self.actor.faces, "colour", SURFACE_SUBJECT,
                        colours=self.actor.colours_bgr, lit=True, closed=True)]
        for i, o in self._moving:
            out += object_meshes(i, o, object_position(o, t_s), self.ground_z)
        dist = [float(np.linalg.norm(c - view.position_m)) for c in self._centres]
        out += [self._static[k] for k in np.argsort(dist, kind="stable")]
        yaw = float(view.ypr_rad[0])
        out += [layer_mesh(i, spec, size, view.position_m, yaw, cut) for i, spec, size, cut in self._layers]
        return out

    def draw(self, view: View, t_s: float,
             colour: bool = True) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, Body]:
        """(sharp BGR image (None without `colour`), depth [m], surface ids, the body) of the view at t_s."""
        body = self.body_at(t_s)
        bgr, depth, surface = self.canvas.draw(self.meshes(view, body, t_s), view.position_m, view.ypr_rad,
                                               view.focal_mm, view.sensor, static=self._static_names, colour=colour)
        return bgr, depth, surface, body

    def render(self, view: View, t_s: float, *, truth: bool = True) -> tuple[np.ndarray, dict]:
        bgr, depth, surface, body = self.draw(view, t_s)
        sig = sigma_px(depth, view.focal_mm, view.f_number, view.focus_m, view.sensor.width_mm, view.width)
        img = apply_dof(bgr, sig)
        geo = self.geometry(view, body)
        if truth:
            geo.update(self.truth(view, depth, surface, geo))
        return img, geo

    def truth_only(self, view: View, t_s: float) -> dict:
        """The truth of a frame without its image (a render with truth but no picture): a depth-only
        draw, whose depths and surface ids are the colour draw's bytes."""
        _, depth, surface, body = self.draw(view, t_s, colour=False)
        geo = self.geometry(view, body)
        geo.update(self.truth(view, depth, surface, geo))
        return geo

    @staticmethod
    def geometry(view: View, body: Body) -> dict:
        joints_c = view.to_camera(body.joints_m)
        return {"pose": body.pose, "joints_w": body.joints_m, "heading_rad": body.heading_rad,
                "subject_depth_m": float(np.mean(joints_c[:, 0])),
                "root_depth_m": float(view.to_camera(body.pose.position_m)[0])}

    def truth(self, view: View, depth: np.ndarray, surface: np.ndarray, geo: dict) -> dict:
        jn = cam.project_world(geo["joints_w"], view.position_m, view.ypr_rad, view.focal_mm, view.sensor)
        vis = joints_visible(jn, view.to_camera(geo["joints_w"])[:, 0], depth, surface)
        s = TRUTH_STRIDE
        # the band below the feet is judged a foreground at the frame's resolution, as the extraction judges it
        subject = surface == SURFACE_SUBJECT
        out = region_truth(depth[s // 2::s, s // 2::s], subject[s // 2::s, s // 2::s],
                           view.focal_mm, view.f_number, view.focus_m, view.sensor.coc_mm,
                           foreground=foreground_present(feet_row(subject), subject.shape[0]))
        lim = self.scene.limits
        out.update({"joints_norm": jn, "joints_visible": vis, "focal_length_mm": view.focal_mm,
                    "lens_limits": np.array([lim.focus_distance_min_m, lim.focus_distance_max_m, lim.f_number_min,
                                             lim.f_number_max], np.float32)})
        return out

    def close(self) -> None:
        self.canvas.close()


def joints_visible(jn: np.ndarray, joint_depth_m: np.ndarray, depth: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """A joint is visible when it projects into the image and, at its pixel, the person's own surface or
    nothing nearer than the joint (less OCCLUSION_MARGIN_M) is seen: hidden by scenery, not by the body."""
    h, w = depth.shape
    vis = np.isfinite(jn).all(axis=1) & (jn >= 0).all(axis=1) & (jn <= 1).all(axis=1)
    for k in np.flatnonzero(vis):
        col = min(int(math.floor(jn[k, 0] * w)), w - 1)
        row = min(int(math.floor(jn[k, 1] * h)), h - 1)
        if surface[row, col] != SURFACE_SUBJECT and depth[row, col] < joint_depth_m[k] - OCCLUSION_MARGIN_M:
            vis[k] = False
    return vis


__all__ = ["WorldRenderer", "joints_visible"]
