"""The paper's literal formulations, solved as nonlinear programs with IPOPT (casadi).

Kept as a baseline for accuracy and speed (benchmarks/smoother_speed.py,
benchmarks/eval_smoother_box.py); the default pipeline does not use it. The paper solved these
with Gekko (local IPOPT); casadi's IPOPT with exact symbolic derivatives is at least as fast, so
the speed ratios we report are conservative.

1. Main subject (bilinear, non-convex):
       min_{R, alpha} sum_f ||R_f - R_{f-1}||^2 + sum_m c_{f,m} alpha_{f,m} ||R_f - r_{f,m}||^2
       s.t. R_f inside the image, sum_m alpha_{f,m} = 1, 0 <= alpha <= 1
   (coordinates normalised by the image size; the minimiser does not depend on that scale).
   Identity of the subject in frame f: argmax_m alpha_{f,m}.
2. Joints: min sum_f ||P_f - P_{f-1}||^2 + sum q_f ||P_f - p_f||^2, P_f inside the image.
3. Focus: min sum_f (B_f - B_{f-1})^2 + (B_f (1 - 2 b_f))^2, 0 <= B <= 1.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from cinetransfer.services.smoother.features import FrameFeatures
from cinetransfer.services.smoother.subject import Selection

IPOPT_OPTS = {"print_time": 0, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": 3000,
              "ipopt.tol": 1e-8}


@dataclass(frozen=True, eq=False)
class LiteralSubject:
    box: np.ndarray  # (F, 4) px, the NLP's R
    person: np.ndarray  # (F,) argmax alpha, -1 for frames without detections
    alpha: np.ndarray  # (N,) flat over all detections in frame order
    status: str
    seconds: float


def literal_subject(frames: list[FrameFeatures], *, smoothness: float = 1.0) -> LiteralSubject:
    """Solve the paper's bilinear main-subject problem (local optimum from a uniform alpha start)."""
    t0 = time.perf_counter()
    F = len(frames)
    W = float(next(f.width for f in frames if f.width > 0))
    H = float(next(f.height for f in frames if f.height > 0))
    scale = np.array([W, H, W, H])
    counts = np.array([f.n_people for f in frames])
    N = int(counts.sum())
    if N == 0:
        raise ValueError("no detections")
    r = np.concatenate([f.boxes for f in frames if f.n_people]) / scale
    c = np.concatenate([f.conf for f in frames if f.n_people])
    frame_of = np.repeat(np.arange(F), counts)
    R = ca.SX.sym("R", F, 4)
    a = ca.SX.sym("a", N)
    obj = smoothness * ca.sumsqr(R[1:, :] - R[:-1, :]) if F > 1 else 0
    diff = R[frame_of.tolist(), :] - ca.DM(r)
    obj = obj + ca.dot(ca.DM(c) * a, ca.sum2(diff * diff))
    rows = np.flatnonzero(counts)
    S = ca.DM.zeros(len(rows), N)
    row_of = {f: k for k, f in enumerate(rows)}
    for i, f in enumerate(frame_of):
        S[row_of[int(f)], i] = 1.0
    x = ca.vertcat(ca.vec(R), a)
    solver = ca.nlpsol("subject", "ipopt", {"x": x, "f": obj, "g": ca.mtimes(S, a)}, IPOPT_OPTS)
    # Start: every alpha uniform in its frame, R the frame's mean detection (previous one if none).
    a0 = 1.0 / counts[frame_of]
    R0 = np.zeros((F, 4))
    last = r[0]
    for f in range(F):
        sel = frame_of == f
        if sel.any():
            last = r[sel].mean(axis=0)
        R0[f] = last
    x0 = np.concatenate([R0.T.reshape(-1), a0])
    lbx = np.concatenate([np.zeros(4 * F), np.zeros(N)])
    ubx = np.concatenate([np.ones(4 * F), np.ones(N)])
    sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=1.0, ubg=1.0)
    xs = np.asarray(sol["x"]).reshape(-1)
    Rs = xs[:4 * F].reshape(4, F).T * scale
    alpha = xs[4 * F:]
    person = np.full(F, -1)
    start = np.concatenate([[0], np.cumsum(counts)])
    for f in rows:
        person[f] = int(np.argmax(alpha[start[f]:start[f + 1]]))
    status = str(solver.stats().get("return_status", ""))
    return LiteralSubject(Rs, person, alpha, status, time.perf_counter() - t0)


def literal_selection(frames: list[FrameFeatures], *, fps: float, max_bridge_s: float = 0.5) -> Selection:
    """The literal problem's identities as a Selection (gaps up to max_bridge_s bridged)."""
    res = literal_subject(frames)
    person = res.person
    det = person >= 0
    visible = det.copy()
    G = int(round(max_bridge_s * fps))
    idx = np.flatnonzero(det)
    for i0, i1 in zip(idx[:-1], idx[1:]):
        if 1 < i1 - i0 <= G + 1:
            visible[i0 + 1:i1] = True
    return Selection(person, visible, visible & ~det, float("nan"))


def literal_smoothing(y: np.ndarray, w: np.ndarray, *, lo: np.ndarray, hi: np.ndarray,
                      smoothness: float = 1.0) -> tuple[np.ndarray, float]:
    """The joint problem as the paper states it, every column at once, solved by IPOPT.

    y, w: (F, C) (NaN y where w == 0); lo, hi: (C,). Returns (x (F, C), seconds)."""
    t0 = time.perf_counter()
    F, C = y.shape
    y0 = np.where(w > 0, y, 0.0)
    X = ca.SX.sym("X", F, C)
    obj = smoothness * ca.sumsqr(X[1:, :] - X[:-1, :]) + ca.sum1(ca.sum2(ca.DM(w) * (X - ca.DM(y0)) ** 2))
    solver = ca.nlpsol("joints", "ipopt", {"x": ca.vec(X), "f": obj}, IPOPT_OPTS)
    lbx = np.repeat(np.asarray(lo, float), F)
    ubx = np.repeat(np.asarray(hi, float), F)
    x0 = np.clip(np.nan_to_num(y0.T.reshape(-1)), lbx, ubx)
    sol = solver(x0=x0, lbx=lbx, ubx=ubx)
    x = np.asarray(sol["x"]).reshape(C, F).T
    return x, time.perf_counter() - t0


def literal_focus(b: np.ndarray) -> tuple[np.ndarray, float]:
    """The paper's printed focus problem for (F, 3) b, solved by IPOPT. Returns (B, seconds)."""
    t0 = time.perf_counter()
    F, C = b.shape
    w = np.where(np.isfinite(b), (1.0 - 2.0 * np.nan_to_num(b)) ** 2, 0.0)
    X = ca.SX.sym("B", F, C)
    obj = ca.sumsqr(X[1:, :] - X[:-1, :]) + ca.sum1(ca.sum2(ca.DM(w) * X ** 2))
    solver = ca.nlpsol("focus", "ipopt", {"x": ca.vec(X), "f": obj}, IPOPT_OPTS)
    sol = solver(x0=np.full(F * C, 0.5), lbx=0.0, ubx=1.0)
    return np.asarray(sol["x"]).reshape(C, F).T, time.perf_counter() - t0
