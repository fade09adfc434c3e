"""The filmed subject: scripted motion and 3-D COCO-17 joints consistent with its cut-out.

The subject is drawn as a camera-facing billboard (a real person cut out of a real clip, see
assets/), so the person always turns to face the camera about the vertical axis — like a
performer playing to the camera. Its joints are the joints measured in the cut-out, placed on
that billboard plane, so that projecting them gives exactly where the drawn person's joints are.

Script actions (scene.ScriptStep):
- stand: stay at `at_m` (or where the previous step ended) for `duration_s`;
- walk: follow `path_m` waypoints at `speed_mps` (the clip keeps playing: the legs move);
- sit: stay for `duration_s` in a seated pose — the cut-out's thighs are folded towards the camera
  (frontal view: the torso drops by the thigh length, knees just under the hips).
The script repeats when `loop` is true, else the last state is held.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.sim.scene import ASSETS_DIR, SubjectSpec

L_HIP, R_HIP, L_KNEE, R_KNEE = 11, 12, 13, 14
#: seated: how much of the hip-to-knee band remains (foreshortened thighs).
SIT_THIGH_KEEP = 0.25


@dataclass(frozen=True)
class ClipFrame:
    """One cut-out: premultiplied BGRA texture, its joints and ground anchor in texture pixels."""

    texture: np.ndarray  # (h, w, 4) uint8, colour premultiplied by alpha
    joints_px: np.ndarray  # (17, 2) float (x right, y down)
    anchor_px: tuple[float, float]  # ground contact point (between the feet)


@dataclass(frozen=True)
class Clip:
    name: str
    frames: tuple[ClipFrame, ...]
    sit_frames: tuple[ClipFrame, ...]
    standing_height_px: float


def _premultiply(bgra: np.ndarray) -> np.ndarray:
    a = bgra[..., 3:4].astype(np.uint16)
    out = bgra.copy()
    out[..., :3] = ((bgra[..., :3].astype(np.uint16) * a + 127) // 255).astype(np.uint8)
    return out


def _sit(frame: ClipFrame) -> ClipFrame:
    """Fold the thighs: compress the hip→knee band of the cut-out (rows), move joints with it."""
    tex, j = frame.texture, frame.joints_px
    h, w = tex.shape[:2]
    yh = float((j[L_HIP, 1] + j[R_HIP, 1]) / 2)
    yk = float((j[L_KNEE, 1] + j[R_KNEE, 1]) / 2)
    band = max(yk - yh, 1.0)
    drop = band * (1.0 - SIT_THIGH_KEEP)
    new_h = int(round(h - drop))

    def src_row(y: np.ndarray) -> np.ndarray:  # new row -> old row
        return np.where(y < yh, y, np.where(y < yh + band * SIT_THIGH_KEEP,
                                            yh + (y - yh) / SIT_THIGH_KEEP, y + drop))

    def dst_row(y: np.ndarray) -> np.ndarray:  # old row -> new row
        return np.where(y < yh, y, np.where(y < yk, yh + (y - yh) * SIT_THIGH_KEEP, y - drop))

    # the whole body is shifted down by `drop` so that the feet stay on the ground
    ys = np.arange(new_h, dtype=np.float32)
    map_y = np.repeat(src_row(ys)[:, None], w, axis=1).astype(np.float32)
    map_x = np.repeat(np.arange(w, dtype=np.float32)[None, :], new_h, axis=0)
    out = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    jj = j.copy()
    jj[:, 1] = dst_row(j[:, 1])
    ax, ay = frame.anchor_px
    return ClipFrame(texture=out, joints_px=jj, anchor_px=(ax, float(dst_row(np.array(ay)))))


@lru_cache(maxsize=8)
def load_clip(name: str, assets_dir: str | None = None) -> Clip:
    """Cut-outs `<name>_NN.png` + `<name>.json` from the assets folder (cached)."""
    d = Path(assets_dir) if assets_dir else ASSETS_DIR
    meta = json.loads((d / f"{name}.json").read_text())
    frames = []
    for fr in meta["frames"]:
        img = cv2.imread(str(d / fr["file"]), cv2.IMREAD_UNCHANGED)
        if img is None or img.ndim != 3 or img.shape[2] != 4:
            raise ValueError(f"clip {name}: {fr['file']} is not a BGRA image")
        frames.append(ClipFrame(texture=_premultiply(img), joints_px=np.asarray(fr["joints_px"], float),
                                anchor_px=tuple(fr["anchor_px"])))
    frames_t = tuple(frames)
    return Clip(name=name, frames=frames_t, sit_frames=tuple(_sit(f) for f in frames_t),
                standing_height_px=float(meta["height_px_standing"]))


@dataclass(frozen=True)
class SubjectPose:
    """Where the subject is at one time (ground point between the feet) and what it does."""

    position_m: np.ndarray  # (3,) world, on the ground
    velocity_mps: np.ndarray  # (3,)
    action: str
    step_index: int


class SubjectScript:
    """Piecewise motion from a scene's script; pure function of time."""

    def __init__(self, spec: SubjectSpec, ground_z_m: float = 0.0):
        self.spec = spec
        self.z = ground_z_m
        # pre-compute (t0, t1, kind, data) segments
        segs = []
        t = 0.0
        pos = np.array(spec.start_m, float)
        for i, st in enumerate(spec.script):
            if st.action == "walk":
                pts = [pos.copy()] + [np.array(p, float) for p in st.path_m]
                if st.at_m is not None:
                    pts[0] = np.array(st.at_m, float)
                for a, b in zip(pts[:-1], pts[1:]):
                    dist = float(np.linalg.norm(b - a))
                    if dist < 1e-9:
                        continue
                    dt = dist / st.speed_mps
                    segs.append((t, t + dt, "walk", a, b, i))
                    t += dt
                pos = pts[-1]
                if st.duration_s > 0:  # pause at the end of the walk, still walking in place
                    segs.append((t, t + st.duration_s, "walk_idle", pos.copy(), pos.copy(), i))
                    t += st.duration_s
            else:
                if st.at_m is not None:
                    pos = np.array(st.at_m, float)
                segs.append((t, t + st.duration_s, st.action, pos.copy(), pos.copy(), i))
                t += st.duration_s
        if not segs:
            segs.append((0.0, 1.0, "stand", pos.copy(), pos.copy(), 0))
            t = 1.0
        self.segments = segs
        self.period_s = t

    def pose_at(self, t_s: float) -> SubjectPose:
        if self.spec.loop and self.period_s > 0:
            t = t_s % self.period_s
        else:
            t = min(max(t_s, 0.0), self.period_s)
        seg = self.segments[-1]
        for cand in self.segments:
            if t <= cand[1]:
                seg = cand
                break
        t0, t1, kind, a, b, i = seg
        span = max(t1 - t0, 1e-9)
        s = min(max((t - t0) / span, 0.0), 1.0)
        xy = a + (b - a) * s
        ended = not self.spec.loop and t_s >= self.period_s
        vel = (b - a) / span if kind == "walk" and not ended else np.zeros(2)
        action = "walk" if kind == "walk_idle" else kind
        return SubjectPose(position_m=np.array([xy[0], xy[1], self.z]),
                           velocity_mps=np.array([vel[0], vel[1], 0.0]), action=action, step_index=i)


