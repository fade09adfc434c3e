"""Who is in the source clip and who was filmed: names and a side-by-side picture for the report.

The target is the simulator's subject (meta `subject`, from the subject library); the source
person is the library person cut from the same clip when there is one, else "the main subject of
<clip>". The picture puts the source clip's middle frame (main subject) beside the target's
first cut-out (on grey), both the same height.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

HEIGHT_PX = 300


def source_person(source_video: str | Path | None) -> str:
    from cinetransfer.services.autopilot_bridge.sim.scene import subject_info, subject_names

    name = Path(str(source_video or "")).name
    for sub in subject_names():
        info = subject_info(sub)
        if info.get("source") == name:
            return f"{info.get('person', sub)} [library subject '{sub}']"
    return f"the main subject of {name}" if name else "unknown"


def _cutout(subject: str) -> np.ndarray | None:
    from cinetransfer.services.autopilot_bridge.sim.scene import ASSETS_DIR, subject_info

    info = subject_info(subject)
    first = next(iter(info["actions"].values()))["frames"][0]
    img = cv2.imread(str(ASSETS_DIR / info["frames"][first]["file"]), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    a = img[..., 3:4].astype(np.float32) / 255.0
    return (img[..., :3].astype(np.float32) * a + 200.0 * (1 - a)).astype(np.uint8)


def _fit(img: np.ndarray) -> np.ndarray:
    s = HEIGHT_PX / img.shape[0]
    return cv2.resize(img, (max(1, int(round(img.shape[1] * s))), HEIGHT_PX), interpolation=cv2.INTER_AREA)


def middle_frame_index(source_video: str | Path | None) -> int | None:
    """The index of the source frame the picture shows (None: the video cannot be opened)."""
    cap = cv2.VideoCapture(str(source_video))
    try:
        return max(0, int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) // 2) if cap.isOpened() else None
    finally:
        cap.release()


def make_people(outdir: Path, meta: dict[str, Any], source_video: str | Path | None,
                middle: np.ndarray | None = None) -> dict[str, Any]:
    """{'source_person', 'target_person', 'figure' (path or None)}; writes fig_people.png. `middle`:
    the source's frame `middle_frame_index` (BGR) when the caller decoded it already (else it is
    sought and decoded here: the same pixels)."""
    out = {"source_person": source_person(source_video), "target_person": meta.get("target_person"),
           "subject": meta.get("subject"), "figure": None}
    subject = meta.get("subject")
    if not subject:
        return out
    ok, frame = middle is not None, middle
    if not ok:
        cap = cv2.VideoCapture(str(source_video))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        cap.set(cv2.CAP_PROP_POS_FRAMES, max(0, n // 2))
        ok, frame = cap.read()
        cap.release()
    cut = _cutout(subject)
    if not ok or cut is None:
        return out
    gap = np.full((HEIGHT_PX, 12, 3), 255, np.uint8)
    pic = np.hstack([_fit(frame), gap, _fit(cut)])
    path = outdir / "fig_people.png"
    cv2.imwrite(str(path), pic)
    out["figure"] = str(path)
    return out
