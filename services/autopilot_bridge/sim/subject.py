"""The filmed subject: a person from the subject library, scripted, with 3-D COCO-17 joints.

The subject is drawn as a camera-facing billboard (a real person cut out of a real clip, see
assets/ and make_subjects.py), so the person always turns to face the camera about the vertical
axis — like a performer playing to the camera. Its joints are the joints measured in the cut-out,
placed on that billboard plane, so that projecting them gives exactly where the drawn person's
joints are.

Library (`subject_names()`): juggler (juggle, stand), dancer (dance, twirl), runner (run, vault),
walker (walk). A script step's action must be one its subject does (scene.py checks it); each
action plays the cut-outs that show it in the footage (`pingpong` or `cycle` loop). Steps:
- in place (stand, juggle, dance, twirl, vault): stay at `at_m` (or where the previous step ended)
  for `duration_s`;
- moving (walk, run): follow `path_m` at `speed_mps`. The gait plays at
  `fps x speed_mps / natural speed` (its stride matches the ground speed: no sliding feet);
  'walk' uses the walking clip, or the running one when the subject only runs.
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

from cinetransfer.services.autopilot_bridge.sim.scene import ASSETS_DIR, MOVING, SubjectSpec


@dataclass(frozen=True)
class ClipFrame:
    """One cut-out: premultiplied BGRA texture, its joints and ground anchor in texture pixels."""

    texture: np.ndarray  # (h, w, 4) uint8, colour premultiplied by alpha
    joints_px: np.ndarray  # (17, 2) float (x right, y down)
    anchor_px: tuple[float, float]  # ground point under the subject (between the feet)
    contact: bool = True  # a foot is on the ground (False mid-air: jumps, running flight)


@dataclass(frozen=True)
class Action:
    """The cut-outs that show one action, how they loop, and (moving actions) the natural speed."""

    name: str
    frames: tuple[int, ...]  # indices into Clip.frames
    loop: str  # 'pingpong' (forth and back, no jump) or 'cycle' (a gait cycle, forward only)
    fps: float
    speed_mps: float | None = None


@dataclass(frozen=True)
class Clip:
    name: str
    frames: tuple[ClipFrame, ...]
    actions: dict
    standing_height_px: float
    person: str = ""
    source: str = ""
    credit: str = ""
    height_m: float = 1.75

    def action(self, name: str) -> Action:
        if name in self.actions:
            return self.actions[name]
        if name == "walk" and "run" in self.actions:
            return self.actions["run"]
        raise ValueError(f"subject {self.name!r} has no action {name!r}; its actions: {sorted(self.actions)}")


def _premultiply(bgra: np.ndarray) -> np.ndarray:
    a = bgra[..., 3:4].astype(np.uint16)
    out = bgra.copy()
    out[..., :3] = ((bgra[..., :3].astype(np.uint16) * a + 127) // 255).astype(np.uint8)
    return out


@lru_cache(maxsize=16)
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
                                anchor_px=tuple(fr["anchor_px"]), contact=bool(fr.get("contact", True))))
    acts = meta.get("actions") or {"stand": {"frames": list(range(len(frames))), "loop": "pingpong", "fps": 12.0}}
    actions = {k: Action(name=k, frames=tuple(int(i) for i in a["frames"]), loop=a.get("loop", "pingpong"),
                         fps=float(a.get("fps", 12.0)), speed_mps=a.get("speed_mps"))
               for k, a in acts.items()}
    return Clip(name=name, frames=tuple(frames), actions=actions,
                standing_height_px=float(meta["height_px_standing"]), person=meta.get("person", name),
                source=meta.get("source", ""), credit=meta.get("credit", ""),
                height_m=float(meta.get("height_m", 1.75)))


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
            if st.action in MOVING:
                pts = [pos.copy()] + [np.array(p, float) for p in st.path_m]
                if st.at_m is not None:
                    pts[0] = np.array(st.at_m, float)
                for a, b in zip(pts[:-1], pts[1:]):
                    dist = float(np.linalg.norm(b - a))
                    if dist < 1e-9:
                        continue
                    dt = dist / st.speed_mps
                    segs.append((t, t + dt, st.action, a, b, i))
                    t += dt
                pos = pts[-1]
                if st.duration_s > 0:  # pause at the end of the walk, still walking in place
                    segs.append((t, t + st.duration_s, st.action + "_idle", pos.copy(), pos.copy(), i))
                    t += st.duration_s
            else:
                if st.at_m is not None:
                    pos = np.array(st.at_m, float)
                segs.append((t, t + st.duration_s, st.action, pos.copy(), pos.copy(), i))
                t += st.duration_s
        if not segs:
            segs.append((0.0, 1.0, spec.script[0].action if spec.script else "stand", pos.copy(), pos.copy(), 0))
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
        vel = (b - a) / span if kind in MOVING and not ended else np.zeros(2)
        action = kind.removesuffix("_idle")
        return SubjectPose(position_m=np.array([xy[0], xy[1], self.z]),
                           velocity_mps=np.array([vel[0], vel[1], 0.0]), action=action, step_index=i)


def clip_frame_index(t_s: float, n: int, fps: float, loop: str = "pingpong") -> int:
    """Ping-pong (no jump at the wrap) or cyclic playback of an n-frame loop."""
    if n <= 1:
        return 0
    k = int(math.floor(t_s * fps + 1e-9))
    if loop == "cycle":
        return k % n
    period = 2 * (n - 1)
    k %= period
    return k if k < n else period - k


class Subject:
    """Script + clip: the billboard to draw and its 3-D joints, for a given camera position."""

    #: the cut-out turns to face the camera, so it has no heading of its own: whatever side the
    #: camera films from it shows the one view of its footage (SubjectState.heading_rad is NaN)
    faces_camera: bool = True

    def __init__(self, spec: SubjectSpec, ground_z_m: float = 0.0, assets_dir: str | None = None):
        self.spec = spec
        self.script = SubjectScript(spec, ground_z_m)
        self.clip = load_clip(spec.clip, assets_dir)
        self.m_per_px = spec.height_m / self.clip.standing_height_px

    def playback(self, action: str, speed_mps: float = 0.0) -> tuple[Action, float]:
        """(the clip action, its playback rate [cut-outs/s]) for a script action at a speed."""
        act = self.clip.action(action)
        fps = self.spec.clip_fps or act.fps
        if act.speed_mps and speed_mps > 0:  # the stride matches the ground speed
            fps *= speed_mps / float(act.speed_mps)
        return act, fps

    def frame_at(self, t_s: float, action: str, speed_mps: float = 0.0) -> ClipFrame:
        act, fps = self.playback(action, speed_mps)
        k = clip_frame_index(t_s, len(act.frames), fps, act.loop)
        return self.clip.frames[act.frames[k]]

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
