"""Box-first backend (the default): SSD person boxes, then landmarks and a mask per box.

Real models (installed by ./setup.sh from the npm packages) on real frames: TUD-Stadtmitte, where
most pedestrians are seen from the back or side, and the juggler. Plus the install step's parsing
and checks, and the fallback when the models are not installed.
"""
from __future__ import annotations

import io
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

from cinetransfer.services.detector import box_models
from cinetransfer.services.detector.box_first import BoxFirstPose, BoxFirstUnavailable, ssd_anchors
from cinetransfer.services.detector.config import ConfigError, DetectorConfig
from cinetransfer.services.detector.core import Detector
from cinetransfer.shared.frame_sources import iter_frames
from cinetransfer.shared.boxes import box_iou
from cinetransfer.data import data_dir as shared_data_dir

REASON = "box-first models not installed (npm missing at ./setup.sh): " + box_models.available()[1]
needs_models = pytest.mark.skipif(not box_models.available()[0], reason=REASON)


def data_dir() -> Path:
    try:
        return shared_data_dir()
    except FileNotFoundError as e:
        pytest.fail(str(e))


def _frame(name: str, index: int):
    return next(iter(iter_frames(data_dir() / name, start=index, stop=index + 1, prefetch=0)))


def _tud_truth(index: int) -> list[np.ndarray]:
    out = []
    for line in (data_dir() / "tud_stadtmitte_gt.txt").read_text().splitlines():
        p = line.strip().split(",")
        if len(p) >= 6 and int(float(p[0])) - 1 == index:
            x, y, w, h = (float(v) for v in p[2:6])
            out.append(np.array([x, y, x + w, y + h]))
    return out


# ---------------------------------------------------------------------- pure parts
def test_ssd_anchors_match_mediapipe_layout():
    a = ssd_anchors()
    assert a.shape == (1917, 4)
    # lowest layer: 19x19 cells x 3 boxes (scale 0.1 square, then 0.2 at ratios 2 and 0.5)
    assert np.allclose(a[0], (0.5 / 19, 0.5 / 19, 0.1, 0.1))
    assert np.allclose(a[1, 2:], (0.2 * np.sqrt(2), 0.2 / np.sqrt(2)), atol=1e-6)
    assert np.allclose(a[3, :2], (1.5 / 19, 0.5 / 19))
    # last layer: one 1x1 cell, 6 boxes; its interpolated box has scale sqrt(0.95 * 1)
    assert np.allclose(a[-6:, :2], 0.5)
    assert np.allclose(a[-1, 2:], np.sqrt(0.95), atol=1e-6)


def test_emscripten_package_offsets_are_parsed_and_checked(tmp_path):
    js = ('var x = 1; loadPackage({"files": [{"filename": "/a.txt", "start": 0, "end": 3}, '
          '{"filename": "/m/b.tflite", "start": 3, "end": 7}], "remote_package_size": 7});')
    assert box_models.packed_offsets(js) == {"/a.txt": (0, 3), "/m/b.tflite": (3, 7)}
    with pytest.raises(box_models.ModelsError, match="loadPackage"):
        box_models.packed_offsets("nothing here")


def test_a_tarball_with_a_wrong_model_is_rejected_and_dropped_from_the_cache(tmp_path, monkeypatch):
    # given a cached "npm tarball" whose model files do not match the recorded sha256
    cache, root = tmp_path / "npm", tmp_path / "models"
    cache.mkdir()
    name, _, fname = box_models.NPM_PACKAGES["pose"]
    with tarfile.open(cache / fname, "w:gz") as tf:
        for member in ("package/pose_landmark_full.tflite", "package/pose_landmark_heavy.tflite"):
            data = b"not a model"
            info = tarfile.TarInfo(member)
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    monkeypatch.setattr(box_models, "NPM_PACKAGES", {"pose": box_models.NPM_PACKAGES["pose"]})
    with pytest.raises(box_models.ModelsError, match="sha256"):
        box_models.install(root, cache)
    assert not (cache / fname).exists() and not (root / "pose_landmark_full.tflite").exists()


