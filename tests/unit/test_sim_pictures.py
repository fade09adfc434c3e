"""A simulation reset with `pictures` renders only the frames in those index ranges (the takes')
and gives every other frame up to the last range's end its ground truth alone: the truth is the same
as when every frame is rendered, in both scene kinds, with the renderer on its own thread or not.
Frames past the last range get nothing: nobody records them."""
import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.lockstep import parse_pictures
from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend

EPOCH = 10**12


def fly(scene, pictures, async_render):
    b = SimBackend(scene, width=160, height=90, async_render=async_render)
    b.start()
    b.reset(EPOCH, 24.0, pictures=pictures)
    b.step(0.0)
    frames, truths = [], []
    for k in range(1, 11):  # 0.5 s: frames 0..12
        b.step(k * 0.05)
        b.flush()
        frames += b.frames()
        truths += b.truths()
    b.close()
    return frames, truths


@pytest.mark.parametrize("scene", ["open_country", "open_country_3d"])
@pytest.mark.parametrize("async_render", [False, True])
def test_only_the_pictured_frames_are_rendered_and_every_truth_is_the_same(scene, async_render):
    all_frames, all_truths = fly(scene, None, async_render)
    frames, truths = fly(scene, [(3, 7), (9, 10)], async_render)
    assert [f.index for f in all_frames] == list(range(13))
    assert [f.index for f in frames] == [3, 4, 5, 6, 9]
    for f in frames:  # the pictured frames are the very same pictures
        assert np.array_equal(f.image, all_frames[f.index].image) and f.image.shape == (90, 160, 3)
    assert [t.frame_index for t in truths] == list(range(10))  # 10-12 lie past the last range: no truth
    for a, b in zip(all_truths, truths):
        assert a.stamp_ns == b.stamp_ns
        assert np.array_equal(a.joints_norm, b.joints_norm, equal_nan=True)
        assert np.array_equal(a.joints_visible, b.joints_visible)
        assert np.array_equal(a.region_in_focus, b.region_in_focus)
        assert np.array_equal(a.region_focus_fraction, b.region_focus_fraction, equal_nan=True)


def test_a_reset_that_pictures_nothing_judges_nothing_and_still_flies():
    b = SimBackend("open_country", width=160, height=90)
    b.start()
    b.reset(EPOCH, 24.0, pictures=[])
    b.step(0.0)
    b.step(0.5)
    assert b.frames() == [] and b.truths() == []
    assert b.sim_time_s == 0.5 and b.vehicle_state().stamp_ns == EPOCH + 500_000_000
    b.close()


def test_pictures_of_a_reset_are_checked():
    assert parse_pictures({}) is None
    assert parse_pictures({"pictures": [[120, 367], [400, 410]]}) == [(120, 367), (400, 410)]
    assert parse_pictures({"pictures": []}) == []
    for bad in ([[5, 2]], [[-1, 3]], [[1, 2, 3]], "all", [[1.5, 3]], [[True, 3]]):
        with pytest.raises(ValueError, match="pictures"):
            parse_pictures({"pictures": bad})


def test_a_transfers_own_bridge_renders_nothing_before_its_reset(tmp_path):
    from cinetransfer.job import deploy_config
    from cinetransfer.services.autopilot_bridge.service import build_parser, config_from_args
    import yaml

    cfg = yaml.safe_load(deploy_config(tmp_path, 7447, "r", "open_country").read_text())
    args = next(n["args"] for n in cfg["nodes"] if n["name"] == "autopilot_bridge")
    assert config_from_args(build_parser().parse_args(args)).frames_before_reset is False
    assert config_from_args(build_parser().parse_args([])).frames_before_reset is True  # the default: frames
    real = yaml.safe_load(deploy_config(tmp_path, 7447, "r", "open_country", realtime=True).read_text())
    assert "--no-frames-before-reset" not in next(n["args"] for n in real["nodes"] if n["name"] == "autopilot_bridge")

