"""Detector core on short real excerpts: people, joints, masks, empty frames, focus, sources."""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from cinetransfer.data import data_dir as shared_data_dir

from cinetransfer.services.detector import pose_bundle
from cinetransfer.services.detector.config import ConfigError, DetectorConfig
from cinetransfer.services.detector.core import Detector, FrameStream, half_covered, people_mask, people_mask_at
from cinetransfer.services.detector.focus import EdgeEvidence, FocusEstimator
from cinetransfer.services.detector.overlay import draw
from cinetransfer.services.detector.pose_mediapipe import BLAZEPOSE_TO_COCO17
from cinetransfer.shared.frame_sources import FrameSourceError, iter_frames, probe
from cinetransfer.shared import codec
from cinetransfer.shared.messages import Measurement, PersonDetection



def data_dir() -> Path:
    try:
        return shared_data_dir()
    except FileNotFoundError as e:
        pytest.fail(str(e))


@pytest.fixture(scope="module")
def detector():
    det = Detector(DetectorConfig())
    yield det
    det.close()


@pytest.fixture(scope="module")
def juggle_frames():
    path = data_dir() / "sam2_juggle_1280x720.mp4"
    return [f for f in iter_frames(path, stop=24) if f.index % 3 == 0]


def test_bundle_builds_offline_into_cache_dir(tmp_path, monkeypatch):
    # given an empty cache dir
    monkeypatch.setenv("CT_CACHE_DIR", str(tmp_path))
    # when the bundle is asked for
    p = pose_bundle.bundle_path()
    # then it was built there from the wheel's two models, with the entries the Tasks API wants
    import zipfile

    assert p.parent == tmp_path and p.suffix == ".task"
    with zipfile.ZipFile(p) as z:
        assert sorted(z.namelist()) == ["pose_detector.tflite", "pose_landmarks_detector.tflite"]
    mtime = p.stat().st_mtime_ns
    assert pose_bundle.bundle_path() == p and p.stat().st_mtime_ns == mtime  # cached, not rebuilt


