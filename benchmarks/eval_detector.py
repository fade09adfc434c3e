"""Detector accuracy on the real clips (../shared/data, MANIFEST.md there).

- juggler (sam2_juggle): fraction of frames where the juggler is found with >= 12 of 17 joints
  confident (confidence >= 0.5).                                             goal >= 95 %
  and fraction of frames with exactly one person (the only one there).       goal >= 97 %
- DAVIS dance-twirl and parkour: main person's box IoU and mask IoU against the ground-truth
  masks (the detection that overlaps the truth most; a frame with no detection scores 0).
                                                             goal mean box IoU >= 0.75, mask >= 0.6
- TUD-Stadtmitte: person recall and precision at box IoU >= 0.5 (greedy matching by confidence).
                                                 goal recall >= 0.75 at precision >= 0.90
  (the mediapipe backend reached 0.189 / 0.876: `--set backend="'mediapipe'"`)

    python benchmarks/eval_detector.py [--only juggler davis tud] [--set key=value ...]

Writes benchmarks/results/eval_detector.json.
"""
from __future__ import annotations

import argparse
import ast
import os
import time

import numpy as np

from eval_detector_common import box_iou, data_dir, davis_masks, mask_box, mask_iou, tud_ground_truth, write_result
from cinetransfer.services.detector.config import DetectorConfig
from cinetransfer.services.detector.core import Detector


def _frames(det: Detector, path):
    det.reset()
    times = []
    for m_img in _iter(det, path, times):
        yield m_img
    _frames.last_ms = 1e3 * float(np.median(times)) if times else float("nan")


def _iter(det: Detector, path, times):
    from cinetransfer.shared.frame_sources import iter_frames

    for f in iter_frames(path):
        t = time.perf_counter()
        m = det.process(f.image, f.index, f.stamp_ns, fps=f.fps)
        times.append(time.perf_counter() - t)
        yield m


def eval_juggler(det: Detector) -> dict:
    n = ok = one = 0
    joints = []
    for m in _frames(det, data_dir() / "sam2_juggle_1280x720.mp4"):
        n += 1
        one += len(m.people) == 1
        best = max((int((s.confidences >= 0.5).sum()) for s in m.skeletons), default=0)
        joints.append(best)
        ok += best >= 12
    res = {"frames": n, "fraction_ge12_joints": ok / n, "median_confident_joints": float(np.median(joints)),
           "fraction_one_person": one / n, "ms_per_frame_median": _frames.last_ms}
    print(f"juggler: {ok}/{n} frames = {100 * ok / n:.1f} % with >= 12/17 confident joints (goal >= 95 %); "
          f"median {res['median_confident_joints']:.0f} joints; exactly one person in {one}/{n} frames = "
          f"{100 * one / n:.1f} % (goal >= 97 %)")
    return res


def eval_davis(det: Detector, name: str) -> dict:
    gts = davis_masks(name)
    box_ious, mask_ious, missed = [], [], 0
    for m in _frames(det, data_dir() / f"davis_{name}_854x480.mp4"):
        if m.frame_index >= len(gts):
            break
        gt = gts[m.frame_index]
        gb = mask_box(gt)
        if gb is None:
            continue
        best_b, best_m = 0.0, 0.0
        if m.people:
            ious = [box_iou(p.box_xyxy, gb) for p in m.people]
            k = int(np.argmax(ious))
            best_b = ious[k]
            best_m = mask_iou(m.people[k].full_mask(m.width, m.height), gt)
        else:
            missed += 1
        box_ious.append(best_b)
        mask_ious.append(best_m)
    res = {"frames": len(box_ious), "box_iou_mean": float(np.mean(box_ious)),
           "mask_iou_mean": float(np.mean(mask_ious)),
           "box_iou_median": float(np.median(box_ious)), "frames_missed": missed,
           "ms_per_frame_median": _frames.last_ms}
    print(f"DAVIS {name}: box IoU mean {res['box_iou_mean']:.3f} (median {res['box_iou_median']:.3f}), "
          f"mask IoU mean {res['mask_iou_mean']:.3f}, missed {missed}/{len(box_ious)} frames "
          f"(goal box >= 0.75, mask >= 0.6)")
    return res


