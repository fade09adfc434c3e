"""Focus estimator vs exact ground truth: DAVIS clips blurred with their masks on a schedule.

Each frame gets one condition (cycled): nothing blurred, background blurred, subject blurred,
foreground band (below the subject's feet) blurred, everything blurred; with a Gaussian blur
sigma cycled over 1.5, 2.5, 3.5, 5 px (native 854x480 pixels). A blurred background is pasted
behind the sharp subject with a hard mask edge; a blurred subject or foreground band is the layer
in front, so its silhouette is blurred as well (alpha = the blurred mask). Regions (DESIGN §1.1): subject =
ground-truth mask; foreground = image rows below the subject's lowest pixel; background = the
rest. Ground truth focused fraction per region = 0 if blurred else 1. The estimate is the
fraction of the region's pixels whose in-focus probability is > 0.5 (the paper's b_{f,t}).

Prints per-region mean absolute error (goal <= 0.12), pixel accuracy and in-focus IoU.

    python benchmarks/eval_detector_focus.py [--clips dance-twirl parkour] [--set key=value ...]
"""
from __future__ import annotations

import argparse
import ast
import time

import cv2
import numpy as np

from eval_detector_common import data_dir, davis_masks, stats, write_result
from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.services.detector.focus import FocusEstimator
from cinetransfer.shared.frame_sources import iter_frames

CONDITIONS = ("none", "background", "subject", "foreground", "all")
SIGMAS = (1.5, 2.5, 3.5, 5.0)
REGIONS = ("foreground", "subject", "background")


def regions(mask: np.ndarray) -> dict[str, np.ndarray]:
    h, w = mask.shape
    ys = np.flatnonzero(mask.any(axis=1))
    fg = np.zeros_like(mask)
    if len(ys) and ys[-1] + 1 < h:
        fg[ys[-1] + 1:, :] = True
    bg = ~mask & ~fg
    return {"foreground": fg, "subject": mask, "background": bg}


def blur_frame(img: np.ndarray, reg: dict[str, np.ndarray], cond: str, sigma: float) -> np.ndarray:
    if cond == "none":
        return img
    blurred = cv2.GaussianBlur(img, (0, 0), sigma)
    if cond == "all":
        return blurred
    sel = reg[cond]
    if cond == "background":
        # the background is behind the sharp subject: the subject's silhouette stays sharp
        out = img.copy()
        out[sel] = blurred[sel]
        return out
    # the subject / foreground band is the out-of-focus layer in front: its silhouette is
    # blurred too (a hard paste would put a sharp edge around a blurred object)
    alpha = cv2.GaussianBlur(sel.astype(np.float32), (0, 0), sigma)[..., None]
    alpha = np.maximum(alpha, sel[..., None].astype(np.float32))
    return (alpha * blurred + (1.0 - alpha) * img).round().astype(np.uint8)