def test_juggler_found_with_joints_inside_his_mask(detector, juggle_frames):
    detector.reset()
    for f in juggle_frames:
        m = detector.process(f.image, f.index, f.stamp_ns, source="juggle", fps=f.fps)
        # then one person, confident, a sensible box
        assert len(m.people) >= 1, f"frame {f.index}: juggler not found"
        p = m.people[0]
        assert p.confidence > 0.8
        x0, y0, x1, y1 = p.box_xyxy
        assert 500 < x0 < x1 < 1000 and y1 - y0 > 400  # he stands mid-frame, ~600 px tall
        sk = [s for s in m.skeletons if s.person_index == 0][0]
        assert sk.keypoints_px.shape == (17, 2) and sk.confidences.shape == (17,)
        conf = sk.confidences >= 0.5
        assert conf.sum() >= 12, f"frame {f.index}: only {conf.sum()} confident joints"
        # the confident joints land inside his (slightly dilated) mask
        mask = cv2.dilate(p.full_mask(m.width, m.height).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
        pts = np.round(sk.keypoints_px[conf]).astype(int)
        inside = mask[pts[:, 1].clip(0, m.height - 1), pts[:, 0].clip(0, m.width - 1)]
        assert inside.mean() >= 0.9, f"frame {f.index}: {inside.mean():.2f} of joints in mask"
        # and the message survives the codec
        assert isinstance(codec.decode(codec.encode(m), Measurement), Measurement)


def test_no_person_frame_gives_an_empty_measurement(detector, juggle_frames):
    # given real footage without anybody (the lawn/trees left of the juggler) and a flat grey frame
    crop = np.ascontiguousarray(juggle_frames[0].image[:, :500])
    for img in (crop, np.full((240, 320, 3), 127, np.uint8)):
        detector.reset()
        m = detector.process(img, 0, 0)
        assert m.people == [] and m.skeletons == []
        assert m.focus_map is not None and m.focus_map.dtype == np.uint8
        assert m.width == img.shape[1] and m.height == img.shape[0]


def test_measurement_fields_and_overlay(detector, juggle_frames):
    detector.reset()
    f = juggle_frames[0]
    m = detector.process(f.image, 7, 123, source="x.mp4", fps=24.0)
    assert (m.frame_index, m.stamp_ns, m.source, m.fps, m.detector) == (7, 123, "x.mp4", 24.0, detector.name)
    assert m.focus_map.shape == (90, 160)
    p = m.people[0]
    assert p.mask.shape == (int(p.box_xyxy[3] - p.box_xyxy[1]), int(p.box_xyxy[2] - p.box_xyxy[0]))
    assert tuple(p.mask_origin_xy) == (int(p.box_xyxy[0]), int(p.box_xyxy[1]))
    out = draw(f.image, m)
    assert out.shape == f.image.shape and not np.array_equal(out, f.image)


def test_blazepose_to_coco_mapping():
    assert BLAZEPOSE_TO_COCO17 == (0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)


def test_sequential_and_parallel_give_the_same_result(juggle_frames):
    f = juggle_frames[1]
    res = []
    for threads in (1, 2):
        with Detector(DetectorConfig(threads=threads, running_mode="image")) as det:
            res.append(det.process(f.image, f.index, f.stamp_ns))
    a, b = res
    assert len(a.people) == len(b.people) == 1
    assert codec.encode(a) == codec.encode(b)  # the worker threads change when, never what



def test_streamed_frames_give_what_one_frame_at_a_time_gives():
    # given consecutive frames of the juggler (tracking, the SSD's skipped frames and camera motion all in play)
    frames = list(iter_frames(data_dir() / "sam2_juggle_1280x720.mp4", stop=8))
    with Detector(DetectorConfig()) as det:
        one = [det.process(f.image, f.index, f.stamp_ns, source="clip", fps=f.fps) for f in frames]
    # when the same frames are streamed (frame k's tail beside the next frames' poses)
    with Detector(DetectorConfig()) as det:
        streamed = list(det.process_frames(frames, source="clip"))
    # then every measurement is the same, in the same order, to the byte
    assert [m.frame_index for m in streamed] == [f.index for f in frames]
    for a, b in zip(one, streamed):
        assert len(a.people) == len(b.people) == 1
        assert [p.track_id for p in a.people] == [p.track_id for p in b.people]
        assert np.allclose(a.people[0].box_xyxy, b.people[0].box_xyxy, atol=0.5)
        assert np.allclose(a.skeletons[0].keypoints_px, b.skeletons[0].keypoints_px, atol=0.5)
        assert np.abs(a.people[0].full_mask(a.width, a.height) ^ b.people[0].full_mask(b.width, b.height)).sum() <= 20
        assert np.abs(a.focus_map.astype(int) - b.focus_map.astype(int)).mean() < 0.5
        assert (a.camera_motion is None) == (b.camera_motion is None)
        if a.camera_motion is not None:
            assert np.allclose(a.camera_motion.rotation_rad, b.camera_motion.rotation_rad, atol=1e-4)
    identical = sum(codec.encode(a) == codec.encode(b) for a, b in zip(one, streamed))
    assert identical == len(frames)
    assert sum(m.camera_motion is not None for m in streamed) == len(frames) - 1



def test_frame_stream_hands_back_in_order_and_a_failed_tail_costs_only_its_frame(monkeypatch):
    frames = list(iter_frames(data_dir() / "sam2_juggle_1280x720.mp4", stop=6))
    with Detector(DetectorConfig()) as det:
        real_tail = det._tail

        def tail(head, frame_index, *args, **kw):  # the real tail, failing on one frame
            if frame_index == 2:
                raise RuntimeError("tail failed")
            return real_tail(head, frame_index, *args, **kw)

        monkeypatch.setattr(det, "_tail", tail)
        due = []
        with FrameStream(det) as stream:
            for f in frames:
                due += stream.push(f.image, f.index, f.stamp_ns, source="clip", fps=f.fps)
                assert stream.in_flight <= Detector.TAILS_IN_FLIGHT
            assert len(due) >= len(frames) - Detector.TAILS_IN_FLIGHT
            due += stream.flush()
        assert stream.in_flight == 0
    assert len(due) == len(frames)
    with pytest.raises(RuntimeError, match="tail failed"):
        due[2].result()
    assert [d.result().frame_index for i, d in enumerate(due) if i != 2] == [0, 1, 3, 4, 5]
    assert due[3].result().camera_motion is None  # the frame before it has no tail: a gap
    assert due[4].result().camera_motion is not None

# ---------------------------------------------------------------------------- focus
def _davis(name: str, index: int):
    d = data_dir()
    f = next(iter(iter_frames(d / f"davis_{name}_854x480.mp4", start=index, stop=index + 1, prefetch=0)))
    mask = cv2.imread(str(d / f"davis_{name}_masks" / f"{index:05d}.png"), cv2.IMREAD_GRAYSCALE) > 127
    return f.image, mask


@pytest.mark.parametrize("name,index", [("parkour", 30), ("dance-twirl", 40)])
def test_blurred_background_is_reported_out_of_focus(name, index):
    img, mask = _davis(name, index)
    blurred = cv2.GaussianBlur(img, (0, 0), 3.0)
    bg_blur = img.copy()
    bg_blur[~mask] = blurred[~mask]
    est = FocusEstimator(DetectorConfig())
    for person_mask in (None, mask):
        prob = cv2.resize(est.estimate(bg_blur, person_mask).prob, (img.shape[1], img.shape[0])) > 0.5
        assert prob[~mask].mean() < 0.2, "blurred background reported in focus"
        assert prob[mask].mean() > 0.6, "sharp subject reported out of focus"


@pytest.mark.parametrize("name,index", [("parkour", 60)])
def test_blurred_subject_is_reported_out_of_focus(name, index):
    img, mask = _davis(name, index)
    blurred = cv2.GaussianBlur(img, (0, 0), 4.0)
    alpha = np.maximum(cv2.GaussianBlur(mask.astype(np.float32), (0, 0), 4.0), mask)[..., None]
    subj_blur = (alpha * blurred + (1 - alpha) * img).astype(np.uint8)
    prob = FocusEstimator(DetectorConfig()).estimate(subj_blur, mask).prob
    prob = cv2.resize(prob, (img.shape[1], img.shape[0])) > 0.5
    assert prob[mask].mean() < 0.3
    assert prob[~mask].mean() > 0.7


def test_all_sharp_and_all_blurred_frames(juggle_frames):
    est = FocusEstimator(DetectorConfig())
    img = juggle_frames[0].image
    sharp = est.estimate(img).prob
    blurred = est.estimate(cv2.GaussianBlur(img, (0, 0), 6.0)).prob
    assert (sharp > 0.5).mean() > 0.9
    assert (blurred > 0.5).mean() < 0.1
    flat = est.estimate(np.full((100, 200, 3), 90, np.uint8))
    assert flat.prob.shape == (80, 160) and np.allclose(flat.prob, DetectorConfig().focus_no_edge_prior, atol=0.01)


def test_focus_edges_do_not_depend_on_where_their_arrays_lie(juggle_frames):
    # given one frame, measured again and again with the heap in other states: numpy's arrays then
    # start at other addresses, as they do from run to run and from thread to thread
    est = FocusEstimator(DetectorConfig())
    grey = cv2.cvtColor(juggle_frames[0].image, cv2.COLOR_BGR2GRAY)
    results, spacers = set(), []
    for k in range(16):
        spacers.append(np.empty(4096 + 16 * k, np.uint8))  # kept: moves where the next arrays land
        ev = est.measure_edges(grey.copy())
        results.add((ev.num.tobytes(), ev.den.tobytes(), ev.sigma_edges.tobytes()))
    # then the edge evidence is the same to the bit every time (cv2.magnitude with Intel IPP was
    # not: its last bit went by where its output lay, and the focus maps changed from run to run)
    assert len(results) == 1


def test_focus_map_resolution_is_stated():
    est = FocusEstimator(DetectorConfig(focus_map_width_px=160))
    r = est.estimate(np.zeros((720, 1280, 3), np.uint8))
    assert r.prob.shape == (90, 160) and r.scale == pytest.approx(0.125)
    small = est.estimate(np.zeros((60, 100, 3), np.uint8))  # narrower than the map: kept as is
    assert small.prob.shape == (60, 100)


def test_people_mask_union():
    assert people_mask([], 10, 10) is None


def _random_people(rng, width: int, height: int) -> list[PersonDetection]:
    out = []
    for _ in range(int(rng.integers(1, 4))):
        w, h = (int(v) for v in rng.integers(1, 300, size=2))
        ox, oy = int(rng.integers(-80, width)), int(rng.integers(-80, height))
        out.append(PersonDetection(box_xyxy=np.array([ox, oy, ox + w, oy + h], np.float32), confidence=0.9,
                                   mask_origin_xy=np.array([ox, oy], np.int32),
                                   mask=rng.random((h, w)) < rng.random()))
    return out


@pytest.mark.parametrize("width, height", [(1280, 720), (854, 480)])
def test_people_mask_at_the_map_grid_gives_the_same_focus_map(width, height):
    """The propagation fed the grid mask (a whole multiple) or the frame's union (else) draws the same map."""
    rng = np.random.default_rng(3)
    est = FocusEstimator(DetectorConfig())
    mw, mh = est.map_size(width, height)
    grid = 0
    for _ in range(40):
        people = _random_people(rng, width, height)
        ev = EdgeEvidence(num=rng.random((mh, mw), dtype=np.float32), den=rng.random((mh, mw), dtype=np.float32),
                          guide=rng.random((mh, mw), dtype=np.float32), sigma_edges=np.zeros(0, np.float32),
                          work_width=640, px_scale=1.0, frame_width=width)
        at = people_mask_at(people, width, height, (mw, mh))
        full = people_mask(people, width, height)
        assert (at is None) == (full is None)
        grid += at is not None and at.shape == (mh, mw)
        np.testing.assert_array_equal(est.propagate(ev, at).prob, est.propagate(ev, full).prob)
    assert grid > 0 if width == 1280 else grid == 0



# ---------------------------------------------------------------------------- sources
def test_image_folder_source(tmp_path, juggle_frames):
    for i, f in enumerate(juggle_frames[:3]):
        cv2.imwrite(str(tmp_path / f"img_{i + 8}.png"), cv2.resize(f.image, (320, 180)))
    (tmp_path / "notes.txt").write_text("ignored")
    (tmp_path / "img_99.png").write_bytes(b"not a png")  # unreadable: skipped with a warning
    frames = list(iter_frames(tmp_path, fps=10.0))
    assert [f.index for f in frames] == [0, 1, 2]
    assert frames[1].stamp_ns == 100_000_000 and frames[0].image.shape == (180, 320, 3)
    assert probe(tmp_path).n_frames == 4


def test_truncated_video_keeps_what_was_decoded(tmp_path, juggle_frames):
    p = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"MJPG"), 24.0, (320, 180))
    for _ in range(5):
        for f in juggle_frames:
            vw.write(cv2.resize(f.image, (320, 180)))
    vw.release()
    n_full = len(list(iter_frames(p)))
    assert n_full == 5 * len(juggle_frames)
    data = p.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: len(data) // 2])
    n_cut = len(list(iter_frames(cut)))
    assert 0 < n_cut < n_full


