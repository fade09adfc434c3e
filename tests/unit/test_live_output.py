"""The output's style measured while filming equals `cinetransfer extract` on the same frames."""
import cv2
import numpy as np

from cinetransfer.extract import extract_features
from cinetransfer.live_output import LiveOutputStyle
from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.core import smooth_sequence
from cinetransfer.shared.frame_sources import DEFAULT_IMAGE_FPS, iter_frames
from cinetransfer.shared.instructions import load_style

FRAMES = 10


def test_frames_measured_as_they_are_recorded_give_the_style_extract_gives(data, tmp_path):
    # given the frames of a take, as the recorder would place them, and the same frames as files
    images = [f.image for f in iter_frames(data / "sam2_juggle_1280x720.mp4", stop=FRAMES)]
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, img in enumerate(images):
        cv2.imwrite(str(folder / f"{k:05d}.png"), img)  # lossless: the same pixels
    live = LiveOutputStyle(folder, DEFAULT_IMAGE_FPS)
    for k, img in enumerate(images):
        live.feed(k, img)
    # when the take ends
    assert live.finish(tmp_path / "live.json", n_frames=FRAMES, cuts=None), live.error
    # then its style is the one `cinetransfer extract` computes from the files
    feats, source = extract_features(folder, SmootherConfig())
    ref = smooth_sequence(feats, SmootherConfig(), source=source).instructions
    got = load_style(tmp_path / "live.json")
    assert got.image_targets.shape == ref.image_targets.shape == (FRAMES, len(ref.joint_names), 2)
    np.testing.assert_array_equal(got.image_targets, ref.image_targets)
    np.testing.assert_array_equal(got.focus_in, ref.focus_in)
    np.testing.assert_array_equal(got.subject_visible, ref.subject_visible)


def test_a_frame_out_of_order_or_a_short_take_is_not_used(tmp_path):
    live = LiveOutputStyle(tmp_path / "output.mp4", 24.0)
    live.feed(1, np.zeros((36, 64, 3), np.uint8))  # slot 0 never came
    assert not live.finish(tmp_path / "out.json", n_frames=1, cuts=None)
    assert "slot 1" in live.error and not (tmp_path / "out.json").exists()
