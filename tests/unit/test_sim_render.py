"""Built-in simulator: renderer geometry, thin-lens blur, ground truth, backend (sim/renderer.py, backend.py)."""
from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.sim.backend import SceneRenderer, SimBackend, load_scene
from cinetransfer.services.autopilot_bridge.sim.renderer import Plane, Texture, View, draw_plane, label_pass, upsample2
from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.services.detector.focus import FocusEstimator
from cinetransfer.shared import camera as cam
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M


def facing_plane(tex: np.ndarray, distance_m: float, m_per_px: float, name: str = "p") -> Plane:
    """A plane facing a camera at the origin that looks along +x, texture centre on the axis."""
    h, w = tex.shape[:2]
    right = np.array([0.0, -1.0, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    base = np.array([distance_m, 0.0, 0.0])
    a = np.column_stack([m_per_px * right, -m_per_px * up, base - w / 2 * m_per_px * right + h / 2 * m_per_px * up])
    st = np.array([[0, h, 1], [w, h, 1], [w, 0, 1], [0, 0, 1]], float)
    return Plane(name, Texture.from_bgra(tex), a, st @ a.T, "background")


def view(**kw) -> View:
    d = dict(position_m=np.zeros(3), ypr_rad=np.zeros(3), focal_mm=50.0, focus_m=10.0, f_number=2.0,
             width=960, height=540)
    d.update(kw)
    return View(**d)


def edge_width_10_90(row: np.ndarray) -> float:
    """10-90 % rise width [px] of a monotonic dark-to-bright edge profile."""
    r = (row - row.min()) / (row.max() - row.min())
    x = np.arange(len(r), dtype=float)
    return float(np.interp(0.9, r, x) - np.interp(0.1, r, x))


@pytest.mark.parametrize("distance_m", [10.0, 7.0, 5.0, 3.0, 2.0])
def test_a_plane_is_blurred_by_the_circle_of_confusion_the_lens_model_predicts(distance_m):
    # given a black/white step edge on a plane, focus at 10 m, 50 mm f/2
    tex = np.zeros((400, 400, 3), np.uint8)
    tex[:, 200:] = 255
    v = view()
    canvas = np.zeros((540, 960, 3), np.uint8)
    # (one texel = one pixel at any distance: 50 mm on a 960 px wide 23.76 mm sensor)
    info = draw_plane(canvas, v, facing_plane(tex, distance_m, m_per_px=distance_m / 2020.0))
    # when measuring the edge's rise width across the image centre
    c_px = cam.blur_diameter_mm(distance_m, 50.0, 2.0, 10.0) / cam.SENSOR_WIDTH_MM * 960
    assert info.coc_px == pytest.approx(c_px, rel=1e-9)
    row = canvas[270, 380:580, 1].astype(float)
    width = edge_width_10_90(row)
    # then a Gaussian with sigma = c/4 (the blur disc's second moment): 10-90 % width 2.563 sigma
    expected = 2.563 * c_px / 4
    if c_px < 1.5:
        assert width < 2.0  # sharp: inside the depth of field the edge stays within ~1-2 px
    else:
        assert width == pytest.approx(expected, rel=0.2, abs=0.8)


def test_blur_grows_with_the_circle_of_confusion_laplacian_variance():
    tex = np.random.default_rng(0).integers(0, 255, (300, 300, 3), dtype=np.uint8)
    v = view(focus_m=4.0, f_number=2.8)
    sharpness = []
    for d in (4.0, 6.0, 10.0, 30.0):
        canvas = np.zeros((540, 960, 3), np.uint8)
        draw_plane(canvas, v, facing_plane(tex, d, m_per_px=d / 2020.0))
        crop = canvas[200:340, 400:560].astype(np.float32)
        sharpness.append(cv2.Laplacian(crop, cv2.CV_32F).var())
    # strictly decreasing sharpness as the plane leaves the depth of field
    assert all(a > 1.5 * b for a, b in zip(sharpness, sharpness[1:])), sharpness


def test_homography_puts_a_texel_where_project_world_puts_its_world_point():
    tex = np.zeros((100, 120, 3), np.uint8)
    tex[39:42, 59:62] = 255  # 3x3 dot centred on texel (60, 40)
    plane = facing_plane(tex, 8.0, m_per_px=0.01)
    # a camera somewhere else, with yaw, pitch and roll
    v = view(position_m=np.array([0.5, 0.3, -0.2]), ypr_rad=np.array([0.05, -0.03, 0.1]), focal_mm=80.0,
             focus_m=7.5, f_number=16.0)
    canvas = np.zeros((540, 960, 3), np.uint8)
    draw_plane(canvas, v, plane)
    g = canvas[..., 0].astype(float)
    ys, xs = np.nonzero(g > 1)
    w = g[ys, xs]
    centroid = np.array([(xs * w).sum() / w.sum(), (ys * w).sum() / w.sum()])
    world = plane.a @ np.array([60.5, 40.5, 1.0])  # texel centre, continuous coordinates
    uv = cam.project_world(world, v.position_m, v.ypr_rad, v.focal_mm)
    expected_px = uv * [960, 540] - 0.5  # pixel index of a normalised position
    np.testing.assert_allclose(centroid, expected_px, atol=0.3)


def _setpoint(p, ypr, focal=float("nan"), focus=float("nan"), fnum=float("nan")) -> M.Setpoint:
    return M.Setpoint(position_m=np.asarray(p, float), camera_ypr_rad=np.asarray(ypr, float),
                      lens=M.LensState(focal_length_mm=focal, focus_distance_m=focus, f_number=fnum))


def test_ground_truth_joints_are_project_world_of_the_subject_state_and_match_the_drawn_person():
    sim = SimBackend("lawn_juggler_25d", epoch_ns=0, width=480, height=270)
    sim.start()
    p0 = np.array(sim.scene.vehicle.position_m)
    sim.apply(_setpoint(p0 + [1.0, 1.5, 0.3], [-0.2, -0.1, 0.05], focal=45.0))
    for k in range(13):
        sim.step(k / 24)
    frames, truths = sim.frames(), sim.truths()
    assert len(frames) == len(truths) == 13
    vs, ss = sim.vehicle_state(), sim.subject_state()
    gt, fr = truths[-1], frames[-1]
    expected = cam.project_world(ss.joints_m, vs.position_m, vs.camera_ypr_rad, fr.lens.focal_length_mm)
    np.testing.assert_allclose(gt.joints_norm, expected, atol=1e-6)
    assert gt.joints_visible.all()
    # the drawn person covers the projected hips and shoulders (alpha of the person layer)
    planes, _ = sim.renderer.planes(sim.view(), sim.sim_time_s)
    depth, subj = label_pass(sim.view(), planes, scale=1.0)
    for j in (5, 6, 11, 12):  # shoulders, hips
        u, v = gt.joints_norm[j]
        assert subj[int(v * 270), int(u * 480)], M.COCO17_NAMES[j]
    # distance along the optical axis
    d = cam.world_to_camera(ss.joints_m, vs.position_m, vs.camera_ypr_rad)[:, 0].mean()
    assert gt.subject_distance_m == pytest.approx(d, rel=1e-6)


def test_frames_come_at_the_camera_rate_with_lens_and_aligned_truths_and_survive_the_codec():
    sim = SimBackend("focus_hedge_25d", epoch_ns=1_000_000_000, width=320, height=180)
    sim.start()
    sim.step(10.0)  # the first call sets time zero
    sim.step(11.0)
    frames, truths = sim.frames(), sim.truths()
    assert [f.index for f in frames] == list(range(25))  # 0 .. 24 at 24 fps over 1 s
    assert [t.frame_index for t in truths] == list(range(25))
    assert all(f.stamp_ns == t.stamp_ns == 1_000_000_000 + round(f.index / 24 * 1e9) for f, t in zip(frames, truths))
    f = frames[3]
    assert f.image.shape == (180, 320, 3) and f.image.dtype == np.uint8 and f.fps == 24.0
    assert f.source == "sim:focus_hedge_25d"
    assert f.lens.sensor_width_mm == cam.SENSOR_WIDTH_MM and f.lens.coc_mm == cam.COC_MM
    assert f.lens.focal_length_mm == pytest.approx(35.0)
    for msg in (f, truths[3], sim.vehicle_state(), sim.subject_state()):
        back = codec.decode(codec.encode(msg), type(msg))
        assert type(back) is type(msg)
    assert sim.frames() == [] and sim.truths() == []


def test_same_calls_give_the_same_frames():
    def run() -> list[np.ndarray]:
        sim = SimBackend("open_country_25d", epoch_ns=0, width=320, height=180)
        sim.start()
        p0 = np.array(sim.scene.vehicle.position_m)
        out = []
        for k in range(6):
            sim.apply(_setpoint(p0 + [0.2 * k, 0, 0], [0.2, -0.1, 0.0], focal=40.0 + k))
            sim.step(k / 12)
            out += [f.image for f in sim.frames()]
        return out
    a, b = run(), run()
    assert len(a) == len(b) > 0
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_hold_setpoint_and_vehicle_state_modes():
    sim = SimBackend("lawn_juggler", epoch_ns=0, render=False, truth=False)
    sim.start()
    sim.step(0.0)
    p0 = np.array(sim.scene.vehicle.position_m)
    sim.apply(_setpoint(p0 + [10, 0, 0], sim.scene.vehicle.camera_ypr_rad))
    sim.step(3.0)
    vs = sim.vehicle_state()
    assert vs.mode == "sim" and vs.backend == "sim" and not vs.holding and vs.armed
    assert vs.velocity_mps[0] > 1.0
    sim.apply(M.Setpoint(mode="hold"))
    sim.step(8.0)
    vs = sim.vehicle_state()
    assert vs.mode == "HOLD" and vs.holding
    assert np.linalg.norm(vs.velocity_mps) < 0.01
    sim.apply(_setpoint(p0, sim.scene.vehicle.camera_ypr_rad))
    assert sim.vehicle_state().mode == "sim"


def test_simulated_time_runs_faster_than_real_time_without_rendering():
    import time

    sim = SimBackend("lawn_juggler", epoch_ns=0, render=False, truth=False)
    sim.start()
    t0 = time.process_time()  # CPU of every thread, not wall: load must not fail it
    for k in range(24 * 60):  # one simulated minute at 24 fps
        sim.step(k / 24)
    assert time.process_time() - t0 < 30.0
    assert len(sim.frames()) == 24 * 60


@pytest.mark.parametrize("focus_m,expected", [(3.0, [True, False, False]), (7.0, [False, True, False]),
                                              (50.0, [False, False, True])])
def test_region_focus_ground_truth_in_the_focus_scene(focus_m, expected):
    # hedge 3 m from the camera, subject at 7 m, trees 37 m away: 35 mm at f/1 (with the circle of
    # confusion where the focus estimator flips, 0.134 mm, f/2 keeps the subject sharp focused at 3 m)
    sim = SimBackend("focus_hedge_25d", epoch_ns=0, width=480, height=270)
    sim.start()
    sim.dyn.focus_m, sim.dyn.f_number = focus_m, 1.0
    sim.dyn.sp_lens = (sim.dyn.focal_mm, focus_m, 1.0)
    sim.step(0.0)
    gt = sim.truths()[0]
    assert gt.region_present.all()
    assert list(gt.region_in_focus) == expected, gt.region_focus_fraction
    near, far = cam.dof_limits_m(35.0, 1.0, focus_m)
    assert gt.dof_near_m == pytest.approx(near)
    assert (math.isnan(gt.dof_far_m) and math.isinf(far)) or gt.dof_far_m == pytest.approx(far)


def test_truth_carries_each_regions_depths_the_focal_length_and_the_lens_range():
    # given the focus scene: hedge 3 m from the camera, subject at 7 m, trees 37 m away and the sky
    sim = SimBackend("focus_hedge_25d", epoch_ns=0, width=480, height=270)
    sim.start()
    sim.step(0.0)
    gt = codec.decode(codec.encode(sim.truths()[0]), M.GroundTruth)
    lim = sim.scene.limits
    # then the report has what it needs to tell which labels any lens could give
    assert gt.focal_length_mm == pytest.approx(35.0)
    assert list(gt.lens_limits) == pytest.approx([lim.focus_distance_min_m, lim.focus_distance_max_m, lim.f_number_min,
                                                  lim.f_number_max])
    inv = gt.region_inverse_depth
    assert inv.shape == (3, 20) and np.isfinite(inv).all()
    assert np.median(1 / inv[0]) == pytest.approx(3.0, rel=0.05)  # the hedge
    assert np.median(1 / inv[1]) == pytest.approx(gt.subject_distance_m, rel=0.05)
    assert np.median(1 / inv[2]) == pytest.approx(37.0, rel=0.05)  # the trees
    assert (inv >= 0).all()  # 0 = the sky
    # and a truth of schema version 1 (no depths) still decodes, with nothing recorded
    old = M.GroundTruth(frame_index=1)
    assert old.lens_limits.shape == (0,) and old.region_inverse_depth.shape == (3, 0)


def test_subject_is_sharper_in_focus_than_out_of_focus_in_a_rendered_scene():
    lap = {}
    for focus_m in (7.0, 3.0):
        sim = SimBackend("focus_hedge_25d", epoch_ns=0)
        sim.start()
        sim.dyn.focus_m = focus_m
        sim.dyn.sp_lens = (sim.dyn.focal_mm, focus_m, sim.dyn.f_number)
        sim.step(0.0)
        fr, gt = sim.frames()[0], sim.truths()[0]
        u = gt.joints_norm[[5, 6, 11, 12], 0] * 960
        v = gt.joints_norm[[5, 6, 11, 12], 1] * 540
        crop = fr.image[int(v.min()):int(v.max()), int(u.min()):int(u.max())]
        lap[focus_m] = cv2.Laplacian(cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY), cv2.CV_32F).var()
    assert lap[7.0] > 3 * lap[3.0], lap


def test_walk_moves_the_subject_at_its_speed_and_an_in_place_action_stays():
    scene = load_scene("open_country", subject="walker")  # walker: walk (0, 1.5) -> (0, -1.5) and back
    sim = SimBackend(scene, epoch_ns=0, render=False, truth=False)
    sim.start()
    sim.step(0.0)
    sim.step(0.5)
    ss = sim.subject_state()
    speed = scene.subject.script[0].speed_mps
    assert np.linalg.norm(ss.velocity_mps) == pytest.approx(speed)
    dancer = SimBackend(load_scene("open_country"), epoch_ns=0, render=False, truth=False)
    dancer.start()
    dancer.step(0.0)
    dancer.step(2.0)
    assert np.linalg.norm(dancer.subject_state().velocity_mps) == 0.0


def test_step_at_a_frame_time_within_rounding_never_goes_back():
    # given a step that lands 1e-10 s before a frame time (the frame is taken, then the clock
    # would move back by 1e-10 s): no error, time stays monotonic
    from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend, load_scene

    sim = SimBackend(load_scene("lawn_juggler_25d"), epoch_ns=0)
    sim.start()
    sim.step(0.0)
    sim.step(1.0 / sim.fps - 1e-10)
    sim.step(1.0 / sim.fps)
    assert len(sim.frames()) >= 2


def test_async_rendering_gives_the_same_frames_in_order():
    # given the same flight stepped with synchronous and with worker-thread rendering
    import time as _time

    from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend, load_scene

    def fly(async_render: bool):
        sim = SimBackend(load_scene("focus_hedge_25d"), epoch_ns=0, async_render=async_render)
        sim.start()
        frames, truths = [], []
        for i in range(13):
            sim.step(i / 24.0)
            frames += sim.frames()
            truths += sim.truths()
        deadline = _time.monotonic() + 120  # a ceiling for a hang: renders on a loaded machine take their time
        while len(frames) < 13 - sim.frames_skipped and _time.monotonic() < deadline:
            _time.sleep(0.01)
            frames += sim.frames()
            truths += sim.truths()
        sim.close()
        return frames, truths, sim.frames_skipped

    f_sync, t_sync, _ = fly(False)
    f_async, t_async, skipped = fly(True)
    # then every frame that was not skipped is identical, in order, with its own truth
    assert len(f_sync) == 13 and len(f_async) == 13 - skipped and len(t_async) == len(f_async)
    by_index = {f.index: f for f in f_sync}
    assert [f.index for f in f_async] == sorted(f.index for f in f_async)
    for f, t in zip(f_async, t_async):
        assert t.frame_index == f.index
        assert np.array_equal(f.image, by_index[f.index].image)


def _contrast(row: np.ndarray, cycles_per_px: float) -> float:
    """Amplitude of the sinusoid of a given frequency in a row of pixels (any phase)."""
    x = np.arange(len(row))
    r = row - row.mean()
    return float(2 * np.hypot((r * np.cos(2 * np.pi * cycles_per_px * x)).mean(),
                              (r * np.sin(2 * np.pi * cycles_per_px * x)).mean()))


@pytest.mark.parametrize("border", [cv2.BORDER_CONSTANT, cv2.BORDER_REFLECT_101, cv2.BORDER_WRAP])
def test_level_minus_one_holds_the_texels_and_the_lanczos_points_between_them(border):
    tex = cv2.GaussianBlur(np.random.default_rng(3).integers(0, 255, (40, 60, 4), dtype=np.uint8), (0, 0), 1.0)
    tex[..., 3] = 255
    up = upsample2(tex, border)
    assert up.shape == (79, 119, 4)
    np.testing.assert_array_equal(up[::2, ::2], tex)
    # the points between: what OpenCV's own Lanczos-4 resampling gives at texel j / 2 (same border)
    p = 4
    padded = cv2.copyMakeBorder(tex, p, p, p, p, border, value=0)
    ref = cv2.warpAffine(padded, np.array([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0]]), (2 * 68 - 1, 2 * 48 - 1),
                         flags=cv2.INTER_LANCZOS4, borderMode=border)[2 * p:-2 * p, 2 * p:-2 * p]
    assert np.abs(up.astype(int) - ref).max() <= 1


