"""Bake the simulator's 3-D people and motions into assets/people and assets/motions (offline).

Never run by setup or CI: the shipped files are its output. To rerun it (about 10 minutes on two
cores, after anny's first model build, which writes ~790 MB to ~/.cache/anny and takes 4-9 minutes):

    python -m venv /tmp/bake && /tmp/bake/bin/pip install -e '.[bake]'
    # the juggle motion's capture: MediaPipe's world landmarks of the juggler's own clip, measured
    # with the project's own venv (setup.sh installs MediaPipe there)
    .venv/bin/python -m cinetransfer.services.autopilot_bridge.sim.make_people landmarks \
        --video ../shared/data/sam2_juggle_1280x720.mp4 --out /tmp/juggle_mediapipe.npz
    /tmp/bake/bin/python -m cinetransfer.services.autopilot_bridge.sim.make_people bake \
        --juggle-landmarks /tmp/juggle_mediapipe.npz

Bodies: anny (NAVER, Apache-2.0; MakeHuman/MPFB2 mesh, CC0), one phenotype per person (PEOPLE
below), its height calibrated to the person's; the mesh decimated once (hidden eye/mouth cavities
dropped, quadric decimation, vertices snapped back to the base mesh so one topology fits every
body), skinning weights collapsed onto the shared skeleton (people.BONES) and cut to the top 4.
Joints: anny's COCO regressor (a fixed blend of base-mesh vertices), baked as per-bone moments.
Colours: clothing by body region (anny's part segmentation and the dominant bone), with 30 %
per-vertex brightness noise.

Motions: real capture retargeted onto the shared skeleton. DeepMimic's humanoid clips shipped in
pybullet_data (zlib licence): their joint rotations are run through the humanoid's own kinematics
(humanoid.urdf offsets, scale 0.25) to 3-D points. The juggle: MediaPipe's world landmarks of the
juggler's clip. Retargeting fits per-frame local bone rotations with Adam (400 iterations) so that
the body's segment directions (hips, spine, shoulders, thighs, shins, feet, upper arms, forearms,
head) match the capture's, with a temporal smoothness term and a small pull towards the rest
pose; the root follows the capture's pelvis scaled by leg length, and the feet are put on the
ground. Deterministic (fixed seeds, CPU).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cinetransfer.services.autopilot_bridge.sim import people as P
from cinetransfer.shared.messages import COCO17_NAMES

log = logging.getLogger("make_people")

FPS = 30.0
TARGET_TRIANGLES = 18000
NOISE = 0.30                   # per-vertex brightness noise (relative)
HIDDEN_PARTS = ("eye_back.L", "eye_back.R", "eye_cavity.L", "eye_cavity.R", "mouth_cavity", "tongue")
# anny's frame (z up, facing -y, left = +x) -> the body frame (x forward, y left, z up)
TO_BODY = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Outfit:
    skin: tuple[float, float, float]
    hair: tuple[float, float, float]
    shirt: tuple[float, float, float]
    trousers: tuple[float, float, float]
    shoes: tuple[float, float, float]
    sleeve: float = 0.5          # how far down the arm the shirt goes: 0 none, 0.5 short sleeve, 2 to the wrist
    trouser_to: float = 2.0      # how far down the leg the trousers go: 0.5 mid-thigh (a skirt), 2 to the ankle
    bare_feet: bool = False


@dataclass(frozen=True)
class PersonSpec:
    height_m: float
    phenotype: dict
    outfit: Outfit
    description: str


# Colours picked from the people in the clips (assets/CREDITS.md) - sRGB in 0..1.
PEOPLE: dict[str, PersonSpec] = {
    "juggler": PersonSpec(1.78, dict(gender=1.0, age=0.66, muscle=0.6, weight=0.42, proportions=0.8),
                          Outfit(skin=(0.36, 0.24, 0.17), hair=(0.06, 0.05, 0.05), shirt=(0.38, 0.44, 0.54),
                                 trousers=(0.10, 0.12, 0.22), shoes=(0.88, 0.88, 0.86), sleeve=0.55),
                          "young man, slate-blue short-sleeved shirt, navy trousers, white trainers"),
    "dancer": PersonSpec(1.65, dict(gender=0.0, age=0.64, muscle=0.5, weight=0.35, proportions=0.9),
                         Outfit(skin=(0.86, 0.68, 0.58), hair=(0.72, 0.58, 0.36), shirt=(0.12, 0.22, 0.42),
                                trousers=(0.42, 0.46, 0.54), shoes=(0.86, 0.72, 0.62), sleeve=0.0, trouser_to=0.55,
                                bare_feet=True),
                         "young woman, navy sleeveless top, grey-blue fringed skirt, bare legs and feet"),
    "runner": PersonSpec(1.80, dict(gender=1.0, age=0.7, muscle=0.85, weight=0.55, proportions=0.7),
                         Outfit(skin=(0.80, 0.60, 0.48), hair=(0.45, 0.35, 0.25), shirt=(0.55, 0.62, 0.78),
                                trousers=(0.08, 0.08, 0.09), shoes=(0.15, 0.15, 0.16), sleeve=0.5),
                         "muscular man, light blue T-shirt, black baggy trousers, dark trainers"),
    "walker": PersonSpec(1.75, dict(gender=0.9, age=0.78, muscle=0.45, weight=0.68, proportions=0.5),
                         Outfit(skin=(0.78, 0.58, 0.46), hair=(0.22, 0.14, 0.10), shirt=(0.27, 0.19, 0.15),
                                trousers=(0.12, 0.14, 0.22), shoes=(0.10, 0.09, 0.08), sleeve=2.0),
                         "man, dark brown jacket, dark jeans, dark shoes"),
}
# the body the motions are retargeted on (a neutral adult); each person scales vertical root motion
REFERENCE = PersonSpec(1.72, dict(gender=0.5, age=0.68, muscle=0.5, weight=0.5, proportions=0.5),
                       PEOPLE["walker"].outfit, "reference")


# ----------------------------------------------------------------------------------------------
# anny bodies


class Anny:
    """anny's model, its skeleton collapsed onto people.BONES."""

    def __init__(self) -> None:
        import anny
        import torch
        from anny.face_segmentation import get_face_segmentation_mask

        self.torch = torch
        self.model = anny.Anny(skinning_method="lbs")
        m = self.model
        self.faces = m.faces.numpy().astype(np.int64)
        self.part = np.full(len(self.faces), "", dtype=object)
        for label in ("head", "hand.L", "hand.R", "foot.L", "foot.R", "eye_front.L", "eye_front.R", *HIDDEN_PARTS):
            self.part[get_face_segmentation_mask(m, [label]).numpy()] = label
        self.to_driven = self._collapse_map(m.bone_labels, m.bone_parents)
        w = m.vertex_bone_weights.numpy()
        idx = m.vertex_bone_indices.numpy()
        self.weights = np.zeros((len(w), len(P.BONES)))
        np.add.at(self.weights, (np.arange(len(w))[:, None], self.to_driven[idx]), w)
        self.weights /= self.weights.sum(axis=1, keepdims=True)
        reg = anny.KeypointsRegressor.coco(m)
        self.regressor = {label: reg.regression_weights[k].numpy() for k, label in enumerate(reg.labels)}

    @staticmethod
    def _collapse_map(labels: list[str], parents: list[int]) -> np.ndarray:
        """Each anny bone's nearest ancestor (itself included) in people.BONES."""
        out = np.zeros(len(labels), np.int64)
        for i in range(len(labels)):
            j = i
            while labels[j] not in P.BONES:
                j = parents[j]
            out[i] = P.BONES.index(labels[j])
        return out

    def rest(self, phenotype: dict) -> tuple[np.ndarray, np.ndarray]:
        """Rest vertices (V, 3) and driven-bone heads (B, 3) in the body frame (not yet grounded)."""
        with self.torch.no_grad():
            out = self.model(phenotype_kwargs={k: float(v) for k, v in phenotype.items()})
        v = out["rest_vertices"][0].numpy() @ TO_BODY.T
        heads = out["rest_bone_heads"][0].numpy() @ TO_BODY.T
        labels = self.model.bone_labels
        return v, np.array([heads[labels.index(b)] for b in P.BONES])

    def body(self, spec: PersonSpec) -> tuple[np.ndarray, np.ndarray, dict]:
        """Rest vertices and heads grounded (feet on z = 0, root over the origin), height calibrated."""
        lo, hi = 0.0, 1.0
        for _ in range(18):  # bisection on anny's monotonic `height` phenotype
            mid = (lo + hi) / 2
            v, _ = self.rest({**spec.phenotype, "height": mid})
            lo, hi = (mid, hi) if np.ptp(v[:, 2]) < spec.height_m else (lo, mid)
        phen = {**spec.phenotype, "height": (lo + hi) / 2}
        v, heads = self.rest(phen)
        shift = np.array([-heads[0, 0], -heads[0, 1], -v[:, 2].min()])
        return v + shift, heads + shift, phen


