"""Joint accuracy on sequences with known truth: raw detector-like measures vs optimised.

    python benchmarks/eval_smoother_joints.py [--frames 300] [--scan]

Truth: smooth 2-D skeleton trajectories (COCO-17 laid out in a body box) for five motions —
walk, run (bobbing), dance (Lissajous path), far (small subject), zoom (scale change) — at
24 fps in a 1280x720 image. Measures: what a pose detector gives — heavy-tailed jitter
(Student-t, 3 dof, scale 1.2% of the body height), 2% outlier joints (10-25% of the body height
off, low confidence), 10% of joints missing, 4% of frames with no detection at all (bursts of
1-6 frames), confidences in [0.5, 1] for good joints. Error: the chest (mid-point of the
shoulders) in normalised image coordinates, |x/W - x*/W| and |y/H - y*/H|, mean and std over
frames (raw: frames where the detector gave both shoulders; optimised: every frame).
Goal: optimised below raw in every case, and <= the paper's Table I (chest mean x 0.065,
y 0.055).
"""
from __future__ import annotations

import argparse

import numpy as np

from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.core import features_from_measurements, smooth_sequence
from cinetransfer.services.smoother.synthetic import measurement, person
from cinetransfer.shared import messages as M

try:
    from smoother_common import mean_std, write_result
except ImportError:
    from benchmarks.smoother_common import mean_std, write_result

W, H, FPS = 1280, 720, 24.0
REL = np.array([[.5, .08], [.47, .06], [.53, .06], [.44, .07], [.56, .07],
                [.35, .22], [.65, .22], [.3, .38], [.7, .38], [.28, .52], [.72, .52],
                [.4, .55], [.6, .55], [.4, .75], [.6, .75], [.4, .95], [.6, .95]])
LS, RS = 5, 6
PAPER = {"x": 0.065, "y": 0.055}


def truth_track(kind: str, n: int) -> np.ndarray:
    """(n, 17, 2) true joints [px]."""
    t = np.arange(n) / FPS
    if kind == "walk":
        cx, cy, h = 200 + 700 * (t / t[-1]), 380 + 6 * np.sin(2 * np.pi * 2.0 * t), 500 + 0 * t
    elif kind == "run":
        cx, cy, h = 150 + 900 * (t / t[-1]), 380 + 14 * np.abs(np.sin(2 * np.pi * 1.5 * t)), 450 + 0 * t
    elif kind == "dance":
        cx, cy, h = 640 + 250 * np.sin(2 * np.pi * 0.4 * t), 380 + 60 * np.sin(2 * np.pi * 0.8 * t), 520 + 0 * t
    elif kind == "far":
        cx, cy, h = 300 + 600 * (t / t[-1]), 300 + 3 * np.sin(2 * np.pi * 2.0 * t), 110 + 0 * t
    elif kind == "zoom":
        cx, cy = 640 + 40 * np.sin(2 * np.pi * 0.2 * t), 360 + 0 * t
        h = 250 + 300 * (0.5 - 0.5 * np.cos(np.pi * t / t[-1]))
    else:
        raise ValueError(kind)
    w = 0.4 * h
    x0, y0 = cx - w / 2, cy - h / 2
    # small limb swing: wrists/elbows/knees/ankles oscillate
    swing = np.zeros((n, 17, 2))
    ph = 2 * np.pi * 1.0 * t
    for j, s in ((7, 1), (9, 1), (13, -1), (15, -1), (8, -1), (10, -1), (14, 1), (16, 1)):
        swing[:, j, 0] = s * 0.06 * np.sin(ph)
    rel = REL[None] + swing
    return np.stack([x0[:, None] + rel[..., 0] * w[:, None], y0[:, None] + rel[..., 1] * h[:, None]], axis=2)


def measure(truth: np.ndarray, rng: np.random.Generator) -> tuple[list[M.Measurement], np.ndarray]:
    """Detector-like measurements of the truth; also the raw joints (n, 17, 2) with NaN for missing."""
    n = truth.shape[0]
    hgt = truth[:, 15:, 1].max(axis=1) - truth[:, :3, 1].min(axis=1)
    noise = rng.standard_t(3, size=truth.shape) * (0.012 * hgt)[:, None, None]
    raw = truth + noise
    conf = rng.uniform(0.5, 1.0, size=(n, 17))
    out = rng.uniform(size=(n, 17)) < 0.02
    ang = rng.uniform(0, 2 * np.pi, size=(n, 17))
    mag = rng.uniform(0.10, 0.25, size=(n, 17)) * hgt[:, None]
    raw[..., 0] += np.where(out, mag * np.cos(ang), 0)
    raw[..., 1] += np.where(out, mag * np.sin(ang), 0)
    conf = np.where(out, rng.uniform(0.15, 0.45, size=(n, 17)), conf)
    miss = rng.uniform(size=(n, 17)) < 0.10
    raw[miss] = np.nan
    conf[miss] = 0.0
    lost = np.zeros(n, dtype=bool)
    i = 0
    while i < n:
        if rng.uniform() < 0.04 / 3.5:
            L = int(rng.integers(1, 7))
            lost[i:i + L] = True
            i += L
        i += 1
    raw[lost] = np.nan
    ms = []
    for f in range(n):
        if lost[f]:
            ms.append(measurement(f, [], [], fps=FPS, width=W, height=H))
            continue
        ok = np.isfinite(raw[f]).all(axis=1)
        p = raw[f][ok]
        box = np.array([p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max()])
        pad = 0.05 * (box[3] - box[1])
        box = np.clip(box + [-pad, -pad, pad, pad], 0, [W, H, W, H])
        sk = M.Skeleton(keypoints_px=raw[f].astype(np.float32), confidences=conf[f].astype(np.float32),
                        person_index=0)
        ms.append(measurement(f, [person(box, float(np.clip(conf[f][ok].mean(), 0, 1)), width=W, height=H)], [sk],
                              fps=FPS, width=W, height=H))
    return ms, raw


