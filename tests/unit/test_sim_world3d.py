"""The simulator's 3-D world (renderer3d.py on Mesa EGL): determinism, exact projection, depth of field
from depth with the lens model of shared/camera.py, occlusion truth, and the real detector on each
library person seen from every side."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.sim import dof
from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend
from cinetransfer.services.autopilot_bridge.sim.gl_canvas import SURFACE_SUBJECT, GLCanvas, MeshData
from cinetransfer.services.autopilot_bridge.sim.renderer import View
from cinetransfer.services.autopilot_bridge.sim.scene import load_scene, parse_scene
from cinetransfer.shared import camera as cam
from cinetransfer.shared import messages as M

pytest.importorskip("moderngl")


def _canvas_or_skip(w: int, h: int) -> GLCanvas:
    c = GLCanvas(w, h)
    try:
        c._context()
    except Exception as e:  # noqa: BLE001 - no EGL here: setup.sh names the apt packages
        pytest.skip(f"no EGL context: {e}")
    return c


def _take(scene: str, n: int) -> list[tuple[bytes, np.ndarray]]:
    sim = SimBackend(scene, epoch_ns=0)
    sim.start()
    v = sim.scene.vehicle
    out = []
    for k in range(n):
        t = k / sim.fps
        sim.apply(M.Setpoint(position_m=np.array(v.position_m) + [0.0, 0.4 * t, 0.1 * t],
                             camera_ypr_rad=np.array(v.camera_ypr_rad) + [0.05 * t, 0.0, 0.0],
                             lens=M.LensState(focal_length_mm=v.focal_length_mm + 4 * t, focus_distance_m=6.0,
                                              f_number=2.8)))
        sim.step(t)
        frames, truths = sim.frames(), sim.truths()
        assert [f.index for f in frames] == [k] and [g.frame_index for g in truths] == [k]  # none skipped
        out += [(f.image.tobytes(), g.joints_norm) for f, g in zip(frames, truths)]
    sim.close()
    return out


def test_the_same_take_twice_gives_identical_frames():
    _canvas_or_skip(8, 8).close()
    a, b = _take("courtyard", 6), _take("courtyard", 6)
    assert all(x[0] == y[0] and np.array_equal(x[1], y[1]) for x, y in zip(a, b))
    assert len({x[0] for x in a}) == len(a)  # and the frames do change: the camera moves


@pytest.mark.parametrize("ypr_deg, focal", [((0.0, 0.0, 0.0), 35.0), ((23.0, -11.0, 7.0), 52.0),
                                            ((-140.0, 18.0, -12.0), 28.0)])
def test_a_point_lands_on_the_pixel_the_camera_model_names(ypr_deg, focal):
    w, h = 320, 180
    canvas = _canvas_or_skip(w, h)
    sensor = cam.Sensor(23.76, 13.365)
    pos = np.array([1.0, -2.0, 1.5])
    ypr = np.radians(ypr_deg)
    r = cam.rotation_ypr(*ypr)
    for k in range(6):
        # a world point, and a quad in its camera-facing plane whose top-left corner is the point
        pc = np.array([4.0 + k, 0.3 * math.sin(k) - 0.2, 0.25 * math.cos(1.7 * k)])
        p = pos + r @ pc
        right, down = -r[:, 1], -r[:, 2]
        quad = np.array([p, p + 3 * right, p + 3 * right + 3 * down, p + 3 * down], np.float32)
        mesh = MeshData("probe", quad, np.array([[0, 1, 2], [0, 2, 3]], np.int32), "colour", SURFACE_SUBJECT,
                        colours=np.ones((4, 3), np.float32))
        _, _, surface = canvas.draw([mesh], pos, ypr, focal, sensor)
        u, v = cam.project_world(p, pos, ypr, focal, sensor) * [w, h]
        if min(abs(u % 1 - 0.5), abs(v % 1 - 0.5)) < 0.01:
            continue  # on a pixel centre: the rasteriser's tie rule decides
        rows, cols = np.nonzero(surface == SURFACE_SUBJECT)
        # pixel i is covered when its centre i + 0.5 lies right of / below the projected corner
        assert cols.min() == math.ceil(u - 0.5) and rows.min() == math.ceil(v - 0.5), (u, v)
    canvas.close()


def test_depth_of_field_uses_the_lens_models_blur_circle():
    focal, n, s, sw, w = 50.0, 2.0, 5.0, 23.76, 640
    depth = np.array([[5.0, 40.0, np.inf]], np.float32)
    sig = dof.sigma_px(depth, focal, n, s, sw, w)
    for d, got in zip(depth[0], sig[0]):
        want = cam.SIGMA_PER_DIAMETER * cam.blur_diameter_mm(min(d, 1e12), focal, n, s) / sw * w
        assert got == pytest.approx(want, rel=1e-4, abs=1e-6)
    # a point at the focus distance stays sharp, a far one spreads with that sigma (second moment)
    img = np.zeros((121, 121, 3), np.uint8)
    img[:, 60] = 255  # a line: its spread across is the blur's (a point's would round away in uint8)
    assert np.array_equal(dof.apply_dof(img, np.zeros((121, 121), np.float32)), img)
    for target in (2.0, 4.0, 6.0):
        out = dof.apply_dof(img, np.full((121, 121), target, np.float32))[..., 0].astype(float)
        xx = np.mgrid[0:121, 0:121][1]
        m = out.sum()
        var_x = float(((xx - (out * xx).sum() / m) ** 2 * out).sum() / m)
        assert math.sqrt(var_x) == pytest.approx(target, rel=0.2)


def _contrast(img: np.ndarray) -> np.ndarray:
    g = img.astype(float).mean(axis=2)
    out = np.zeros_like(g)
    out[:-1, :-1] = np.abs(np.diff(g, axis=1))[:-1] + np.abs(np.diff(g, axis=0))[:, :-1]
    return out


def test_the_rendered_frame_is_sharp_at_the_focus_distance_and_blurred_beyond():
    _canvas_or_skip(8, 8).close()
    sim = SimBackend("courtyard", epoch_ns=0)
    r = sim.renderer
    # a pillar 2.75 m ahead in focus (50 mm f/1.4), the brick building 18 m behind it
    view = View(position_m=np.array([-5.0, 4.5, 1.6]), ypr_rad=np.radians([0.0, 0.0, 0.0]), focal_mm=50.0,
                focus_m=2.75, f_number=1.4, width=r.width, height=r.height, sensor=r.sensor)
    bgr, depth, _, _ = r.draw(view, 0.0)
    img, _ = r.render(view, 0.0)
    sig = dof.sigma_px(depth, view.focal_mm, view.f_number, view.focus_m, view.sensor.width_mm, view.width)
    sharp, far = sig < 0.1, sig > 4.0
    assert sharp.sum() > 2000 and far.sum() > 20000
    # within the depth of field the picture is (nearly) untouched; far behind, its detail is gone
    assert np.abs(img[sharp].astype(int) - bgr[sharp]).mean() < 3.0
    assert _contrast(img)[far].mean() < 0.35 * _contrast(bgr)[far].mean()
    r.close()


WALL_SCENE = """
name: wall_test
world: 3d
camera: {width: 480, height: 270, fps: 24}
vehicle:
  position_m: [-8.0, 0.0, 1.6]
  camera_ypr_deg: [0.0, -4.0, 0.0]
  lens: {focal_length_mm: 30.0, focus_distance_m: 8.0, f_number: 4.0}
