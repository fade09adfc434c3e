"""Main subject on real clips: box against the DAVIS masks, identity on TUD-Stadtmitte.

    python benchmarks/eval_smoother_box.py [--no-literal]

Measurements come from the project's detector (MediaPipe pose + masks, services/detector), run
once per clip and cached under benchmarks/results/cache/. Box: per frame, the mean absolute
error of the four coordinates (normalised by width/height) between the main-subject box and
the box of the DAVIS ground-truth mask — raw (the selected detection), optimised (our Viterbi +
box QP) and the paper's literal bilinear NLP (IPOPT) — mean and std over frames with a box.
Identity (TUD-Stadtmitte, ten pedestrians, MOT ground truth): every frame's selected detection
is matched to a ground-truth box (IoU >= 0.3); we count identity switches of the chosen track
and the share of matched frames on its most frequent identity (purity). The same is measured
with 'oracle' detections (ground-truth boxes with jitter, 10% dropouts, random confidences and
false positives), which isolates the selection from the detector's misses.
"""
from __future__ import annotations

import argparse
import os

import cv2
import numpy as np

from cinetransfer.services.smoother import baseline
from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.core import features_from_measurements, smooth_sequence
from cinetransfer.services.smoother.synthetic import person
from cinetransfer.shared import messages as M
from cinetransfer.shared.boxes import box_iou

try:
    from smoother_common import CACHE, data_dir, mean_std, write_result
except ImportError:
    from benchmarks.smoother_common import CACHE, data_dir, mean_std, write_result


def cached_measurements(video: str, fallback: str = "none") -> list[M.Measurement]:
    from cinetransfer.shared.measurements_file import read_measurements
    from cinetransfer.extract import measure_video

    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / (os.path.basename(video) + ("" if fallback == "none" else f".{fallback}") + ".msgpack")
    if not path.exists():
        from cinetransfer.services.detector.config import DetectorConfig
        from cinetransfer.shared.measurements_file import MeasurementsWriter

        ms, source, det = measure_video(video, progress=True,
                                        detector_config=DetectorConfig(person_fallback=fallback))
        tmp = path.with_suffix(".tmp")
        try:
            with MeasurementsWriter(tmp, source=source, detector=det.name, config=det.cfg) as w:
                for m in ms:
                    w.write(m)
        finally:
            det.close()
        os.replace(tmp, path)
    return list(read_measurements(path))


def mask_box(mask: np.ndarray) -> np.ndarray | None:
    ys = np.flatnonzero(mask.any(axis=1))
    xs = np.flatnonzero(mask.any(axis=0))
    if len(xs) == 0:
        return None
    return np.array([xs[0], ys[0], xs[-1] + 1, ys[-1] + 1], dtype=float)


def davis(name: str, cfg: SmootherConfig, literal: bool) -> dict:
    d = data_dir()
    ms = cached_measurements(str(d / f"davis_{name}_854x480.mp4"))
    masks = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) > 127 for p in sorted((d / f"davis_{name}_masks").glob("*.png"))]
    W, H = ms[0].width, ms[0].height
    scale = np.array([W, H, W, H], dtype=float)
    gt = np.array([mask_box(m) if mask_box(m) is not None else np.full(4, np.nan) for m in masks]) / scale
    feats = features_from_measurements(ms, cfg)
    r = smooth_sequence(feats, cfg)
    n = min(len(gt), r.instructions.subject_box.shape[0])
    raw = r.diagnostics["raw_box"][:n]
    opt = r.instructions.subject_box[:n].astype(float)
    out = {"frames": n, "detected": int(np.isfinite(raw).all(axis=1).sum()),
           "visible": int(r.instructions.subject_visible[:n].sum()),
           "raw": mean_std(np.abs(raw - gt[:n]).mean(axis=1)),
           "optimised": mean_std(np.abs(opt - gt[:n]).mean(axis=1))}
    if literal:
        lit = baseline.literal_subject(feats)
        out["literal"] = mean_std(np.abs(lit.box[:n] / scale - gt[:n]).mean(axis=1))
        out["literal_seconds"] = lit.seconds
    return out


def tud_gt() -> dict[int, list[tuple[int, np.ndarray]]]:
    gt: dict[int, list[tuple[int, np.ndarray]]] = {}
    for line in open(data_dir() / "tud_stadtmitte_gt.txt"):
        p = line.strip().split(",")
        if len(p) < 6:
            continue
        f, tid, x, y, w, h = (float(v) for v in p[:6])
        gt.setdefault(int(f) - 1, []).append((int(tid), np.array([x, y, x + w, y + h])))
    return gt


