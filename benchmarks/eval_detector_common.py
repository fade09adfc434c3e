"""Shared helpers of the detector evaluation scripts (data paths, ground truth; result files and
statistics come from harness.py)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from cinetransfer.shared.boxes import box_iou  # noqa: F401 - used by the evaluation scripts
from cinetransfer.data import data_dir as shared_data_dir
from harness import stats, write_result  # noqa: F401 - the evaluation scripts' statistics and result files

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"


def data_dir() -> Path:
    try:
        return shared_data_dir()
    except FileNotFoundError as e:
        raise SystemExit(str(e)) from None


def davis_masks(name: str) -> list[np.ndarray]:
    """Boolean ground-truth masks of a DAVIS clip ('dance-twirl' or 'parkour'), frame order."""
    d = data_dir() / f"davis_{name}_masks"
    files = sorted(d.glob("*.png"))
    return [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) > 127 for f in files]


def mask_box(mask: np.ndarray) -> np.ndarray | None:
    ys = np.flatnonzero(mask.any(axis=1))
    xs = np.flatnonzero(mask.any(axis=0))
    if len(xs) == 0:
        return None
    return np.array([xs[0], ys[0], xs[-1] + 1, ys[-1] + 1], dtype=np.float64)


def tud_ground_truth() -> dict[int, list[np.ndarray]]:
    """TUD-Stadtmitte boxes (x0, y0, x1, y1) per 0-based frame index."""
    gt: dict[int, list[np.ndarray]] = {}
    for line in open(data_dir() / "tud_stadtmitte_gt.txt"):
        parts = line.strip().split(",")
        if len(parts) < 6:
            continue
        f, _, x, y, w, h = (float(v) for v in parts[:6])
        gt.setdefault(int(f) - 1, []).append(np.array([x, y, x + w, y + h]))
    return gt


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    u = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / u) if u else 0.0


