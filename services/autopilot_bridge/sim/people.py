"""3-D people for the simulator: baked bodies and motions, skinned in numpy (see docs/simulator.md).

    person = load_person("walker")      # juggler, dancer, runner, walker (PEOPLE)
    motion = load_motion("walk")        # walk, run, dance, idle, juggle, jump (MOTIONS)
    posed = person.pose(motion, t_s)    # a few ms

- `person.faces` (F, 3) int32 triangles, counter-clockwise seen from outside; `person.colors`
  (V, 3) float32 in 0..1 (clothing-like colours by body region, with per-vertex brightness noise:
  flat colours read as soft to the focus map); `person.height_m` standing height;
  `person.vertices_m` the rest mesh.
- `motion.fps`, `.duration_s`, `.loop`, `.speed_mps` (the root's mean horizontal speed along +x,
  0 for in-place motions), `.n_frames`.
- `posed.vertices_m` (V, 3) float32 and `posed.joints_m` (17, 3) float32 (COCO-17 order,
  shared.messages.COCO17_NAMES) in the BODY frame: x forward (the way the person faces), y left,
  z up, feet on z = 0, the root over the origin at t = 0; `posed.root_m` (3,) the root (pelvis)
  position in that frame. A moving motion's root advances along +x by `speed_mps * t` on average
  (a looping one keeps advancing cycle after cycle); an in-place one stays near the origin. Placing
  the person in the world (position, heading) is the scene's job.

Files: `assets/people/<name>.npz` (rest mesh, top-4 skinning weights, the bones' rest heads, the
joint regressor) and `assets/motions/<name>.npz` (per-frame local bone rotations as unit
quaternions w, x, y, z, and the root's offset from its rest position), written by the offline bake
`make_people.py` (anny body model, motions retargeted from real capture; credits in
assets/CREDITS.md). Both use one skeleton (`BONES`): a bone's local rotation is expressed in
world-aligned axes, so it means the same for every body shape.

Skinning (linear blend): a bone's world rotation is G_c = G_parent R_c, its head
p_c = p_parent + G_parent (h_c - h_parent) (h: rest heads), and a vertex
v' = sum_k w_k (G_k (v - h_k) + p_k). A joint is a fixed blend of rest-mesh vertices (anny's COCO
regressor), so it is skinned the same way from per-bone moments baked with the person.
"""
from __future__ import annotations

import dataclasses
import math
from functools import lru_cache
from pathlib import Path

import numpy as np

ASSETS = Path(__file__).resolve().parent / "assets"
PEOPLE_DIR = ASSETS / "people"
MOTIONS_DIR = ASSETS / "motions"

#: The skeleton every person and motion shares, parents before children (parent index in PARENTS).
BONES: tuple[str, ...] = (
    "root", "spine04", "spine02", "neck01", "head",
    "upperleg01.L", "lowerleg01.L", "foot.L", "upperleg01.R", "lowerleg01.R", "foot.R",
    "upperarm01.L", "lowerarm01.L", "wrist.L", "upperarm01.R", "lowerarm01.R", "wrist.R",
)
PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 3, 0, 5, 6, 0, 8, 9, 2, 11, 12, 2, 14, 15)

PEOPLE: tuple[str, ...] = ("juggler", "dancer", "runner", "walker")
MOTIONS: tuple[str, ...] = ("walk", "run", "dance", "idle", "juggle", "jump")

#: The motion that plays each action of the subject library's scripts (sim/subject.py). `vault`
#: plays the jump (a moving motion: an in-place step holds the root where the step is).
ACTION_MOTIONS: dict[str, str] = {"stand": "idle", "juggle": "juggle", "dance": "dance", "twirl": "dance",
                                  "walk": "walk", "run": "run", "vault": "jump"}
#: Each person's own motion: what its clip shows, or the nearest capture.
DEFAULT_MOTIONS: dict[str, str] = {"juggler": "juggle", "dancer": "dance", "runner": "run", "walker": "walk"}


class PeopleError(ValueError):
    """A person or motion name that does not exist, or a baked file that does not fit this module."""


@dataclasses.dataclass(frozen=True)
class Posed:
    vertices_m: np.ndarray  # (V, 3) float32, body frame
    joints_m: np.ndarray    # (17, 3) float32, COCO-17 order, body frame
    root_m: np.ndarray      # (3,) float32, body frame


