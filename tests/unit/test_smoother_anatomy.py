"""The anatomy check: a body that cannot belong to its head (hand-computed skeletons)."""
from __future__ import annotations

import numpy as np
import pytest

from cinetransfer.services.smoother.anatomy import (drop_implausible_bodies, drop_short_trunks, head_body_ratios,
                                                    torso_ratio)
from cinetransfer.services.smoother.features import frame_features
from cinetransfer.services.smoother.synthetic import measurement, person, skeleton_in


def skeleton(ears_x: tuple[float, float], ears_y: float, shoulders: tuple[tuple[float, float], tuple[float, float]]):
    """Joints (17, 2) with ears and shoulders where given, the rest below them; confidences 1."""
    j = np.zeros((17, 2))
    j[:, 0], j[:, 1] = 100.0, 400.0
    j[3], j[4] = (ears_x[0], ears_y), (ears_x[1], ears_y)
    j[5], j[6] = shoulders
    return j, np.ones(17)


def test_ratios_by_hand():
    # ears 20 px apart at y=100; shoulders 60 px apart on the line y=130: neck 30/20, span 60/20
    j, c = skeleton((90, 110), 100, ((70, 130), (130, 130)))
    neck, span = head_body_ratios(j[None], c[None])
    assert neck[0] == pytest.approx(1.5) and span[0] == pytest.approx(3.0)
    # a tilted shoulder line: (0,0)-(40,30) (length 50); ear midpoint (20,-10): distance |40*-10 - 30*20| / 50 = 20
    j, c = skeleton((10, 30), -10, ((0, 0), (40, 30)))
    neck, span = head_body_ratios(j[None], c[None])
    assert neck[0] == pytest.approx(20 / 20) and span[0] == pytest.approx(50 / 20)


def test_a_face_close_up_loses_its_body_and_keeps_its_head():
    # "shoulders" at the jaw: 5 px below ears 40 px apart, 60 px apart (neck 0.125, span 1.5)
    j, c = skeleton((80, 120), 100, ((70, 105), (130, 105)))
    out = drop_implausible_bodies(j[None], c[None], neck_min=0.45, span_min=2.0)[0]
    assert np.all(out[5:] == 0.0) and np.all(out[:5] == 1.0)
    assert c[5] == 1.0  # the input is not changed


@pytest.mark.parametrize("shoulders", [((50, 105), (150, 105)),   # neck short, shoulders wide: kept
                                       ((90, 160), (110, 160))])  # sideways: narrow, long neck: kept
def test_one_measure_alone_does_not_drop(shoulders):
    j, c = skeleton((80, 120), 100, shoulders)
    assert np.all(drop_implausible_bodies(j[None], c[None], neck_min=0.45, span_min=2.0) == 1.0)


def test_unjudged_or_switched_off_keeps_everything():
    j, c = skeleton((80, 120), 100, ((70, 105), (130, 105)))
    c_low = c.copy()
    c_low[3] = 0.3  # an ear not confident: not judged
    assert np.isnan(head_body_ratios(j[None], c_low[None])[0][0])
    assert np.all(drop_implausible_bodies(j[None], c_low[None], neck_min=0.45, span_min=2.0)[0] == c_low)
    assert np.all(drop_implausible_bodies(j[None], c[None], neck_min=0.0, span_min=2.0) == 1.0)
    empty = drop_implausible_bodies(np.zeros((0, 17, 2)), np.zeros((0, 17)), neck_min=0.45, span_min=2.0)
    assert empty.shape == (0, 17)


def test_frame_features_applies_the_check_to_a_real_measurement_layout():
    box = (500.0, 100.0, 700.0, 600.0)
    good = measurement(0, [person(box)], [skeleton_in(box)])
    f = frame_features(good, body_neck_min=0.45, body_span_min=2.0)
    assert np.all(f.joint_conf[0, 5:] > 0)  # the synthetic body is a normal one (neck 3.1, span 2.5)
    sk = good.skeletons[0]
    kp = np.array(sk.keypoints_px, dtype=float)
    kp[5, 1] = kp[6, 1] = kp[3, 1] + 2.0  # shoulders up at the ears ...
    mid, w = (kp[3, 0] + kp[4, 0]) / 2, abs(kp[3, 0] - kp[4, 0])
    kp[5, 0], kp[6, 0] = mid + 0.8 * w, mid - 0.8 * w  # ... and 1.6 head widths apart
    bad = measurement(0, [person(box)], [type(sk)(keypoints_px=kp.astype(np.float32), confidences=sk.confidences,
                                                  person_index=sk.person_index)])
    f = frame_features(bad, body_neck_min=0.45, body_span_min=2.0)
    assert np.all(f.joint_conf[0, 5:] == 0) and np.all(f.joint_conf[0, :5] > 0)
    assert np.all(frame_features(bad).joint_conf[0, 5:] > 0)  # off by default in the pure function


def with_hips(j: np.ndarray, hips: tuple[tuple[float, float], tuple[float, float]]) -> np.ndarray:
    j = j.copy()
    j[11], j[12] = hips
    return j


def test_torso_ratio_by_hand_and_the_torso_rule():
    # shoulders (70,130)-(130,130): span 60, midpoint (100,130); hips midpoint (100,160): trunk 30 -> 0.5
    j, c = skeleton((90, 110), 100, ((70, 130), (130, 130)))
    j = with_hips(j, ((80, 160), (120, 160)))
    assert torso_ratio(j[None], c[None])[0] == pytest.approx(0.5)
    out = drop_implausible_bodies(j[None], c[None], neck_min=0.45, span_min=2.0, torso_min=0.7)[0]
    assert np.all(out[5:] == 0.0) and np.all(out[:5] == 1.0)  # head fine (neck 1.5), trunk too short
    long = with_hips(j, ((80, 220), (120, 220)))  # trunk 90 -> 1.5
    assert np.all(drop_implausible_bodies(long[None], c[None], neck_min=0.45, span_min=2.0, torso_min=0.7) == 1.0)
    c_hip = c.copy()
    c_hip[11] = 0.2  # a hip not confident: the torso is not judged
    assert np.isnan(torso_ratio(j[None], c_hip[None])[0])


def test_smoothed_rows_with_a_short_trunk_lose_hips_and_legs():
    j, _ = skeleton((90, 110), 100, ((70, 130), (130, 130)))
    rows = np.stack([with_hips(j, ((80, 160), (120, 160))),   # trunk 0.5 spans: hips and legs dropped
                     with_hips(j, ((80, 220), (120, 220))),   # 1.5: kept
                     with_hips(j, ((np.nan, np.nan), (120, 160)))])  # one hip unknown: not judged
    out = drop_short_trunks(rows, 0.7)
    assert np.all(np.isnan(out[0, 11:])) and np.all(np.isfinite(out[0, :11]))
    assert np.array_equal(out[1], rows[1]) and np.array_equal(out[2], rows[2], equal_nan=True)
    assert np.array_equal(drop_short_trunks(rows, 0.0), rows, equal_nan=True)
