"""Single-shot test sources with known focus choices, made from a DAVIS clip and its masks.

    python benchmarks/focus_sources.py OUT_DIR [--clip davis_parkour] [--choices all]

Regions per frame, from the clip's binary mask of the person, as the style extraction splits a
frame (smoother features): the subject (the mask), the foreground (every row below the subject's
feet: the ground nearer than the subject) and the background (everything else). A region asked
to be soft is blurred with a Gaussian of `SOFT_FLIPS` times the focus estimator's flip
(shared.camera.FOCUS_FLIP_SIGMA_PER_WIDTH) at the clip's width, composited through a feathered
mask; a sharp region is the clip as filmed. Choices (foreground, subject, background in focus):

- subject_soft: the subject and the band in front of it soft, the background sharp (focus beyond);
- background_soft: only the subject sharp;
- rack_focus: only the subject sharp, then at half the clip only the background;
- foreground_sharp: only the band below the feet sharp;
- all_sharp: the clip as filmed.

Writes OUT_DIR/<clip>_<choice>.mp4 and OUT_DIR/<clip>_<choice>.labels.json (the per-frame labels).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from cinetransfer.shared import camera as cam
from cinetransfer.data import data_dir

#: a soft region's blur, in units of the estimator's flip (well clear of it: it reads soft)
SOFT_FLIPS = 3.0
CLIPS = {"davis_parkour": ("davis_parkour_854x480.mp4", "davis_parkour_masks"),
         "davis_dance-twirl": ("davis_dance-twirl_854x480.mp4", "davis_dance-twirl_masks")}


def labels_of(choice: str, k: int, n: int) -> tuple[bool, bool, bool]:
    """(foreground, subject, background) in focus at frame k of n."""
    table = {"subject_soft": (False, False, True), "background_soft": (False, True, False),
             "foreground_sharp": (True, False, False), "all_sharp": (True, True, True)}
    if choice == "rack_focus":
        return (False, True, False) if k < n // 2 else (False, False, True)
    return table[choice]


CHOICES = ("subject_soft", "background_soft", "rack_focus", "foreground_sharp", "all_sharp")


def regions(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(foreground, subject, background) float masks in [0, 1] of one frame."""
    subj = (mask > 127).astype(np.float32)
    fg = np.zeros_like(subj)
    rows = np.nonzero(subj.any(axis=1))[0]
    if rows.size:
        fg[int(rows[-1]) + 1:, :] = 1.0
    return fg, subj, np.clip(1.0 - subj - fg, 0.0, 1.0)


def compose(frame: np.ndarray, mask: np.ndarray, focus: tuple[bool, bool, bool]) -> np.ndarray:
    """`frame` with each region not in focus blurred (feathered region masks)."""
    w = frame.shape[1]
    sigma = SOFT_FLIPS * cam.FOCUS_FLIP_SIGMA_PER_WIDTH * w
    soft = cv2.GaussianBlur(frame, (0, 0), sigma).astype(np.float32)
    alpha = np.zeros(frame.shape[:2], np.float32)
    for region, sharp in zip(regions(mask), focus):
        if not sharp:
            alpha += region
    alpha = np.clip(cv2.GaussianBlur(alpha, (0, 0), max(1.0, 0.5 * sigma)), 0.0, 1.0)[..., None]
    out = frame.astype(np.float32) * (1.0 - alpha) + soft * alpha
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def make(clip: str, choice: str, out_dir: Path) -> Path:
    """Write one source and its labels; returns the video's path."""
    video, masks = CLIPS[clip]
    root = data_dir()
    cap = cv2.VideoCapture(str(root / video))
    fps = cap.get(cv2.CAP_PROP_FPS) or 24.0
    frames = []
    while True:
        ok, fr = cap.read()
        if not ok:
            break
        frames.append(fr)
    cap.release()
    if not frames:
        raise SystemExit(f"focus_sources: cannot read {root / video}")
    n = len(frames)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{clip}_{choice}.mp4"
    h, w = frames[0].shape[:2]
    wr = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    labels = []
    for k, fr in enumerate(frames):
        m = cv2.imread(str(root / masks / f"{k:05d}.png"), cv2.IMREAD_GRAYSCALE)
        if m is None:
            raise SystemExit(f"focus_sources: mask {k:05d}.png missing in {root / masks}")
        focus = labels_of(choice, k, n)
        wr.write(compose(fr, cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST), focus))
        labels.append(list(focus))
    wr.release()
    (out_dir / f"{clip}_{choice}.labels.json").write_text(json.dumps(
        {"clip": video, "choice": choice, "fps": fps, "regions": ["foreground", "subject", "background"],
         "soft_sigma_flips": SOFT_FLIPS, "in_focus": labels}))
    return path


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--clip", choices=sorted(CLIPS), default="davis_parkour")
    ap.add_argument("--choices", nargs="+", choices=CHOICES, default=list(CHOICES))
    args = ap.parse_args(argv)
    for c in args.choices:
        print(make(args.clip, c, args.out_dir))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