def test_config_validation_names_box_first_fields():
    assert DetectorConfig().backend == "box_first"
    with pytest.raises(ConfigError, match="bf_landmark_model"):
        DetectorConfig(bf_landmark_model="huge").validate()
    with pytest.raises(ConfigError, match="bf_score_threshold"):
        DetectorConfig(bf_score_threshold=1.0).validate()


# ---------------------------------------------------------------------- fallback without the models
def test_without_the_npm_models_the_backend_says_so_and_mediapipe_runs(tmp_path, monkeypatch):
    # given a models folder without the npm models
    monkeypatch.setenv("CT_DETECTOR_MODELS", str(tmp_path / "empty"))
    ok, why = box_models.available()
    assert not ok and "npm" in why and "setup.sh" in why
    with pytest.raises(BoxFirstUnavailable):
        BoxFirstPose(DetectorConfig())
    # when the detector starts with the default (box_first) backend
    f = _frame("sam2_juggle_1280x720.mp4", 0)
    with Detector(DetectorConfig(focus=False, running_mode="image")) as det:
        m = det.process(f.image, 0, 0)
    # then it runs MediaPipe's landmarker, and says that box_first is unavailable and why
    assert det.name == "mediapipe (box_first unavailable)" == m.detector
    assert "npm" in det.backend.unavailable
    assert len(m.people) == 1 and len(m.skeletons) == 1


def test_setup_step_without_npm_installs_nothing_and_explains(tmp_path):
    env = {"PATH": str(tmp_path / "bin"), "CT_DETECTOR_MODELS": str(tmp_path / "models"),
           "CT_CACHE_DIR": str(tmp_path / "cache"), "HOME": str(tmp_path)}
    r = subprocess.run([sys.executable, "-m", "cinetransfer.services.detector.box_models", "fetch"],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "npm not found" in r.stderr and "apt-get install npm" in r.stderr
    assert not any((tmp_path / "models").glob("*.tflite"))
    r = subprocess.run([sys.executable, "-m", "cinetransfer.services.detector.box_models", "check"],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 1 and "missing" in r.stdout


def test_detect_logs_the_fallback(tmp_path, data):
    out = tmp_path / "m.msgpack"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "detect", str(data / "sam2_juggle_1280x720.mp4"),
                        "-o", str(out), "--stop", "2", "--no-progress", "--no-focus"],
                       capture_output=True, text=True, timeout=240,
                       env={**os.environ, "CT_DETECTOR_MODELS": str(tmp_path / "none")})
    assert r.returncode == 0, r.stderr[-2000:]
    assert "box_first backend unavailable" in r.stderr
    from cinetransfer.shared.measurements_file import read_measurements

    assert read_measurements(out).header.detector == "mediapipe (box_first unavailable)"


# ---------------------------------------------------------------------- real models, real frames
@needs_models
def test_installed_models_match_their_recorded_sha256():
    assert box_models.verify() == []


@needs_models
@pytest.mark.parametrize("index", [20, 150])
def test_tud_back_and_side_views_get_boxes_skeletons_and_masks(index):
    # given a TUD-Stadtmitte frame: 6-8 pedestrians, most seen from the back or side
    f = _frame("tud_stadtmitte_640x480.mp4", index)
    truth = _tud_truth(index)
    with Detector(DetectorConfig(focus=False, running_mode="image")) as det:
        m = det.process(f.image, f.index, f.stamp_ns)
    assert det.name == "box_first"
    # then most of them are found (the face-anchored mediapipe backend finds one here)
    found = [max((box_iou(p.box_xyxy, t) for p in m.people), default=0.0) >= 0.5 for t in truth]
    assert sum(found) >= 0.6 * len(truth), f"{sum(found)}/{len(truth)} pedestrians found"
    # and every person has a plausible skeleton inside its box, a mask and a track id
    assert len(m.skeletons) == len(m.people)
    for i, (p, s) in enumerate(zip(m.people, m.skeletons)):
        assert s.person_index == i and s.keypoints_px.shape == (17, 2)
        good = s.confidences >= 0.3
        assert good.sum() >= 10
        x0, y0, x1, y1 = p.box_xyxy
        pad = 0.25 * (y1 - y0)
        kp = s.keypoints_px[good]
        assert ((kp[:, 0] > x0 - pad) & (kp[:, 0] < x1 + pad) & (kp[:, 1] > y0 - pad) & (kp[:, 1] < y1 + pad)).all()
        assert p.mask.any() and 0.0 < p.confidence <= 1.0 and p.track_id >= 0
    # and nobody is reported twice
    assert all(box_iou(a.box_xyxy, b.box_xyxy) < 0.5 for i, a in enumerate(m.people) for b in m.people[i + 1:])


