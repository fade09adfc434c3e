"""Person masks refined to the image and to the person's own body (pure, no state).

The pose models give a coarse segmentation: a 256x256 map warped back into the frame, so its
edge is a few pixels off the person's silhouette, and a crop that holds two people (or a person
and a lamp in front) can leave a detached blob of the other in the mask. Two steps fix what they
can without any model:

1. **Edges**: the mask is filtered with the grey image as guide (He et al.'s guided filter, the
   same one the focus map uses) and thresholded again at 0.5, so its boundary moves onto the
   nearest image edge within `radius` pixels.
2. **Own body**: of the mask's connected pieces only those holding one of the person's confident
   joints are kept; a piece with none of them belongs to something else in the crop.

A mask with no confident joint inside (a box-only person) is left to step 1 alone. Measured on
the DAVIS ground-truth masks (benchmarks/eval_detector.py, docs/detector.md).
"""
from __future__ import annotations

import cv2
import numpy as np

from cinetransfer.services.detector.focus import guided_filter
from cinetransfer.shared.messages import PersonDetection, Skeleton

#: a joint counts as the person's own when its confidence reaches this
JOINT_CONFIDENCE = 0.3


def snap_to_edges(grey: np.ndarray, mask: np.ndarray, *, radius: int = 3, eps: float = 1e-3) -> np.ndarray:
    """The mask (bool, same shape as `grey`, uint8 or float in [0, 1]) with its boundary moved
    onto the image's edges: guided filter of the mask, thresholded at 0.5."""
    g = grey.astype(np.float32)
    if grey.dtype == np.uint8:
        g /= 255.0
    return guided_filter(g, mask.astype(np.float32), radius, eps) > 0.5


def own_pieces(mask: np.ndarray, joints_xy: np.ndarray) -> np.ndarray:
    """The connected pieces of `mask` that hold at least one of `joints_xy` (N, 2) [px, in the
    mask's own pixel coordinates]; the mask unchanged when no joint falls on it."""
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    if n <= 2:
        return mask
    h, w = mask.shape
    p = np.floor(np.asarray(joints_xy, dtype=float).reshape(-1, 2)).astype(int)
    p = p[(p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)]
    keep = np.unique(labels[p[:, 1], p[:, 0]]) if len(p) else np.zeros(0, int)
    keep = keep[keep > 0]
    if keep.size == 0:
        return mask
    own = np.zeros(n, dtype=bool)
    own[keep] = True
    return own[labels]  # a look-up per label: cheaper than np.isin over the whole crop


def refine_person(image_bgr: np.ndarray, person: PersonDetection, skeleton: Skeleton | None, *,
                  radius: int = 3, eps: float = 1e-3, grey: np.ndarray | None = None) -> PersonDetection:
    """The person with its mask snapped to the image edges and cut to its own body, within its
    crop rectangle (box, crop, confidence and track id kept). A person without a mask is returned
    as is. `grey`: the whole frame in grey, when the caller has it already (the same pixels as
    converting the crop: the conversion is per pixel)."""
    mask = np.asarray(person.mask, dtype=bool)
    if mask.size == 0 or not mask.any():
        return person
    H, W = image_bgr.shape[:2]
    ox, oy = int(person.mask_origin_xy[0]), int(person.mask_origin_xy[1])
    m = 2 * radius + 1  # margin: the filter sees the image around the crop too
    x0, y0 = max(0, ox - m), max(0, oy - m)
    x1, y1 = min(W, ox + mask.shape[1] + m), min(H, oy + mask.shape[0] + m)
    if x1 <= x0 or y1 <= y0:
        return person
    local = np.zeros((y1 - y0, x1 - x0), dtype=bool)
    sx0, sy0 = max(0, x0 - ox), max(0, y0 - oy)  # part of the mask inside the frame
    sx1, sy1 = min(mask.shape[1], x1 - ox), min(mask.shape[0], y1 - oy)
    local[oy + sy0 - y0:oy + sy1 - y0, ox + sx0 - x0:ox + sx1 - x0] = mask[sy0:sy1, sx0:sx1]
    part = grey[y0:y1, x0:x1] if grey is not None else cv2.cvtColor(image_bgr[y0:y1, x0:x1], cv2.COLOR_BGR2GRAY)
    out = snap_to_edges(part, local, radius=radius, eps=eps)
    if skeleton is not None:
        ok = np.asarray(skeleton.confidences) >= JOINT_CONFIDENCE
        out = own_pieces(out, np.asarray(skeleton.keypoints_px, dtype=float)[ok] - (x0, y0))
    # back into the model's own crop rectangle: the box (the mask's box for most backends) and the
    # crop stay as they were; the edge moves within it (growing past it measured no better on DAVIS)
    crop = np.zeros_like(mask)
    crop[sy0:sy1, sx0:sx1] = out[oy + sy0 - y0:oy + sy1 - y0, ox + sx0 - x0:ox + sx1 - x0]
    if not crop.any():
        return person  # the filter dissolved a sliver: keep the model's mask
    return PersonDetection(box_xyxy=person.box_xyxy, confidence=person.confidence,
                           mask_origin_xy=person.mask_origin_xy, mask=crop, track_id=person.track_id)


def refine_people(image_bgr: np.ndarray, people: list[PersonDetection], skeletons: list[Skeleton],
                  **kw) -> list[PersonDetection]:
    """`refine_person` for every person, each with the skeleton that names it (if any)."""
    by_person = {s.person_index: s for s in skeletons if s.person_index >= 0}
    return [refine_person(image_bgr, p, by_person.get(i), **kw) for i, p in enumerate(people)]
