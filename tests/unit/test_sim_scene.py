"""Built-in simulator: scene files load and validate with clear errors (sim/scene.py)."""
from __future__ import annotations

import copy

import pytest
import yaml

from cinetransfer.services.autopilot_bridge.sim.scene import (SCENES_DIR, SceneError, load_scene, parse_scene,
                                                              scene_names)


def base_doc() -> dict:
    return yaml.safe_load((SCENES_DIR / "lawn_juggler.yaml").read_text())


def test_bundled_scenes_load():
    names = scene_names()
    assert {"lawn_juggler", "open_country", "focus_hedge"} <= set(names)
    for n in names:
        s = load_scene(n)
        assert s.name == n
        assert s.subject.script and s.camera.width > 0 and s.ground is not None
        assert any(layer.region == "sky" for layer in s.layers)
    focus = load_scene("focus_hedge")
    assert any(layer.region == "foreground" for layer in focus.layers)


def test_load_by_path(tmp_path):
    p = tmp_path / "mine.yaml"
    doc = base_doc()
    doc["name"] = "mine"
    doc["camera"] = {"width": 1280, "height": 720, "fps": 30}
    p.write_text(yaml.safe_dump(doc))
    s = load_scene(p)
    assert (s.name, s.camera.width, s.camera.fps) == ("mine", 1280, 30.0)


@pytest.mark.parametrize("mutate,message", [
    (lambda d: d.pop("vehicle"), r"vehicle: required"),
    (lambda d: d.__setitem__("colour", 1), r"unknown field\(s\) \['colour'\]"),
    (lambda d: d["vehicle"].__setitem__("position_m", [1, 2]), r"vehicle.position_m: must be a list of 3"),
    (lambda d: d["vehicle"]["lens"].__setitem__("focal_length_mm", -5), r"vehicle.lens.focal_length_mm: must be > 0"),
    (lambda d: d["vehicle"]["lens"].__setitem__("f_number", float("nan")), r"f_number: must be a finite number"),
    (lambda d: d["subject"]["script"].append({"action": "dance", "duration_s": 1}),
     r"subject.script\[2\].action: subject 'juggler' has no action 'dance'; its actions: \['juggle', 'stand'\]"),
    (lambda d: d["subject"]["script"].append({"action": "sit", "duration_s": 1}),
     r"subject.script\[2\].action: must be one of \['stand', 'walk', 'run'"),
    (lambda d: d["subject"].update(clip="walker", script=[{"action": "walk"}]), r"path_m: a walk needs"),
    (lambda d: d["subject"].__setitem__("script", []), r"subject.script: required"),
    (lambda d: d["subject"].__setitem__("clip", "nobody"), r"subject.clip: asset file .*nobody.json not found"),
    (lambda d: d["layers"][1].__setitem__("texture", "missing.png"), r"layers\[1\].texture: asset file"),
    (lambda d: d["layers"][1].__setitem__("region", "middle"), r"layers\[1\].region: must be one of"),
    (lambda d: d["layers"][1].pop("extent_m"), r"layers\[1\].extent_m: required when wrap is 'reflect'"),
    (lambda d: d.__setitem__("limits", {"speed_max_mps": 0}), r"speed_max_mps: must be > 0"),
    (lambda d: d["camera"].__setitem__("fps", 0), r"camera.fps: must be >= 1"),
    (lambda d: d.__setitem__("seed", "x"), r"scene.seed: must be an integer"),
])
def test_bad_scenes_are_refused_with_the_field_named(mutate, message):
    doc = copy.deepcopy(base_doc())
    mutate(doc)
    with pytest.raises(SceneError, match=message):
        parse_scene(doc)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(SceneError, match="bundled scenes"):
        load_scene("no_such_scene")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed")
    with pytest.raises(SceneError, match="not valid YAML"):
        load_scene(bad)
    top = tmp_path / "list.yaml"
    top.write_text("- 1\n- 2\n")
    with pytest.raises(SceneError, match="mapping at the top level"):
        load_scene(top)
