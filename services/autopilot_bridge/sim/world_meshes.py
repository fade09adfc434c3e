"""A scene's geometry as triangle meshes for the 3-D world (gl_canvas.MeshData): ground, photo layers,
solid objects (boxes, pillars, trees) and the textures they use. Pure geometry: numpy only.

The photo layers keep the 2.5-D scenes' placement (renderer.py): a vertical plane whose texture maps
to world by X = A (s, t, 1); here it is a quad with texture coordinates at its corners (a layer that
`wrap`s past its picture repeats it mirrored, like the 2.5-D renderer's reflect border).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.sim import textures
from cinetransfer.services.autopilot_bridge.sim.gl_canvas import (AMBIENT, SUN_DIR, SURFACE_BACKGROUND,
                                                                  SURFACE_FOREGROUND, SURFACE_GROUND, SURFACE_OBJECT,
                                                                  SURFACE_SKY, MeshData)
from cinetransfer.services.autopilot_bridge.sim.scene import LayerSpec, ObjectSpec, Scene, SceneError

#: the ground's detail texture: metres per repeat of its tile (TILE_PX texels: ~1 mm a texel) and its strength
GROUND_DETAIL_PERIOD_M = 0.5
DETAIL_GAIN = 0.25
#: a photo layer's detail: texels of detail per texel of the photograph (finer than the photo, so that a
#: close look at a backdrop still has a texel per pixel)
LAYER_DETAIL_PER_TEXEL = 4.0
CYLINDER_SEGMENTS = 24
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
SURFACE_OF_REGION = {"background": SURFACE_BACKGROUND, "foreground": SURFACE_FOREGROUND, "sky": SURFACE_SKY}


def read_texture(path, wrap: str) -> np.ndarray:
    """A layer's picture as BGRA, tiled 2 x 2 mirrored when it wraps by reflection (then repeated)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SceneError(f"cannot read texture {path}")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 3:
        img = np.dstack([img, np.full(img.shape[:2], 255, np.uint8)])
    if wrap == "reflect":
        row = np.hstack([img, img[:, ::-1]])
        img = np.vstack([row, row[::-1]])
    return img


def ground_texture(path) -> np.ndarray:
    """The ground's tile: a procedural texture by name (seamless already), or a picture tiled 2 x 2 mirrored."""
    if isinstance(path, str) and path in textures.NAMES:
        return textures.texture(path, 2 * textures.TILE_PX)
    g = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if g is None:
        raise SceneError(f"cannot read texture {path}")
    row = np.hstack([g, g[:, ::-1]])
    return np.vstack([row, row[::-1]])


