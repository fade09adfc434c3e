"""A subject who moves in the world as a crop source's person moved: the fair set for the crops.

A crop source (camera_motion_sources.py) is a virtual camera moving inside real static footage, so
its person moves in the frame by the camera's move and by his own walking. Flown with a subject who
stands, the output must pan by what the person walked to frame him as the source does: a pan the
source never made. His own motion is his track in the uncropped, static footage: his place in the
crop (the source's style: the joints' centre and the shoulder-to-hip length, per frame) carried back
through the crop's known homography. Seen by a static pinhole camera of the source's field of view, a
person whose torso is TORSO_M long stands at depth f * TORSO_M / torso_px, and his centre's column
places him sideways. The clip's own person (CLIP_PERSON) follows that path across the view from
where the drone stands when the take starts (found by flying the pre-roll in-process), after
waiting on his mark for the pre-roll as the rendered moves' walker does (camera_motion_mark.py).

Metres follow from one assumed torso length, but the frame does not care: at the distance that
frames the torso as large as the source's, a sideways step of TORSO_M moves him by the same share
of the frame as the source's person moved. In depth it does not: his approach is scaled to the
output camera's distance (camera_frame_path). docs/camera_motion.md, "The crop sources flown with
their person's own motion".

    from camera_motion_crop_subject import write_crop_scene
    write_crop_scene(run / "scene.yaml", truth, run / "source_style.json", wait_s=10.0)   # then --preroll 10
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml

try:
    from camera_motion_sources import CLIPS, MOVES, SOURCE_HFOV_DEG, homography
except ImportError:  # imported as a package
    from benchmarks.camera_motion_sources import CLIPS, MOVES, SOURCE_HFOV_DEG, homography

from cinetransfer.shared import camera_motion as cm

SCENE = "open_country"
#: each static clip's own person in the subject library, and how he follows his path: the
#: pedestrian walks it (facing the way he walks, as TUD's pedestrians do); the juggler, who faces
#: the camera and shuffles a few centimetres, stands at each knot in turn (a step can place a
#: standing person, not slide him; every knot restarts his motion, so he stands rather than juggles)
CLIP_PERSON = {"sam2_juggle_1280x720.mp4": ("juggler", "stand"), "tud_stadtmitte_640x480.mp4": ("walker", "walk")}
#: shoulder-to-hip length assumed for the source's person and the scene's [m] (0.29 of 1.75 m)
TORSO_M = 0.5
#: the path's knots are this many source frames apart, each the mean of the track round it (the
#: joints jitter by a pixel or two frame to frame); a walk step restarts the gait, so its knots are
#: sparse, while a standing person jumps from knot to knot, so his are dense
KNOT_FRAMES = {"walk": 12, "stand": 2}
#: how many times the path is laid again across the view from where the drone settled
SETTLE_PASSES = 1
#: a step shorter than this is stood rather than walked [m]
STILL_M = 0.02


def crop_to_source(points_px: np.ndarray, h_src_to_crop: np.ndarray) -> np.ndarray:
    """Crop pixels (N x 2) -> source pixels through the inverse of the crop's homography (pure)."""
    p = np.c_[np.asarray(points_px, float), np.ones(len(points_px))] @ np.linalg.inv(h_src_to_crop).T
    return p[:, :2] / p[:, 2:3]


