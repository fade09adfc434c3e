"""`SimBackend`: the built-in simulator behind the VehiclePort interface.

Usable in-process without Zenoh, faster than real time on a simulated clock:

    from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend, load_scene
    sim = SimBackend(load_scene("lawn_juggler"), epoch_ns=0)
    sim.start()
    for k in range(48):
        sim.apply(setpoint)            # or sim.hold()
        sim.step(k / 24)               # seconds of simulated time (any monotonic clock)
        frames, truths = sim.frames(), sim.truths()

`step(now_s)` integrates the dynamics to `now_s` (the first call sets time zero) and renders
every frame due at the camera's rate on the way (frame k at k / fps). A frame is rendered with
the state at its own time. Deterministic: same scene + same calls = same frames.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import math
import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Sequence

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.port import VehiclePort
from cinetransfer.shared.dynamics import VehicleDynamics
from cinetransfer.services.autopilot_bridge.sim.renderer import (MIN_SIGMA_PX, NEAR_M, SIGMA_PER_DIAMETER,
                                                                 DrawInfo, Plane, Texture, View, draw_plane,
                                                                 ground_bands, label_pass)
from cinetransfer.services.autopilot_bridge.sim.scene import LayerSpec, Scene, SceneError, load_scene
from cinetransfer.services.autopilot_bridge.sim.heading import subject_heading_rad
from cinetransfer.services.autopilot_bridge.sim.subject import Subject
from cinetransfer.services.autopilot_bridge.sim.truth import region_truth
from cinetransfer.shared import camera as cam
from cinetransfer.shared import messages as M

__all__ = ["SimBackend", "SceneRenderer", "load_scene", "SceneError"]

log = logging.getLogger("autopilot_bridge.sim")

#: ground bands are drawn a little nearer than their own start, under the next band (no seams).
BAND_OVERLAP = 1.25


def _read_texture(path, wrap: str) -> Texture:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SceneError(f"cannot read texture {path}")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    return Texture.from_bgra(img, wrap=wrap)


def _vertical_plane_a(base_m: np.ndarray, right: np.ndarray, m_per_px: float,
                      anchor_px: tuple[float, float]) -> np.ndarray:
    up = np.array([0.0, 0.0, 1.0])
    au, av = anchor_px
    return np.column_stack([m_per_px * right, -m_per_px * up, base_m - au * m_per_px * right + av * m_per_px * up])


def _same_side(corners_w: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether points `a` and `b` lie on the same side of the vertical plane through `corners_w` (its first
    two corners span it horizontally)."""
    along = np.asarray(corners_w[1], float) - np.asarray(corners_w[0], float)
    normal = np.array([along[1], -along[0]])
    side = [float(normal @ (np.asarray(q, float)[:2] - corners_w[0][:2])) for q in (a, b)]
    return side[0] * side[1] > 0


def _right_axis(facing_yaw: float) -> np.ndarray:
    return np.array([-math.sin(facing_yaw), math.cos(facing_yaw), 0.0])


