"""A detected body that cannot belong to its own head: its joints are dropped (pure numpy).

A pose model shown a face close-up (shoulders below the frame) or a figure that is not a person
(tos_clip01's robot) still returns shoulders and hips, often with high confidence. On tos_clip01's
close-ups it puts the "shoulders" at the jaw and the "hips" at the nose; a camera made to follow
them flew up 7 m to look down 47 degrees on a squashed torso. Two scale-free measures against the
head's width w (ear to ear), judged only where both ears and both shoulders are confident:

- neck: the distance from the ears' midpoint to the shoulder line, over w. A real neck and lower
  head: about 1 (median 1.15-1.3 on the juggler and the dancer); it shrinks when the head bows or
  the camera looks down on it (a vaulting runner seen from behind and above: 0.22).
- span: shoulder to shoulder, over w. A real body: about 2.5 from the front; turned sideways the
  shoulders close up (0.53 on the vaulting runner), but then the neck is long in the image.

A skeleton with both neck < `neck_min` and span < `span_min` has a head with no room for a body
under it: its body joints (shoulders down) get confidence 0, i.e. missing, which the joint QP
bridges like any undetected joint; its head joints are kept. Either bound 0 turns the check off.
Measured with the default bounds (0.45, 2.0) on the detector's skeletons (box_first): juggler
0 of 248, DAVIS parkour 0 of 108, DAVIS dance-twirl 2 of 406 (two seated spectators, not the
dancer), tos_clip01 41 of 345 (close-ups of the actor's face and the robot).
"""
from __future__ import annotations

import numpy as np

# COCO-17 indices
L_EAR, R_EAR, L_SHOULDER, R_SHOULDER = 3, 4, 5, 6
FIRST_BODY_JOINT = 5  # shoulders, elbows, wrists, hips, knees, ankles follow


def head_body_ratios(joints: np.ndarray, conf: np.ndarray, min_confidence: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
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


def drop_implausible_bodies(joints: np.ndarray, conf: np.ndarray, *, neck_min: float, span_min: float,
                            min_confidence: float = 0.5) -> np.ndarray:
    """`conf` (P, 17) with the body joints of implausible skeletons set to 0 (a copy)."""
    out = np.array(conf, dtype=float, copy=True).reshape(-1, 17)
    if neck_min <= 0 or span_min <= 0 or out.shape[0] == 0:
        return out
    neck, span = head_body_ratios(joints, out, min_confidence)
    bad = (neck < neck_min) & (span < span_min)  # NaN compares False: not judged, kept
    out[bad, FIRST_BODY_JOINT:] = 0.0
    return out
