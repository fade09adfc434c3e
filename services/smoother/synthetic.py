"""Synthetic Measurements (no detector needed): used by the smoother tests, benchmarks and docs."""
from __future__ import annotations

import numpy as np

from cinetransfer.shared import messages as M

W, H = 640, 480


def person(box, conf=0.9, *, width=W, height=H) -> M.PersonDetection:
    x0, y0, x1, y1 = [int(round(v)) for v in box]
    x0, y0 = max(0, x0), max(0, y0)
    x1, y1 = min(width, x1), min(height, y1)
    mask = np.zeros((max(1, y1 - y0), max(1, x1 - x0)), dtype=bool)
    # an ellipse inside the box
    yy, xx = np.mgrid[0:mask.shape[0], 0:mask.shape[1]]
    cy, cx = (mask.shape[0] - 1) / 2, (mask.shape[1] - 1) / 2
    mask = ((yy - cy) / max(cy, 1)) ** 2 + ((xx - cx) / max(cx, 1)) ** 2 <= 1.0
    return M.PersonDetection(box_xyxy=np.array(box, dtype=np.float32), confidence=float(conf),
                             mask_origin_xy=np.array([x0, y0], dtype=np.int32), mask=mask)


def skeleton_in(box, *, conf=0.9, person_index=-1, rng=None, noise=0.0) -> M.Skeleton:
    """A plausible COCO-17 skeleton laid out inside a box."""
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    rel = np.array([[.5, .08], [.47, .06], [.53, .06], [.44, .07], [.56, .07],
                    [.35, .22], [.65, .22], [.3, .38], [.7, .38], [.28, .52], [.72, .52],
                    [.4, .55], [.6, .55], [.4, .75], [.6, .75], [.4, .95], [.6, .95]])
    kp = np.stack([x0 + rel[:, 0] * w, y0 + rel[:, 1] * h], axis=1)
    if rng is not None and noise:
        kp = kp + rng.normal(0, noise, kp.shape)
    return M.Skeleton(keypoints_px=kp.astype(np.float32), confidences=np.full(17, conf, np.float32),
                      person_index=person_index)


def measurement(i, people=(), skeletons=(), focus_map=None, *, fps=24.0, width=W, height=H) -> M.Measurement:
    return M.Measurement(stamp_ns=1_000_000_000 + int(i * 1e9 / fps), frame_index=i, fps=fps, width=width,
                         height=height, people=list(people), skeletons=list(skeletons), focus_map=focus_map,
                         source="synthetic")


def walking_sequence(n=120, *, fps=24.0, seed=0, focus=True, flicker=True):
    """A subject walking right (continuous) and a flickering bystander of higher confidence."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        u = (1.5 * i) % 600.0
        dx = u if u <= 300.0 else 600.0 - u  # walks right, then back (stays in the image)
        a = np.array([100 + dx, 120, 200 + dx, 400.0]) + rng.normal(0, 2, 4)
        people = [person(a, 0.7)]
        sks = [skeleton_in(a, person_index=0, rng=rng, noise=3.0)]
        if flicker and i % 3 == 0:
            bb = np.array([480, 100, 560, 300.0])
            people.append(person(bb, 0.98))
            sks.append(skeleton_in(bb, person_index=1))
        fm = None
        if focus:
            fm = np.zeros((H // 4, W // 4), np.uint8)
            x0, y0, x1, y1 = (a / 4).astype(int)
            fm[y0:y1, x0:x1] = 255  # subject sharp, rest blurred
        out.append(measurement(i, people, sks, fm, fps=fps))
    return out