@pytest.mark.parametrize("content", [b"", b"garbage" * 100])
def test_corrupt_or_missing_file_is_a_clear_error(tmp_path, content):
    p = tmp_path / "bad.mp4"
    p.write_bytes(content)
    with pytest.raises(FrameSourceError, match="bad.mp4"):
        list(iter_frames(p))
    with pytest.raises(FrameSourceError, match="no such"):
        list(iter_frames(tmp_path / "missing.mp4"))
    with pytest.raises(FrameSourceError, match="no images"):
        list(iter_frames(tmp_path))


def test_config_validation_names_the_field():
    with pytest.raises(ConfigError, match="num_poses"):
        DetectorConfig(num_poses=0).validate()
    with pytest.raises(ConfigError, match="tv_mask_checkpoint"):
        DetectorConfig(backend="torchvision").validate()


def test_hog_fallback_adds_back_view_pedestrians_without_duplicates():
    # given a TUD-Stadtmitte frame (pedestrians, several seen from the back or side)
    f = next(iter(iter_frames(data_dir() / "tud_stadtmitte_640x480.mp4", start=20, stop=21, prefetch=0)))
    with Detector(DetectorConfig(backend="mediapipe", running_mode="image", focus=False)) as plain, \
            Detector(DetectorConfig(backend="mediapipe", running_mode="image", focus=False,
                                    person_fallback="hog")) as fb:
        a = plain.process(f.image, f.index, f.stamp_ns)
        b = fb.process(f.image, f.index, f.stamp_ns)
    # then the fallback adds people, keeps the pose people first (skeleton indices stay valid)
    assert len(b.people) > len(a.people)
    for pa, pb in zip(a.people, b.people):
        assert np.allclose(pa.box_xyxy, pb.box_xyxy)
    extra = b.people[len(a.people):]
    assert all(not p.mask.any() for p in extra)  # box-only: mask unknown
    assert all(s.person_index < len(a.people) for s in b.skeletons)
    # and no added box duplicates a pose person
    from cinetransfer.services.detector.pose_mediapipe import box_iou

    assert all(box_iou(e.box_xyxy, p.box_xyxy) < 0.3 for e in extra for p in a.people)


