"""Smoother speed: ours (Viterbi + banded QPs + HMM) vs the paper's literal formulation (IPOPT).

    python benchmarks/smoother_speed.py [--frames 300 3000] [--samples 20] [--literal-samples 3]

Input: a synthetic sequence (subject walking, a flickering bystander, noisy skeletons, a focus
map every frame), turned into per-frame features once (that per-frame cost is reported apart:
in the service it is paid as each measurement arrives). Timed: the whole optimisation,
`smooth_sequence` (selection, box QP, mask/skeleton choice, joint QP over 17 joints x 2, focus
HMM, instructions); and the literal formulation of the same three problems with casadi/IPOPT
(bilinear main-subject NLP, joint QP, focus QP), problem build included, as Gekko would.
Goal: 300 frames < 20 ms total, >= 20x faster than the literal baseline.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from cinetransfer.services.smoother import baseline
from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.core import features_from_measurements, smooth_sequence
from cinetransfer.services.smoother.synthetic import walking_sequence

try:
    from smoother_common import stats, write_result
except ImportError:  # run as a module
    from benchmarks.smoother_common import stats, write_result


def literal_pipeline(feats, raw_joints_px, joint_conf, b, W, H) -> dict[str, float]:
    t0 = time.perf_counter()
    subj = baseline.literal_subject(feats)
    t1 = time.perf_counter()
    F = raw_joints_px.shape[0]
    y = raw_joints_px.reshape(F, -1)
    w = np.repeat(joint_conf, 2, axis=1)
    hi = np.tile([float(W), float(H)], y.shape[1] // 2)
    baseline.literal_smoothing(y, w, lo=np.zeros(y.shape[1]), hi=hi)
    t2 = time.perf_counter()
    baseline.literal_focus(b)
    t3 = time.perf_counter()
    return {"subject": t1 - t0, "joints": t2 - t1, "focus": t3 - t2, "total": t3 - t0, "status": subj.status}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[300, 3000])
    ap.add_argument("--samples", type=int, default=20)
    ap.add_argument("--literal-samples", type=int, default=3)
    args = ap.parse_args(argv)
    cfg = SmootherConfig()
    out = {}
    for n in args.frames:
        ms = walking_sequence(n, seed=n)
        t = time.perf_counter()
        feats = features_from_measurements(ms, cfg)
        feat_ms = (time.perf_counter() - t) * 1e3 / n
        smooth_sequence(feats, cfg)  # warm-up
        ours = []
        for _ in range(args.samples):
            t = time.perf_counter()
            r = smooth_sequence(feats, cfg)
            ours.append(time.perf_counter() - t)
        d = r.diagnostics
        W, H = feats[0].width, feats[0].height
        raw_px = np.nan_to_num(d["raw_joints"] * [W, H])
        conf = np.where(np.isfinite(d["raw_joints"]).all(axis=2), d["raw_joint_conf"], 0.0)
        b = r.instructions.focus_raw.astype(float)
        lit = [literal_pipeline(feats, raw_px, conf, b, W, H) for _ in range(args.literal_samples)]
        o = stats(1e3 * np.asarray(ours))
        lt = stats(1e3 * np.asarray([x["total"] for x in lit]))
        parts = {k: float(np.median([x[k] for x in lit]) * 1e3) for k in ("subject", "joints", "focus")}
        ratio = lt["median"] / o["median"]
        out[str(n)] = {"ours_ms": o, "literal_ms": lt, "literal_parts_median_ms": parts, "ratio": ratio,
                       "features_ms_per_frame": feat_ms, "literal_status": lit[-1]["status"]}
        print(f"{n:5d} frames: ours median {o['median']:.2f} ms (p95 {o['p95']:.2f}, max {o['max']:.2f}); "
              f"literal median {lt['median']:.0f} ms (subject {parts['subject']:.0f}, joints {parts['joints']:.0f}, "
              f"focus {parts['focus']:.0f}; IPOPT {lit[-1]['status']}); ratio {ratio:.0f}x; "
              f"per-frame features {feat_ms:.2f} ms")
    g300 = out.get("300")
    if g300:
        ok = g300["ours_ms"]["median"] < 20 and g300["ratio"] >= 20
        print(f"goal (300 frames < 20 ms and >= 20x): {'MET' if ok else 'NOT MET'}")
    p = write_result("smoother_speed", {"config": {"samples": args.samples, "literal_samples": args.literal_samples},
                                        "results": out})
    print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
