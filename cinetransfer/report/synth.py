"""Small synthetic runs (instructions, truths, videos) for the report's tests and docs.

Nothing here is used by a real run; it only builds messages from shared/messages.py.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from cinetransfer.shared import messages as M

JOINTS: tuple[str, ...] = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")


def targets(k: int, *, phase: float = 0.0) -> np.ndarray:
    """(K, 4, 2) smooth shoulder/hip trajectories inside the image."""
    t = np.arange(k) / max(k - 1, 1)
    cx = 0.5 + 0.15 * np.sin(2 * np.pi * t + phase)
    cy = 0.45 + 0.05 * np.cos(2 * np.pi * t + phase)
    off = np.array([[-0.05, -0.1], [0.05, -0.1], [-0.04, 0.1], [0.04, 0.1]])
    return (np.stack([cx, cy], axis=1)[:, None, :] + off[None]).astype(np.float32)


def instructions(k: int = 48, *, fps: float = 24.0, image_targets: np.ndarray | None = None,
                 focus_in: np.ndarray | None = None, present: np.ndarray | None = None,
                 visible: np.ndarray | None = None, joint_names: Sequence[str] = JOINTS,
                 first_frame: int = 0, path: str = "synthetic.mp4") -> M.Instructions:
    """An Instructions message; focus_in defaults to 'subject in focus' throughout."""
    tg = targets(k) if image_targets is None else np.asarray(image_targets, np.float32)
    fin = np.tile([False, True, False], (k, 1)) if focus_in is None else np.asarray(focus_in, bool)
    pres = np.ones((k, 3), bool) if present is None else np.asarray(present, bool)
    vis = np.ones(k, bool) if visible is None else np.asarray(visible, bool)
    b = np.where(fin, 0.9, 0.1).astype(np.float32)
    B = np.where(fin, 0.97, 0.03).astype(np.float32)
    box = np.stack([tg[..., 0].min(1) - 0.05, tg[..., 1].min(1) - 0.15, tg[..., 0].max(1) + 0.05,
                    tg[..., 1].max(1) + 0.35], axis=1).clip(0, 1).astype(np.float32)
    return M.Instructions(
        source=M.SourceInfo(path=path, width=320, height=180, fps=fps, n_frames=k), fps=fps,
        frame_duration_s=1.0 / fps, first_frame=first_frame, joint_names=list(joint_names), image_targets=tg,
        subject_visible=vis, subject_box=box, focus_raw=np.where(pres, b, np.nan).astype(np.float32),
        focus_smoothed=np.where(pres, B, np.nan).astype(np.float32), focus_in=fin & pres)


def truths(image_targets: np.ndarray, *, joint_names: Sequence[str] = JOINTS, focus_in: np.ndarray | None = None,
           present: np.ndarray | None = None, first_index: int = 0,
           visible: np.ndarray | None = None) -> list[M.GroundTruth]:
    """One GroundTruth per row: the given joints placed at their COCO-17 slots (others NaN)."""
    tg = np.asarray(image_targets, float)
    k = tg.shape[0]
    fin = np.tile([False, True, False], (k, 1)) if focus_in is None else np.asarray(focus_in, bool)
    pres = np.ones((k, 3), bool) if present is None else np.asarray(present, bool)
    out = []
    for i in range(k):
        jn = np.full((17, 2), np.nan, np.float32)
        jv = np.zeros(17, bool)
        for e, name in enumerate(joint_names):
            j = M.COCO17_NAMES.index(name)
            jn[j] = tg[i, e]
            jv[j] = True if visible is None else bool(visible[i, e])
        out.append(M.GroundTruth(
            frame_index=first_index + i, joints_norm=jn, joints_visible=jv, subject_distance_m=6.0,
            dof_near_m=5.0, dof_far_m=8.0, region_present=pres[i].copy(), region_in_focus=fin[i] & pres[i],
            region_focus_fraction=np.where(pres[i], np.where(fin[i], 0.95, 0.05), np.nan).astype(np.float32)))
    return out


def video(path: Path, image_targets: np.ndarray, *, fps: float = 24.0, size: tuple[int, int] = (320, 180),
          colour: tuple[int, int, int] = (60, 90, 40)) -> Path:
    """A small mp4v video with a figure drawn at the targets (for the frames figure)."""
    import cv2

    w, h = size
    wr = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not wr.isOpened():
        raise OSError(f"cannot write {path}")
    try:
        for tg in np.asarray(image_targets, float):
            img = np.full((h, w, 3), colour, np.uint8)
            img[: h // 3] = (200, 170, 120)
            pts = (tg * [w, h]).astype(int)
            cv2.fillConvexPoly(img, pts[[0, 1, 3, 2]].reshape(-1, 1, 2), (40, 40, 200))
            c = pts[:2].mean(0).astype(int)
            cv2.circle(img, (int(c[0]), int(c[1] - 0.08 * h)), int(0.05 * h), (150, 180, 230), -1)
            wr.write(img)
    finally:
        wr.release()
    return path
