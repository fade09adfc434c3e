"""Scene files of the built-in simulator: YAML → validated, frozen dataclasses.

A scene names its camera (resolution, frame rate, sensor), the vehicle's initial pose and lens,
optional dynamics limits, a ground plane, planar layers (backdrops, foreground objects, sky),
and the subject (which cut-out clip, how tall, and a script of actions). Bundled scenes live in
`scenes/`; `load_scene("lawn_juggler")` finds one by name, `load_scene("path/to/x.yaml")` reads
a file. Every error names the offending field and what is allowed. See docs/simulator.md.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from cinetransfer.shared import camera as cam
from cinetransfer.shared.dynamics import DynamicsLimits
from cinetransfer.shared.vehicle import VehicleProfile

SCENES_DIR = Path(__file__).resolve().parent / "scenes"
ASSETS_DIR = Path(__file__).resolve().parent / "assets"

#: what a step may ask for; which of them a subject can do is in its library entry (subjects())
ACTIONS = ("stand", "walk", "run", "juggle", "dance", "twirl", "vault")
#: steps that follow a path (`path_m`, `speed_mps`); the others stay at a point for `duration_s`
MOVING = ("walk", "run")
REGIONS = ("foreground", "background", "sky")
WRAPS = ("none", "reflect", "replicate")
#: how a scene is drawn: '3d' (renderer3d.py: meshes on the GPU path, the person a skinned 3-D body)
#: or '2.5d' (renderer.py: photographs on planes, the person a camera-facing cut-out)
WORLDS = ("2.5d", "3d")
#: the 3-D world's solid objects (`objects:`); see ObjectSpec
OBJECT_KINDS = ("box", "pillar", "tree")


class SceneError(ValueError):
    """A scene file is missing, malformed or inconsistent (the message names the field)."""


def _num(d: dict, key: str, where: str, default: Any = None, *, lo: float | None = None,
         hi: float | None = None, positive: bool = False) -> float:
    if key not in d:
        if default is None:
            raise SceneError(f"{where}.{key}: required (a number)")
        return float(default)
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise SceneError(f"{where}.{key}: must be a finite number, got {v!r}")
    v = float(v)
    if positive and v <= 0:
        raise SceneError(f"{where}.{key}: must be > 0, got {v}")
    if lo is not None and v < lo:
        raise SceneError(f"{where}.{key}: must be >= {lo}, got {v}")
    if hi is not None and v > hi:
        raise SceneError(f"{where}.{key}: must be <= {hi}, got {v}")
    return v


def _vec(d: dict, key: str, where: str, n: int, default: Any = None) -> tuple[float, ...]:
    if key not in d:
        if default is None:
            raise SceneError(f"{where}.{key}: required (a list of {n} numbers)")
        return tuple(float(x) for x in default)
    v = d[key]
    if not isinstance(v, (list, tuple)) or len(v) != n or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(float(x)) for x in v):
        raise SceneError(f"{where}.{key}: must be a list of {n} finite numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _str(d: dict, key: str, where: str, default: str | None = None, choices: tuple[str, ...] | None = None) -> str:
    if key not in d:
        if default is None:
            raise SceneError(f"{where}.{key}: required (a string)")
        return default
    v = d[key]
    if not isinstance(v, str) or not v:
        raise SceneError(f"{where}.{key}: must be a non-empty string, got {v!r}")
    if choices is not None and v not in choices:
        raise SceneError(f"{where}.{key}: must be one of {list(choices)}, got {v!r}")
    return v


def _dict(d: dict, key: str, where: str, required: bool = False) -> dict:
    if key not in d:
        if required:
            raise SceneError(f"{where}.{key}: required (a mapping)")
        return {}
    v = d[key]
    if not isinstance(v, dict):
        raise SceneError(f"{where}.{key}: must be a mapping, got {type(v).__name__}")
    return v


def _known(d: dict, where: str, allowed: set[str]) -> None:
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise SceneError(f"{where}: unknown field(s) {unknown}; allowed: {sorted(allowed)}")


def _asset(name: str, where: str) -> Path:
    p = Path(name)
    if not p.is_absolute():
        p = ASSETS_DIR / name
    if not p.is_file():
        raise SceneError(f"{where}: asset file {p} not found (assets are made by sim/make_assets.py)")
    return p


@dataclass(frozen=True)
class CameraSpec:
    width: int = 960
    height: int = 540
    fps: float = 24.0
    sensor_width_mm: float = 23.76
    sensor_height_mm: float = 13.365
    coc_mm: float = cam.COC_MM  # derived from the sensor width (shared.camera.coc_mm_for_sensor), not a key


@dataclass(frozen=True)
class VehicleSpec:
    position_m: tuple[float, float, float]
    camera_ypr_rad: tuple[float, float, float]
    focal_length_mm: float
    focus_distance_m: float
    f_number: float


@dataclass(frozen=True)
class GroundSpec:
    texture: Path | str  # a picture, or (3-D world) a procedural texture's name (textures.NAMES)
    m_per_px: float
    z_m: float = 0.0
    extent_m: float = 400.0


@dataclass(frozen=True)
class LayerSpec:
    """A planar textured layer standing on the ground (or floating, `bottom_z_m`)."""

    name: str
    region: str  # 'foreground' | 'background' | 'sky' (sky: infinitely far, never blurred by depth)
    texture: Path
    position_m: tuple[float, float]  # world (x, y) of the texture's anchor
    bottom_z_m: float
    m_per_px: float
    anchor_px: tuple[float, float] | None  # texture pixel at (position, bottom_z); None = bottom centre
    facing: str  # 'camera' or 'fixed'
    facing_yaw_rad: float  # direction the front faces (fixed layers)
    wrap: str
    extent_m: tuple[float, float] | None  # quad size (width, height) for wrapping layers
    distance_m: float | None = None  # camera-facing layers: kept at this distance from the camera


@dataclass(frozen=True)
class ObjectSpec:
    """A solid object of the 3-D world standing on the ground: a box (walls, blocks), a pillar (a
    cylinder) or a tree (a trunk under an ellipsoid crown). 3-D scenes only."""

    name: str
    kind: str
    position_m: tuple[float, float]  # world (x, y) of its foot's centre
    size_m: tuple[float, float, float]  # box: length (along yaw), depth, height; pillar/tree: diameter, -, height
    yaw_rad: float
    texture: str  # a procedural texture (textures.NAMES)
    period_m: float  # metres per texture repeat
    crown_m: tuple[float, float] = (0.0, 0.0)  # tree: crown diameter and height
    path_m: tuple[tuple[float, float], ...] = ()  # moving objects: waypoints walked back and forth
    speed_mps: float = 0.0


@dataclass(frozen=True)
class ScriptStep:
    action: str
    duration_s: float
    at_m: tuple[float, float] | None = None
    path_m: tuple[tuple[float, float], ...] = ()
    speed_mps: float = 1.2


@dataclass(frozen=True)
class SubjectSpec:
    clip: str
    height_m: float
    script: tuple[ScriptStep, ...]
    loop: bool = True
    start_m: tuple[float, float] = (0.0, 0.0)
    subject_id: str = "subject"
    clip_fps: float | None = None  # None: each action's own rate from the library
    facing_rad: float = math.pi  # the way the person faces while in place (3-D world), until a walk turns it


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    seed: int
    camera: CameraSpec
    vehicle: VehicleSpec
    limits: DynamicsLimits
    ground: GroundSpec | None
    layers: tuple[LayerSpec, ...]
    subject: SubjectSpec
    path: Path | None = field(default=None, compare=False)
    world: str = "2.5d"
    objects: tuple[ObjectSpec, ...] = ()


def _parse_camera(d: dict) -> CameraSpec:
    w = "camera"
    _known(d, w, {"width", "height", "fps", "sensor_width_mm", "sensor_height_mm"})
    width = int(_num(d, "width", w, 960, lo=32, hi=7680))
    height = int(_num(d, "height", w, 540, lo=32, hi=4320))
    sensor_w = _num(d, "sensor_width_mm", w, 23.76, positive=True)
    return CameraSpec(width=width, height=height, fps=_num(d, "fps", w, 24.0, lo=1, hi=240), sensor_width_mm=sensor_w,
                      sensor_height_mm=_num(d, "sensor_height_mm", w, 13.365, positive=True),
                      coc_mm=cam.coc_mm_for_sensor(sensor_w))


def _parse_vehicle(d: dict) -> VehicleSpec:
    w = "vehicle"
    _known(d, w, {"position_m", "camera_ypr_deg", "lens"})
    lens = _dict(d, "lens", w, required=True)
    _known(lens, w + ".lens", {"focal_length_mm", "focus_distance_m", "f_number"})
    ypr = _vec(d, "camera_ypr_deg", w, 3, (0.0, 0.0, 0.0))
    return VehicleSpec(position_m=_vec(d, "position_m", w, 3),
                       camera_ypr_rad=tuple(math.radians(a) for a in ypr),
                       focal_length_mm=_num(lens, "focal_length_mm", w + ".lens", positive=True),
                       focus_distance_m=_num(lens, "focus_distance_m", w + ".lens", positive=True),
                       f_number=_num(lens, "f_number", w + ".lens", lo=0.5))


def _parse_layer(d: dict, i: int) -> LayerSpec:
    w = f"layers[{i}]"
    if not isinstance(d, dict):
        raise SceneError(f"{w}: must be a mapping")
    _known(d, w, {"name", "region", "texture", "position_m", "bottom_z_m", "m_per_px", "height_m",
                  "anchor_px", "facing", "facing_deg", "wrap", "extent_m", "distance_m"})
    tex = _asset(_str(d, "texture", w), w + ".texture")
    facing = _str(d, "facing", w, "fixed", ("fixed", "camera"))
    if "m_per_px" in d and "height_m" in d:
        raise SceneError(f"{w}: give either m_per_px or height_m, not both")
    m_per_px = _num(d, "m_per_px", w, positive=True) if "m_per_px" in d else None
    if m_per_px is None:
        import cv2

        img = cv2.imread(str(tex), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise SceneError(f"{w}.texture: {tex} is not a readable image")
        m_per_px = _num(d, "height_m", w, positive=True) / img.shape[0]
    anchor = _vec(d, "anchor_px", w, 2) if "anchor_px" in d else None
    wrap = _str(d, "wrap", w, "none", WRAPS)
    extent = _vec(d, "extent_m", w, 2) if "extent_m" in d else None
    if wrap != "none" and extent is None:
        raise SceneError(f"{w}.extent_m: required when wrap is {wrap!r} (the quad's width and height [m])")
    distance = _num(d, "distance_m", w, positive=True) if "distance_m" in d else None
    if facing == "camera" and distance is None and "position_m" not in d:
        raise SceneError(f"{w}: a camera-facing layer needs position_m or distance_m")
    return LayerSpec(name=_str(d, "name", w, f"layer{i}"), region=_str(d, "region", w, "background", REGIONS),
                     texture=tex, position_m=_vec(d, "position_m", w, 2, (0.0, 0.0)),
                     bottom_z_m=_num(d, "bottom_z_m", w, 0.0), m_per_px=m_per_px, anchor_px=anchor,
                     facing=facing, facing_yaw_rad=math.radians(_num(d, "facing_deg", w, 180.0)),
                     wrap=wrap, extent_m=extent, distance_m=distance)


def _procedural() -> tuple[str, ...]:
    from cinetransfer.services.autopilot_bridge.sim import textures

    return textures.NAMES


def subject_names() -> list[str]:
    """Names of the subjects in the library (assets/<name>.json with an `actions` table)."""
    return sorted(n for n, _ in _library().items())


def _library() -> dict[str, dict]:
    import json

    out = {}
    for p in sorted(ASSETS_DIR.glob("*.json")):
        try:
            meta = json.loads(p.read_text())
        except ValueError:
            continue
        if isinstance(meta, dict) and "actions" in meta and "frames" in meta:
            out[p.stem] = meta
    return out


def subject_info(name: str) -> dict:
    """The library entry of a subject: person, source, credit, height_m, actions, default_script."""
    import json

    p = _asset(f"{name}.json", "subject.clip")
    meta = json.loads(p.read_text())
    if "actions" not in meta:
        raise SceneError(f"subject.clip: {p.name} is not a library subject (no actions); "
                         f"subjects: {subject_names()}")
    return meta


def _parse_step(d: dict, i: int, subject: str = "", actions: tuple[str, ...] = ACTIONS) -> ScriptStep:
    w = f"subject.script[{i}]"
    if not isinstance(d, dict):
        raise SceneError(f"{w}: must be a mapping")
    _known(d, w, {"action", "duration_s", "at_m", "path_m", "speed_mps"})
    action = _str(d, "action", w, choices=ACTIONS)
    # a 'walk' is done by a walking clip, or else by a running one (at a rate matching the stride)
    can = set(actions) | ({"walk"} if "run" in actions else set())
    if action not in can:
        raise SceneError(f"{w}.action: subject {subject!r} has no action {action!r}; "
                         f"its actions: {sorted(actions)}")
    at = _vec(d, "at_m", w, 2) if "at_m" in d else None
    if action in MOVING:
        path = d.get("path_m")
        if not isinstance(path, list) or not path:
            raise SceneError(f"{w}.path_m: a walk needs a non-empty list of [x, y] waypoints")
        pts = tuple(_vec({"p": p}, "p", f"{w}.path_m[{k}]", 2) for k, p in enumerate(path))
        speed = _num(d, "speed_mps", w, 1.2 if action == "walk" else 3.0, positive=True, hi=10.0)
        return ScriptStep(action=action, duration_s=_num(d, "duration_s", w, 0.0, lo=0.0), at_m=at,
                          path_m=pts, speed_mps=speed)
    if "path_m" in d:
        raise SceneError(f"{w}.path_m: only a {' or '.join(repr(a) for a in MOVING)} has a path")
    return ScriptStep(action=action, duration_s=_num(d, "duration_s", w, positive=True), at_m=at)


def _parse_subject(d: dict, swap: str | None = None) -> SubjectSpec:
    w = "subject"
    _known(d, w, {"clip", "height_m", "script", "loop", "start_m", "id", "clip_fps", "facing_deg"})
    clip = _str(d, "clip", w)
    script = d.get("script")
    if swap is not None and swap != clip:
        # --subject: another person in this scene; its own height, and its default script when
        # the scene's script asks for an action this person does not do
        if swap not in subject_names():
            raise SceneError(f"subject {swap!r} is not in the library; subjects: {subject_names()}")
        clip = swap
        d = {k: v for k, v in d.items() if k != "height_m"}
        info = subject_info(clip)
        acts = set(info["actions"]) | ({"walk"} if "run" in info["actions"] else set())
        if not isinstance(script, list) or any(not isinstance(s, dict) or s.get("action") not in acts
                                               for s in script):
            x0, y0 = _vec(d, "start_m", w, 2, (0.0, 0.0))
            script = [{**st, **({"path_m": [[x + x0, y + y0] for x, y in st["path_m"]]} if "path_m" in st else {})}
                      for st in info.get("default_script", [])]
    info = subject_info(clip)
    if not isinstance(script, list) or not script:
        raise SceneError(f"{w}.script: required, a non-empty list of steps "
                         f"(subject {clip!r} does {sorted(info['actions'])})")
    loop = d.get("loop", True)
    if not isinstance(loop, bool):
        raise SceneError(f"{w}.loop: must be true or false")
    acts = tuple(sorted(info["actions"]))
    return SubjectSpec(clip=clip, height_m=_num(d, "height_m", w, float(info.get("height_m", 1.75)), lo=0.5, hi=2.5),
                       script=tuple(_parse_step(s, i, clip, acts) for i, s in enumerate(script)), loop=loop,
                       start_m=_vec(d, "start_m", w, 2, (0.0, 0.0)), subject_id=_str(d, "id", w, "subject"),
                       clip_fps=_num(d, "clip_fps", w, positive=True, hi=120) if "clip_fps" in d else None,
                       facing_rad=math.radians(_num(d, "facing_deg", w, 180.0)))


def parse_scene(doc: Any, path: Path | None = None, subject: str | None = None) -> Scene:
    """Validate a scene document (the YAML's mapping); `subject` swaps in another library person."""
    if not isinstance(doc, dict):
        raise SceneError("scene: the file must contain a mapping at the top level")
    _known(doc, "scene", {"name", "description", "seed", "camera", "vehicle", "limits", "ground", "layers",
                          "subject", "world", "objects"})
    world = _str(doc, "world", "scene", "2.5d", WORLDS)
    name = _str(doc, "name", "scene", path.stem if path else "scene")
    seed = doc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise SceneError(f"scene.seed: must be an integer, got {seed!r}")
    try:
        limits = DynamicsLimits.from_dict(_dict(doc, "limits", "scene"))
    except (TypeError, ValueError) as e:
        raise SceneError(str(e)) from None
    g = _dict(doc, "ground", "scene")
    ground = None
    if g:
        _known(g, "ground", {"texture", "m_per_px", "z_m", "extent_m"})
        gtex = _str(g, "texture", "ground")
        if gtex in _procedural() and world != "3d":
            raise SceneError(f"ground.texture: the procedural texture {gtex!r} needs `world: 3d`")
        ground = GroundSpec(texture=gtex if world == "3d" and gtex in _procedural() else _asset(gtex, "ground.texture"),
                            m_per_px=_num(g, "m_per_px", "ground", positive=True), z_m=_num(g, "z_m", "ground", 0.0),
                            extent_m=_num(g, "extent_m", "ground", 400.0, positive=True))
    layers = doc.get("layers", [])
    if not isinstance(layers, list):
        raise SceneError("scene.layers: must be a list")
    return Scene(name=name, description=str(doc.get("description", "")), seed=seed,
                 camera=_parse_camera(_dict(doc, "camera", "scene")),
                 vehicle=_parse_vehicle(_dict(doc, "vehicle", "scene", required=True)),
                 limits=limits, ground=ground,
                 layers=tuple(_parse_layer(d, i) for i, d in enumerate(layers)),
                 subject=_parse_subject(_dict(doc, "subject", "scene", required=True), subject), path=path,
                 world=world, objects=_parse_objects(doc.get("objects", []), world))


def _parse_object(d: Any, i: int) -> ObjectSpec:
    from cinetransfer.services.autopilot_bridge.sim import textures

    w = f"objects[{i}]"
    if not isinstance(d, dict):
        raise SceneError(f"{w}: must be a mapping")
    _known(d, w, {"name", "kind", "position_m", "size_m", "yaw_deg", "texture", "period_m", "crown_m", "path_m",
                  "speed_mps"})
    kind = _str(d, "kind", w, choices=OBJECT_KINDS)
    size = _vec(d, "size_m", w, 3)
    if min(size[0], size[2]) <= 0 or size[1] < 0 or (kind == "box" and size[1] <= 0):
        raise SceneError(f"{w}.size_m: lengths must be > 0, got {list(size)}")
    path = d.get("path_m", [])
    if not isinstance(path, list):
        raise SceneError(f"{w}.path_m: must be a list of [x, y] waypoints")
    pts = tuple(_vec({"p": p}, "p", f"{w}.path_m[{k}]", 2) for k, p in enumerate(path))
    crown = _vec(d, "crown_m", w, 2, (2.5, 3.0) if kind == "tree" else (0.0, 0.0))
    return ObjectSpec(name=_str(d, "name", w, f"object{i}"), kind=kind, position_m=_vec(d, "position_m", w, 2),
                      size_m=size, yaw_rad=math.radians(_num(d, "yaw_deg", w, 0.0)),
                      texture=_str(d, "texture", w, "bark" if kind == "tree" else "stone", textures.NAMES),
                      period_m=_num(d, "period_m", w, 1.0, positive=True), crown_m=crown, path_m=pts,
                      speed_mps=_num(d, "speed_mps", w, 0.5 if pts else 0.0, lo=0.0, hi=10.0))


def _parse_objects(objs: Any, world: str) -> tuple[ObjectSpec, ...]:
    if not isinstance(objs, list):
        raise SceneError("scene.objects: must be a list")
    if objs and world != "3d":
        raise SceneError("scene.objects: solid objects need `world: 3d`")
    return tuple(_parse_object(d, i) for i, d in enumerate(objs))


def scene_names() -> list[str]:
    """Names of the bundled scenes."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.yaml"))


def _scene_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if not p.suffix:
        cand = SCENES_DIR / f"{name_or_path}.yaml"
        if not cand.is_file():
            raise SceneError(f"scene {name_or_path!r} not found; bundled scenes: {scene_names()}")
        p = cand
    if not p.is_file():
        raise SceneError(f"scene file {p} not found")
    return p


def _read_doc(p: Path, seen: tuple[Path, ...] = ()) -> Any:
    """A scene file's mapping; `extends: NAME` starts from another scene's and replaces its top-level keys."""
    try:
        doc = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise SceneError(f"{p}: not valid YAML: {e}") from None
    if not isinstance(doc, dict) or "extends" not in doc:
        return doc
    base = _str(doc, "extends", "scene")
    bp = _scene_path(base if not Path(base).suffix else p.parent / base)
    if bp in seen or bp == p:
        raise SceneError(f"{p.name}: scene.extends: {base!r} extends itself")
    parent = _read_doc(bp, (*seen, p))
    if not isinstance(parent, dict):
        raise SceneError(f"{p.name}: scene.extends: {base!r} is not a scene mapping")
    return {**parent, **{k: v for k, v in doc.items() if k != "extends"}}


def load_scene(name_or_path: str | Path, subject: str | None = None) -> Scene:
    """A bundled scene by name ('lawn_juggler') or a scene file by path; `subject`: another
    person from the library in place of the scene's own (see subject_names())."""
    p = _scene_path(name_or_path)
    doc = _read_doc(p)
    try:
        return parse_scene(doc, p, subject)
    except SceneError as e:
        raise SceneError(f"{p.name}: {e}") from None


def with_vehicle(scene: Scene, vehicle: VehicleProfile) -> Scene:
    """`scene` flown by `vehicle` (shared/vehicle.py): its limits (the scene's `limits:` keeps only
    the simulated autopilot's time constants and gains) and its camera sensor. The rendered image
    keeps the scene's size."""
    camera = dataclasses.replace(scene.camera, sensor_width_mm=vehicle.camera.sensor_width_mm,
                              sensor_height_mm=vehicle.camera.sensor_height_mm, coc_mm=vehicle.camera.coc_mm)
    return dataclasses.replace(scene, limits=DynamicsLimits.from_vehicle(vehicle, scene.limits), camera=camera)