@dataclasses.dataclass(frozen=True, eq=False)
class Motion:
    name: str
    fps: float
    loop: bool
    speed_mps: float
    rotations: np.ndarray   # (N, B, 4) float32 unit quaternions (w, x, y, z), local, world-aligned axes
    root_offset: np.ndarray  # (N, 3) float32: the root's offset from its rest position [m]
    cycle_m: np.ndarray     # (3,) root displacement over one loop (added per completed loop)
    source: str

    @property
    def n_frames(self) -> int:
        return int(self.rotations.shape[0])

    @property
    def duration_s(self) -> float:
        """A looping motion's period (its last frame is followed by its first), else first to last frame."""
        n = self.n_frames if self.loop else self.n_frames - 1
        return n / self.fps

    def sample(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(B, 4) quaternions and (3,) root offset at time `t_s` (linear between frames)."""
        if not math.isfinite(t_s):
            raise PeopleError(f"motion {self.name!r}: time {t_s!r} is not finite")
        f = t_s * self.fps
        n = self.n_frames
        cycles = 0.0
        if self.loop:
            cycles = math.floor(f / n)
            f -= cycles * n
        else:
            f = min(max(f, 0.0), n - 1.0)
        i0 = min(int(f), n - 1)
        a = f - i0
        i1 = (i0 + 1) % n if self.loop else min(i0 + 1, n - 1)
        q0, q1 = self.rotations[i0], self.rotations[i1]
        # nlerp on the short arc: frames are 1/fps apart, so the angle between them is small
        sign = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -1.0, 1.0).astype(np.float32)
        q = (1 - a) * q0 + a * sign * q1
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
        r1 = self.root_offset[i1] + (self.cycle_m if self.loop and i1 < i0 else 0.0)
        off = (1 - a) * self.root_offset[i0] + a * r1 + cycles * self.cycle_m
        return q.astype(np.float32), off.astype(np.float32)


@dataclasses.dataclass(frozen=True, eq=False)
class Person:
    name: str
    vertices_m: np.ndarray     # (V, 3) float32 rest mesh, body frame, feet on z = 0
    faces: np.ndarray          # (F, 3) int32, counter-clockwise seen from outside
    colors: np.ndarray         # (V, 3) float32 in 0..1
    skin_bones: np.ndarray     # (V, 4) int: bone index per influence
    skin_weights: np.ndarray   # (V, 4) float32, rows sum to 1
    bone_heads_m: np.ndarray   # (B, 3) float32 rest heads
    joint_weights: np.ndarray  # (17, B) float32: sum over the regressor's vertices of r * w_b
    joint_moments: np.ndarray  # (17, B, 3) float32: the same sums of r * w_b * v (rest)
    height_m: float
    root_height_scale: float   # this body's root height over the retargeting body's (scales vertical offsets)
    description: str

    def pose(self, motion: Motion, t_s: float) -> Posed:
        """The body at time `t_s` of `motion` (see the module docstring for the frame)."""
        return self.skin(*self._bones_at(motion, t_s))

    def pose_joints(self, motion: Motion, t_s: float) -> np.ndarray:
        """(17, 3) float32: `pose(motion, t_s).joints_m`, the same numbers, without skinning the mesh
        (the subject's state and the report's floor need the joints only)."""
        g, p = forward_kinematics(self.bone_heads_m, *self._bones_at(motion, t_s))
        return self._joints(g, p)

    def _bones_at(self, motion: Motion, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        quats, offset = motion.sample(t_s)
        return quat_to_matrix(quats), offset * np.array([1.0, 1.0, self.root_height_scale], np.float32)

    def skin(self, rotations: np.ndarray, root_offset: np.ndarray) -> Posed:
        """Skin with (B, 3, 3) local rotations (world-aligned axes) and the root's (3,) offset from rest."""
        g, p = forward_kinematics(self.bone_heads_m, rotations, root_offset)
        v = skin_vertices(self.vertices_m, self.skin_bones, self.skin_weights, bone_matrices(g, p, self.bone_heads_m))
        return Posed(vertices_m=v.astype(np.float32), joints_m=self._joints(g, p), root_m=p[0].astype(np.float32))

    def _joints(self, g: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The COCO-17 joints (17, 3) float32 of the bones' world rotations g and heads p."""
        joints = (np.einsum("bij,kbj->ki", g, self.joint_moments)
                  + self.joint_weights @ (p - np.einsum("bij,bj->bi", g, self.bone_heads_m)))
        return joints.astype(np.float32)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(np.asarray(q, np.float64), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def forward_kinematics(heads: np.ndarray, rotations: np.ndarray, root_offset: np.ndarray,
                       parents: tuple[int, ...] = PARENTS) -> tuple[np.ndarray, np.ndarray]:
    """World rotations G (B, 3, 3) and posed heads p (B, 3) from local rotations in world-aligned axes."""
    heads = np.asarray(heads, np.float64)
    g = np.empty((len(parents), 3, 3))
    p = np.empty((len(parents), 3))
    for c, par in enumerate(parents):
        if par < 0:
            g[c] = rotations[c]
            p[c] = heads[c] + root_offset
        else:
            g[c] = g[par] @ rotations[c]
            p[c] = p[par] + g[par] @ (heads[c] - heads[par])
    return g, p


def bone_matrices(g: np.ndarray, p: np.ndarray, heads: np.ndarray) -> np.ndarray:
    """(B, 3, 4) [G | p - G h]: each bone's map from rest to posed position."""
    t = p - np.einsum("bij,bj->bi", g, np.asarray(heads, np.float64))
    return np.concatenate([g, t[:, :, None]], axis=2)


def skin_vertices(vertices: np.ndarray, bones: np.ndarray, weights: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Linear blend skinning of (V, 3) vertices with (V, K) bone indices/weights and (B, 3, 4) bone maps."""
    # a gather and per-column products: faster here than a dense (V, B) product or a 3x4 einsum
    m = np.asarray(m, np.float32).reshape(len(m), 12)
    blend = np.einsum("vk,vkj->vj", np.asarray(weights, np.float32), m[bones])    # (V, 12): row-major 3x4
    x, y, z = (vertices[:, i:i + 1] for i in range(3))
    return blend[:, 0:12:4] * x + blend[:, 1:12:4] * y + blend[:, 2:12:4] * z + blend[:, 3:12:4]


def _npz(path: Path, kind: str, name: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise PeopleError(f"unknown {kind} {name!r}: expected one of {', '.join(names)} ({path} not found)")
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    bones = tuple(str(b) for b in data.pop("bones"))
    if bones != BONES:
        raise PeopleError(f"{path.name}: baked for another skeleton {bones}; rebake with make_people.py")
    return data


@lru_cache(maxsize=None)
def load_person(name: str) -> Person:
    """The baked person `name` (one of PEOPLE); cached, treat as read-only."""
    return person_from_arrays(name, _npz(PEOPLE_DIR / f"{name}.npz", "person", name, PEOPLE))


def person_from_arrays(name: str, d: dict) -> Person:
    """A Person from the arrays of a baked file (what make_people.py writes)."""
    w = np.asarray(d["skin_weights"], np.float32)
    return _frozen(Person(name=name, vertices_m=np.asarray(d["vertices_m"], np.float32),
                  faces=np.asarray(d["faces"], np.int32), colors=np.asarray(d["colors"], np.float32) / 255.0,
                  skin_bones=np.asarray(d["skin_bones"], np.intp), skin_weights=w / w.sum(axis=1, keepdims=True),
                  bone_heads_m=np.asarray(d["bone_heads_m"], np.float32),
                  joint_weights=np.asarray(d["joint_weights"], np.float32),
                  joint_moments=np.asarray(d["joint_moments"], np.float32), height_m=float(d["height_m"]),
                  root_height_scale=float(d["root_height_scale"]), description=str(d["description"])))


@lru_cache(maxsize=None)
def load_motion(name: str) -> Motion:
    """The baked motion `name` (one of MOTIONS); cached, treat as read-only."""
    d = _npz(MOTIONS_DIR / f"{name}.npz", "motion", name, MOTIONS)
    q = d["rotations"].astype(np.float32)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return _frozen(Motion(name=name, fps=float(d["fps"]), loop=bool(d["loop"]), speed_mps=float(d["speed_mps"]),
                          rotations=q, root_offset=d["root_offset"].astype(np.float32),
                          cycle_m=d["cycle_m"].astype(np.float32), source=str(d["source"])))


def _frozen(obj):
    """Make the arrays of a cached Person/Motion read-only: every caller shares them."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return obj
