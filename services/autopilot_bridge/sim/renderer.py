"""2.5-D renderer: real photographs on planes in 3-D, a pinhole camera and thin-lens blur.

Model (docs/simulator.md has the long version):
- Every scene element is a textured plane: the ground (z = const, texture tiled by reflection),
  backdrops and foreground objects (vertical planes standing on the ground), the subject (a
  camera-facing vertical billboard, a real person cut out with its mask) and the sky (a
  camera-facing plane far away). Textures are premultiplied BGRA with mip levels, and level -1 for
  magnified views (the texels and Lanczos-4 points between them: bilinear alone softens them).
- Each plane maps to the image by a homography H = K' R^T [a1 a2 a0 - C] (texture → world →
  camera → pixels, shared/camera.py conventions), drawn with cv2.warpPerspective into the
  plane's bounding box only; planes crossing the camera's near plane are clipped (polygon).
- Depth of field: each plane is blurred by a Gaussian with the second moment of its blur disc,
  sigma = d/4 with d the blur-circle diameter in pixels from shared/camera.blur_diameter_mm at
  the plane's depth. The ground is cut into depth bands (uniform in inverse depth, so that the
  blur changes by a bounded step from one band to the next, and cut at the subject's and every
  object's depth so that occlusion order is right); each band gets its own blur and mip level.
- Layers are composited back to front with premultiplied "over".
- Ground-truth region labels come from a low-resolution label pass that computes every pixel's
  depth exactly (ray/plane intersection of the front-most opaque plane).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.sim.blur import gaussian_blur
from cinetransfer.shared import camera as cam

NEAR_M = 0.05
#: Gaussian sigma per blur-circle diameter (the lens model's: shared.camera)
SIGMA_PER_DIAMETER = cam.SIGMA_PER_DIAMETER
MIN_SIGMA_PX = 0.35
#: the widest blur done at full size of a plane's warp; wider ones on a downscaled copy (sim/blur.py)
MAX_SIGMA_PX = 6.0
#: blur-circle step [px] between ground bands, and the most bands.
BAND_COC_STEP_PX = 2.0
MAX_BANDS = 10
#: A texture seen magnified (a texel wider than a pixel of the warp) is warped from "mip level -1":
#: its texels plus the Lanczos-4 points halfway between them (`upsample2`), not from the texture
#: itself. Why: bilinear interpolation is a low-pass of its own; magnifying a sinusoid it keeps
#: 0.74 of the contrast at 0.3 cycles/texel and 0.57 at 0.4 (measured with cv2.warpPerspective,
#: any magnification), so a sharp cut-out magnified 1.01-1.96x (the juggler in the tos_clip01 ->
#: focus_hedge transfer) rendered soft enough for the focus estimator to call it out of focus.
#: Lanczos-4 is close to the band-limited reconstruction of the samples (1.00-1.01 up to 0.3
#: cycles/texel: it adds no detail the photograph does not hold); bilinear from level -1 keeps 0.93
#: and 0.78. Lanczos-4 straight in the warp keeps 1.01 and 0.90 but tripled the render time (a
#: backdrop filling the frame is magnified too).
UPSAMPLE_PAD_TEXELS = 4  # Lanczos-4's reach


def lanczos4_halfway() -> np.ndarray:
    """Lanczos-4 weights (OpenCV's INTER_LANCZOS4 kernel) of the point halfway between two texels,
    from the texels at offsets -3.5 ... +3.5, normalised."""
    x = np.arange(-3.5, 4.0)
    w = np.sinc(x) * np.sinc(x / 4)
    return (w / w.sum()).astype(np.float32)


LANCZOS4_HALFWAY = lanczos4_halfway()


@dataclass
class Texture:
    """Premultiplied BGRA texture with a mip pyramid (and level -1, `magnified`, for close views)."""

    levels: list[np.ndarray]
    border: int = cv2.BORDER_CONSTANT

    @classmethod
    def from_bgra(cls, bgra: np.ndarray, *, premultiplied: bool = False, wrap: str = "none",
                  max_levels: int = 6) -> "Texture":
        img = np.ascontiguousarray(bgra)
        if img.shape[2] == 3:
            img = np.dstack([img, np.full(img.shape[:2], 255, np.uint8)])
        if not premultiplied:
            a = img[..., 3:4].astype(np.uint16)
            img = img.copy()
            img[..., :3] = ((img[..., :3].astype(np.uint16) * a + 127) // 255).astype(np.uint8)
        levels = [img]
        while len(levels) < max_levels and min(levels[-1].shape[:2]) >= 16:
            levels.append(cv2.pyrDown(levels[-1]))
        border = {"none": cv2.BORDER_CONSTANT, "reflect": cv2.BORDER_REFLECT_101,
                  "replicate": cv2.BORDER_REPLICATE, "wrap": cv2.BORDER_WRAP}[wrap]
        return cls(levels=levels, border=border)

    @property
    def size(self) -> tuple[int, int]:
        h, w = self.levels[0].shape[:2]
        return w, h

    @cached_property
    def magnified(self) -> np.ndarray:
        """Level -1: level 0 on a grid twice as fine (`upsample2`), made on first use."""
        return upsample2(self.levels[0], self.border)

    def level(self, i: int) -> np.ndarray:
        """Mip level i (0 = full resolution, -1 = `magnified`)."""
        return self.magnified if i < 0 else self.levels[i]


def clamp_premultiplied(bgra: np.ndarray) -> np.ndarray:
    """Colour <= alpha (in place): a kernel with negative lobes rings at an alpha edge and can leave
    more colour than coverage, which "over" would add as a bright halo."""
    bgra[..., :3] = cv2.min(bgra[..., :3], cv2.merge([bgra[..., 3]] * 3))
    return bgra


def upsample2(bgra: np.ndarray, border: int) -> np.ndarray:
    """Premultiplied BGRA (h, w) resampled on a grid twice as fine, (2h - 1, 2w - 1): pixel j of the
    result is texel j / 2, so the even pixels are the texels themselves and the odd ones Lanczos-4
    interpolated between them (a warp aligned with the texels then copies them exactly, as from
    level 0). The edges are continued the way the warp continues them (`border`)."""
    p = UPSAMPLE_PAD_TEXELS
    padded = cv2.copyMakeBorder(bgra, p, p, p, p, border, value=0)
    h, w = padded.shape[:2]
    # separable filtering (cv2.warpAffine with INTER_LANCZOS4 gives the same values, 10x slower):
    # the halfway points along x, along y and along both (int16: the lobes over- and undershoot),
    # interleaved with the texels
    half, one = LANCZOS4_HALFWAY, np.ones(1, np.float32)
    up = np.empty((2 * h - 1, 2 * w - 1, padded.shape[2]), np.int16)
    up[::2, ::2] = padded
    up[::2, 1::2] = cv2.sepFilter2D(padded, cv2.CV_16S, half, one, anchor=(3, 0))[:, :-1]
    up[1::2, ::2] = cv2.sepFilter2D(padded, cv2.CV_16S, one, half, anchor=(0, 3))[:-1, :]
    up[1::2, 1::2] = cv2.sepFilter2D(padded, cv2.CV_16S, half, half, anchor=(3, 3))[:-1, :-1]
    up = np.clip(up[2 * p:-2 * p, 2 * p:-2 * p], 0, 255).astype(np.uint8)
    return clamp_premultiplied(up)


@dataclass(frozen=True)
class View:
    """Camera pose, lens and image size for one frame."""

    position_m: np.ndarray
    ypr_rad: np.ndarray
    focal_mm: float
    focus_m: float
    f_number: float
    width: int
    height: int
    sensor: cam.Sensor = field(default_factory=cam.Sensor)

    @property
    def rotation(self) -> np.ndarray:
        return cam.rotation_ypr(*np.asarray(self.ypr_rad, float))

    def kmat(self, scale: float = 1.0) -> np.ndarray:
        """Camera coords (x fwd, y left, z up) → continuous pixel coords (u W, v H) (homogeneous)."""
        w, h = self.width * scale, self.height * scale
        f, sw, sh = self.focal_mm, self.sensor.width_mm, self.sensor.height_mm
        return np.array([[w / 2, -f * w / sw, 0.0], [h / 2, 0.0, -f * h / sh], [1.0, 0.0, 0.0]])

    def to_camera(self, pts_w: np.ndarray) -> np.ndarray:
        return (np.asarray(pts_w, float) - self.position_m) @ self.rotation

    def coc_px(self, depth_m: float) -> float:
        if not depth_m > 0:
            return 0.0
        d = cam.blur_diameter_mm(depth_m, self.focal_mm, self.f_number, self.focus_m)
        return float(d) / self.sensor.width_mm * self.width

    def ray_dirs_camera(self, w: int, h: int) -> np.ndarray:
        """Camera-frame ray (x = 1) through each pixel centre of a (h, w) grid."""
        u = (np.arange(w) + 0.5) / w
        v = (np.arange(h) + 0.5) / h
        y = -(u - 0.5) * self.sensor.width_mm / self.focal_mm
        z = -(v - 0.5) * self.sensor.height_mm / self.focal_mm
        rays = np.empty((h, w, 3))
        rays[..., 0] = 1.0
        rays[..., 1] = y[None, :]
        rays[..., 2] = z[:, None]
        return rays


@dataclass
class Plane:
    """A textured planar polygon: world X = A @ (s, t, 1) for continuous texture coords (s, t)."""

    name: str
    texture: Texture
    a: np.ndarray  # (3, 3)
    corners_w: np.ndarray  # (N, 3) polygon in world (convex)
    region: str  # 'subject' | 'foreground' | 'background' | 'ground' | 'sky'
    depth_key: float = 0.0  # composite order (larger = drawn earlier)
    blur_depth_m: float | None = None  # depth used for the blur (None = polygon centroid depth)
    clip_x: tuple[float, float] = (NEAR_M, math.inf)  # camera-depth range kept (ground bands)


def _clip_polygon(poly: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Clip a convex polygon (camera coords) to lo <= x <= hi (Sutherland–Hodgman)."""
    def clip(pts: list[np.ndarray], keep, bound: float) -> list[np.ndarray]:
        out = []
        n = len(pts)
        for i in range(n):
            p, q = pts[i], pts[(i + 1) % n]
            kp, kq = keep(p[0]), keep(q[0])
            if kp:
                out.append(p)
            if kp != kq:
                t = (bound - p[0]) / (q[0] - p[0])
                out.append(p + t * (q - p))
        return out

    pts = list(poly)
    pts = clip(pts, lambda x: x >= lo, lo)
    if pts and math.isfinite(hi):
        pts = clip(pts, lambda x: x <= hi, hi)
    return np.array(pts) if len(pts) >= 3 else np.zeros((0, 3))


def plane_homography(view: View, a: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Continuous texture coords → continuous pixel coords of an image `scale` times the view's size."""
    m = np.asarray(a, float).copy()
    m[:, 2] = m[:, 2] - view.position_m
    return view.kmat(scale) @ view.rotation.T @ m


def _to_index(h_cont: np.ndarray, level: int, x0: int, y0: int, k: int = 1) -> np.ndarray:
    """Homography from texture-level pixel indices to ROI pixel indices (ROI downscaled k times)."""
    s = float(2 ** level)
    o = 0.5 if level < 0 else 0.5 * s  # where pixel 0's centre lies (level -1: on texel 0's, upsample2)
    src = np.array([[s, 0.0, o], [0.0, s, o], [0.0, 0.0, 1.0]])
    dst = np.array([[1.0 / k, 0.0, -x0 / k - 0.5], [0.0, 1.0 / k, -y0 / k - 0.5], [0.0, 0.0, 1.0]])
    return dst @ h_cont @ src


@dataclass
class DrawInfo:
    """What happened to one plane in one frame (tests and debugging)."""

    name: str
    region: str
    drawn: bool
    depth_m: float = math.nan
    coc_px: float = 0.0
    level: int = 0
    roi: tuple[int, int, int, int] = (0, 0, 0, 0)


def draw_plane(canvas: np.ndarray, view: View, plane: Plane) -> DrawInfo:
    """Warp, blur and composite one plane onto a uint8 BGR canvas (in place)."""
    info = DrawInfo(plane.name, plane.region, False)
    pc = view.to_camera(plane.corners_w)
    poly = _clip_polygon(pc, plane.clip_x[0], plane.clip_x[1])
    if len(poly) == 0:
        return info
    k = view.kmat()
    uvw = poly @ k.T
    px = uvw[:, :2] / uvw[:, 2:3] - 0.5
    depth = plane.blur_depth_m if plane.blur_depth_m is not None else float(np.mean(poly[:, 0]))
    coc = view.coc_px(depth) if plane.region != "sky" else view.coc_px(1e6)
    sigma = SIGMA_PER_DIAMETER * coc
    pad = int(math.ceil(3 * sigma)) + 2 if sigma >= MIN_SIGMA_PX else 1
    hgt, wid = canvas.shape[:2]
    x0 = max(int(math.floor(px[:, 0].min())) - pad, 0)
    y0 = max(int(math.floor(px[:, 1].min())) - pad, 0)
    x1 = min(int(math.ceil(px[:, 0].max())) + pad + 1, wid)
    y1 = min(int(math.ceil(px[:, 1].max())) + pad + 1, hgt)
    if x1 <= x0 or y1 <= y0:
        return info
    # mip level from the size of a texel on screen at the plane's depth (foreshortening included)
    h_cont = plane_homography(view, plane.a)
    centre_c = poly.mean(axis=0)
    texel_m = float(np.linalg.norm(plane.a[:, 0]))
    px_m = centre_c[0] * view.sensor.width_mm / (view.focal_mm * view.width)
    normal = np.cross(plane.a[:, 0], plane.a[:, 1])
    normal_c = normal @ view.rotation
    ray = centre_c / np.linalg.norm(centre_c)
    cosang = abs(float(normal_c @ ray)) / max(float(np.linalg.norm(normal_c)), 1e-12)
    texel_per_px = px_m / max(texel_m, 1e-12) / math.sqrt(max(cosang, 0.05))
    # blurred planes (and the sky) are warped at a lower resolution, blurred, then upscaled
    k = 8 if plane.region == "sky" else (4 if sigma >= 8.0 else (2 if sigma >= 3.0 else 1))
    # magnified (a texel wider than a pixel of the warp): level -1, the Lanczos-upsampled copy
    level = int(min(max(math.floor(math.log2(max(texel_per_px * k, 1e-6))), -1), len(plane.texture.levels) - 1))
    tex = plane.texture.level(level)
    roi_w, roi_h = x1 - x0, y1 - y0
    lw, lh = max(-(-roi_w // k), 1), max(-(-roi_h // k), 1)
    hm = _to_index(h_cont, level, x0, y0, k)
    warped = cv2.warpPerspective(tex, hm, (lw, lh), flags=cv2.INTER_LINEAR,
                                 borderMode=plane.texture.border, borderValue=0)
    clipped = len(poly) != len(pc) or plane.texture.border != cv2.BORDER_CONSTANT or np.isfinite(plane.clip_x[1])
    if clipped:
        mask = np.zeros((lh, lw), np.uint8)
        pts = np.round(((px - [x0, y0] + 0.5) / k - 0.5) * 16).astype(np.int32)
        cv2.fillConvexPoly(mask, pts, 255, lineType=cv2.LINE_AA, shift=4)
        warped = cv2.multiply(warped, cv2.merge([mask] * 4), scale=1.0 / 255)
    if sigma / k >= MIN_SIGMA_PX:
        warped = gaussian_blur(warped, sigma / k, max_sigma_px=MAX_SIGMA_PX, border=cv2.BORDER_CONSTANT)
    if k > 1:
        warped = cv2.resize(warped, (lw * k, lh * k), interpolation=cv2.INTER_LINEAR)[:roi_h, :roi_w]
    region = canvas[y0:y1, x0:x1]
    alpha8 = warped[..., 3]
    col = warped[..., :3]
    if alpha8.min() == 255:
        region[...] = col
    else:
        # premultiplied "over" in uint8 with OpenCV's saturating SIMD arithmetic
        inv = cv2.cvtColor(cv2.bitwise_not(alpha8), cv2.COLOR_GRAY2BGR)
        cv2.add(cv2.multiply(region, inv, scale=1.0 / 255), col, dst=region)
    info.drawn = True
    info.depth_m = depth
    info.coc_px = coc
    info.level = level
    info.roi = (x0, y0, x1, y1)
    return info


def label_pass(view: View, planes: list[Plane], scale: float = 1.0 / 6.0) -> tuple[np.ndarray, np.ndarray]:
    """(depth [m] along the optical axis, subject mask) at `scale` resolution, front-most opaque plane.

    Planes are taken in the draw order; an opaque pixel (alpha > 0.5) overwrites what is behind."""
    w, h = max(int(round(view.width * scale)), 1), max(int(round(view.height * scale)), 1)
    depth = np.full((h, w), np.inf, np.float64)
    subj = np.zeros((h, w), bool)
    rays = view.ray_dirs_camera(w, h)
    r_t = view.rotation.T
    for p in planes:
        if p.region == "sky":
            continue
        pc = view.to_camera(p.corners_w)
        poly = _clip_polygon(pc, p.clip_x[0], p.clip_x[1])
        if len(poly) == 0:
            continue
        h_cont = plane_homography(view, p.a, scale=w / view.width)
        level = min(2, len(p.texture.levels) - 1)
        tex = p.texture.levels[level][..., 3]
        hm = _to_index(h_cont, level, 0, 0)
        a = cv2.warpPerspective(tex, hm, (w, h), flags=cv2.INTER_LINEAR, borderMode=p.texture.border,
                                borderValue=0)
        mask = np.zeros((h, w), np.uint8)
        k = view.kmat(scale=w / view.width)
        uvw = poly @ k.T
        px = uvw[:, :2] / uvw[:, 2:3] - 0.5
        cv2.fillConvexPoly(mask, np.round(px * 16).astype(np.int32), 255, shift=4)
        cover = (a > 127) & (mask > 0)
        if not cover.any():
            continue
        # plane in camera coords: n . X = c
        n_c = r_t @ np.cross(p.a[:, 0], p.a[:, 1])
        x0_c = r_t @ (p.a[:, 2] - view.position_m)
        c = float(n_c @ x0_c)
        denom = rays @ n_c
        with np.errstate(divide="ignore", invalid="ignore"):
            d = c / denom
        d = np.where((d > 0) & np.isfinite(d), d, np.inf)
        depth[cover] = d[cover]
        subj[cover] = p.region == "subject"
    return depth, subj


def ground_bands(view: View, z_m: float, extent_m: float, cuts_m: list[float]) -> list[tuple[float, float]]:
    """Camera-depth intervals for the ground: uniform in inverse depth (bounded blur step), cut at
    `cuts_m` (subject and object depths)."""
    # visible depth range of the ground square around the camera
    c = view.position_m
    sq = np.array([[c[0] - extent_m, c[1] - extent_m, z_m], [c[0] + extent_m, c[1] - extent_m, z_m],
                   [c[0] + extent_m, c[1] + extent_m, z_m], [c[0] - extent_m, c[1] + extent_m, z_m]])
    poly = _clip_polygon(view.to_camera(sq), NEAR_M, math.inf)
    if len(poly) == 0:
        return []
    d_lo, d_hi = max(float(poly[:, 0].min()), NEAR_M), float(poly[:, 0].max())
    # ground actually inside the view: the image's bottom edge rays limit the nearest visible ground
    rays = view.ray_dirs_camera(9, 2)[-1] @ view.rotation.T  # bottom row, world dirs
    dz = rays[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (z_m - c[2]) / dz
    t = t[(t > 0) & np.isfinite(t)]
    if len(t):
        d_lo = max(d_lo, float(t.min()) * 0.8)
    # inverse-depth bands: coc(d) = k |1 - s/d| is linear in 1/d
    f = view.focal_mm / 1000.0
    kpx = (f * f / (view.f_number * max(view.focus_m - f, 1e-6))) * 1000.0 / view.sensor.width_mm * view.width
    inv_lo, inv_hi = 1.0 / d_hi, 1.0 / d_lo
    span_px = kpx * view.focus_m * (inv_hi - inv_lo)
    n = int(min(max(math.ceil(span_px / BAND_COC_STEP_PX), 1), MAX_BANDS))
    # also at most a depth ratio of 4 per band (mip level choice)
    n = int(min(max(n, math.ceil(math.log(max(d_hi / d_lo, 1.0), 4.0))), MAX_BANDS + 4))
    inv = np.linspace(inv_hi, inv_lo, n + 1)
    edges = sorted(set([1.0 / x if x > 0 else math.inf for x in inv] +
                       [d for d in cuts_m if d_lo < d < d_hi]))
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a * 1.0001]
