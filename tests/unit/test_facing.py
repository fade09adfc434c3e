"""Left and right by image side for a person seen from behind (shared/facing.py), as the planner
aims the targets and the report compares them (docs/planner.md, "Back views")."""
import numpy as np

from cinetransfer.report import fidelity as F
from cinetransfer.services.planner.core import stage_targets
from cinetransfer.shared.facing import by_image_side, faces_opposite, lateral_sign, mirror_permutation

NAMES = ["left_shoulder", "right_shoulder", "left_hip", "right_hip"]
# a front view: the person's left shoulder on the image's right
FRONT = np.array([[0.56, 0.40], [0.44, 0.40], [0.53, 0.60], [0.47, 0.60]])
# the same framing seen from behind: left and right change sides of the image
BACK = FRONT[[1, 0, 3, 2]]


def test_mirror_permutation_swaps_only_pairs_present():
    assert mirror_permutation(NAMES).tolist() == [1, 0, 3, 2]
    assert mirror_permutation(["nose", "left_hip", "right_hip", "left_knee"]).tolist() == [0, 2, 1, 3]


def test_lateral_sign_by_hand():
    # (0.56 - 0.44) + (0.53 - 0.47) = 0.18
    assert abs(lateral_sign(FRONT, NAMES) - 0.18) < 1e-12
    assert abs(lateral_sign(BACK, NAMES) + 0.18) < 1e-12
    half = FRONT.copy()
    half[1] = np.nan  # a pair with an unknown joint does not count: 0.06 from the hips alone
    assert abs(lateral_sign(half, NAMES) - 0.06) < 1e-12
    assert lateral_sign(np.full((4, 2), np.nan), NAMES) == 0.0


def test_swap_only_when_the_views_face_opposite_ways():
    assert faces_opposite(FRONT, BACK, NAMES) and not faces_opposite(FRONT, FRONT + 0.1, NAMES)
    assert not faces_opposite(FRONT, np.full((4, 2), np.nan), NAMES)  # unknown: never swapped
    out, swapped = by_image_side(FRONT, BACK, NAMES)
    assert swapped and np.allclose(out, FRONT)
    out, swapped = by_image_side(FRONT, FRONT + 0.01, NAMES)
    assert not swapped and np.allclose(out, FRONT + 0.01)


def test_planner_targets_are_met_by_image_side_on_a_back_view():
    targets = np.stack([FRONT, FRONT])  # two instruction rows of a front-view style
    w = np.array([1.0, 1.0, 4.0, 4.0, 0.0])  # E_max = 5, hips weigh 4
    t, m = stage_targets(targets, [0, 1], NAMES, w, BACK)
    # seen from behind: the left-shoulder joint (on the image's left) gets the target on the left
    assert np.allclose(t[:, :4], BACK) and np.allclose(m, [w, w])
    t, _ = stage_targets(targets, [0, 1], NAMES, w, FRONT)  # seen from the front: by name
    assert np.allclose(t[:, :4], FRONT)


def _track(xy: np.ndarray) -> F.Track:
    n, e = xy.shape[:2]
    tr = F.empty_track(n, e)
    return F.Track(xy=xy, ok=np.ones((n, e), bool), available=np.ones(n, bool), frac=tr.frac,
                   smoothed=tr.smoothed, focus_in=tr.focus_in, present=tr.present)


def test_fidelity_compares_a_back_view_by_image_side_and_keeps_the_by_name_error():
    ref = _track(np.stack([FRONT, FRONT]))
    # frame 0 seen from behind, exactly on the framing; frame 1 from the front, 0.01 to the right
    est = _track(np.stack([BACK, FRONT + [0.01, 0.0]]))
    js, per_frame = F.compare_joints(ref, est, NAMES)
    assert js["frames_by_image_side"] == 1
    assert np.allclose(per_frame, [0.0, 0.01])
    assert abs(js["overall"]["euclidean"]["mean"] - 0.005) < 1e-12
    # by name, frame 0 errs by the shoulder width (0.12) on the shoulders and the hip width (0.06) on the hips
    assert abs(js["overall"]["euclidean_by_name"]["mean"] - (0.12 * 2 + 0.06 * 2 + 0.01 * 4) / 8) < 1e-12


def test_the_report_says_when_it_compared_by_image_side():
    from cinetransfer.report import html as H

    js = {"frames_by_image_side": 3, "frames_compared": 5, "overall": {"euclidean_by_name": {"mean": 0.07}}}
    note = H._image_side_note({"truth": {"joints": js}})
    assert "by image side" in note and "in 3 of 5 frames" in note and "0.0700" in note
    assert H._image_side_note({"truth": {"joints": {**js, "frames_by_image_side": 0}}}) == ""


def test_left_right_setting_is_validated_and_names_the_field():
    import pytest

    from cinetransfer.services.planner import config as pc
    from cinetransfer.shared.errors import ConfigError

    assert pc.PlannerConfig().left_right == "name"
    assert pc.PlannerConfig(left_right="name").validate().left_right == "name"
    with pytest.raises(ConfigError, match="left_right"):
        pc.PlannerConfig(left_right="mirror").validate()