# ----------------------------------------------------------------------------------------------
# mesh: one decimated topology over base-mesh vertices


def decimate(anny: Anny, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(kept base-mesh vertex indices (V',), faces (F, 3) into them), from the body `v`."""
    import fast_simplification
    import torch

    visible = np.array([p not in HIDDEN_PARTS for p in anny.part])
    faces = anny.faces[visible]
    used = np.unique(faces)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    pts, tris = fast_simplification.simplify(v[used].astype(np.float32), remap[faces].astype(np.int64),
                                             target_count=TARGET_TRIANGLES)
    # snap the decimated vertices back onto base-mesh vertices, so that every body shape shares them
    d = torch.cdist(torch.as_tensor(pts, dtype=torch.float64), torch.as_tensor(v[used], dtype=torch.float64))
    nearest = used[d.argmin(dim=1).numpy()]
    return _compact(nearest[tris])


def _compact(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    f = f[np.sort(first)]
    keep = np.unique(f)
    remap = np.full(f.max() + 1, -1)
    remap[keep] = np.arange(len(keep))
    return keep, remap[f].astype(np.int32)


# ----------------------------------------------------------------------------------------------
# people: colours, joints, files


def top4(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    bones = np.argsort(-weights, axis=1, kind="stable")[:, :4]
    w = np.take_along_axis(weights, bones, axis=1)
    return bones, w / w.sum(axis=1, keepdims=True)


def regressed(anny: Anny, v: np.ndarray, labels: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(K, B) weights and (K, B, 3) moments of anny's regressor points `labels` on rest vertices `v`."""
    r = np.stack([anny.regressor[label] for label in labels])                # (K, V)
    return r @ anny.weights, np.einsum("kv,vb,vi->kbi", r, anny.weights, v)


def vertex_parts(anny: Anny, n: int) -> np.ndarray:
    part = np.full(n, "", dtype=object)
    for label in ("head", "foot.L", "foot.R", "hand.L", "hand.R", "eye_front.L", "eye_front.R"):  # later wins
        part[np.unique(anny.faces[anny.part == label])] = label
    return part


def _along(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Position of each vertex along the segment a -> b, in segment lengths."""
    d = b - a
    return (v - a) @ d / float(d @ d)


def regions(anny: Anny, v: np.ndarray, heads: np.ndarray, outfit: Outfit, height: float) -> np.ndarray:
    """Clothing region per base-mesh vertex: skin, hair, shirt, trousers, shoes or eyes."""
    b = {name: i for i, name in enumerate(P.BONES)}
    h = {name: heads[i] for name, i in b.items()}
    part = vertex_parts(anny, len(v))
    dom = np.argmax(anny.weights, axis=1)
    w, jm = regressed(anny, v, ["left_eye", "left_ear", "right_ear"])
    eye, ear_l, ear_r = (jm.sum(1) / w.sum(1, keepdims=True))
    ear = (ear_l + ear_r) / 2
    out = np.full(len(v), "shirt", dtype=object)
    waist = 0.585 * height
    torso = np.isin(dom, [b["root"], b["spine04"], b["spine02"]])
    out[torso & (v[:, 2] < waist)] = "trousers"
    out[torso & (v[:, 2] > h["upperarm01.L"][2] + 0.05)] = "skin"
    out[dom == b["neck01"]] = "skin"
    for s in "LR":
        up = np.isin(dom, [b[f"upperarm01.{s}"], b[f"lowerarm01.{s}"], b[f"wrist.{s}"]])
        frac = np.where(dom == b[f"upperarm01.{s}"], _along(v, h[f"upperarm01.{s}"], h[f"lowerarm01.{s}"]),
                        1 + _along(v, h[f"lowerarm01.{s}"], h[f"wrist.{s}"]))
        out[up & (frac >= outfit.sleeve)] = "skin"
        leg = np.isin(dom, [b[f"upperleg01.{s}"], b[f"lowerleg01.{s}"], b[f"foot.{s}"]])
        frac = np.where(dom == b[f"upperleg01.{s}"], _along(v, h[f"upperleg01.{s}"], h[f"lowerleg01.{s}"]),
                        1 + _along(v, h[f"lowerleg01.{s}"], h[f"foot.{s}"]))
        out[leg] = np.where(frac[leg] < outfit.trouser_to, "trousers", "skin")
    head = part == "head"
    out[head] = "skin"
    hair = head & ((v[:, 2] > eye[2] + 0.045) | ((v[:, 0] < ear[0] - 0.01) & (v[:, 2] > ear[2] - 0.06)))
    out[hair] = "hair"
    out[np.isin(part, ["hand.L", "hand.R"])] = "skin"
    out[np.isin(part, ["foot.L", "foot.R"])] = "shoes"
    out[np.isin(part, ["eye_front.L", "eye_front.R"])] = "eyes"
    return out


def colours(region: np.ndarray, outfit: Outfit, seed: int) -> np.ndarray:
    table = {"skin": outfit.skin, "hair": outfit.hair, "shirt": outfit.shirt, "trousers": outfit.trousers,
             "shoes": outfit.shoes, "eyes": (0.12, 0.09, 0.08)}
    c = np.array([table[r] for r in region], np.float64)
    # flat colours read as soft to the focus map: every vertex gets its own brightness
    c *= np.random.default_rng(seed).uniform(1 - NOISE, 1 + NOISE, (len(c), 1))
    return np.clip(np.round(c * 255), 0, 255).astype(np.uint8)


def person_arrays(anny: Anny, name: str, spec: PersonSpec, keep: np.ndarray, faces: np.ndarray,
                  ref_root_z: float) -> dict[str, np.ndarray]:
    """Everything people.load_person reads, for the body `spec` on the shared topology (keep, faces)."""
    v, heads, phen = anny.body(spec)
    bones, w = top4(anny.weights[keep])
    jw, jm = regressed(anny, v, list(COCO17_NAMES))
    height = float(v[:, 2].max())
    region = regions(anny, v, heads, spec.outfit, height)
    return dict(bones=np.array(P.BONES), vertices_m=v[keep].astype(np.float32), faces=faces.astype(np.int32),
                colors=colours(region[keep], spec.outfit, seed=sum(map(ord, name))),
                skin_bones=bones.astype(np.uint8), skin_weights=w.astype(np.float16),
                bone_heads_m=heads.astype(np.float32), joint_weights=jw.astype(np.float32),
                joint_moments=jm.astype(np.float32), height_m=np.float64(height),
                root_height_scale=np.float64(heads[0, 2] / ref_root_z), description=np.str_(spec.description),
                phenotype=np.str_(json.dumps(phen, sort_keys=True)))


def save(path: Path, arrays: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)
    log.info("%s: %.0f kB", path.name, path.stat().st_size / 1e3)


# ----------------------------------------------------------------------------------------------
# capture: 3-D points per frame in the body frame (x forward, y left, z up)

# DeepMimic's humanoid (pybullet_data humanoid/humanoid.urdf, loaded at globalScaling 0.25): y up,
# facing +x, right = +z. Frame layout: duration, root position (3), root, chest, neck rotations
# (w, x, y, z), then per side (right first) hip (4), knee angle, ankle (4), shoulder (4), elbow angle.
_URDF_SCALE = 0.25
_FROM_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])   # (x, y, z) -> (x, -z, y)


def _rot_z(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _at(rot: np.ndarray, origin: np.ndarray, offset) -> np.ndarray:
    return origin + np.einsum("nij,j->ni", rot, np.asarray(offset, np.float64))


def deepmimic_points(path: Path) -> tuple[dict[str, np.ndarray], float]:
    """3-D points of a DeepMimic clip (body frame, metres) and its frame rate."""
    data = json.loads(path.read_text())
    f = np.array(data["Frames"], np.float64)
    q = P.quat_to_matrix
    s = _URDF_SCALE
    root_r = q(f[:, 4:8])
    pts = {"pelvis": f[:, 1:4]}
    chest = _at(root_r, f[:, 1:4], (0, 0.944604 * s, 0))
    chest_r = root_r @ q(f[:, 8:12])
    neck = _at(chest_r, chest, (0, 0.895576 * s, 0))
    neck_r = chest_r @ q(f[:, 12:16])
    head = _at(neck_r, neck, (0, 0.7 * s, 0))
    pts.update(nose=_at(neck_r, head, (0.1, -0.01, 0)), ear_r=_at(neck_r, head, (0, 0, 0.075)),
               ear_l=_at(neck_r, head, (0, 0, -0.075)))
    for side, k, z in (("r", 16, 1.0), ("l", 30, -1.0)):
        hip = _at(root_r, f[:, 1:4], (0, 0, z * 0.339548 * s))
        hip_r = root_r @ q(f[:, k:k + 4])
        knee = _at(hip_r, hip, (0, -1.686184 * s, 0))
        knee_r = hip_r @ _rot_z(f[:, k + 4])
        ankle = _at(knee_r, knee, (0, -1.63948 * s, 0))
        ankle_r = knee_r @ q(f[:, k + 5:k + 9])
        shoulder = _at(chest_r, chest, (-0.0962 * s, 0.974 * s, z * 0.73244 * s))
        shoulder_r = chest_r @ q(f[:, k + 9:k + 13])
        elbow = _at(shoulder_r, shoulder, (0, -1.099152 * s, 0))
        elbow_r = shoulder_r @ _rot_z(f[:, k + 13])
        pts.update({f"hip_{side}": hip, f"knee_{side}": knee, f"ankle_{side}": ankle,
                    f"heel_{side}": _at(ankle_r, ankle, (-0.0435, -0.05, 0)),
                    f"toe_{side}": _at(ankle_r, ankle, (0.1335, -0.05, 0)),
                    f"shoulder_{side}": shoulder, f"elbow_{side}": elbow,
                    f"wrist_{side}": _at(elbow_r, elbow, (0, -1.035788 * s, 0))})
    return {k: v @ _FROM_Y_UP.T for k, v in pts.items()}, 1.0 / float(f[0, 0])


_BLAZE = dict(nose=0, ear_l=7, ear_r=8, shoulder_l=11, shoulder_r=12, elbow_l=13, elbow_r=14, wrist_l=15, wrist_r=16,
              hip_l=23, hip_r=24, knee_l=25, knee_r=26, ankle_l=27, ankle_r=28, heel_l=29, heel_r=30, toe_l=31,
              toe_r=32)


def mediapipe_points(path: Path) -> tuple[dict[str, np.ndarray], float]:
    """3-D points from MediaPipe world landmarks (x right, y down, z away from the camera, hips at 0)."""
    with np.load(path) as z:
        world, fps = z["world"][:, :, :3].astype(np.float64), float(z["fps"])
    ok = np.isfinite(world[:, 0, 0])
    if ok.sum() < 10:
        raise SystemExit(f"{path}: MediaPipe found the person in only {ok.sum()} frames")
    t = np.arange(len(world))
    world = np.stack([np.stack([np.interp(t, t[ok], world[ok, j, i]) for i in range(3)], -1)
                      for j in range(world.shape[1])], 1)
    zup = world @ np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]).T           # (x, z, -y): right-handed, z up
    pts = {k: zup[:, j] for k, j in _BLAZE.items()}
    pts["pelvis"] = (pts["hip_l"] + pts["hip_r"]) / 2
    return pts, fps


def derived(pts: dict) -> dict:
    """Add the points both sides define the same way: neck (shoulders' mid-point), ear mid-point."""
    return {**pts, "neck": (pts["shoulder_l"] + pts["shoulder_r"]) / 2, "ear_mid": (pts["ear_l"] + pts["ear_r"]) / 2}


def face_forward(pts: dict, yaw: float | None = None) -> dict:
    """Rotate about z so that `yaw` (default: the mean facing) points along +x, pelvis xy at 0 at frame 0."""
    if yaw is None:
        left = (pts["hip_l"] - pts["hip_r"] + pts["shoulder_l"] - pts["shoulder_r"]).mean(0)
        yaw = math.atan2(-left[0], left[1])              # forward = left x up
    c, s = math.cos(-yaw), math.sin(-yaw)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    origin = np.array([pts["pelvis"][0, 0], pts["pelvis"][0, 1], 0.0])
    out = {k: (v - origin) @ rz.T for k, v in pts.items()}
    d = derived(out)
    if np.mean(d["nose"][:, 0] - d["ear_mid"][:, 0]) <= 0:
        raise SystemExit("capture: the nose is not in front of the ears after facing +x (mirrored landmarks?)")
    return out


def resample(pts: dict, fps: float, new_fps: float, n_out: int | None = None) -> dict:
    n = len(next(iter(pts.values())))
    t = np.arange(n) / fps
    n_out = n_out or int(math.floor(t[-1] * new_fps + 1e-9)) + 1
    tn = np.arange(n_out) / new_fps
    return {k: np.stack([np.interp(tn, t, v[:, i]) for i in range(3)], -1) for k, v in pts.items()}


# ----------------------------------------------------------------------------------------------
# retargeting: per-frame local rotations of people.BONES fitted to the capture's directions

# the body's points: ("bone", name) = a bone's head, ("reg", label) = anny's regressor point
POINTS: dict[str, list[tuple[str, str, float]]] = {
    "pelvis": [("bone", "upperleg01.L", 0.5), ("bone", "upperleg01.R", 0.5)],
    "neck": [("bone", "upperarm01.L", 0.5), ("bone", "upperarm01.R", 0.5)],
    "nose": [("reg", "nose", 1.0)],
    "ear_mid": [("reg", "left_ear", 0.5), ("reg", "right_ear", 0.5)],
    **{f"{k}_{s}": [("bone", f"{b}.{s.upper()}", 1.0)] for s in "lr" for k, b in (
        ("hip", "upperleg01"), ("knee", "lowerleg01"), ("ankle", "foot"), ("shoulder", "upperarm01"),
        ("elbow", "lowerarm01"), ("wrist", "wrist"))},
    **{f"ear_{s}": [("reg", f"{side}_ear", 1.0)] for s, side in (("l", "left"), ("r", "right"))},
    **{f"heel_{s}": [("reg", f"{side}_heel", 1.0)] for s, side in (("l", "left"), ("r", "right"))},
    **{f"toe_{s}": [("reg", f"{side}_big_toe", 0.5), ("reg", f"{side}_small_toe", 0.5)]
       for s, side in (("l", "left"), ("r", "right"))},
}
PAIRS: list[tuple[str, str, float]] = [
    ("hip_r", "hip_l", 2.0), ("pelvis", "neck", 2.0), ("shoulder_r", "shoulder_l", 2.0),
    ("neck", "ear_mid", 1.0), ("ear_r", "ear_l", 1.0), ("ear_mid", "nose", 1.0),
    *[(f"{a}_{s}", f"{b}_{s}", w) for s in "lr" for a, b, w in (
        ("hip", "knee", 1.0), ("knee", "ankle", 1.0), ("heel", "toe", 1.0), ("ankle", "toe", 0.5),
        ("shoulder", "elbow", 1.0), ("elbow", "wrist", 1.0))],
]
SMOOTH = 0.05         # temporal smoothness (squared quaternion change per frame) against the directions' 1 - cos
REST_PULL = 0.01      # pull of every non-root bone towards its rest rotation (fixes what directions leave free)
HAND_PULL = 0.5       # the wrists follow the forearms
ITERATIONS = 400


def point_regressor(anny: Anny, v: np.ndarray, heads: np.ndarray) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, (K, B) weights and (K, B, 3) moments of POINTS on the body (v, heads)."""
    names = sorted(POINTS)
    weights = np.zeros((len(names), len(P.BONES)))
    moments = np.zeros((len(names), len(P.BONES), 3))
    for k, name in enumerate(names):
        for kind, key, w in POINTS[name]:
            if kind == "bone":
                b = P.BONES.index(key)
                weights[k, b] += w
                moments[k, b] += w * heads[b]
            else:
                jw, jm = regressed(anny, v, [key])
                weights[k] += w * jw[0]
                moments[k] += w * jm[0]
    return names, weights, moments


def frame_of(pts: dict) -> np.ndarray:
    """(N, 3, 3) body frames (columns forward, left, up) from the hips and the spine."""
    left = pts["hip_l"] - pts["hip_r"]
    left /= np.linalg.norm(left, axis=-1, keepdims=True)
    up = pts["neck"] - pts["pelvis"]
    up -= np.sum(up * left, -1, keepdims=True) * left
    up /= np.linalg.norm(up, axis=-1, keepdims=True)
    return np.stack([np.cross(left, up), left, up], -1)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations -> (N, 4) unit quaternions (w, x, y, z), sign-continuous along N."""
    out = np.empty((len(m), 4))
    for i, r in enumerate(m):
        k = np.array([[r[0, 0] - r[1, 1] - r[2, 2], r[1, 0] + r[0, 1], r[2, 0] + r[0, 2], r[2, 1] - r[1, 2]],
                      [r[1, 0] + r[0, 1], r[1, 1] - r[0, 0] - r[2, 2], r[2, 1] + r[1, 2], r[0, 2] - r[2, 0]],
                      [r[2, 0] + r[0, 2], r[2, 1] + r[1, 2], r[2, 2] - r[0, 0] - r[1, 1], r[1, 0] - r[0, 1]],
                      [r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1], r[0, 0] + r[1, 1] + r[2, 2]]]) / 3
        vals, vecs = np.linalg.eigh(k)
        x, y, z, w = vecs[:, -1]
        out[i] = (w, x, y, z)
        if i and out[i] @ out[i - 1] < 0:
            out[i] = -out[i]
    return out


def _torch_quat_to_matrix(q):
    import torch

    w, x, y, z = q.unbind(-1)
    return torch.stack([
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        torch.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        torch.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def _torch_points(rot, heads, weights, moments):
    """(N, K, 3) body points for (N, B, 3, 3) local rotations (root offset 0); mirrors people.Person.skin."""
    import torch

    g, p = [], []
    for c, par in enumerate(P.PARENTS):
        if par < 0:
            g.append(rot[:, c])
            p.append(heads[c].expand(len(rot), 3))
        else:
            g.append(g[par] @ rot[:, c])
            p.append(p[par] + g[par] @ (heads[c] - heads[par]))
    g, p = torch.stack(g, 1), torch.stack(p, 1)
    t = p - torch.einsum("nbij,bj->nbi", g, heads)
    return torch.einsum("nbij,kbj->nki", g, moments) + torch.einsum("kb,nbi->nki", weights, t)


def _direction_loss(x, src_dirs, idx):
    import torch

    d = x[:, idx[:, 1]] - x[:, idx[:, 0]]
    d = d / torch.linalg.norm(d, dim=-1, keepdim=True)
    return torch.sum(d * src_dirs, -1)                                       # (N, pairs) cosines


def retarget(pts: dict, names: list[str], weights: np.ndarray, moments: np.ndarray, heads: np.ndarray,
             rest_pts: dict, loop: bool) -> tuple[np.ndarray, float]:
    """(N, B, 4) local rotations fitting the capture `pts`, and the mean direction error [deg]."""
    import torch

    torch.manual_seed(0)
    dt = torch.float64
    idx = torch.tensor([[names.index(a), names.index(b)] for a, b, _ in PAIRS])
    pw = torch.tensor([w for *_, w in PAIRS], dtype=dt)
    src = torch.tensor(np.stack([pts[n] for n in names], 1), dtype=dt)
    src_dirs = src[:, idx[:, 1]] - src[:, idx[:, 0]]
    src_dirs = src_dirs / torch.linalg.norm(src_dirs, dim=-1, keepdim=True)
    n = len(src)
    q0 = np.zeros((n, len(P.BONES), 4))
    q0[..., 0] = 1.0
    q0[:, 0] = matrix_to_quat(frame_of(pts) @ frame_of({k: v[None] for k, v in rest_pts.items()})[0].T)
    q = torch.tensor(q0, dtype=dt, requires_grad=True)
    pull = torch.full((len(P.BONES),), REST_PULL, dtype=dt)
    pull[0] = 0.0
    pull[[P.BONES.index("wrist.L"), P.BONES.index("wrist.R")]] = HAND_PULL
    h, w, m = (torch.tensor(a, dtype=dt) for a in (heads, weights, moments))
    opt = torch.optim.Adam([q], lr=0.02)
    for _ in range(ITERATIONS):
        opt.zero_grad()
        qn = q / torch.linalg.norm(q, dim=-1, keepdim=True)
        cos = _direction_loss(_torch_points(_torch_quat_to_matrix(qn), h, w, m), src_dirs, idx)
        step = qn[1:] - qn[:-1]
        if loop:
            step = torch.cat([step, (qn[:1] - qn[-1:])], 0)
        loss = (torch.sum((1 - cos).mean(0) * pw) + SMOOTH * torch.sum(step ** 2, -1).mean(0).sum()
                + torch.sum(pull * torch.sum(qn[..., 1:] ** 2, -1).mean(0)))
        loss.backward()
        opt.step()
    with torch.no_grad():
        qn = q / torch.linalg.norm(q, dim=-1, keepdim=True)
        cos = _direction_loss(_torch_points(_torch_quat_to_matrix(qn), h, w, m), src_dirs, idx)
        err = float(torch.rad2deg(torch.arccos(cos.clamp(-1, 1))).mean())
    return qn.numpy(), err


# ----------------------------------------------------------------------------------------------
# motions


@dataclass(frozen=True)
class MotionSpec:
    source: str      # "deepmimic:<clip>", "mediapipe" (the juggle landmarks) or "stand"
    moving: bool     # the root travels (walk, run) or stays in place
    credit: str


DEEPMIMIC_CREDIT = "DeepMimic humanoid clip {} (pybullet_data, zlib licence; Peng et al., SIGGRAPH 2018)"
MOTIONS: dict[str, MotionSpec] = {
    "walk": MotionSpec("deepmimic:walk", True, DEEPMIMIC_CREDIT.format("humanoid3d_walk")),
    "run": MotionSpec("deepmimic:run", True, DEEPMIMIC_CREDIT.format("humanoid3d_run")),
    "dance": MotionSpec("deepmimic:dance_b", False, DEEPMIMIC_CREDIT.format("humanoid3d_dance_b")),
    "juggle": MotionSpec("mediapipe", False, "MediaPipe Pose world landmarks of sam2_juggle_1280x720.mp4 "
                                             "(the juggler's own clip; sam2 demo, Apache-2.0)"),
    "idle": MotionSpec("stand", False, "synthetic: the rest pose with the arms lowered and a slow sway"),
}


def pybullet_motions_dir() -> Path:
    import pybullet_data

    return Path(pybullet_data.getDataPath()) / "data" / "motions"


def _loop_deepmimic(pts: dict, fps: float, moving: bool) -> tuple[dict, float]:
    """One period resampled to about FPS frames (a 'wrap' clip's last frame repeats its first pose)."""
    n_src = len(pts["pelvis"])
    period = (n_src - 1) / fps
    disp = pts["pelvis"][-1] - pts["pelvis"][0]
    pts = face_forward(pts, math.atan2(disp[1], disp[0]) if moving else None)
    n = int(round(period * FPS))
    t = np.arange(n_src) / fps
    tn = np.arange(n) * period / n
    out = {k: np.stack([np.interp(tn, t, v[:, i]) for i in range(3)], -1) for k, v in pts.items()}
    out["cycle"] = (pts["pelvis"][-1] - pts["pelvis"][0]) * np.array([1.0, 1.0, 0.0])
    if not moving:  # close the loop in place: the small drift over one period goes
        ramp = np.arange(n)[:, None] / n
        out = {k: (v - ramp * out["cycle"] if k != "cycle" else v * 0) for k, v in out.items()}
    return out, n / period


def _smooth(x: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Gaussian smoothing along time (edges repeated): the landmarks' frame-to-frame jitter goes."""
    r = int(3 * sigma)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    pad = np.concatenate([np.repeat(x[:1], r, 0), x, np.repeat(x[-1:], r, 0)])
    return np.stack([np.convolve(pad[:, i], k / k.sum(), mode="valid") for i in range(x.shape[1])], -1)


def _loop_capture(pts: dict, fps: float, min_period_s: float = 4.0) -> tuple[dict, float]:
    """The stretch of a non-looping capture whose end best matches its start, closed with a ramp."""
    pts = {k: _smooth(v) for k, v in pts.items()}
    x = np.stack([pts[k] - pts["pelvis"] for k in sorted(pts)], 1)                      # (N, K, 3)
    vel = np.gradient(x, axis=0)
    n_src, gap = len(x), int(min_period_s * fps)
    best = min(((np.linalg.norm(x[i] - x[j], axis=-1).mean() + 3 * np.linalg.norm(vel[i] - vel[j], axis=-1).mean(),
                 i, j) for i in range(n_src - gap) for j in range(i + gap, n_src)))
    _, i, j = best
    period = (j - i) / fps
    n = int(round(period * FPS))
    t = np.arange(n_src) / fps
    tn = i / fps + np.arange(n) * period / n
    out = {k: np.stack([np.interp(tn, t, v[:, c]) for c in range(3)], -1) for k, v in pts.items()}
    ramp = np.arange(n)[:, None] / n
    out = {k: v + ramp * (pts[k][i] - pts[k][j]) for k, v in out.items()}
    log.info("capture loop: source frames %d-%d (%.2f s), mismatch %.3f", i, j, period, best[0])
    out["cycle"] = np.zeros(3)
    return out, n / period


def _stand(rest: dict, seconds: float = 4.0) -> tuple[dict, float]:
    """The rest pose with the arms hanging and a slow sideways sway of the upper body (synthetic)."""
    n = int(seconds * FPS)
    out = {k: np.repeat(v[None], n, 0) for k, v in rest.items()}
    for s, y in (("l", 1.0), ("r", -1.0)):
        sh = rest[f"shoulder_{s}"]
        up = np.linalg.norm(rest[f"elbow_{s}"] - sh)
        fore = np.linalg.norm(rest[f"wrist_{s}"] - rest[f"elbow_{s}"])
        elbow = sh + up * np.array([-0.05, 0.12 * y, -1.0]) / np.linalg.norm([-0.05, 0.12, -1.0])
        wrist = elbow + fore * np.array([0.25, 0.04 * y, -1.0]) / np.linalg.norm([0.25, 0.04, -1.0])
        out[f"elbow_{s}"], out[f"wrist_{s}"] = np.repeat(elbow[None], n, 0), np.repeat(wrist[None], n, 0)
        # feet under the hips (anny's rest stance is wide): a natural stand, a hand's width apart
        dy = np.array([0.0, rest[f"hip_{s}"][1] + 0.03 * y - rest[f"ankle_{s}"][1], 0.0])
        out[f"knee_{s}"] = out[f"knee_{s}"] + dy / 2
        for k in ("ankle", "heel", "toe"):
            out[f"{k}_{s}"] = out[f"{k}_{s}"] + dy
    angle = np.deg2rad(1.2) * np.sin(2 * np.pi * np.arange(n) / n)             # one sway per loop
    upper = ["neck", "nose", "ear_l", "ear_r", "ear_mid", *[f"{k}_{s}" for k in ("shoulder", "elbow", "wrist")
                                                              for s in "lr"]]
    pel = rest["pelvis"]
    for k in upper:
        d = out[k] - pel
        c, s_ = np.cos(angle)[:, None], np.sin(angle)[:, None]
        out[k] = pel + np.stack([d[:, 0], c[:, 0] * d[:, 1] - s_[:, 0] * d[:, 2],
                                 s_[:, 0] * d[:, 1] + c[:, 0] * d[:, 2]], -1)
    out["cycle"] = np.zeros(3)
    return out, FPS


def capture(spec: MotionSpec, rest: dict, juggle_landmarks: Path | None) -> tuple[dict, float]:
    """Looping capture points at about FPS (body frame, facing +x) + 'cycle' displacement, and their rate."""
    if spec.source.startswith("deepmimic:"):
        clip = pybullet_motions_dir() / f"humanoid3d_{spec.source.split(':')[1]}.txt"
        pts, fps = deepmimic_points(clip)
        return _loop_deepmimic(derived(pts), fps, spec.moving)
    if spec.source == "mediapipe":
        if juggle_landmarks is None:
            raise SystemExit("the juggle motion needs --juggle-landmarks (see the module docstring)")
        pts, fps = mediapipe_points(juggle_landmarks)
        return _loop_capture(face_forward(derived(pts)), fps)
    return _stand(rest)


@dataclass
class Reference:
    """The retargeting body: its skeleton, its points' regressor and its mesh (for grounding)."""
    heads: np.ndarray
    names: list[str]
    weights: np.ndarray
    moments: np.ndarray
    person: P.Person

    @property
    def rest_points(self) -> dict[str, np.ndarray]:
        return dict(zip(self.names, self.moments.sum(1)))


def _leg_length(pts: dict) -> float:
    return float(np.mean([np.linalg.norm(pts[f"hip_{s}"] - pts[f"knee_{s}"], axis=-1)
                          + np.linalg.norm(pts[f"knee_{s}"] - pts[f"ankle_{s}"], axis=-1) for s in "lr"]))


def motion_arrays(name: str, spec: MotionSpec, ref: Reference, juggle_landmarks: Path | None) -> dict:
    """Everything people.load_motion reads, for the motion `spec` retargeted onto `ref`."""
    pts, fps = capture(spec, ref.rest_points, juggle_landmarks)
    cycle = pts.pop("cycle")
    quats, err = retarget(pts, ref.names, ref.weights, ref.moments, ref.heads, ref.rest_points, loop=True)
    rot = P.quat_to_matrix(quats)
    scale = _leg_length(ref.rest_points) / _leg_length(pts)
    hips = [P.BONES.index("upperleg01.L"), P.BONES.index("upperleg01.R")]
    pelvis = np.array([P.forward_kinematics(ref.heads, r, np.zeros(3))[1][hips].mean(0) for r in rot])
    offset = scale * pts["pelvis"] - pelvis
    offset[:, :2] -= offset[0, :2]                      # the root over the origin at t = 0
    low = np.array([ref.person.skin(r, o).vertices_m[:, 2].min() for r, o in zip(rot, offset)])
    if spec.source in ("mediapipe", "stand"):            # standing throughout: a foot on the ground in every frame
        offset[:, 2] -= low
    else:                                                # steps, flights: the lowest tenth of frames touch down
        offset[:, 2] -= np.percentile(low, 10)
    n = len(quats)
    cycle_m = scale * cycle
    speed = float(np.linalg.norm(cycle_m[:2]) * fps / n)
    log.info("%s: %d frames at %.2f fps (%.2f s), direction error %.1f deg, scale %.3f, speed %.2f m/s",
             name, n, fps, n / fps, err, scale, speed)
    return dict(bones=np.array(P.BONES), rotations=quats.astype(np.float32), root_offset=offset.astype(np.float32),
                cycle_m=cycle_m.astype(np.float32), fps=np.float64(fps), loop=np.bool_(True),
                speed_mps=np.float64(speed), source=np.str_(spec.credit), fit_error_deg=np.float64(err))


def reference(anny: Anny) -> tuple[Reference, np.ndarray, np.ndarray]:
    """The retargeting body, and the shared topology (kept base-mesh vertices, faces) decimated on it."""
    v, heads, _ = anny.body(REFERENCE)
    keep, faces = decimate(anny, v)
    names, w, m = point_regressor(anny, v, heads)
    person = P.person_from_arrays("reference", person_arrays(anny, "reference", REFERENCE, keep, faces, heads[0, 2]))
    return Reference(heads, names, w, m, person), keep, faces


def bake(args: argparse.Namespace) -> None:
    anny = Anny()
    ref, keep, faces = reference(anny)
    log.info("topology: %d vertices, %d triangles", len(keep), len(faces))
    for name in args.people:
        save(P.PEOPLE_DIR / f"{name}.npz", person_arrays(anny, name, PEOPLE[name], keep, faces, ref.heads[0, 2]))
    for name in args.motions:
        save(P.MOTIONS_DIR / f"{name}.npz", motion_arrays(name, MOTIONS[name], ref, args.juggle_landmarks))


def landmarks(args: argparse.Namespace) -> None:
    """MediaPipe Pose world landmarks of every frame of a video (run with the project's venv)."""
    import cv2
    import mediapipe as mp

    cap = cv2.VideoCapture(str(args.video))
    if not cap.isOpened():
        raise SystemExit(f"cannot read {args.video}")
    fps = cap.get(cv2.CAP_PROP_FPS)
    world = []
    with mp.solutions.pose.Pose(static_image_mode=False, model_complexity=1, smooth_landmarks=True) as pose:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            res = pose.process(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
            lm = res.pose_world_landmarks
            world.append(np.full((33, 4), np.nan) if lm is None
                         else [[p.x, p.y, p.z, p.visibility] for p in lm.landmark])
    np.savez(args.out, world=np.array(world, np.float32), fps=np.float64(fps))
    log.info("%s: %d frames at %.1f fps -> %s", args.video, len(world), fps, args.out)


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("bake", help="bake people and motions into assets/ (needs the `bake` extra)")
    b.add_argument("--people", nargs="*", default=list(PEOPLE), choices=list(PEOPLE))
    b.add_argument("--motions", nargs="*", default=list(MOTIONS), choices=list(MOTIONS))
    b.add_argument("--juggle-landmarks", type=Path, help="output of the `landmarks` step (for the juggle motion)")
    lm = sub.add_parser("landmarks", help="MediaPipe world landmarks of a video (project venv)")
    lm.add_argument("--video", type=Path, required=True)
    lm.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    (bake if args.cmd == "bake" else landmarks)(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