def eval_tud(det: Detector) -> dict:
    gt = tud_ground_truth()
    tp = fp = fn = 0
    scored = []  # (confidence, is_tp) for a precision/recall curve
    for m in _frames(det, data_dir() / "tud_stadtmitte_640x480.mp4"):
        g = gt.get(m.frame_index, [])
        used: set[int] = set()
        for p in sorted(m.people, key=lambda p: -p.confidence):
            best, best_iou = -1, 0.5
            for j, b in enumerate(g):
                if j not in used:
                    iou = box_iou(p.box_xyxy, b)
                    if iou >= best_iou:
                        best, best_iou = j, iou
            if best >= 0:
                used.add(best)
                tp += 1
            else:
                fp += 1
            scored.append((p.confidence, best >= 0))
        fn += len(g) - len(used)
    n_gt = tp + fn
    recall, precision = tp / max(1, n_gt), tp / max(1, tp + fp)
    # best recall reachable at precision >= 0.8 by raising the confidence threshold
    scored.sort(key=lambda s: -s[0])
    best_r, ctp = 0.0, 0
    for i, (_, t) in enumerate(scored, 1):
        ctp += t
        if ctp / i >= 0.8:
            best_r = max(best_r, ctp / n_gt)
    res = {"recall": recall, "precision": precision, "tp": tp, "fp": fp, "fn": fn,
           "recall_at_precision_0.8": best_r, "ms_per_frame_median": _frames.last_ms}
    print(f"TUD-Stadtmitte: recall {recall:.3f}, precision {precision:.3f} at IoU 0.5 ({tp} TP, {fp} FP, {fn} FN); "
          f"best recall at precision >= 0.8: {best_r:.3f} (goal recall >= 0.75 at precision >= 0.90)")
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=("juggler", "davis", "tud"), default=["juggler", "davis", "tud"])
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="DetectorConfig overrides")
    ap.add_argument("--tud-set", nargs="*", default=None, metavar="KEY=VALUE",
                    help="overrides for the TUD run only (default: same as --set)")
    ap.add_argument("--name", default="eval_detector", help="result file name")
    a = ap.parse_args()

    def parse(kvs):
        return {kv.split("=", 1)[0]: ast.literal_eval(kv.split("=", 1)[1]) for kv in kvs}

    over = parse(a.set)
    cfg = DetectorConfig(**over).validate()
    print(f"config overrides: {over or 'none (defaults)'}; "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    out: dict = {"config": over}
    with Detector(cfg) as det:
        print(f"backend: {det.name}")
        out["backend"] = det.name
        if "juggler" in a.only:
            out["juggler"] = eval_juggler(det)
        if "davis" in a.only:
            clips = ("dance-twirl", "parkour")
            davis = out["davis"] = {n: eval_davis(det, n) for n in clips}
            davis["mean_box_iou"] = float(np.mean([davis[n]["box_iou_mean"] for n in clips]))
            davis["mean_mask_iou"] = float(np.mean([davis[n]["mask_iou_mean"] for n in clips]))
            print(f"DAVIS both: box IoU {davis['mean_box_iou']:.3f}, mask IoU {davis['mean_mask_iou']:.3f}")
    if "tud" in a.only:
        tud_over = parse(a.tud_set) if a.tud_set is not None else over
        if a.tud_set is not None:
            print(f"TUD config overrides: {tud_over}")
        with Detector(DetectorConfig(**tud_over).validate()) as det:
            out["tud"] = eval_tud(det)
            out["tud"]["config"] = tud_over
    print(f"wrote {write_result(a.name, out)}")


if __name__ == "__main__":
    main()