def evaluate(kind: str, n: int, seed: int, cfg: SmootherConfig) -> dict:
    rng = np.random.default_rng(seed)
    truth = truth_track(kind, n)
    ms, _ = measure(truth, rng)
    feats = features_from_measurements(ms, cfg)
    r = smooth_sequence(feats, cfg)
    d = r.diagnostics
    chest_t = 0.5 * (truth[:, LS] + truth[:, RS]) / [W, H]
    raw = d["raw_joints"]
    raw_ok = (np.isfinite(raw[:, LS]).all(axis=1) & np.isfinite(raw[:, RS]).all(axis=1)
              & (d["raw_joint_conf"][:, LS] >= cfg.min_joint_confidence)
              & (d["raw_joint_conf"][:, RS] >= cfg.min_joint_confidence))
    chest_r = 0.5 * (raw[:, LS] + raw[:, RS])
    chest_o = 0.5 * (d["smoothed_joints"][:, LS] + d["smoothed_joints"][:, RS])
    err_r = np.abs(chest_r - chest_t)[raw_ok]
    err_o = np.abs(chest_o - chest_t)
    all_r = np.abs(raw - truth / [W, H]).reshape(-1)
    all_o = np.abs(d["smoothed_joints"] - truth / [W, H]).reshape(-1)
    return {"raw": {"x": mean_std(err_r[:, 0]), "y": mean_std(err_r[:, 1])},
            "optimised": {"x": mean_std(err_o[:, 0]), "y": mean_std(err_o[:, 1])},
            "all_joints": {"raw": mean_std(all_r), "optimised": mean_std(all_o)},
            "visible": float(r.instructions.subject_visible.mean())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--scan", action="store_true", help="also scan the joint smoothness weight")
    args = ap.parse_args(argv)
    cfg = SmootherConfig()
    kinds = ("walk", "run", "dance", "far", "zoom")
    res, all_ok = {}, True
    paper_cfg = cfg.replace(joint_smoothness=1.0, joint_accel_smoothness=0.0)
    print(f"chest error, normalised, mean ± std over {args.seeds} seeds x {args.frames} frames "
          f"(ours: first-difference weight {cfg.joint_smoothness}, second-difference {cfg.joint_accel_smoothness} "
          f"at 24 fps; paper's QP: first-difference weight 1)")
    print(f"{'case':6s} {'raw x':>16s} {'opt x':>16s} {'raw y':>16s} {'opt y':>16s}  all joints raw -> opt"
          f"   paper's QP x / y")
    for kind in kinds:
        runs = [evaluate(kind, args.frames, 100 * s + 7, cfg) for s in range(args.seeds)]
        agg = {}
        for part in ("raw", "optimised"):
            agg[part] = {ax: {"mean": float(np.mean([r[part][ax]["mean"] for r in runs])),
                              "std": float(np.mean([r[part][ax]["std"] for r in runs]))} for ax in ("x", "y")}
        agg["all_joints"] = {p: float(np.mean([r["all_joints"][p]["mean"] for r in runs]))
                             for p in ("raw", "optimised")}
        pq = [evaluate(kind, args.frames, 100 * s + 7, paper_cfg)["optimised"] for s in range(args.seeds)]
        agg["paper_qp"] = {ax: {"mean": float(np.mean([r[ax]["mean"] for r in pq])),
                                "std": float(np.mean([r[ax]["std"] for r in pq]))} for ax in ("x", "y")}
        ok = all(agg["optimised"][ax]["mean"] < agg["raw"][ax]["mean"] and agg["optimised"][ax]["mean"] <= PAPER[ax]
                 for ax in ("x", "y"))
        all_ok &= ok
        res[kind] = agg
        f = lambda a: f"{a['mean']:.4f}±{a['std']:.4f}"  # noqa: E731
        print(f"{kind:6s} {f(agg['raw']['x']):>16s} {f(agg['optimised']['x']):>16s} {f(agg['raw']['y']):>16s} "
              f"{f(agg['optimised']['y']):>16s}  {agg['all_joints']['raw']:.4f} -> {agg['all_joints']['optimised']:.4f}"
              f"   {agg['paper_qp']['x']['mean']:.4f} / {agg['paper_qp']['y']['mean']:.4f}  {'ok' if ok else 'FAIL'}")
    print(f"goal (optimised < raw in every case, <= paper chest x {PAPER['x']}, y {PAPER['y']}): "
          f"{'MET' if all_ok else 'NOT MET'}")
    scan = {}
    if args.scan:
        for lam in (1.0, 2.0, 4.0, 6.0, 10.0, 16.0, 30.0):
            c = cfg.replace(joint_smoothness=lam)
            e = [evaluate(k, args.frames, 7, c)["optimised"] for k in kinds]
            scan[lam] = float(np.mean([0.5 * (x["x"]["mean"] + x["y"]["mean"]) for x in e]))
            print(f"  joint_smoothness {lam:5.1f}: mean chest error {scan[lam]:.5f}")
    p = write_result("eval_smoother_joints", {"frames": args.frames, "seeds": args.seeds, "paper_table1": PAPER,
                                              "results": res, "goal_met": all_ok, "scan": scan})
    print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