def evaluate(cfg: DetectorConfig, clips: list[str], stride: int = 1, verbose: bool = True,
             masks_from: str = "detector") -> dict:
    """`masks_from`: which person masks guide the propagation: 'detector' (the full pipeline, as
    deployed), 'gt' (ground-truth masks: the estimator's ceiling), 'none' (no masks)."""
    focus_prob = _focus_method(cfg, masks_from)
    errs: dict[str, list[float]] = {r: [] for r in REGIONS}
    by_cond: dict[str, list[float]] = {c: [] for c in CONDITIONS}
    acc, ious, times = [], [], []
    k = 0
    for clip in clips:
        masks = davis_masks(clip)
        for f in iter_frames(data_dir() / f"davis_{clip}_854x480.mp4"):
            if f.index >= len(masks) or f.index % stride:
                continue
            reg = regions(masks[f.index])
            cond, sigma = CONDITIONS[k % len(CONDITIONS)], SIGMAS[(k // len(CONDITIONS)) % len(SIGMAS)]
            k += 1
            img = blur_frame(f.image, reg, cond, sigma)
            t = time.perf_counter()
            prob = focus_prob(img, masks[f.index])
            times.append(time.perf_counter() - t)
            h, w = img.shape[:2]
            focused = cv2.resize(prob, (w, h), interpolation=cv2.INTER_LINEAR) > 0.5
            a, iou, region_errs = frame_scores(focused, reg, cond)
            acc.append(a)
            ious.append(iou)
            for r, e in region_errs.items():
                errs[r].append(e)
                by_cond[cond].append(e)
    out = {
        "frames": k,
        "mean_abs_error": {r: float(np.mean(v)) for r, v in errs.items()},
        "error_by_condition": {c: float(np.mean(v)) for c, v in by_cond.items() if v},
        "pixel_accuracy": float(np.mean(acc)),
        "in_focus_iou": float(np.mean(ious)),
        "ms": stats(1e3 * np.asarray(times)),
    }
    if verbose:
        _print_summary(out, clips, stride, masks_from)
    return out


def _focus_method(cfg: DetectorConfig, masks_from: str):
    """(image, ground-truth mask) -> focus probability map: the whole detector (pose + focus) with
    'detector', else the focus estimator alone, given the ground-truth mask ('gt') or none."""
    if masks_from == "detector":
        from cinetransfer.services.detector.core import Detector

        det = Detector(cfg.replace(running_mode="image"))
        return lambda img, _mask: det.analyse(img, 0)[2].prob
    est = FocusEstimator(cfg)
    return lambda img, mask: est.estimate(img, mask if masks_from == "gt" else None).prob


def frame_scores(focused: np.ndarray, reg: dict[str, np.ndarray], cond: str) -> tuple[float, float, dict[str, float]]:
    """One frame blurred under `cond`: pixel accuracy and in-focus IoU of the focused map, and the
    error |b - b_true| of each region present (a region under 1 % of the frame is left out)."""
    h, w = focused.shape
    truth = np.ones((h, w), bool)
    if cond == "all":
        truth[:] = False
    elif cond != "none":
        truth[reg[cond]] = False
    u = (focused | truth).sum()
    iou = float((focused & truth).sum() / u) if u else 1.0
    region_errs = {}
    for r in REGIONS:
        if reg[r].sum() < 0.01 * h * w:  # region absent (or a sliver)
            continue
        gt = 0.0 if cond in (r, "all") else 1.0
        region_errs[r] = abs(float(focused[reg[r]].mean()) - gt)
    return float((focused == truth).mean()), iou, region_errs


def _print_summary(out: dict, clips: list[str], stride: int, masks_from: str) -> None:
    print(f"focus on {', '.join(clips)}: {out['frames']} frames (stride {stride}), person masks from {masks_from}")
    for r in REGIONS:
        print(f"  region {r:<10} mean |b - b_true| = {out['mean_abs_error'][r]:.3f}   (goal <= 0.12)")
    for c, v in out["error_by_condition"].items():
        print(f"  condition {c:<10} mean error {v:.3f}")
    print(f"  pixel accuracy {out['pixel_accuracy']:.3f}, in-focus IoU {out['in_focus_iou']:.3f}")
    what = "pose + focus" if masks_from == "detector" else "focus"
    print(f"  {what} time median {out['ms']['median']:.1f} ms, p95 {out['ms']['p95']:.1f} ms (854x480 input)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", nargs="+", default=["dance-twirl", "parkour"])
    ap.add_argument("--stride", type=int, default=1)
    ap.add_argument("--masks", choices=("detector", "gt", "none"), default="detector",
                    help="person masks guiding the propagation (default: the detector's own)")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="DetectorConfig overrides")
    a = ap.parse_args()
    over = {kv.split("=", 1)[0]: ast.literal_eval(kv.split("=", 1)[1]) for kv in a.set}
    cfg = DetectorConfig(**over).validate()
    res = evaluate(cfg, a.clips, a.stride, masks_from=a.masks)
    p = write_result(f"eval_detector_focus_{a.masks}", {"config": over, **res})
    print(f"wrote {p}")


if __name__ == "__main__":
    main()
