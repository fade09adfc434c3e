"""The courtyard with its walker waiting on his mark: the set a camera-move transfer is judged on.

The rendered camera moves (camera_motion_3d_sources.py) film the courtyard's walker from 1 s into
his loop. A transfer flies a pre-roll first, and in the bundled scene the walker keeps walking
through it: with `--preroll 12.667` he is at the same point of his loop when the take starts, but
he has walked a whole loop (four turns) while the drone settled on the first frame's framing, and
no drone keeps a framing's bearing round a walker who turns 90 deg every 3 s, so the take starts
from wherever the chase left it (docs/planner.md, "Camera motion"). On a set the actor waits on his
mark until the take: this scene is the bundled one with the walker waiting where (and facing the
way) the sources film him first, for the pre-roll, and then walking the rest of his loop.

    from camera_motion_mark import write_mark_scene
    write_mark_scene(run_dir / "scene.yaml", wait_s=10.0)   # then: transfer ... --scene run_dir/scene.yaml --preroll 10
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

SCENE = "courtyard"
#: how far into his loop the sources film the walker first (camera_motion_3d_sources.START_TIME_S)
PHASE_S = 1.0


def path_after(start_xy: tuple[float, float], legs: list[list[list[float]]], distance_m: float) -> list[list[float]]:
    """The polyline `legs` (after `start_xy`) from `distance_m` along it: the point reached, then the
    corners still ahead (pure; the walk wraps round the loop)."""
    pts = [np.asarray(start_xy, float)] + [np.asarray(p, float) for leg in legs for p in leg]
    seg = [(a, b, float(np.linalg.norm(b - a))) for a, b in zip(pts[:-1], pts[1:])]
    total = sum(s[2] for s in seg)
    left = distance_m % total if total > 0 else 0.0
    for i, (a, b, n) in enumerate(seg):
        if left <= n and n > 0:
            here = a + (b - a) * (left / n)
            return [[round(float(v), 4) for v in here]] + [[float(v) for v in s[1]] for s in seg[i:]]
        left -= n
    return [[float(v) for v in pts[-1]]]


def mark_subject(subject: dict, phase_s: float, wait_s: float) -> dict:
    """The scene's `subject:` entry with the walker waiting `wait_s` at his place `phase_s` into his
    walk, facing along it, then walking the rest of the loop once."""
    steps = subject["script"]
    if not steps or any(s.get("action") != "walk" for s in steps):
        raise ValueError("the mark needs a subject whose script only walks")
    speed = float(steps[0].get("speed_mps", 1.2))
    if any(float(s.get("speed_mps", 1.2)) != speed for s in steps):
        raise ValueError("the mark needs one walking speed")
    path = path_after(tuple(subject["start_m"]), [s["path_m"] for s in steps], speed * phase_s)
    here, ahead = path[0], path[1] if len(path) > 1 else path[0]
    facing = math.degrees(math.atan2(ahead[1] - here[1], ahead[0] - here[0]))
    out = {k: v for k, v in subject.items() if k not in ("script", "start_m", "facing_deg", "loop")}
    return {**out, "start_m": here, "facing_deg": round(facing, 3), "loop": False,
            # a walk that ends where it starts and then waits: he marks time on the spot (the walker
            # has no standing action), facing `facing_deg`
            "script": [{"action": "walk", "path_m": [here], "speed_mps": speed, "duration_s": float(wait_s)},
                       {"action": "walk", "path_m": path[1:], "speed_mps": speed}]}


def write_mark_scene(path: Path, *, wait_s: float, phase_s: float = PHASE_S, scene: str = SCENE) -> Path:
    """Write the bundled `scene` with its walker on his mark for `wait_s` (the transfer's pre-roll)."""
    from cinetransfer.services.autopilot_bridge.sim.scene import SCENES_DIR

    doc = yaml.safe_load((SCENES_DIR / f"{scene}.yaml").read_text(encoding="utf-8"))
    doc["name"] = f"{scene}_mark"
    doc["description"] = f"{doc.get('description', scene)}; the walker waits {wait_s:g} s on his mark"
    doc["subject"] = mark_subject(doc["subject"], phase_s, wait_s)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path