def layer_quad(spec: LayerSpec, size_px: tuple[int, int], camera_pos_m: np.ndarray, camera_yaw: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """(corners (4, 3) world, texture coordinates (4, 2) in GL's convention) of a photo layer whose
    picture is `size_px` (w, h) (before any mirrored tiling)."""
    w, h = size_px
    if spec.facing == "camera":
        xy = (camera_pos_m[:2] + spec.distance_m * np.array([math.cos(camera_yaw), math.sin(camera_yaw)])
              if spec.distance_m is not None else np.array(spec.position_m))
        d = camera_pos_m[:2] - xy
        phi = math.atan2(d[1], d[0])
    else:
        xy, phi = np.array(spec.position_m), spec.facing_yaw_rad
    right = np.array([-math.sin(phi), math.cos(phi), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    base = np.array([xy[0], xy[1], spec.bottom_z_m])
    au, av = spec.anchor_px if spec.anchor_px is not None else (w / 2.0, float(h))
    if spec.extent_m is not None:
        ew, eh = spec.extent_m
        corners = np.array([base - ew / 2 * right, base + ew / 2 * right,
                            base + ew / 2 * right + eh * up, base - ew / 2 * right + eh * up])
    else:
        st = np.array([[0, h], [w, h], [w, 0], [0, 0]], float)
        corners = np.array([base + ((s - au) * right + (av - t) * up) * spec.m_per_px for s, t in st])
    # texture pixel (s, t) of each corner: X = base + m ((s - au) right + (av - t) up)
    rel = corners - base
    s = rel @ right / spec.m_per_px + au
    t = av - rel @ up / spec.m_per_px
    tile = 2.0 if spec.wrap == "reflect" else 1.0
    uv = np.column_stack([s / (tile * w), 1.0 - t / (tile * h)])
    return corners.astype(np.float32), uv.astype(np.float32)


def ground_mesh(scene: Scene, texture_px: tuple[int, int]) -> MeshData:
    """The ground: a square of 2 extent_m around the origin, its texture tiled in world metres."""
    g = scene.ground
    e, z = g.extent_m, g.z_m
    verts = np.array([[-e, -e, z], [e, -e, z], [e, e, z], [-e, e, z]], np.float32)
    period = np.array(texture_px, float) * g.m_per_px
    return MeshData("ground", verts, QUAD_FACES, "uv", SURFACE_GROUND, uv=(verts[:, :2] / period).astype(np.float32),
                    texture="ground", detail="detail", detail_period_m=float(period[0] / GROUND_DETAIL_PERIOD_M),
                    detail_gain=DETAIL_GAIN)


def solid_mesh(name: str, verts: np.ndarray, faces: np.ndarray, texture: str, period_m: float) -> MeshData:
    """A lit, world-textured solid as a uv mesh: every triangle gets its own corners, its texture
    projected along the dominant axis of its normal (metres / period_m) and the sun's light on it."""
    tri = verts[faces]  # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    axis = np.argmax(np.abs(n), axis=1)
    keep = np.array([[0, 1], [1, 2], [0, 2]])[np.where(axis == 2, 0, np.where(axis == 0, 1, 2))]  # (F, 2)
    uv = np.take_along_axis(tri, keep[:, None, :], axis=2) / period_m  # (F, 3, 2)
    sun = np.asarray(SUN_DIR) / np.linalg.norm(SUN_DIR)
    light = AMBIENT + (1.0 - AMBIENT) * np.abs(n @ sun)
    f = len(faces)
    return MeshData(name, tri.reshape(-1, 3).astype(np.float32), np.arange(3 * f, dtype=np.int32).reshape(f, 3),
                    "uv", SURFACE_OBJECT, uv=uv.reshape(-1, 2).astype(np.float32), texture=texture,
                    colours=np.repeat(light, 3)[:, None].repeat(3, axis=1).astype(np.float32), detail="detail",
                    detail_period_m=float(period_m / GROUND_DETAIL_PERIOD_M), detail_gain=DETAIL_GAIN)


def layer_mesh(i: int, spec: LayerSpec, size_px: tuple[int, int], camera_pos_m: np.ndarray,
               camera_yaw: float, cut_out: bool = False) -> MeshData:
    """A photo layer's quad; `cut_out`: its picture has transparent parts (not drawn)."""
    corners, uv = layer_quad(spec, size_px, camera_pos_m, camera_yaw)
    sky = spec.region == "sky"
    tile = 2.0 if spec.wrap == "reflect" else 1.0
    return MeshData(f"layer{i}:{spec.name}", corners, QUAD_FACES, "uv", SURFACE_OF_REGION[spec.region], uv=uv,
                    texture=f"layer{i}", detail=None if sky else "detail",
                    detail_period_m=LAYER_DETAIL_PER_TEXEL * tile * max(size_px) / textures.TILE_PX,
                    detail_gain=0.0 if sky else DETAIL_GAIN * 0.6, sky=sky, alpha=cut_out)


# -- solid objects ------------------------------------------------------------------------------
def box(centre_xy: tuple[float, float], size: tuple[float, float, float], yaw: float, z0: float = 0.0
        ) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a box standing on z0: length along yaw, depth across, height up."""
    lx, ly, hz = size[0] / 2, size[1] / 2, size[2]
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([[x, y] for x, y in ((-lx, -ly), (lx, -ly), (lx, ly), (-lx, ly))])
    xy = local @ np.array([[c, s], [-s, c]]) + np.asarray(centre_xy)
    verts = np.vstack([np.column_stack([xy, np.full(4, z0)]), np.column_stack([xy, np.full(4, z0 + hz)])])
    faces = np.array([[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7],
                      [4, 5, 6], [4, 6, 7]], np.int32)
    return verts.astype(np.float32), faces


def cylinder(centre_xy: tuple[float, float], radius: float, z0: float, z1: float, n: int = CYLINDER_SEGMENTS
             ) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of an upright cylinder with a top cap."""
    a = 2 * math.pi * np.arange(n) / n
    ring = np.column_stack([centre_xy[0] + radius * np.cos(a), centre_xy[1] + radius * np.sin(a)])
    verts = np.vstack([np.column_stack([ring, np.full(n, z0)]), np.column_stack([ring, np.full(n, z1)]),
                       [[centre_xy[0], centre_xy[1], z1]]])
    k = np.arange(n)
    k1 = (k + 1) % n
    side = np.vstack([np.column_stack([k, k1, n + k1]), np.column_stack([k, n + k1, n + k])])
    cap = np.column_stack([n + k, n + k1, np.full(n, 2 * n)])
    return verts.astype(np.float32), np.vstack([side, cap]).astype(np.int32)


def ellipsoid(centre: tuple[float, float, float], radii: tuple[float, float, float], rings: int = 10,
              segments: int = CYLINDER_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a UV ellipsoid."""
    th = np.linspace(0, math.pi, rings + 1)
    ph = 2 * math.pi * np.arange(segments) / segments
    t, p = np.meshgrid(th, ph, indexing="ij")
    verts = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    verts = verts * np.asarray(radii) + np.asarray(centre)
    faces = []
    for i in range(rings):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            c, d = a + segments, b + segments
            faces += [[a, c, d], [a, d, b]]
    return verts.astype(np.float32), np.array(faces, np.int32)


def object_meshes(i: int, spec: ObjectSpec, xy: tuple[float, float], z0: float) -> list[MeshData]:
    """The meshes of one solid object with its foot's centre at `xy`."""
    name = f"object{i}:{spec.name}"
    if spec.kind == "box":
        return [solid_mesh(name, *box(xy, spec.size_m, spec.yaw_rad, z0), spec.texture, spec.period_m)]
    height = spec.size_m[2]
    out = [solid_mesh(name, *cylinder(xy, spec.size_m[0] / 2, z0, z0 + height), spec.texture, spec.period_m)]
    if spec.kind == "tree":
        crown = ellipsoid(*tree_crown(spec, xy, z0))
        out.append(solid_mesh(name + ":crown", *crown, "leaves", 1.5))
    return out


def tree_crown(spec: ObjectSpec, xy: tuple[float, float], z0: float) -> tuple[tuple[float, float, float],
                                                                               tuple[float, float, float]]:
    """(centre, radii) of a tree's crown ellipsoid: it sits on the trunk, a third of it below the
    trunk's top (the keep-outs of sim/obstacles.py take the same shape)."""
    cd, ch = spec.crown_m
    return (xy[0], xy[1], z0 + spec.size_m[2] + 0.35 * ch), (cd / 2, cd / 2, ch / 2)


def object_position(spec: ObjectSpec, t_s: float) -> tuple[float, float]:
    """Where a (moving) object's foot is at time t_s: back and forth along position -> path_m."""
    if not spec.path_m or spec.speed_mps <= 0:
        return spec.position_m
    pts = np.array([spec.position_m, *spec.path_m], float)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    total = float(seg.sum())
    if total <= 0:
        return spec.position_m
    s = (spec.speed_mps * t_s) % (2 * total)
    s = s if s <= total else 2 * total - s
    k = int(min(np.searchsorted(np.cumsum(seg), s, side="right"), len(seg) - 1))
    s0 = float(np.cumsum(seg)[k] - seg[k])
    f = (s - s0) / max(seg[k], 1e-9)
    p = pts[k] + f * (pts[k + 1] - pts[k])
    return float(p[0]), float(p[1])