ground: {texture: paving, m_per_px: 0.0025}
objects:
  - {name: wall, kind: box, position_m: [-3.0, 0.0], size_m: [0.3, 3.0, HEIGHT], texture: brick, period_m: 2.0}
subject:
  clip: juggler
  start_m: [0.0, 0.0]
  script:
    - {action: juggle, duration_s: 5.0}
"""


def _wall_truth(height_m: float) -> M.GroundTruth:
    import yaml

    scene = parse_scene(yaml.safe_load(WALL_SCENE.replace("HEIGHT", str(height_m))))
    sim = SimBackend(scene, epoch_ns=0)
    sim.start()
    sim.step(0.0)
    truth = sim.truths()[0]
    sim.close()
    return truth


def test_a_wall_between_camera_and_person_hides_the_joints_behind_it():
    _canvas_or_skip(8, 8).close()
    tall, low = _wall_truth(2.5), _wall_truth(1.1)
    # a tall wall: every joint projects into the frame but is hidden, and no subject region is seen
    assert not tall.joints_visible.any()
    assert not tall.region_present[1]
    # a wall up to the hips hides the legs (knees, ankles) and leaves the head and shoulders visible
    names = list(M.COCO17_NAMES)
    vis = dict(zip(names, low.joints_visible))
    assert not any(vis[j] for j in ("left_knee", "right_knee", "left_ankle", "right_ankle"))
    assert all(vis[j] for j in ("nose", "left_shoulder", "right_shoulder"))
    assert low.region_present[1]


def test_the_subjects_heading_follows_its_walk():
    sim = SimBackend(load_scene("courtyard"), epoch_ns=0, render=False, truth=False)
    sim.start()
    sim.step(0.0)
    sim.step(1.0)  # walking from (0, -2) to (0, 2): facing +y
    assert sim.subject_heading_rad() == pytest.approx(math.pi / 2, abs=1e-6)
    st = sim.subject_state()
    assert st.joints_m.shape == (17, 3) and np.isfinite(st.joints_m).all()


def _orbit_frames(person: str, views: int, w: int, h: int):
    """(image, truth joints) of `person` standing in open country, seen from `views` directions round them."""
    from cinetransfer.services.autopilot_bridge.sim.scene import subject_info

    info = subject_info(person)
    scene = load_scene("open_country", subject=person)
    sim = SimBackend(scene, width=w, height=h, epoch_ns=0)
    r = sim.renderer
    for k in range(views):
        t = 0.37 * k
        body = r.body_at(t)
        root = body.pose.position_m
        ang = 2 * math.pi * k / views
        dist = 5.0
        pos = root + [dist * math.cos(ang), dist * math.sin(ang), 1.3]
        target = root + [0.0, 0.0, 0.5 * float(info.get("height_m", 1.75))]
        d = target - pos
        ypr = np.array([math.atan2(d[1], d[0]), math.atan2(d[2], math.hypot(d[0], d[1])), 0.0])
        view = View(position_m=pos, ypr_rad=ypr, focal_mm=24.0, focus_m=dist, f_number=8.0, width=w, height=h,
                    sensor=r.sensor)
        img, geo = r.render(view, t)
        yield img, geo
    r.close()


@pytest.mark.slow
@pytest.mark.parametrize("person", ["juggler", "dancer", "runner", "walker"])
def test_each_person_is_detected_once_from_front_side_and_back(pose_detector, person):
    _canvas_or_skip(8, 8).close()
    pose_detector.reset()
    visible, found, once = 0, 0, 0
    for k, (img, geo) in enumerate(_orbit_frames(person, 24, 640, 360)):
        if geo["joints_visible"].sum() < 12:
            continue
        visible += 1
        m = pose_detector.process(img, k, k * 41_666_667 + 1)
        h, w = img.shape[:2]
        hits = [sk for sk in m.skeletons
                if np.nanmedian(np.linalg.norm(sk.keypoints_px / [w, h] - geo["joints_norm"], axis=1)) < 0.1]
        found += len(hits) >= 1
        once += len(m.people) == 1 and len(hits) == 1
    assert visible >= 20
    assert found >= 0.95 * visible, f"{person}: found in {found}/{visible} views"
    # exactly one person: measured 24/24 for every person (the dancer's two views with a second box
    # nested in hers, arms raised, both skeletons on her, were 22/24 before duplicate removal looked at
    # nested boxes)
    assert once >= 0.95 * visible, f"{person}: detected as exactly one person in {once}/{visible} views"


def _views_round(scene, n: int) -> list[View]:
    v = scene.vehicle
    return [View(np.array(v.position_m, float) + [0.5 * k, -0.3 * k, 0.2 * k],
                 np.array(v.camera_ypr_rad, float) + np.radians([7.0 * k - 10.0, -2.0 * k, 0.0]),
                 v.focal_length_mm + 5.0 * k, 6.0, 2.8, 320, 180) for k in range(n)]


@pytest.mark.parametrize("scene_name", ["open_country", "focus_hedge"])
def test_a_frame_drawn_for_its_truth_alone_has_the_pictures_depths_and_surfaces(scene_name):
    """The truth of a frame without its picture (pre-roll, settle, idle) is a depth-only draw: no
    shading and no texture but a cut-out's alpha; its depths, surface ids and truth are the colour
    draw's to the bit, cut-outs included."""
    from cinetransfer.services.autopilot_bridge.sim.renderer3d import WorldRenderer

    _canvas_or_skip(8, 8).close()
    r = WorldRenderer(load_scene(scene_name), 320, 180)
    try:
        views = _views_round(r.scene, 4)
        assert any(m.alpha for m in r.meshes(views[0], r.body_at(0.0), 0.0))  # a cut-out is drawn
        for k, view in enumerate(views):
            t = 0.4 * k
            bgr, depth, surface, _ = r.draw(view, t)
            none, depth_only, surface_only, _ = r.draw(view, t, colour=False)
            assert none is None and bgr is not None
            assert np.array_equal(depth, depth_only) and np.array_equal(surface, surface_only)
            _, geo = r.render(view, t)
            alone = r.truth_only(view, t)
            assert alone.keys() == geo.keys()
            for name, value in geo.items():
                if isinstance(value, np.ndarray):
                    assert np.array_equal(value, alone[name], equal_nan=value.dtype.kind == "f"), name
        assert len({s.tobytes() for s in [r.draw(v, 0.0, colour=False)[2] for v in views]}) > 1  # views differ
    finally:
        r.close()


def test_the_subjects_joints_alone_are_the_skinned_bodys():
    """The subject's state and the report's floor pose the joints without skinning the mesh: the same
    float numbers as the whole body's."""
    from cinetransfer.services.autopilot_bridge.sim.actor import Actor

    spec = load_scene("courtyard").subject
    whole, alone = Actor(spec), Actor(spec)
    for t in np.arange(0.0, 12.0, 0.37):
        a, b = whole.body_at(float(t)).joints_m, alone.joints_at(float(t))
        assert a.dtype == b.dtype and np.array_equal(a, b)