def identity_metrics(boxes: np.ndarray, gt: dict, n: int) -> dict:
    ids = []
    for f in range(n):
        b = boxes[f]
        if not np.isfinite(b).all():
            continue
        best = max(((box_iou(b, g), tid) for tid, g in gt.get(f, [])), default=(0.0, -1))
        if best[0] >= 0.3:
            ids.append(best[1])
    if not ids:
        return {"matched_frames": 0, "switches": 0, "purity": float("nan"), "main_id": -1}
    switches = int(sum(a != b for a, b in zip(ids[:-1], ids[1:])))
    vals, counts = np.unique(ids, return_counts=True)
    return {"matched_frames": len(ids), "switches": switches, "purity": float(counts.max() / len(ids)),
            "main_id": int(vals[np.argmax(counts)])}


def chosen_boxes(feats, person_idx) -> np.ndarray:
    out = np.full((len(feats), 4), np.nan)
    for f, k in enumerate(person_idx):
        if k >= 0:
            out[f] = feats[f].boxes[k]
    return out


def tud(cfg: SmootherConfig, literal: bool, oracle: bool, seed: int = 0, fallback: str = "none") -> dict:
    gt = tud_gt()
    d = data_dir()
    if oracle:
        rng = np.random.default_rng(seed)
        ms = []
        n = 179
        for f in range(n):
            ppl = []
            for tid, g in gt.get(f, []):
                if rng.uniform() < 0.10:
                    continue
                s = 0.03 * (g[3] - g[1])
                ppl.append(person(g + rng.normal(0, s, 4), float(rng.uniform(0.4, 1.0))))
            if rng.uniform() < 0.2:  # a false positive somewhere
                x, y = rng.uniform(0, 560), rng.uniform(100, 300)
                ppl.append(person(np.array([x, y, x + 50, y + 150]), float(rng.uniform(0.3, 0.9))))
            ms.append(M.Measurement(frame_index=f, fps=25.0, width=640, height=480, people=ppl, source="tud-oracle"))
    else:
        ms = cached_measurements(str(d / "tud_stadtmitte_640x480.mp4"), fallback)
        n = len(ms)
    feats = features_from_measurements(ms, cfg)
    r = smooth_sequence(feats, cfg)
    out = {"ours": identity_metrics(chosen_boxes(feats, r.diagnostics["person"]), gt, n),
           "detections_per_frame": float(np.mean([f.n_people for f in feats]))}
    if literal:
        lit = baseline.literal_subject(feats)
        out["literal"] = identity_metrics(chosen_boxes(feats, lit.person), gt, n)
        out["literal_seconds"] = lit.seconds
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-literal", action="store_true")
    args = ap.parse_args(argv)
    cfg = SmootherConfig()
    lit = not args.no_literal
    res: dict = {"davis": {}, "tud": {}}
    print("main-subject box error vs DAVIS mask box (normalised, mean of |dx0|,|dy0|,|dx1|,|dy1|): mean ± std")
    for name in ("dance-twirl", "parkour"):
        r = davis(name, cfg, lit)
        res["davis"][name] = r
        f = lambda a: f"{a['mean']:.4f} ± {a['std']:.4f} (n={a['n']})"  # noqa: E731
        print(f"  {name:12s} detected {r['detected']}/{r['frames']}  raw {f(r['raw'])}   optimised {f(r['optimised'])}"
              + (f"   literal NLP {f(r['literal'])}" if lit else ""))
    print("identity on TUD-Stadtmitte (switches of the chosen track; purity = share on its main identity)")
    for label, oracle, fb in (("detector", False, "none"), ("detector+hog", False, "hog"), ("oracle", True, "none")):
        r = tud(cfg, lit, oracle, fallback=fb)
        res["tud"][label] = r
        o = r["ours"]
        line = (f"  {label:8s} ({r['detections_per_frame']:.1f} detections/frame) ours: {o['switches']} switches, "
                "purity "
                f"{o['purity']:.3f} over {o['matched_frames']} matched frames")
        if lit:
            li = r["literal"]
            line += f"; literal NLP: {li['switches']} switches, purity {li['purity']:.3f} over {li['matched_frames']}"
        print(line)
    p = write_result("eval_smoother_box", res)
    print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
