"""Mask and skeleton of the main subject (DESIGN §1.1 step 2) and the joint QP (step 3).

Step 2: M_f = argmax_m g(m_{f,m}, R_f) with g = pixels of mask m inside the smoothed box R_f;
p_f = argmax_p h(p_{f,p}, M_f) with h = joints of skeleton p inside M_f (ties: higher summed
joint confidence). A frame where no skeleton has a joint inside M_f has no skeleton.

Step 3: per joint and axis, min sum_f lam (P_f - P_{f-1})^2 + q_f (P_f - p_f)^2 with P_f inside
the image: the banded, box-constrained QP of `qp.smooth`, all 17 x 2 coordinates in one solve.
A joint that is missing (NaN) or below `min_joint_confidence` has weight 0 in that frame and is
bridged by the smoothness term. Frames where the subject is not visible cut the chain.

A joint the detector places outside the image (the hips below the bottom edge of a medium shot)
is not a dropout but out of frame: it has weight 0 and no target in that frame (NaN), so that
the instructions never ask for a joint the source does not show, pulled to the image edge.
"""
from __future__ import annotations

import numpy as np

from cinetransfer.services.smoother import qp
from cinetransfer.services.smoother.features import N_JOINTS, FrameFeatures, mask_pixels_inside


def subject_mask_index(feat: FrameFeatures, box: np.ndarray) -> int:
    """M_f: the person whose mask has the most pixels inside `box` (px); -1 if none overlaps."""
    if feat.n_people == 0 or not np.all(np.isfinite(box)):
        return -1
    if feat.n_people == 1:
        return 0 if feat.mask_pixels_inside(0, box) > 0 else -1
    g = np.array([feat.mask_pixels_inside(m, box) for m in range(feat.n_people)])
    k = int(np.argmax(g))
    return k if g[k] > 0 else -1


def subject_skeleton_index(feat: FrameFeatures, mask_index: int) -> int:
    """p_f: the skeleton with the most joints inside mask M_f; -1 if none has any."""
    if mask_index < 0 or feat.inside.shape[0] == 0:
        return -1
    if feat.inside.shape[0] == 1:
        return 0 if feat.inside[0, mask_index] > 0 else -1
    h = feat.inside[:, mask_index].astype(float)
    if h.max() <= 0:
        return -1
    # Tie-break by summed confidence (strictly below 1 joint's worth).
    score = h + 0.5 * feat.joint_conf.sum(axis=1) / (N_JOINTS + 1.0)
    return int(np.argmax(score))


def subject_mask_indices(feats: list[FrameFeatures], boxes_px: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """M_f for every frame at once (batched g over all people of the visible frames); -1 = none."""
    F = len(feats)
    out = np.full(F, -1)
    counts_all = np.fromiter((f.n_people for f in feats), dtype=int, count=F)
    fr = np.flatnonzero(visible & (counts_all > 0) & np.isfinite(boxes_px).all(axis=1)).tolist()
    if not fr:
        return out
    counts = np.array([feats[f].n_people for f in fr])
    grids = np.concatenate([feats[f].grids for f in fr])
    gx = np.concatenate([feats[f].grid_x for f in fr])
    gy = np.concatenate([feats[f].grid_y for f in fr])
    owner = np.repeat(np.arange(len(fr)), counts)
    g = mask_pixels_inside(grids, gx, gy, boxes_px[np.asarray(fr)][owner])
    start = np.concatenate([[0], np.cumsum(counts)])
    # First maximum of g within each frame's group.
    order = np.lexsort((np.arange(g.size), -g, owner))
    first = order[start[:-1]]
    best = first - start[:-1]
    ok = g[first] > 0
    out[np.asarray(fr)[ok]] = best[ok]
    return out


def raw_subject_joints(feats: list[FrameFeatures], boxes_px: np.ndarray, visible: np.ndarray,
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per frame: mask index M_f, skeleton index p_f, joints (F, 17, 2) px and confidences (F, 17)."""
    F = len(feats)
    mask_idx = subject_mask_indices(feats, boxes_px, visible)
    skel_idx = np.full(F, -1)
    joints = np.full((F, N_JOINTS, 2), np.nan)
    conf = np.zeros((F, N_JOINTS))
    for f in np.flatnonzero(mask_idx >= 0):
        feat = feats[f]
        skel_idx[f] = p = subject_skeleton_index(feat, int(mask_idx[f]))
        if p >= 0:
            joints[f] = feat.joints[p]
            conf[f] = feat.joint_conf[p]
    return mask_idx, skel_idx, joints, conf


def frames_from_observation(ok: np.ndarray) -> np.ndarray:
    """Per frame and joint (F, J): frames to the nearest frame where the joint was observed
    (0 where observed; a large number where it never was)."""
    F = ok.shape[0]
    idx = np.arange(F)[:, None].astype(float)
    big = float(10 * F + 10)
    last = np.maximum.accumulate(np.where(ok, idx, -big), axis=0)
    nxt = np.minimum.accumulate(np.where(ok, idx, 2 * big)[::-1], axis=0)[::-1]
    return np.minimum(idx - last, nxt - idx)


def outside_image(joints: np.ndarray, width: int, height: int) -> np.ndarray:
    """(F, J) the joint's position is known and lies outside the image [0, W] x [0, H] (px)."""
    x, y = joints[..., 0], joints[..., 1]
    with np.errstate(invalid="ignore"):
        out = (x < 0.0) | (x > width) | (y < 0.0) | (y > height)
    return out & np.isfinite(x) & np.isfinite(y)


def smooth_joints(joints: np.ndarray, conf: np.ndarray, visible: np.ndarray, *, lam: float, width: int,
                  height: int, min_confidence: float = 0.1, lam2: float = 0.0,
                  max_gap: int | None = None, cuts: np.ndarray | None = None) -> np.ndarray:
    """Smoothed joints (F, J, 2) px; NaN where the subject is not visible, and (with `max_gap`)
    where a joint is more than `max_gap` frames from any frame it was observed in — a joint
    that is out of the picture for a whole shot (hips in a close-up) is not controlled there,
    rather than bridged by a straight line or extrapolated. A joint placed outside the image is
    NaN in that frame whatever its confidence (module docstring)."""
    F, J, _ = joints.shape
    if F == 0:
        return joints.copy()
    outside = outside_image(joints, width, height)
    ok = np.all(np.isfinite(joints), axis=2) & (conf >= min_confidence) & (conf > 0) & visible[:, None] & ~outside
    w = np.where(ok, conf, 0.0)  # (F, J)
    y = joints.reshape(F, J * 2)
    ww = np.repeat(w, 2, axis=1)
    hi = np.tile([float(width), float(height)], J)
    link = visible[:-1] & visible[1:]
    if cuts is not None:
        link &= ~np.asarray(cuts, dtype=bool)[1:]  # never smooth from one shot into the next
    res = qp.smooth(y, ww, lam, lo=0.0, hi=hi, link=link, lam2=lam2)
    out = res.x.reshape(F, J, 2)
    out[~visible] = np.nan
    out[outside] = np.nan
    if max_gap is not None:
        # Distances are counted within a shot: an observation in the next shot bridges nothing.
        from cinetransfer.services.smoother.shots import segments

        for seg in segments(np.zeros(F, bool) if cuts is None else np.asarray(cuts, dtype=bool)):
            out[seg][frames_from_observation(ok[seg]) > max_gap] = np.nan
    return out