def test_level_minus_one_of_a_hard_cut_out_keeps_colour_within_alpha():
    tex = np.zeros((60, 60, 4), np.uint8)
    cv2.circle(tex, (30, 30), 20, (255, 255, 255, 255), -1)  # hard edge: Lanczos rings on it
    up = Texture.from_bgra(tex).magnified
    assert (up[..., :3] <= up[..., 3:]).all()


@pytest.mark.parametrize("cycles_per_texel", [0.1, 0.3, 0.4])
def test_a_magnified_texture_keeps_its_contrast_and_gains_none(cycles_per_texel):
    # vertical stripes on a plane in focus, one texel = 1.6 px (magnified, as the juggler seen close)
    x = np.arange(300)
    stripes = np.clip(128 + 100 * np.cos(2 * np.pi * cycles_per_texel * x), 0, 255).astype(np.uint8)
    tex = np.repeat(np.repeat(stripes[None, :, None], 200, axis=0), 3, axis=2)
    canvas = np.zeros((540, 960, 3), np.uint8)
    info = draw_plane(canvas, view(), facing_plane(tex, 10.0, m_per_px=10.0 / 2020.0 * 1.6))
    assert info.level == -1 and info.coc_px == 0.0
    kept = _contrast(canvas[270, 300:660, 1].astype(float), cycles_per_texel / 1.6) / 100
    # bilinear straight from the texture kept 0.97 / 0.74 / 0.57 (any magnification)
    assert {0.1: 0.975, 0.3: 0.9, 0.4: 0.72}[cycles_per_texel] < kept < 1.02