def test_native_startup_noise_is_filtered_but_real_errors_pass(capfd):
    import os

    from cinetransfer.services.detector.pose_mediapipe import _filtered_native_stderr

    with _filtered_native_stderr():
        os.write(2, b"W0000 inference_feedback_manager.cc:114] Feedback manager requires ...\n")
        os.write(2, b"E0000 something real went wrong\n")
    err = capfd.readouterr().err
    assert "something real went wrong" in err and "inference_feedback_manager" not in err


def test_shot_change_scores_find_the_cuts_of_a_film_clip(detector):
    # given frames 58-72 of tos_clip01 (a cut from the actor on the bridge to the two-shot at 65)
    from cinetransfer.services.smoother.shots import find_cuts

    detector.reset()
    scores = {}
    for f in iter_frames(data_dir() / "tos_clip01_640x360.mp4", start=58, stop=73):
        scores[f.index] = detector.process(f.image, f.index, f.stamp_ns, source="tos").shot_change
    # then the first frame has no score, the cut scores high and the rest of each shot low
    assert math.isnan(scores[58])
    assert scores[65] > 0.6 and max(v for k, v in scores.items() if k not in (58, 65)) < 0.2
    s = np.array([scores[k] for k in sorted(scores)])
    assert (np.flatnonzero(find_cuts(s)) + 58).tolist() == [65]
    # and a frame that does not follow the previous one (a gap) is not scored
    f = next(iter_frames(data_dir() / "tos_clip01_640x360.mp4", start=100, stop=101))
    assert math.isnan(detector.process(f.image, f.index, f.stamp_ns, source="tos").shot_change)


@pytest.mark.parametrize("k", [2, 4, 8, 16])
def test_half_covered_counts_each_block_exactly(k):
    rng = np.random.default_rng(k)
    canvas = rng.random((6 * k, 5 * k)) < 0.5
    # hand-made blocks: exactly half covered (counts), one pixel short of half, all, none
    canvas[:k, :k] = False
    canvas[:k, :k].flat[: k * k // 2] = True
    canvas[:k, k:2 * k] = False
    canvas[:k, k:2 * k].flat[: k * k // 2 - 1] = True
    canvas[k:2 * k, :k], canvas[k:2 * k, k:2 * k] = True, False
    want = np.array([[2 * canvas[i * k:(i + 1) * k, j * k:(j + 1) * k].sum() >= k * k for j in range(5)]
                     for i in range(6)])
    got = half_covered(canvas, k)
    assert got.shape == (6, 5) and np.array_equal(got, want)
    assert got[0, 0] and not got[0, 1] and got[1, 0] and not got[1, 1]
