"""A detected body that cannot belong to its own head: its joints are dropped (pure numpy).

A pose model shown a face close-up (shoulders below the frame) or a figure that is not a person
(tos_clip01's robot) still returns shoulders and hips, often with high confidence. On tos_clip01's
close-ups it puts the "shoulders" at the jaw and the "hips" at the nose; a camera made to follow
them flew up 7 m to look down 47 degrees on a squashed torso. Three scale-free measures, the first
two against the head's width w (ear to ear), judged only where the joints they use are confident:

- neck: the distance from the ears' midpoint to the shoulder line, over w. A real neck and lower
  head: about 1 (median 1.15-1.3 on the juggler and the dancer); it shrinks when the head bows or
  the camera looks down on it (a vaulting runner seen from behind and above: 0.22).
- span: shoulder to shoulder, over w. A real body: about 2.5 from the front; turned sideways the
  shoulders close up (0.53 on the vaulting runner), but then the neck is long in the image.
- torso: from the shoulders' midpoint to the hips' midpoint, over the span (judged where both
  shoulders and both hips are confident). A real body: 1.2-1.5 from the front, more when turned;
  a camera looking down at 60 degrees halves it. Measured minimum on the juggler, parkour and
  dance-twirl skeletons: 1.02; tos_clip01's close-ups: down to 0.03 (hips at the nose).

A skeleton with both neck < `neck_min` and span < `span_min` has a head with no room for a body
under it, and one with torso < `torso_min` a trunk with no room for its organs: either way its body
joints (shoulders down) get confidence 0, i.e. missing, which the joint QP bridges like any
undetected joint; its head joints are kept. A bound of 0 turns its rule off. Measured with the
default bounds (neck 0.45 with span 2.0; torso 0.7) on the detector's skeletons (box_first):
juggler 0 of 248, DAVIS parkour 0 of 108, DAVIS dance-twirl 2 of 406 (two seated spectators, not
the dancer), tos_clip01 see docs/smoother.md §2. The cost: a real person seen from more than about
55 degrees above (torso 1.3 x cos 55 = 0.75) is near the bound.

The joint QP fills a joint from frames up to `max_bridge_s` away, so smoothed shoulders of one
frame can meet hips bridged from another skeleton; `drop_short_trunks` applies the torso rule to
the smoothed targets too and leaves such a row without hips and legs (the shoulders stay: in a
close-up they are the joints nearer the frame).
"""
from __future__ import annotations

import numpy as np

# COCO-17 indices
L_EAR, R_EAR, L_SHOULDER, R_SHOULDER, L_HIP, R_HIP = 3, 4, 5, 6, 11, 12
FIRST_BODY_JOINT = 5  # shoulders, elbows, wrists, hips, knees, ankles follow


def head_body_ratios(joints: np.ndarray, conf: np.ndarray,
                     min_confidence: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """(neck, span) of each skeleton (P, 17, 2) over its head width (module docstring); NaN where
    an ear or a shoulder is missing or below `min_confidence`."""
    joints = np.asarray(joints, dtype=float).reshape(-1, 17, 2)
    conf = np.asarray(conf, dtype=float).reshape(-1, 17)
    need = [L_EAR, R_EAR, L_SHOULDER, R_SHOULDER]
    judged = np.all(conf[:, need] >= min_confidence, axis=1) & np.all(np.isfinite(joints[:, need]), axis=(1, 2))
    ears_l, ears_r = joints[:, L_EAR], joints[:, R_EAR]
    sh_l, sh_r = joints[:, L_SHOULDER], joints[:, R_SHOULDER]
    w = np.maximum(np.linalg.norm(ears_l - ears_r, axis=1), 1e-6)
    line = sh_r - sh_l
    span_px = np.maximum(np.linalg.norm(line, axis=1), 1e-6)
    mid = (ears_l + ears_r) / 2 - sh_l
    neck_px = np.abs(line[:, 0] * mid[:, 1] - line[:, 1] * mid[:, 0]) / span_px
    nan = np.full(len(w), np.nan)
    return np.where(judged, neck_px / w, nan), np.where(judged, span_px / w, nan)


def torso_ratio(joints: np.ndarray, conf: np.ndarray, min_confidence: float = 0.5) -> np.ndarray:
    """Shoulders' midpoint to hips' midpoint over the shoulder span, per skeleton (P,); NaN where a
    shoulder or a hip is missing or below `min_confidence`."""
    joints = np.asarray(joints, dtype=float).reshape(-1, 17, 2)
    conf = np.asarray(conf, dtype=float).reshape(-1, 17)
    need = [L_SHOULDER, R_SHOULDER, L_HIP, R_HIP]
    judged = np.all(conf[:, need] >= min_confidence, axis=1) & np.all(np.isfinite(joints[:, need]), axis=(1, 2))
    span = np.maximum(np.linalg.norm(joints[:, L_SHOULDER] - joints[:, R_SHOULDER], axis=1), 1e-6)
    trunk = np.linalg.norm((joints[:, L_HIP] + joints[:, R_HIP] - joints[:, L_SHOULDER] - joints[:, R_SHOULDER]) / 2,
                           axis=1)
    return np.where(judged, trunk / span, np.nan)


def drop_implausible_bodies(joints: np.ndarray, conf: np.ndarray, *, neck_min: float, span_min: float,
                            torso_min: float = 0.0, min_confidence: float = 0.5) -> np.ndarray:
    """`conf` (P, 17) with the body joints of implausible skeletons set to 0 (a copy)."""
    out = np.array(conf, dtype=float, copy=True).reshape(-1, 17)
    if out.shape[0] == 0:
        return out
    bad = np.zeros(out.shape[0], dtype=bool)
    if neck_min > 0 and span_min > 0:
        neck, span = head_body_ratios(joints, out, min_confidence)
        bad |= (neck < neck_min) & (span < span_min)  # NaN compares False: not judged, kept
    if torso_min > 0:
        bad |= torso_ratio(joints, out, min_confidence) < torso_min
    out[bad, FIRST_BODY_JOINT:] = 0.0
    return out


def drop_short_trunks(joints: np.ndarray, torso_min: float) -> np.ndarray:
    """Smoothed joints (F, 17, 2) with hips and legs NaN in the rows whose trunk is shorter than
    `torso_min` shoulder spans (a copy; 0 = off)."""
    out = np.array(joints, dtype=float, copy=True)
    if torso_min <= 0 or out.shape[0] == 0:
        return out
    short = torso_ratio(out, np.ones(out.shape[:2])) < torso_min
    out[short, L_HIP:] = np.nan
    return out