def test_the_juggler_seen_close_and_in_focus_reads_in_focus_to_the_detector():
    # the focus_hedge juggler at 7 m through 70 mm: his cut-out magnified ~1.7x (tos_clip01's
    # second shot); bilinear magnification read 0.45-0.6 of his pixels in focus in that transfer
    rr = SceneRenderer(load_scene("focus_hedge_25d"))
    v = View(np.array([-7.0, 0.0, 1.0]), np.array([0.0, math.atan2(0.3, 7.0), 0.0]), 70.0, 7.0, 4.0,
             960, 540, rr.sensor)
    img, _ = rr.render(v, 0.0, truth=False)
    subject = next(d for d in rr.last_draw if d.name == "subject")
    assert subject.level == -1 and subject.coc_px < 1.0
    planes, _ = rr.planes(v, 0.0)
    _, mask = label_pass(v, planes, scale=0.5)
    res = FocusEstimator(DetectorConfig()).estimate(img, person_mask=mask)
    m = cv2.resize(mask.astype(np.uint8), res.prob.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    assert (res.prob[m] >= 0.5).mean() > 0.65  # 0.74 (bilinear: 0.55)


def test_a_layer_behind_the_person_seen_obliquely_is_drawn_before_him():
    """lawn_juggler's backdrop (x = 21.9 m, 160 m wide) seen from the start towards a person 14 m to the
    side: its anchor is nearer along the optical axis than he is, but he and the camera are on the same
    side of it, so it is drawn first and does not cover him."""
    sim = SimBackend(load_scene("lawn_juggler_25d"), epoch_ns=0)
    r = sim.renderer
    root = np.array([1.0, -14.0, 0.0])
    r.subject.script.pose_at = lambda t, _p=r.subject.script.pose_at: dataclasses.replace(_p(t), position_m=root)
    c = np.array([-5.5, 0.0, 1.4])
    d = root + [0.0, 0.0, 0.9] - c
    v = dataclasses.replace(sim.view(), position_m=c, ypr_rad=np.array([math.atan2(d[1], d[0]), 0.0, 0.0]),
                            focal_mm=60.0)
    planes, geo = r.planes(v, 0.0)
    names = [p.name for p in planes]
    backdrop = next(p for p in planes if p.name == "trees_building")
    assert float(v.to_camera(np.array([21.9, 0.0, 0.0]))[0]) < geo["root_depth_m"]  # the anchor is nearer
    assert names.index("trees_building") < names.index("subject") and backdrop.depth_key > geo["root_depth_m"]