class SceneRenderer:
    """Builds the planes of a scene for one camera view and time, draws them, computes the truth."""

    def __init__(self, scene: Scene, width: int | None = None, height: int | None = None):
        self.scene = scene
        self.width = int(width or scene.camera.width)
        self.height = int(height or scene.camera.height)
        self.sensor = cam.Sensor(scene.camera.sensor_width_mm, scene.camera.sensor_height_mm, scene.camera.coc_mm)
        gz = scene.ground.z_m if scene.ground else 0.0
        self.subject = Subject(scene.subject, ground_z_m=gz)
        self.script = self.subject.script
        self._layer_tex = [_read_texture(layer.texture, layer.wrap) for layer in scene.layers]
        self._ground_tex = None
        self._ground_period_m = (0.0, 0.0)
        if scene.ground:
            g = cv2.imread(str(scene.ground.texture), cv2.IMREAD_COLOR)
            if g is None:
                raise SceneError(f"cannot read texture {scene.ground.texture}")
            # mirror-tiled 2x2 = one period of the reflected tiling; BORDER_WRAP repeats it, and the
            # texture origin follows the camera (by whole periods) so near ground samples in range
            row = np.hstack([g, g[:, ::-1]])
            tiled = np.vstack([row, row[::-1]])
            self._ground_tex = Texture.from_bgra(tiled, wrap="wrap")
            self._ground_period_m = (tiled.shape[1] * scene.ground.m_per_px, tiled.shape[0] * scene.ground.m_per_px)
        self._clip_tex = {id(f): Texture.from_bgra(f.texture, premultiplied=True)
                          for f in self.subject.clip.frames}
        # the scenery's magnified levels now (up to ~60 ms each), not in the middle of a real-time
        # take; the subject's cut-outs are small (a few ms) and make theirs on first use
        for tex in [*self._layer_tex, self._ground_tex]:
            if tex is not None:
                tex.magnified  # noqa: B018 (a cached_property: computed here, once)
        self.last_draw: list[DrawInfo] = []

    world = "2.5d"

    # -- the subject ------------------------------------------------------------------------
    def subject_joints(self, t_s: float, camera_pos_m: np.ndarray) -> np.ndarray:
        """The subject's joints [m, world] at t_s, on the billboard that faces `camera_pos_m`."""
        pose = self.subject.script.pose_at(t_s)
        frame = self.subject.frame_at(t_s, pose.action)
        return self.subject.joints_world(frame, pose.position_m, camera_pos_m)

    def subject_heading(self, t_s: float) -> float:
        """NaN: the cut-out turns to face the camera, so it has no heading of its own (a heading read
        from its joints would follow the camera round)."""
        return math.nan

    def truth_only(self, view: View, t_s: float) -> dict:
        planes, geo = self.planes(view, t_s)
        geo.update(self.truth(view, planes, geo))
        return geo

    def close(self) -> None:
        pass

    # -- geometry --------------------------------------------------------------------------
    def _layer_plane(self, spec: LayerSpec, tex: Texture, view: View) -> Plane:
        w, h = tex.size
        cpos = view.position_m
        if spec.facing == "camera":
            if spec.distance_m is not None:
                yaw = float(view.ypr_rad[0])
                xy = cpos[:2] + spec.distance_m * np.array([math.cos(yaw), math.sin(yaw)])
            else:
                xy = np.array(spec.position_m)
            d = cpos[:2] - xy
            phi = math.atan2(d[1], d[0])
        else:
            xy = np.array(spec.position_m)
            phi = spec.facing_yaw_rad
        right = _right_axis(phi)
        base = np.array([xy[0], xy[1], spec.bottom_z_m])
        anchor = spec.anchor_px if spec.anchor_px is not None else (w / 2.0, float(h))
        a = _vertical_plane_a(base, right, spec.m_per_px, anchor)
        if spec.extent_m is not None:
            ew, eh = spec.extent_m
            up = np.array([0.0, 0.0, 1.0])
            corners = np.array([base - ew / 2 * right, base + ew / 2 * right,
                                base + ew / 2 * right + eh * up, base - ew / 2 * right + eh * up])
        else:
            st = np.array([[0, h, 1], [w, h, 1], [w, 0, 1], [0, 0, 1]], float)
            corners = st @ a.T
        depth = float(view.to_camera(base)[0])
        region = spec.region
        return Plane(spec.name, tex, a, corners, region, depth_key=math.inf if region == "sky" else depth)

    def planes(self, view: View, t_s: float) -> tuple[list[Plane], dict]:
        """Planes in draw order (far to near) and the subject's geometry at time t_s."""
        pose = self.subject.script.pose_at(t_s)
        frame = self.subject.frame_at(t_s, pose.action, float(np.hypot(*pose.velocity_mps[:2])))
        root = pose.position_m
        joints = self.subject.joints_world(frame, root, view.position_m)
        right, _ = self.subject.facing_axes(root, view.position_m)
        a = _vertical_plane_a(root, right, self.subject.m_per_px, frame.anchor_px)
        h, w = frame.texture.shape[:2]
        st = np.array([[0, h, 1], [w, h, 1], [w, 0, 1], [0, 0, 1]], float)
        root_depth = float(view.to_camera(root)[0])
        joints_c = view.to_camera(joints)
        subj_depth = float(np.mean(joints_c[:, 0]))
        planes = [Plane("subject", self._clip_tex[id(frame)], a, st @ a.T, "subject", depth_key=root_depth,
                        blur_depth_m=subj_depth)]
        cuts = [root_depth]
        for spec, tex in zip(self.scene.layers, self._layer_tex):
            p = self._layer_plane(spec, tex, view)
            if spec.region != "sky" and p.depth_key > NEAR_M:
                cuts.append(p.depth_key)
            if spec.region != "sky" and p.depth_key <= root_depth and _same_side(p.corners_w, view.position_m, root):
                # a wide layer seen obliquely: its anchor can be nearer along the optical axis than the person
                # while the whole plane lies behind him (he and the camera on the same side of it)
                p = dataclasses.replace(p, depth_key=math.nextafter(root_depth, math.inf))
            planes.append(p)
        g = self.scene.ground
        if g is not None:
            m = g.m_per_px
            c = view.position_m
            # texture s runs along world y, t along world x; shift the origin by whole periods
            py, px_ = self._ground_period_m[0], self._ground_period_m[1]
            ox = math.floor((c[0] - px_ / 2) / px_) * px_
            oy = math.floor((c[1] - py / 2) / py) * py
            ga = np.array([[0.0, m, ox], [m, 0.0, oy], [0.0, 0.0, g.z_m]])
            e = g.extent_m
            sq = np.array([[c[0] - e, c[1] - e, g.z_m], [c[0] + e, c[1] - e, g.z_m],
                           [c[0] + e, c[1] + e, g.z_m], [c[0] - e, c[1] + e, g.z_m]])
            bands = ground_bands(view, g.z_m, e, cuts)
            # merge neighbouring sharp bands that share a mip level (one warp instead of several)
            merged: list[list[float]] = []
            for lo, hi in bands:
                mid = math.sqrt(lo * hi) if math.isfinite(hi) else 2.0 * lo
                sharp = view.coc_px(mid) * SIGMA_PER_DIAMETER < MIN_SIGMA_PX
                lvl = int(math.log2(max(mid * view.sensor.width_mm / (view.focal_mm * view.width) / m, 1.0)))
                if merged and sharp and merged[-1][2] and merged[-1][3] == lvl and lo not in cuts:
                    merged[-1][1] = hi
                else:
                    merged.append([lo, hi, sharp, lvl])
            for i, (lo, hi, sharp, _) in enumerate(merged):
                lo_draw = NEAR_M if i == 0 else lo / (1.02 if sharp else BAND_OVERLAP)
                mid = math.sqrt(lo * hi) if math.isfinite(hi) else 2.0 * lo
                planes.append(Plane(f"ground{i}", self._ground_tex, ga, sq, "ground", depth_key=mid,
                                    blur_depth_m=mid, clip_x=(lo_draw, hi)))
        planes.sort(key=lambda p: -p.depth_key)
        geo = {"pose": pose, "joints_w": joints, "subject_depth_m": subj_depth, "root_depth_m": root_depth}
        return planes, geo

    # -- drawing ---------------------------------------------------------------------------
    def render(self, view: View, t_s: float, *, truth: bool = True) -> tuple[np.ndarray, dict]:
        planes, geo = self.planes(view, t_s)
        img = np.zeros((view.height, view.width, 3), np.uint8)
        self.last_draw = [draw_plane(img, view, p) for p in planes]
        if truth:
            geo.update(self.truth(view, planes, geo))
        return img, geo

    def truth(self, view: View, planes: list[Plane], geo: dict) -> dict:
        jn = cam.project_world(geo["joints_w"], view.position_m, view.ypr_rad, view.focal_mm, view.sensor)
        vis = np.isfinite(jn).all(axis=1) & (jn >= 0).all(axis=1) & (jn <= 1).all(axis=1)
        # the ground's depth is the same plane whatever the band: one pass over it is enough
        first_ground = True
        lab_planes = []
        for p in planes:
            if p.region == "ground":
                if not first_ground:
                    continue
                first_ground = False
                p = Plane(p.name, p.texture, p.a, p.corners_w, p.region, p.depth_key, p.blur_depth_m,
                          (NEAR_M, math.inf))
            lab_planes.append(p)
        depth, subj = label_pass(view, lab_planes)
        out = region_truth(depth, subj, view.focal_mm, view.f_number, view.focus_m, view.sensor.coc_mm)
        out.update({"joints_norm": jn, "joints_visible": vis, "focal_length_mm": view.focal_mm,
                    "lens_limits": self._lens_limits()})
        return out

    def _lens_limits(self) -> np.ndarray:
        lim = self.scene.limits
        return np.array([lim.focus_distance_min_m, lim.focus_distance_max_m, lim.f_number_min, lim.f_number_max],
                        np.float32)