@needs_models
def test_tud_people_keep_their_track_ids_over_consecutive_frames():
    with Detector(DetectorConfig(focus=False)) as det:
        ms = [det.process(f.image, f.index, f.stamp_ns)
              for f in iter_frames(data_dir() / "tud_stadtmitte_640x480.mp4", start=40, stop=50, prefetch=0)]
    first = {p.track_id for p in ms[0].people}
    last = {p.track_id for p in ms[-1].people}
    assert len(first) == len(ms[0].people) >= 4  # ids are unique within a frame
    assert len(first & last) >= 3, (first, last)  # walkers keep their ids for 10 frames


@needs_models
def test_juggler_is_the_one_person_with_a_full_skeleton_and_a_stable_id():
    with Detector(DetectorConfig(focus=False)) as det:
        ms = [det.process(f.image, f.index, f.stamp_ns)
              for f in iter_frames(data_dir() / "sam2_juggle_1280x720.mp4", stop=40, prefetch=0) if f.index % 2 == 0]
    assert all(len(m.people) == 1 for m in ms), [len(m.people) for m in ms]
    assert len({m.people[0].track_id for m in ms}) == 1
    for m in ms:
        p, s = m.people[0], m.skeletons[0]
        assert p.confidence > 0.5 and (s.confidences >= 0.5).sum() >= 12
        x0, y0, x1, y1 = p.box_xyxy
        assert 500 < x0 < x1 < 1000 and y1 - y0 > 400
        # the box is the mask's box, widened at most a little by the second look's mask
        mh, mw = p.mask.shape
        ox, oy = p.mask_origin_xy
        assert x0 <= ox + 1 and y0 <= oy + 1 and ox + mw <= x1 + 1 and oy + mh <= y1 + 1
        assert mh * mw >= 0.8 * (y1 - y0) * (x1 - x0)


@needs_models
def test_heavy_landmark_model_is_selectable():
    f = _frame("sam2_juggle_1280x720.mp4", 10)
    with Detector(DetectorConfig(focus=False, running_mode="image", bf_landmark_model="heavy")) as det:
        m = det.process(f.image, f.index, f.stamp_ns)
    assert len(m.people) == 1 and (m.skeletons[0].confidences >= 0.5).sum() >= 12


def _tud_truth_ids(index: int) -> dict[int, np.ndarray]:
    out = {}
    for line in (data_dir() / "tud_stadtmitte_gt.txt").read_text().splitlines():
        p = line.strip().split(",")
        if len(p) >= 6 and int(float(p[0])) - 1 == index:
            x, y, w, h = (float(v) for v in p[2:6])
            out[int(float(p[1]))] = np.array([x, y, x + w, y + h])
    return out