def clip_frame_index(t_s: float, n: int, fps: float) -> int:
    """Ping-pong playback of an n-frame loop (no jump at the wrap)."""
    if n <= 1:
        return 0
    k = int(math.floor(t_s * fps + 1e-9))
    period = 2 * (n - 1)
    k %= period
    return k if k < n else period - k


class Subject:
    """Script + clip: the billboard to draw and its 3-D joints, for a given camera position."""

    def __init__(self, spec: SubjectSpec, ground_z_m: float = 0.0, assets_dir: str | None = None):
        self.spec = spec
        self.script = SubjectScript(spec, ground_z_m)
        self.clip = load_clip(spec.clip, assets_dir)
        self.m_per_px = spec.height_m / self.clip.standing_height_px

    def frame_at(self, t_s: float, action: str) -> ClipFrame:
        frames = self.clip.sit_frames if action == "sit" else self.clip.frames
        return frames[clip_frame_index(t_s, len(frames), self.spec.clip_fps)]

    @staticmethod
    def facing_axes(root_m: np.ndarray, camera_pos_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(right, up) unit axes of the billboard as seen from the camera."""
        d = np.asarray(camera_pos_m, float)[:2] - root_m[:2]
        n = float(np.hypot(d[0], d[1]))
        phi = math.atan2(d[1], d[0]) if n > 1e-6 else math.pi
        right = np.array([-math.sin(phi), math.cos(phi), 0.0])
        return right, np.array([0.0, 0.0, 1.0])

    def joints_world(self, frame: ClipFrame, root_m: np.ndarray, camera_pos_m: np.ndarray) -> np.ndarray:
        right, up = self.facing_axes(root_m, camera_pos_m)
        ax, ay = frame.anchor_px
        dx = (frame.joints_px[:, 0] - ax) * self.m_per_px
        dz = (ay - frame.joints_px[:, 1]) * self.m_per_px
        return root_m[None, :] + dx[:, None] * right[None, :] + dz[:, None] * up[None, :]
