"""Duplicate removal: whether two of a frame's candidate people are one person seen twice.

Two crops on one body give two candidates. Mostly their boxes nearly coincide (IoU > `dedup_iou`),
but a crop that saw only part of the body (arms raised, a side view) gives a box nested inside the
other, overlapping it by IoU ~0.4, with its landmarks on the same body. Box overlap alone cannot
tell that from two real people, one partly behind the other (a crowd): there the nested box holds a
different skeleton and a mask of other pixels. So a nested box (>= `dedup_inside` of its area inside
the other's) is the same person only when the body in it is the same: its confident joints lie where
the other's are (median distance <= `dedup_joint_dist` x the nested box's height), or, when too few
joints are confident in both to compare, its mask lies in the other's mask (>= `dedup_mask_inside`
of its pixels). The skeletons come first because a crop on a half-hidden person may segment the
person in front: on TUD-Stadtmitte, letting a mask alone merge cost one true person, the skeleton
first none (5 false people fewer either way).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from cinetransfer.shared.boxes import box_iou

JOINT_CONFIDENT = 0.5  # a joint's confidence from which its position is compared
MIN_SHARED_JOINTS = 5  # joints confident in both skeletons needed to call them one


class Seen(NamedTuple):
    """What duplicate removal looks at in one candidate person."""

    box: np.ndarray  # (4,) xyxy [px]
    keypoints: np.ndarray  # (17, 2) [px]
    confidences: np.ndarray  # (17,)
    mask: np.ndarray | None  # bool crop, or None (no mask)
    origin: tuple[int, int]  # the mask crop's top-left pixel (x, y)


def inside_fraction(small, big) -> float:  # noqa: ANN001 - any (x0, y0, x1, y1) sequences
    """Fraction of box `small`'s area that lies inside box `big` (0 for an empty `small`)."""
    iw = max(0.0, min(small[2], big[2]) - max(small[0], big[0]))
    ih = max(0.0, min(small[3], big[3]) - max(small[1], big[1]))
    area = max(0.0, small[2] - small[0]) * max(0.0, small[3] - small[1])
    return float(iw * ih / area) if area > 0 else 0.0


def skeleton_distance(a: Seen, b: Seen) -> float:
    """Median image distance [px] between the joints confident in both, NaN if fewer than
    MIN_SHARED_JOINTS are."""
    ok = (a.confidences >= JOINT_CONFIDENT) & (b.confidences >= JOINT_CONFIDENT)
    if int(ok.sum()) < MIN_SHARED_JOINTS:
        return float("nan")
    return float(np.median(np.linalg.norm(a.keypoints[ok] - b.keypoints[ok], axis=1)))


def mask_inside_fraction(small: Seen, big: Seen) -> float:
    """Fraction of `small`'s mask pixels that are also in `big`'s mask (NaN when `small` has none)."""
    if small.mask is None or not small.mask.any():
        return float("nan")
    if big.mask is None:
        return 0.0
    sx, sy = small.origin
    bx, by = big.origin
    sh, sw = small.mask.shape
    bh, bw = big.mask.shape
    x0, y0 = max(sx, bx), max(sy, by)
    x1, y1 = min(sx + sw, bx + bw), min(sy + sh, by + bh)
    if x1 <= x0 or y1 <= y0:
        return 0.0
    both = small.mask[y0 - sy:y1 - sy, x0 - sx:x1 - sx] & big.mask[y0 - by:y1 - by, x0 - bx:x1 - bx]
    return float(both.sum() / small.mask.sum())


def same_person(a: Seen, b: Seen, *, iou: float, inside: float, joint_dist: float, mask_inside: float) -> bool:
    """Whether candidates `a` and `b` are one person (see the module docstring for the rule)."""
    if box_iou(a.box, b.box) > iou:
        return True
    small, big = (a, b) if _area(a.box) <= _area(b.box) else (b, a)
    if inside_fraction(small.box, big.box) < inside:
        return False
    d = skeleton_distance(small, big)
    if not math.isnan(d):  # the skeletons decide when they can be compared: a mask may take in a neighbour
        return d <= joint_dist * max(1.0, float(small.box[3] - small.box[1]))
    return mask_inside_fraction(small, big) >= mask_inside


def keep_distinct(seen: list[Seen], cfg, limit: int) -> list[int]:  # noqa: ANN001 - DetectorConfig
    """Indices of the candidates kept, in the given order (surest first): each one that is not the
    same person as one kept before it, at most `limit`."""
    keep: list[int] = []
    for i, s in enumerate(seen):
        if len(keep) >= limit:
            break
        if not any(same_person(s, seen[k], iou=cfg.dedup_iou, inside=cfg.dedup_inside,
                               joint_dist=cfg.dedup_joint_dist, mask_inside=cfg.dedup_mask_inside) for k in keep):
            keep.append(i)
    return keep


def _area(b) -> float:  # noqa: ANN001
    return float(max(0.0, b[2] - b[0]) * max(0.0, b[3] - b[1]))