def make_renderer(scene: Scene, width: int | None = None, height: int | None = None):
    """The scene's renderer: the 3-D world (`world: 3d`) or the 2.5-D compositor."""
    if scene.world == "3d":
        from cinetransfer.services.autopilot_bridge.sim.renderer3d import WorldRenderer

        return WorldRenderer(scene, width, height)
    return SceneRenderer(scene, width, height)


class SimBackend(VehiclePort):
    """Simulated multirotor + gimbal + zoom lens filming a scripted subject in a rendered scene."""

    name = "sim"

    def __init__(self, scene: Scene | str, *, width: int | None = None, height: int | None = None,
                 fps: float | None = None, render: bool = True, truth: bool = True,
                 epoch_ns: int | None = None, seed: int | None = None,
                 max_frame_lag_s: float | None = None, async_render: bool = False):
        self.scene = load_scene(scene) if isinstance(scene, str) else scene
        self.seed = self.scene.seed if seed is None else seed
        self.fps = float(fps or self.scene.camera.fps)
        if not self.fps > 0:
            raise ValueError("fps must be > 0")
        self.renderer = make_renderer(self.scene, width, height)
        self.render_enabled = render
        self.truth_enabled = truth
        self.pictures: tuple[tuple[int, int], ...] | None = None  #: see reset()
        self._init_timeline(epoch_ns)
        #: when set (real-time use), frames more than this behind `now_s` are skipped, not rendered
        self.max_frame_lag_s = max_frame_lag_s
        self.frames_skipped = 0
        self.render_ms: list[float] = []
        self.started = False
        #: render on a worker thread so that `step` (the bridge's control loop) never waits for a
        #: frame; frames come out of `frames()` in order once rendered. OpenCV releases the GIL.
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-render") if async_render else None
        self._pending: collections.deque[tuple[Future, int, float, M.LensState]] = collections.deque()

    def _init_timeline(self, epoch_ns: int | None) -> None:
        """The scene's initial vehicle, subject at script time 0, no frame rendered yet."""
        v = self.scene.vehicle
        self.dyn = VehicleDynamics(limits=self.scene.limits, position=np.array(v.position_m),
                                   camera_ypr=np.array(v.camera_ypr_rad), focal_mm=v.focal_length_mm,
                                   focus_m=v.focus_distance_m, f_number=v.f_number)
        self._epoch_ns = epoch_ns
        self._t0: float | None = None
        self._t = 0.0
        self._next_frame = 0
        self._frames: list[M.Frame] = []
        self._truths: list[M.GroundTruth] = []
        self._seq = 0

    def reset(self, epoch_ns: int, fps: float | None = None,
              pictures: Sequence[tuple[int, int]] | None = None) -> None:
        """Start the simulation over: scene initial state, time 0 stamped `epoch_ns`, frame 0
        next (at `fps` if given). Renders still in flight are discarded. `pictures`: the frame
        index ranges [lo, hi) that get an image (None: every frame); the others before the last
        range's end get only their ground truth (no Frame message), those after it nothing at all:
        a recording that keeps only its takes' frames does not pay for rendering the pre-roll's,
        nor for judging the frames of a simulation left running after its last take."""
        self.flush()
        self._pending.clear()
        if fps is not None:
            if not (math.isfinite(fps) and 0 < fps <= 240):
                raise ValueError(f"fps must be in (0, 240], got {fps!r}")
            self.fps = float(fps)
        self.pictures = None if pictures is None else tuple((int(a), int(b)) for a, b in pictures)
        self._init_timeline(int(epoch_ns))

    def _pictured(self, index: int) -> bool:
        return self.render_enabled and (self.pictures is None or any(a <= index < b for a, b in self.pictures))

    def _past_pictures(self, index: int) -> bool:
        """Whether frame `index` lies past the last pictured range (nobody records it)."""
        return self.pictures is not None and index >= max((b for _, b in self.pictures), default=0)

    def flush(self) -> None:
        """Wait for every frame still being rendered (lockstep: a step ends with its frames)."""
        for fut, *_ in list(self._pending):
            fut.result()
        self._collect()

    # -- VehiclePort -----------------------------------------------------------------------
    def start(self) -> None:
        self.started = True
        if self._epoch_ns is None:
            self._epoch_ns = time.time_ns()

    def apply(self, setpoint: M.Setpoint) -> None:
        if setpoint.mode == "hold" or not setpoint.valid:
            self.hold()
            return
        ln = setpoint.lens
        self.dyn.set_target(position=setpoint.position_m, velocity=setpoint.velocity_mps,
                            acceleration=setpoint.acceleration_mps2, camera_ypr=setpoint.camera_ypr_rad,
                            lens=(ln.focal_length_mm, ln.focus_distance_m, ln.f_number))

    def hold(self) -> None:
        self.dyn.hold()

    def step(self, now_s: float) -> None:
        if self._epoch_ns is None:
            self._epoch_ns = time.time_ns()
        if self._t0 is None:
            self._t0 = float(now_s)
        t_new = float(now_s) - self._t0
        if t_new < self._t:
            return  # clocks never go back
        while True:
            t_f = self._next_frame / self.fps
            if t_f > t_new + 1e-9:
                break
            self.dyn.advance(max(t_f - self._t, 0.0))
            self._t = max(self._t, t_f)
            if self.max_frame_lag_s is not None and t_new - t_f > self.max_frame_lag_s:
                self.frames_skipped += 1
            else:
                self._emit_frame(self._next_frame, t_f)
            self._next_frame += 1
        # A frame due within 1e-9 s after t_new was already taken: never step backwards.
        self.dyn.advance(max(0.0, t_new - self._t))
        self._t = max(self._t, t_new)

    def vehicle_state(self) -> M.VehicleState:
        d = self.dyn
        return M.VehicleState(stamp_ns=self._stamp(self._t), seq=self._seq, valid=True,
                              position_m=d.position.copy(), velocity_mps=d.velocity.copy(),
                              attitude_ypr_rad=d.body_attitude_ypr(), camera_ypr_rad=d.camera_ypr.copy(),
                              lens=self.lens_state(), mode="HOLD" if d.holding else "sim", armed=True,
                              holding=d.holding, backend="sim")

    def subject_state(self) -> M.SubjectState:
        pose = self.renderer.script.pose_at(self._t)
        joints = self.renderer.subject_joints(self._t, self.dyn.position)
        return M.SubjectState(stamp_ns=self._stamp(self._t), seq=self._seq, valid=True,
                              subject_id=self.scene.subject.subject_id, joints_m=joints,
                              velocity_mps=pose.velocity_mps.copy(),
                              heading_rad=subject_heading_rad(self.renderer.subject, self._t, M.COCO17_NAMES, joints))

    def subject_heading_rad(self) -> float:
        """Which way the subject faces now [rad, world yaw: 0 faces +x, pi/2 faces +y]; NaN for the
        2.5-D cut-out, which faces the camera."""
        joints = self.renderer.subject_joints(self._t, self.dyn.position)
        return subject_heading_rad(self.renderer.subject, self._t, M.COCO17_NAMES, joints)

    def frames(self) -> list[M.Frame]:
        self._collect()
        out, self._frames = self._frames, []
        return out

    def truths(self) -> list[M.GroundTruth]:
        self._collect()
        out, self._truths = self._truths, []
        return out

    def health_counters(self) -> dict[str, float | int]:
        """Renderer figures for the bridge's Health: frames skipped, render time, renders in flight."""
        ms = sorted(self.render_ms)
        out: dict[str, float | int] = {"frames_skipped": self.frames_skipped, "renders_pending": len(self._pending)}
        if ms:
            out["render_ms_p50"] = round(ms[len(ms) // 2], 2)
        return out

    def close(self) -> None:
        self.started = False
        if self._pool is not None:
            self._pool.submit(self.renderer.close).result()
            self._pool.shutdown(wait=True, cancel_futures=True)
        else:
            self.renderer.close()

    # -- helpers ---------------------------------------------------------------------------
    @property
    def sim_time_s(self) -> float:
        return self._t

    def _stamp(self, t_s: float) -> int:
        return int(self._epoch_ns or 0) + int(round(t_s * 1e9))

    def lens_state(self) -> M.LensState:
        s = self.renderer.sensor
        return M.LensState(focal_length_mm=self.dyn.focal_mm, focus_distance_m=self.dyn.focus_m,
                           f_number=self.dyn.f_number, sensor_width_mm=s.width_mm, sensor_height_mm=s.height_mm,
                           coc_mm=s.coc_mm)

    def view(self) -> View:
        """The camera now, at the exact time asked for (a frame falls between dynamics sub-steps)."""
        d = self.dyn
        position, ypr, focal = d.pose_now()
        return View(position_m=position, ypr_rad=ypr, focal_mm=focal, focus_m=d.focus_m, f_number=d.f_number,
                    width=self.renderer.width, height=self.renderer.height, sensor=self.renderer.sensor)

    def render_at(self, t_s: float | None = None) -> tuple[np.ndarray, dict]:
        """Render the current state (at sim time `t_s`, default now) without queuing a frame."""
        args = (self.view(), self._t if t_s is None else t_s)
        if self._pool is not None:  # the renderer's GL context lives on the render thread
            return self._pool.submit(self.renderer.render, *args, truth=self.truth_enabled).result()
        return self.renderer.render(*args, truth=self.truth_enabled)

    #: async rendering: a frame due while this many are still being rendered is skipped (counted)
    MAX_PENDING_RENDERS = 2

    def _render_timed(self, view: View, t_s: float) -> tuple[np.ndarray, dict]:
        t0 = time.perf_counter()
        out = self.renderer.render(view, t_s, truth=self.truth_enabled)
        self.render_ms.append((time.perf_counter() - t0) * 1e3)
        del self.render_ms[:-200]
        return out

    def _truth_timed(self, view: View, t_s: float) -> tuple[None, dict]:
        return None, (self.renderer.truth_only(view, t_s) if self.truth_enabled else {})

    def _emit_frame(self, index: int, t_s: float) -> None:
        if self._past_pictures(index):  # after the takes (or before the first reset): neither drawn nor judged
            self._seq += 1
            return
        lens = self.lens_state()
        if not self._pictured(index) and self.render_enabled:  # truth only, in order with the renders
            if self._pool is None:
                self._finish_frame(index, t_s, lens, None, self._truth_timed(self.view(), t_s)[1], self.view())
            else:  # the renderer's (GL) context lives on the render thread
                self._pending.append((self._pool.submit(self._truth_timed, self.view(), t_s), index, t_s, lens))
            return
        if self.render_enabled and self._pool is not None:
            self._collect()
            if len(self._pending) >= self.MAX_PENDING_RENDERS:
                if self.max_frame_lag_s is not None:  # real time: a late frame is skipped (counted)
                    self.frames_skipped += 1
                    return
                self._pending[0][0].result()  # simulation time: never skip, wait for the renderer
                self._collect()
            self._pending.append((self._pool.submit(self._render_timed, self.view(), t_s), index, t_s, lens))
            return
        if self.render_enabled:
            img, geo = self._render_timed(self.view(), t_s)
        else:
            img, geo = np.zeros((0, 0, 3), np.uint8), {}
        self._finish_frame(index, t_s, lens, img, geo, self.view())

    def _collect(self) -> None:
        """Move finished asynchronous renders, in order, to the frame and truth outboxes."""
        while self._pending and self._pending[0][0].done():
            fut, index, t_s, lens = self._pending.popleft()
            img, geo = fut.result()
            self._finish_frame(index, t_s, lens, img, geo, None)

    def _finish_frame(self, index: int, t_s: float, lens: M.LensState, img: np.ndarray | None, geo: dict,
                      view: View | None) -> None:
        """The frame (none when `img` is None: not pictured) and its truth into the outboxes."""
        stamp = self._stamp(t_s)
        if img is not None:
            self._frames.append(M.Frame(stamp_ns=stamp, seq=index, valid=True, source=f"sim:{self.scene.name}",
                                        index=index, fps=self.fps, image=img, lens=lens))
        if self.truth_enabled:
            if not geo:
                geo = self.renderer.truth_only(view or self.view(), t_s)
            self._truths.append(M.GroundTruth(
                stamp_ns=stamp, seq=index, valid=True, frame_index=index,
                joints_norm=np.asarray(geo["joints_norm"], np.float32),
                joints_visible=np.asarray(geo["joints_visible"], bool),
                subject_distance_m=float(geo["subject_depth_m"]), dof_near_m=float(geo["dof_near_m"]),
                dof_far_m=float(geo["dof_far_m"]), region_present=geo["region_present"],
                region_in_focus=geo["region_in_focus"],
                region_focus_fraction=np.asarray(geo["region_focus_fraction"], np.float32),
                focal_length_mm=float(geo["focal_length_mm"]), lens_limits=geo["lens_limits"],
                region_inverse_depth=geo["region_inverse_depth"]))
        self._seq += 1