@needs_models
def test_main_subject_keeps_its_identity_through_a_tud_crossing():
    # given TUD-Stadtmitte frames 40-79, right part of the street (x >= 300): pedestrians 2 (walking
    # right) and 7 (walking left) cross there, one hiding the other, and the SSD sees one merged box
    from cinetransfer.services.smoother.config import SmootherConfig
    from cinetransfer.services.smoother.core import features_from_measurements, smooth_sequence

    x0, start, stop = 300, 40, 80
    truth = {f: {i: b - [x0, 0, x0, 0] for i, b in _tud_truth_ids(f).items()} for f in range(start, stop)}
    assert max(box_iou(t[2], t[7]) for t in truth.values()) > 0.5  # they do overlap in view
    with Detector(DetectorConfig(focus=False)) as det:
        ms = [det.process(np.ascontiguousarray(f.image[:, x0:]), f.index - start, f.stamp_ns, fps=25.0)
              for f in iter_frames(data_dir() / "tud_stadtmitte_640x480.mp4", start=start, stop=stop, prefetch=0)]

    # then the detector does not pass one walker's track id to the other (a box is the pedestrian it
    # overlaps most; a box that spans both for a frame or two may be counted on either)
    frames_on: dict[tuple[int, int], int] = {}
    for f, m in enumerate(ms):
        for p in m.people:
            who, b = max(truth[start + f].items(), key=lambda t: box_iou(p.box_xyxy, t[1]))
            if who in (2, 7) and box_iou(p.box_xyxy, b) >= 0.5:
                frames_on[who, p.track_id] = frames_on.get((who, p.track_id), 0) + 1
    ids = {i for _, i in frames_on}
    assert max(frames_on.get((2, i), 0) for i in ids) >= 30 and max(frames_on.get((7, i), 0) for i in ids) >= 10
    assert all(min(frames_on.get((2, i), 0), frames_on.get((7, i), 0)) <= 2 for i in ids), frames_on

    # and the smoother's main subject is one of the two walkers, the same one in every frame
    cfg = SmootherConfig()
    feats = features_from_measurements(ms, cfg)
    chosen = smooth_sequence(feats, cfg).diagnostics["person"]
    who = []
    for f, k in enumerate(chosen):
        if k >= 0:
            best = max(truth[start + f].items(), key=lambda t: box_iou(feats[f].boxes[k], t[1]))
            who.append(best[0] if box_iou(feats[f].boxes[k], best[1]) >= 0.3 else -1)
    assert len(who) >= 0.9 * len(ms)
    assert len(set(who)) == 1 and who[0] in (2, 7), who


class _CountingSsd(BoxFirstPose):
    """The real backend, counting the frames its SSD runs on."""

    ssd_runs = 0

    def boxes(self, image_bgr):
        self.ssd_runs += 1
        return super().boxes(image_bgr)


