"""Duplicate removal (services/detector/dedupe.py) on hand-made candidates: a box nested in another on
the same body is one person; two overlapping people stay two."""
from __future__ import annotations

import numpy as np
import pytest

from cinetransfer.services.detector import dedupe
from cinetransfer.services.detector.config import ConfigError, DetectorConfig
from cinetransfer.shared.boxes import box_iou

CFG = DetectorConfig()


def _skeleton(x0: float, y0: float, h: float) -> np.ndarray:
    """17 COCO joints of an upright figure of height `h` whose head top is at (x0, y0)."""
    rel = np.array([(0, .05), (-.02, .03), (.02, .03), (-.04, .05), (.04, .05), (-.1, .2), (.1, .2), (-.15, .35),
                    (.15, .35), (-.17, .5), (.17, .5), (-.07, .52), (.07, .52), (-.08, .75), (.08, .75), (-.08, .97),
                    (.08, .97)])
    return (np.array([x0, y0]) + rel * h).astype(np.float32)


def _mask_box(box, full: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """The part of the frame-sized mask `full` inside `box`, as a mask crop and its origin."""
    x0, y0, x1, y1 = (int(v) for v in box)
    return full[y0:y1, x0:x1].copy(), (x0, y0)


def _seen(box, kp: np.ndarray, full: np.ndarray | None, conf: float = 0.9) -> dedupe.Seen:
    box = np.asarray(box, np.float32)
    mask, origin = _mask_box(box, full) if full is not None else (None, (int(box[0]), int(box[1])))
    return dedupe.Seen(box, kp, np.full(17, conf, np.float32), mask, origin)


def _body(frame=(400, 600), x=(250, 350), y=(50, 350)) -> np.ndarray:
    m = np.zeros(frame, bool)
    m[y[0]:y[1], x[0]:x[1]] = True
    return m


def test_inside_fraction_is_the_share_of_the_small_box_in_the_big_one():
    assert dedupe.inside_fraction([0, 0, 10, 10], [5, 0, 20, 10]) == pytest.approx(0.5)
    assert dedupe.inside_fraction([2, 2, 4, 4], [0, 0, 10, 10]) == pytest.approx(1.0)
    assert dedupe.inside_fraction([0, 0, 0, 10], [0, 0, 10, 10]) == 0.0


def test_mask_inside_fraction_aligns_the_two_crops_by_their_origins():
    a = dedupe.Seen(np.zeros(4), np.zeros((17, 2)), np.zeros(17), np.ones((4, 4), bool), (10, 10))
    b = dedupe.Seen(np.zeros(4), np.zeros((17, 2)), np.zeros(17), np.ones((4, 4), bool), (12, 10))
    assert dedupe.mask_inside_fraction(a, b) == pytest.approx(0.5)  # columns 12, 13 of 10..13
    assert np.isnan(dedupe.mask_inside_fraction(a._replace(mask=np.zeros((4, 4), bool)), b))


def test_a_nested_box_on_the_same_body_is_one_person():
    # the whole dancer (300 px tall) and a crop that saw her from the head to the knees, as in the orbit
    body = _body()
    kp = _skeleton(300, 50, 300)
    whole = _seen([230, 40, 370, 360], kp, body)
    part = _seen([260, 50, 340, 280], kp + np.float32([3, -2]), body)
    assert box_iou(whole.box, part.box) < CFG.dedup_iou  # box overlap alone says two
    assert dedupe.keep_distinct([whole, part], CFG, 10) == [0]
    # the mask alone decides when too few joints are confident in both
    few = part._replace(confidences=np.where(np.arange(17) < 3, 0.9, 0.1).astype(np.float32))
    assert np.isnan(dedupe.skeleton_distance(few, whole))
    assert dedupe.keep_distinct([whole, few], CFG, 10) == [0]
    # the skeleton alone decides when there is no mask
    bare = part._replace(mask=None)
    assert dedupe.keep_distinct([whole, bare], CFG, 10) == [0]


def test_two_overlapping_people_stay_two():
    # a near person and one behind, half hidden: the far box lies 88 % inside the near one, IoU 0.27
    near_mask = _body(x=(200, 360), y=(40, 380))
    far_mask = _body(x=(340, 380), y=(100, 300)) & ~near_mask
    near = _seen([200, 40, 370, 380], _skeleton(280, 40, 340), near_mask)
    far = _seen([300, 100, 380, 300], _skeleton(345, 100, 200), far_mask)
    assert dedupe.inside_fraction(far.box, near.box) >= CFG.dedup_inside
    assert dedupe.skeleton_distance(far, near) > CFG.dedup_joint_dist * 200
    assert dedupe.mask_inside_fraction(far, near) == 0.0
    assert dedupe.keep_distinct([near, far], CFG, 10) == [0, 1]
    # the far person's crop segmented the near one (mask inside), but its skeleton is its own: two
    taken = far._replace(mask=near_mask[100:300, 300:380].copy())
    assert dedupe.mask_inside_fraction(taken, near) >= CFG.dedup_mask_inside
    assert dedupe.keep_distinct([near, taken], CFG, 10) == [0, 1]
    # side by side with plain overlap (IoU 0.33, neither nested): two, whatever their skeletons
    left = _seen([100, 50, 200, 350], _skeleton(150, 50, 300), None)
    right = _seen([150, 50, 250, 350], _skeleton(150, 50, 300), None)
    assert dedupe.keep_distinct([left, right], CFG, 10) == [0, 1]


def test_near_identical_boxes_are_one_person_and_the_limit_holds():
    a = _seen([100, 50, 200, 350], _skeleton(150, 50, 300), None)
    b = _seen([105, 55, 205, 355], _skeleton(400, 50, 300), None)  # IoU 0.87: one, whatever the skeleton
    c = _seen([400, 50, 500, 350], _skeleton(450, 50, 300), None)
    assert dedupe.keep_distinct([a, b, c], CFG, 10) == [0, 2]
    assert dedupe.keep_distinct([a, b, c], CFG, 1) == [0]


@pytest.mark.parametrize("field,value", [("dedup_inside", 0.0), ("dedup_joint_dist", -0.1),
                                         ("dedup_mask_inside", 1.5)])
def test_config_validation_names_the_dedupe_fields(field, value):
    with pytest.raises(ConfigError, match=field):
        DetectorConfig(**{field: value}).validate()