def person_track(joints: np.ndarray, homographies: list[np.ndarray],
                 crop_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(centre px [K x 2], torso px [K]) of the person in the static source, from his four joints
    (left/right shoulder, left/right hip; K x 4 x 2, shares of the crop frame) per crop frame. A
    joint the style leaves out (NaN) is left out of the centre; a frame without a shoulder and a hip
    takes its torso, and one without any joint its centre too, from the frames round it."""
    w, h = crop_size
    centre, torso = [], []
    for j, hom in zip(np.asarray(joints, float), homographies):
        src = crop_to_source(j * [w, h], hom)
        ok = np.isfinite(src).all(axis=1)
        centre.append(src[ok].mean(axis=0) if ok.any() else [np.nan, np.nan])
        top, low = src[:2][ok[:2]], src[2:][ok[2:]]
        torso.append(float(np.linalg.norm(top.mean(axis=0) - low.mean(axis=0))) if len(top) and len(low) else np.nan)
    return _fill(np.array(centre)), _fill(np.array(torso)[:, None])[:, 0]


def _fill(v: np.ndarray) -> np.ndarray:
    """Each column's NaNs filled by straight lines between its known values (held at the ends)."""
    k = np.arange(len(v))
    out = v.copy()
    for c in range(v.shape[1]):
        ok = np.isfinite(v[:, c])
        if not ok.any():
            raise ValueError("the style has no joints of its person to track")
        out[:, c] = np.interp(k, k[ok], v[ok, c])
    return out


def camera_frame_path(centre_px: np.ndarray, torso_px: np.ndarray, src_size: tuple[int, int],
                      torso_m: float = TORSO_M, distance_m: float | None = None) -> np.ndarray:
    """The person's place [K x 2: sideways right, forward; m] in the static source camera's frame,
    relative to the first frame (pure). His depth comes from a straight line through his torso's
    length over the clip: frame to frame it changes with his pose too (the juggler's torso grows
    10 % in two frames as he straightens, which read as depth is a lunge at 2 m/s), and a pose the
    detector gets wrong is far off (sam2_pan_tilt's first row: 107 px where the rest read 150-190),
    so the line is the median one (Theil-Sen), not the least-squares one.

    Sideways, a metre is the same share of the frame at any distance that frames the torso as the
    source does; nearer or farther is not: his size changes by the share of his distance he moves.
    `distance_m`, the output camera's distance from him, scales the depth so that it changes by the
    same share as the source's (None: the source camera's own distance)."""
    f = cm.focal_px(src_size[0], SOURCE_HFOV_DEG)
    z = f * torso_m / np.maximum(median_line(np.asarray(torso_px, float)), 1.0)
    x = z * (centre_px[:, 0] - (src_size[0] - 1) / 2) / f
    scale = 1.0 if distance_m is None else distance_m / z[0]
    return np.c_[x - x[0], (z - z[0]) * scale]


def median_line(v: np.ndarray) -> np.ndarray:
    """The Theil-Sen line through v over its indices: the median of the slopes between every two
    samples, through the median of what is left (pure; a third of the samples may be wild)."""
    k = np.arange(len(v), dtype=float)
    if len(v) < 2:
        return v.astype(float)
    i, j = np.triu_indices(len(v), 1)
    slope = float(np.median((v[j] - v[i]) / (j - i)))
    return slope * k + float(np.median(v - slope * k))


def knots(path: np.ndarray, every: int) -> tuple[np.ndarray, np.ndarray]:
    """(frame indices, places) of the path's knots: every `every` frames and the last, each the mean
    place over a window centred on it, narrowed at the ends so the first and last are exact (pure)."""
    n = len(path)
    idx = list(range(0, n, every)) + ([n - 1] if (n - 1) % every else [])
    pts = []
    for i in idx:
        hw = min(every // 2, i, n - 1 - i)
        pts.append(path[i - hw:i + hw + 1].mean(axis=0))
    return np.array(idx), np.array(pts)


def world_axes(vehicle_xy: tuple[float, float], subject_xy: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(right, forward) unit vectors on the ground of a camera at `vehicle_xy` looking at the subject."""
    fwd = np.asarray(subject_xy, float) - np.asarray(vehicle_xy, float)
    fwd /= np.linalg.norm(fwd)
    return np.array([fwd[1], -fwd[0]]), fwd


def walk_script(start_xy: np.ndarray, places: np.ndarray, frames: np.ndarray, fps: float,
                wait_s: float) -> list[dict[str, Any]]:
    """The walker's script: wait on his mark for `wait_s`, then reach each knot on its frame's time
    (a step too short to walk is stood for its time). Pure."""
    here = [round(float(v), 4) for v in start_xy]
    steps = [{"action": "walk", "path_m": [here], "speed_mps": 1.0, "duration_s": float(wait_s)}]
    for (f0, f1), p in zip(zip(frames[:-1], frames[1:]), places[1:]):
        dt = (f1 - f0) / fps
        nxt = [round(float(v), 4) for v in p]
        dist = math.dist(here, nxt)
        if dist < STILL_M:
            steps.append({"action": "walk", "path_m": [here], "speed_mps": 1.0, "duration_s": round(float(dt), 4)})
            continue
        steps.append({"action": "walk", "path_m": [nxt], "speed_mps": round(float(dist / dt), 4)})
        here = nxt
    # at the end he stands where the clip leaves him (facing as he last walked)
    steps.append({"action": "walk", "path_m": [here], "speed_mps": 1.0, "duration_s": 60.0})
    return steps


def stand_script(places: np.ndarray, frames: np.ndarray, fps: float, wait_s: float) -> list[dict[str, Any]]:
    """The standing person's script: stand on his mark for `wait_s`, then at each knot from its
    frame's time to the next one's (pure)."""
    ends = list(frames[1:]) + [frames[-1] + 60 * fps]  # at the end he stays where the clip leaves him
    steps = [{"action": "stand", "at_m": [round(float(v), 4) for v in places[0]], "duration_s": float(wait_s)}]
    for f0, f1, p in zip(frames, ends, places):
        steps.append({"action": "stand", "at_m": [round(float(v), 4) for v in p],
                      "duration_s": round(float((f1 - f0) / fps), 4)})
    return steps


def crop_homographies(truth: dict[str, Any], crop_size: tuple[int, int]) -> tuple[list[np.ndarray], tuple[int, int]]:
    """(source -> crop homography per frame, the static clip's size) of a crop source's truth file."""
    move = {m.name: m for m in MOVES}[truth["name"]]
    clip = re.match(r"crop of (\S+)", truth["origin"]).group(1)
    size = re.search(r"_(\d+)x(\d+)\.", clip)
    src_size = (int(size.group(1)), int(size.group(2)))
    if clip not in {c for c, _ in CLIPS}:
        raise ValueError(f"{truth['origin']!r}: not a clip of camera_motion_sources.CLIPS")
    fps, n = float(truth["fps"]), int(truth["frames"])
    t0 = (n - 1) / 2 / fps
    return [homography(move, k / fps, t0, src_size, crop_size) for k in range(n)], src_size


def crop_subject(truth: dict[str, Any], style: dict[str, Any], subject: dict[str, Any],
                 vehicle_xy: tuple[float, float], wait_s: float, facing_deg: float | None = None) -> dict[str, Any]:
    """The scene's `subject:` entry: the clip's own person, moving as he moved in the static footage
    seen from `vehicle_xy`, facing `facing_deg` while he waits (None: the way he will walk, or the
    camera if he stands)."""
    ins = style.get("instructions", style)
    crop_size = (int(ins["source"]["width"]), int(ins["source"]["height"]))
    homs, src_size = crop_homographies(truth, crop_size)
    person, action = CLIP_PERSON[re.match(r"crop of (\S+)", truth["origin"]).group(1)]
    n = min(len(homs), len(ins["image_targets"]))
    centre, torso = person_track(np.asarray(ins["image_targets"][:n]), homs[:n], crop_size)
    start = np.asarray(subject.get("start_m", [0.0, 0.0]), float)
    distance = float(np.linalg.norm(start - np.asarray(vehicle_xy, float)))
    idx, pts = knots(camera_frame_path(centre, torso, src_size, distance_m=distance), KNOT_FRAMES[action])
    right, fwd = world_axes(vehicle_xy, tuple(start))
    world = start + pts[:, :1] * right + pts[:, 1:2] * fwd
    fps = float(truth["fps"])
    if action == "walk":  # he waits facing the way he will walk
        way = world[1] - world[0]
        script = walk_script(world[0], world, idx, fps, wait_s)
    else:  # he faces the camera
        way = -fwd
        script = stand_script(world, idx, fps, wait_s)
    facing = math.degrees(math.atan2(way[1], way[0])) if facing_deg is None else facing_deg
    return {"clip": person, "loop": False, "start_m": [round(float(v), 4) for v in world[0]],
            "facing_deg": round(facing, 3), "script": script}


def settled_xy(style_path: Path, scene_path: Path, preroll_s: float) -> tuple[float, float]:
    """Where the drone stands when the take starts: the planner flown in-process (no rendering) on
    the style's first row for the pre-roll, as camera_motion_flight.py flies a style."""
    from cinetransfer.plan import make_sim
    from cinetransfer.services.planner.config import PlannerConfig
    from cinetransfer.services.planner.scenarios import planner_maker
    from cinetransfer.shared import messages as M
    from cinetransfer.shared.instructions import load_style

    ins = load_style(str(style_path))
    cfg = PlannerConfig()
    planner = planner_maker(dataclasses.replace(cfg, max_solve_time_s=max(cfg.max_solve_time_s, 10.0 / cfg.rate_hz)))()
    sim, _ = make_sim(str(scene_path))
    t0 = 1_700_000_000_000_000_000
    try:
        planner.command(M.Command(action="start", args={"start_frame": int(ins.first_frame),
                                                        "preroll_s": float(preroll_s)}), t0)
        period, t = 1.0 / planner.cfg.rate_hz, 0.0
        while t < preroll_s - 1e-9:
            now = t0 + int(round(t * 1e9))
            sim.apply(planner.step(now, ins, sim.vehicle_state(now), sim.subject_state(now)))
            sim.step(min(period, preroll_s - t))
            t += period
        x, y = sim.vehicle_state(t0 + int(round(preroll_s * 1e9))).position_m[:2]
    finally:
        sim.close()
    return float(x), float(y)


def write_crop_scene(path: Path, truth: dict[str, Any], style_path: Path, *, wait_s: float,
                     scene: str = SCENE, passes: int = SETTLE_PASSES) -> Path:
    """Write the bundled `scene` with its subject replaced by the clip's own person moving as he moved,
    seen from where the drone settles for the take. That place depends on the subject's facing and
    on the framing (the planner may move metres round him, and a path laid across the view from the
    drone's start is then partly along it), so it is found by flying the pre-roll in-process and laying
    the path again across the view from there, `passes` times."""
    from cinetransfer.services.autopilot_bridge.sim.scene import SCENES_DIR

    doc = yaml.safe_load((SCENES_DIR / f"{scene}.yaml").read_text(encoding="utf-8"))
    style = json.loads(Path(style_path).read_text(encoding="utf-8"))
    subject = doc["subject"]
    doc["name"] = f"{scene}_crop_{truth['name']}"
    doc["description"] = (f"{doc.get('description', scene)}; the subject moves as the person of "
                          f"{truth['origin']} ({truth['name']}), after waiting {wait_s:g} s on his mark")
    path.parent.mkdir(parents=True, exist_ok=True)
    view, facing = tuple(doc["vehicle"]["position_m"][:2]), None
    for k in range(passes + 1):
        doc["subject"] = crop_subject(truth, style, subject, view, wait_s, facing)
        facing = doc["subject"]["facing_deg"]
        path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
        if k < passes:
            view = settled_xy(Path(style_path), path, wait_s)
    return path
