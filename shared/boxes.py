"""Axis-aligned box helpers shared by the detector, the smoother and the evaluations."""
from __future__ import annotations


def box_iou(a, b) -> float:  # noqa: ANN001 - any (x0, y0, x1, y1) sequence
    """Intersection over union of two (x0, y0, x1, y1) boxes (0 when either is empty)."""
    iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = iw * ih
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0
