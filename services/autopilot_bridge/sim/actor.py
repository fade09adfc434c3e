"""The filmed person in the 3-D world: a skinned body (people.py) placed by the scene's script.

The script (subject.SubjectScript) says where the person is and what they do at each time; here
each action plays a baked motion (`ACTION_MOTIONS`), at a rate that matches a moving step's ground
speed to the motion's own (no sliding feet), and the body turns to its heading (script_heading.py). A
moving motion's mean advance (speed_mps x its time) is taken out, so that the script says where the
person goes; the body's own sway, bob and an in-place motion's wandering stay. Pure functions of
time: the same time gives the same body.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from cinetransfer.services.autopilot_bridge.sim import people
from cinetransfer.services.autopilot_bridge.sim.script_heading import ScriptHeading
from cinetransfer.services.autopilot_bridge.sim.scene import SubjectSpec
from cinetransfer.services.autopilot_bridge.sim.subject import SubjectPose, SubjectScript

#: the baked motions that can play each script action, best first (the first one shipped is used)
ACTION_MOTIONS = {
    "walk": ("walk",),
    "run": ("run", "walk"),
    "juggle": ("juggle", "stand", "idle"),
    "stand": ("stand", "idle", "juggle"),
    "dance": ("dance", "dance_a", "dance_b"),
    "twirl": ("twirl", "dance_b", "spin", "dance", "dance_a"),
    "vault": ("vault", "jump", "run"),
}
#: what plays an action none of whose own motions is shipped
FALLBACK_MOTIONS = ("stand", "idle", "walk")


@lru_cache(maxsize=None)
def motion_for(action: str):
    """The baked motion that plays `action` (a fallback if none of its own is shipped)."""
    for name in ACTION_MOTIONS.get(action, ()) + (action,) + FALLBACK_MOTIONS:
        try:
            return people.load_motion(name)
        except (FileNotFoundError, KeyError, ValueError):
            continue
    raise ValueError(f"no baked motion plays the action {action!r} (tried {ACTION_MOTIONS.get(action, ())})")


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Body:
    """The person at one time, in world metres."""

    vertices_m: np.ndarray  # (V, 3)
    joints_m: np.ndarray  # (17, 3) COCO-17
    heading_rad: float  # the way the body faces (0 = +x)
    pose: SubjectPose


class Actor:
    """A library person following a scene's script in the 3-D world."""

    def __init__(self, spec: SubjectSpec, ground_z_m: float = 0.0):
        self.spec = spec
        self.script = SubjectScript(spec, ground_z_m)
        self.person = people.load_person(spec.clip)
        self.faces = np.asarray(self.person.faces, np.int32)
        self.colours_bgr = np.ascontiguousarray(np.asarray(self.person.colors, np.float32)[:, ::-1])
        self.heading = ScriptHeading(self.script, spec.facing_rad)
        self._last: tuple[float, Body] | None = None

    def heading_at(self, t_s: float) -> float:
        return self.heading.heading_at(t_s)

    def body_at(self, t_s: float) -> Body:
        """The body at t_s (the last one is kept: the bridge asks for the subject's state more often
        than frames are drawn, and skinning costs a few ms)."""
        last = self._last  # one read: the render thread and the control loop both ask
        if last is not None and last[0] == t_s:
            return last[1]
        pose, motion, t_motion, heading = self._placing(t_s)
        posed = self.person.pose(motion, t_motion)
        verts, joints = self._placed(motion, t_motion, heading, pose, posed.vertices_m, posed.joints_m)
        body = Body(vertices_m=verts.astype(np.float32), joints_m=joints, heading_rad=heading, pose=pose)
        self._last = (t_s, body)
        return body

    def joints_at(self, t_s: float) -> np.ndarray:
        """(17, 3) COCO-17 joints [m, world] at t_s: `body_at(t_s).joints_m`, the same numbers,
        without skinning the mesh (the subject's state at every step, the report's floor)."""
        last = self._last
        if last is not None and last[0] == t_s:
            return last[1].joints_m
        pose, motion, t_motion, heading = self._placing(t_s)
        return self._placed(motion, t_motion, heading, pose, None, self.person.pose_joints(motion, t_motion))[1]

    def _placing(self, t_s: float):
        """(the script's pose, the motion playing, the time in it, the heading) at t_s."""
        pose = self.script.pose_at(t_s)
        t, k = self.heading.segment_at(t_s)
        seg_t0 = self.script.segments[k][0]
        motion = motion_for(pose.action)
        speed = float(np.hypot(*pose.velocity_mps[:2]))
        rate = speed / motion.speed_mps if (motion.speed_mps and speed > 0) else 1.0
        return pose, motion, max(t - seg_t0, 0.0) * rate, self.heading_at(t_s)

    @staticmethod
    def _placed(motion, t_motion: float, heading: float, pose: SubjectPose, vertices_m, joints_m):
        """The posed body's vertices (None: not wanted) and joints [m, world] where the script puts it."""
        rot = yaw_matrix(heading)
        # a moving motion's mean advance is the script's to make (the body's own sway and bob stay)
        origin = np.array([(motion.speed_mps or 0.0) * t_motion, 0.0, 0.0])
        verts = None if vertices_m is None else (np.asarray(vertices_m, float) - origin) @ rot.T + pose.position_m
        joints = (np.asarray(joints_m, float) - origin) @ rot.T + pose.position_m
        return verts, joints