@needs_models
def test_ssd_runs_every_nth_frame_on_a_followed_juggler_with_the_same_people():
    frames = list(iter_frames(data_dir() / "sam2_juggle_1280x720.mp4", stop=16, prefetch=0))
    out = {}
    for every in (1, 2, DetectorConfig().bf_ssd_every):
        be = _CountingSsd(DetectorConfig(focus=False, bf_ssd_every=every))
        with Detector(DetectorConfig(focus=False, bf_ssd_every=every), backend=be) as det:
            out[every] = ([det.process(f.image, f.index, f.stamp_ns) for f in frames], be.ssd_runs)
    each, runs_each = out[1]
    assert runs_each == len(frames)
    for every, (skip, runs_skip) in out.items():
        assert runs_skip == -(-len(frames) // every), (every, runs_skip)
        assert len({m.people[0].track_id for m in skip}) == 1
        for a, b in zip(each, skip):
            assert len(a.people) == len(b.people) == 1
            assert box_iou(a.people[0].box_xyxy, b.people[0].box_xyxy) > 0.9
            assert abs(a.people[0].confidence - b.people[0].confidence) < 0.1
            assert (b.skeletons[0].confidences >= 0.5).sum() >= 12


@needs_models
def test_without_the_pose_worker_or_switching_it_on_midway_a_crowd_is_measured_the_same():
    # given a crowd (several landmark crops a frame, split over two threads with the worker), measured with
    # the worker, without it, and without it until the fourth frame
    frames = list(iter_frames(data_dir() / "tud_stadtmitte_640x480.mp4", stop=6, prefetch=0))
    runs = {}
    for mode in ("worker", "none", "switched on"):
        cfg = DetectorConfig(focus=False, camera_motion=False, bf_pose_worker=mode == "worker")
        with Detector(cfg) as det:
            assert (det.backend._pool is not None) is (mode == "worker")
            runs[mode] = []
            for k, f in enumerate(frames):
                if mode == "switched on" and k == 3:
                    det.backend.use_worker(True)
                    assert det.backend._pool is not None
                runs[mode].append(det.process(f.image, f.index, f.stamp_ns))
    # then every person, mask and skeleton is the same to the bit
    for mode in ("none", "switched on"):
        for a, b in zip(runs["worker"], runs[mode]):
            assert len(a.people) == len(b.people) >= 3 and len(a.skeletons) == len(b.skeletons)
            for p, q in zip(a.people, b.people):
                assert p.track_id == q.track_id and p.confidence == q.confidence
                np.testing.assert_array_equal(p.box_xyxy, q.box_xyxy)
                np.testing.assert_array_equal(p.mask, q.mask)
            for p, q in zip(a.skeletons, b.skeletons):
                np.testing.assert_array_equal(p.keypoints_px, q.keypoints_px)
                np.testing.assert_array_equal(p.confidences, q.confidences)


@needs_models
def test_a_person_the_landmarks_lose_makes_the_ssd_look_on_that_frame():
    frames = list(iter_frames(data_dir() / "sam2_juggle_1280x720.mp4", stop=3, prefetch=0))
    cfg = DetectorConfig(focus=False, camera_motion=False, bf_ssd_every=10)
    be = _CountingSsd(cfg)
    with Detector(cfg, backend=be) as det:
        det.process(frames[0].image, 0, frames[0].stamp_ns)
        det.process(frames[1].image, 1, frames[1].stamp_ns)
        assert be.ssd_runs == 1  # followed: no SSD
        empty = det.process(np.zeros_like(frames[2].image), 2, frames[2].stamp_ns)
        assert be.ssd_runs == 2 and not empty.people  # lost: the SSD looked, and found no one


def _looker() -> BoxFirstPose:
    """The second look's bookkeeping alone (no model is run): a backend without its interpreters."""
    bf = BoxFirstPose.__new__(BoxFirstPose)
    bf.cfg = DetectorConfig()
    bf._look_gain, bf._since_look = float("inf"), 0
    bf._prev = [{"box": np.array([0, 0, 100, 200], np.float32), "moved": 0.10}]
    return bf


def test_a_look_that_widens_the_box_keeps_looking_and_records_its_gain():
    bf = _looker()
    assert bf._look_roi() == (50.0, 100.0, 250.0, 1.0, 0.0)  # 1.25 x the long side, upright
    finals = [np.array([0, 0, 100, 200], np.float32)]
    bf._widen(finals, np.array([0, 0, 100, 210], np.float32))  # IoU 200/210 >= 0.6: the same person
    np.testing.assert_array_equal(finals[0], [0, 0, 100, 210])
    assert bf._look_gain == pytest.approx(1 - 200 / 210, abs=1e-6)
    assert bf._look_roi() is not None  # it gained 4.8 %: the next changing frame looks again


def test_a_look_that_gains_under_one_percent_rests_the_looks_for_three_frames():
    bf = _looker()
    assert bf._look_roi() is not None
    bf._widen([np.array([0, 0, 100, 200], np.float32)], np.array([0, 0, 100, 201], np.float32))
    assert bf._look_gain == pytest.approx(1 - 200 / 201, abs=1e-6)  # 0.5 %: under look_min_gain
    assert [bf._look_roi() is not None for _ in range(5)] == [False, False, False, True, False]


def test_a_look_that_agrees_with_no_box_gains_nothing_and_a_steady_box_gets_no_look():
    bf = _looker()
    bf._look_roi()
    bf._widen([np.array([0, 0, 100, 200], np.float32)], np.array([300, 0, 400, 200], np.float32))
    assert bf._look_gain == 0.0
    bf._since_look = BoxFirstPose.look_rest_frames
    bf._prev[0]["moved"] = 0.04  # under look_min_change
    assert bf._look_roi() is None
