"""The camera-motion style: per-frame motions (the detector's) -> smoothed rates and a class per
row, shot by shot (a cut is no camera move: the motion across it is dropped)."""
from __future__ import annotations

import math

import numpy as np

from cinetransfer.shared import camera_motion as cm

#: rates are smoothed over this long a window [s]
SMOOTH_S = 0.5
#: a translation counts in a row when the window's mean direction is at least this long (the
#: frames around it agree that the camera translates)
TRANSLATION_AGREEMENT = 0.5


def motion_style(motion: np.ndarray, fps: float, cuts: np.ndarray) -> dict:
    """The Instructions' camera-motion fields for per-frame motions (F, 7) (pan, tilt, roll [rad],
    log-zoom, translation direction) at `fps`, with the shots starting where `cuts` (F,) is True."""
    mo = np.array(motion, dtype=float).reshape(-1, 7)
    n = len(mo)
    starts = np.asarray(cuts, dtype=bool).copy() if cuts is not None else np.zeros(n, dtype=bool)
    if n:
        starts[0] = True
    mo[starts] = np.nan  # the motion into a shot's first frame crosses the cut
    rates = np.column_stack([np.degrees(mo[:, :3]) * fps, mo[:, 3] * fps])
    window = max(1, int(round(SMOOTH_S * fps)) | 1)
    sm = np.full_like(rates, np.nan)
    trans = np.full((n, 3), np.nan)
    bounds = list(np.flatnonzero(starts)) + [n]
    for a, b in zip(bounds, bounds[1:]):
        sm[a:b] = cm.smooth_rates(rates[a:b], window)
        trans[a:b] = _smooth_translation(mo[a:b, 4:], window)
    classes = [cm.classify(*sm[k], trans[k]) for k in range(n)]
    return {"camera_motion_class": classes, "pan_rate_dps": sm[:, 0].astype(np.float32),
            "tilt_rate_dps": sm[:, 1].astype(np.float32), "roll_rate_dps": sm[:, 2].astype(np.float32),
            "zoom_rate": sm[:, 3].astype(np.float32), "translation_dir": trans.astype(np.float32)}


def _smooth_translation(t: np.ndarray, window: int) -> np.ndarray:
    """Mean direction over a centred window, unit length where the frames agree, else zeros; NaN
    where no frame of the window is known."""
    n = len(t)
    out = np.full((n, 3), np.nan)
    h = window // 2
    for k in range(n):
        w = t[max(0, k - h):k + h + 1]
        w = w[np.isfinite(w).all(axis=1)]
        if not len(w):
            continue
        m = w.mean(axis=0)
        norm = float(np.linalg.norm(m))
        out[k] = m / norm if norm >= TRANSLATION_AGREEMENT and math.isfinite(norm) else 0.0
    return out
