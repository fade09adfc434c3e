"""Focus per region (DESIGN §1.1 step 4): from measured fractions b_{f,t} to smoothed B_{f,t}.

b_{f,t} = focused pixels / pixels of region t in frame f (NaN = no measurement: region absent
or no focus map). The paper then minimises

    sum_f (B_f - B_{f-1})^2 + (B_f (1 - 2 b_f))^2,   0 <= B <= 1,          ('literal')

and calls region t in focus when B > theta. As printed, the second term is minimised by B = 0
whatever b is (it is a weighted penalty on B itself, with weight (1 - 2b)^2 >= 0), so the
optimum is B = 0 everywhere (any B is optimal only where b = 0.5 exactly): that cannot be what
was run. The text asks for continuity with values pushed towards 0 or 1.

Our formulation ('hmm', the default) says exactly that: each region is a two-state hidden
Markov chain (in focus / out of focus) that switches with a small probability per frame (the
continuity term), and b is a noisy measurement of the state (b ~ N(state, sigma^2)). B_{f,t} is
the posterior probability that region t is in focus in frame f given the whole sequence
(forward-backward), so it is in [0, 1], pushed towards 0 or 1 where the evidence agrees, and a
frame without a measurement is bridged by its neighbours. In focus: B > theta (0.5 = the
maximum a posteriori state per frame). Exact, O(F), no solver.

Also available: 'viterbi' (the most probable whole state sequence of the same model; B is 0/1)
and 'l2' (quadratic smoothing sum (B_f - B_{f-1})^2 lam + (B_f - b_f)^2, then threshold).
"""
from __future__ import annotations

import math

import numpy as np

from cinetransfer.services.smoother import qp


def switch_probability(p_at_24: float, fps: float) -> float:
    """Per-frame switching probability at `fps` with the same rate per second as at 24 fps."""
    return 1.0 - (1.0 - p_at_24) ** (24.0 / float(fps))


def _llr(b: np.ndarray, sigma: float | np.ndarray, mu0: float | np.ndarray = 0.0,
         mu1: float | np.ndarray = 1.0) -> np.ndarray:
    """Log-likelihood ratio log p(b | in) / p(b | out) for b ~ N(mu_state, sigma^2); 0 where b is NaN."""
    llr = ((b - mu0) ** 2 - (b - mu1) ** 2) / (2.0 * np.asarray(sigma) ** 2)
    return np.where(np.isfinite(b), llr, 0.0)


def fit_levels(b: np.ndarray, *, min_separation: float = 0.2, min_share: float = 0.05,
               fisher: float = 3.0, min_sigma: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per column, the levels of b in and out of focus, from the sequence itself (1-D 2-means).

    A focus estimator rarely gives exactly 0 or 1: a blurred region next to sharp ones can read
    0.6 where a sharp one reads 1.0. When a column clearly has two levels (means at least
    `min_separation` apart, each level in at least `min_share` of the frames, separation at least
    `fisher` pooled within-level deviations) its levels are used; otherwise the nominal 0 / 1.
    Returns mu0, mu1, sigma (within-level deviation, >= min_sigma; NaN when not fitted) and a
    'fitted' flag, each (C,)."""
    b = np.asarray(b, dtype=float)
    C = b.shape[1]
    mu0, mu1 = np.zeros(C), np.ones(C)
    sig = np.full(C, np.nan)
    fitted = np.zeros(C, dtype=bool)
    for c in range(C):
        v = b[np.isfinite(b[:, c]), c]
        if v.size < 10:
            continue
        lo, hi = np.quantile(v, [0.1, 0.9])
        if hi - lo < min_separation:
            continue
        for _ in range(20):
            mid = 0.5 * (lo + hi)
            a, z = v[v > mid], v[v <= mid]
            if a.size == 0 or z.size == 0:
                break
            nlo, nhi = float(z.mean()), float(a.mean())
            if nlo == lo and nhi == hi:
                break
            lo, hi = nlo, nhi
        a, z = v[v > 0.5 * (lo + hi)], v[v <= 0.5 * (lo + hi)]
        if min(a.size, z.size) < min_share * v.size:
            continue
        pooled = float(np.sqrt((np.sum((a - hi) ** 2) + np.sum((z - lo) ** 2)) / v.size))
        if hi - lo >= min_separation and hi - lo >= fisher * pooled:
            mu0[c], mu1[c], sig[c], fitted[c] = lo, hi, max(pooled, min_sigma), True
    return mu0, mu1, sig, fitted


def hmm_posterior(b: np.ndarray, *, switch_prob: float, sigma: float, adaptive: bool = False) -> np.ndarray:
    """P(in focus | all b), per frame and column: b (F, C) -> (F, C). Forward-backward in log-odds.

    adaptive: use the levels `fit_levels` finds in each column instead of the nominal 0 / 1."""
    b = np.asarray(b, dtype=float)
    one_d = b.ndim == 1
    if one_d:
        b = b[:, None]
    F, C = b.shape
    if adaptive:
        mu0, mu1, sig, fitted = fit_levels(b)
        llr = _llr(b, np.where(fitted, sig, sigma), mu0, mu1)
    else:
        llr = _llr(b, sigma)
    p = float(switch_prob)
    out = np.empty((F, C))
    exp, log = math.exp, math.log
    for c in range(C):
        e = llr[:, c].tolist()
        fwd = [0.0] * F  # log-odds of the state given b_0..b_f
        L = 0.0  # prior 1/2
        for f in range(F):
            if f:
                # prior log-odds after a transition: logit(p + (1 - 2p) sigmoid(L))
                if L >= 0:
                    z = exp(-L)  # sigmoid = 1 / (1 + z)
                    L = log((1.0 - p) + p * z) - log(p + (1.0 - p) * z)
                else:
                    z = exp(L)  # sigmoid = z / (1 + z)
                    L = log(p + (1.0 - p) * z) - log((1.0 - p) + p * z)
            L += e[f]
            fwd[f] = L
        post = [0.0] * F
        Lb = 0.0  # log-odds message from frames after f
        post[F - 1] = fwd[F - 1]
        for f in range(F - 2, -1, -1):
            q = e[f + 1] + Lb
            # beta_f(1)/beta_f(0) = ((1-p) Q + p) / (p Q + 1 - p), Q = exp(q), in log form
            if q > 0:
                z = exp(-q)
                Lb = log((1.0 - p) + p * z) - log(p + (1.0 - p) * z)
            else:
                z = exp(q)
                Lb = log((1.0 - p) * z + p) - log(p * z + 1.0 - p)
            post[f] = fwd[f] + Lb
        out[:, c] = post
    out = 1.0 / (1.0 + np.exp(-np.clip(out, -700, 700)))
    return out[:, 0] if one_d else out


def hmm_viterbi(b: np.ndarray, *, switch_prob: float, sigma: float) -> np.ndarray:
    """Most probable 0/1 state sequence of the same model (as float), b (F, C) -> (F, C)."""
    b = np.asarray(b, dtype=float)
    one_d = b.ndim == 1
    if one_d:
        b = b[:, None]
    F, C = b.shape
    ok = np.isfinite(b)
    bz = np.where(ok, b, 0.0)
    c0 = np.where(ok, bz ** 2, 0.0) / (2 * sigma * sigma)  # cost of state 0
    c1 = np.where(ok, (bz - 1.0) ** 2, 0.0) / (2 * sigma * sigma)
    sw = -math.log(switch_prob) + math.log(1.0 - switch_prob)  # extra cost of a switch
    out = np.empty((F, C))
    for c in range(C):
        e0, e1 = c0[:, c].tolist(), c1[:, c].tolist()
        v0, v1 = e0[0], e1[0]
        bp0 = [0] * F
        bp1 = [1] * F
        for f in range(1, F):
            s00, s10 = v0, v1 + sw
            s11, s01 = v1, v0 + sw
            if s00 <= s10:
                n0, bp0[f] = s00 + e0[f], 0
            else:
                n0, bp0[f] = s10 + e0[f], 1
            if s11 <= s01:
                n1, bp1[f] = s11 + e1[f], 1
            else:
                n1, bp1[f] = s01 + e1[f], 0
            v0, v1 = n0, n1
        s = 0 if v0 <= v1 else 1
        path = [0] * F
        for f in range(F - 1, -1, -1):
            path[f] = s
            s = bp0[f] if s == 0 else bp1[f]
        out[:, c] = path
    return out[:, 0] if one_d else out


def l2_smooth(b: np.ndarray, *, lam: float) -> np.ndarray:
    """min sum lam (B_f - B_{f-1})^2 + (B_f - b_f)^2, 0 <= B <= 1 (NaN b bridged)."""
    b = np.asarray(b, dtype=float)
    w = np.isfinite(b).astype(float)
    return qp.smooth(b, w, lam, lo=0.0, hi=1.0).x


def literal(b: np.ndarray) -> np.ndarray:
    """The paper's printed problem: min sum (B_f - B_{f-1})^2 + (B_f (1 - 2 b_f))^2, 0 <= B <= 1."""
    b = np.asarray(b, dtype=float)
    w = np.where(np.isfinite(b), (1.0 - 2.0 * np.nan_to_num(b)) ** 2, 0.0)
    return qp.smooth(np.zeros_like(b), w, 1.0, lo=0.0, hi=1.0).x


def soft_shot(b: np.ndarray, *, theta: float, floor: float, quantile: float = 0.9) -> tuple[np.ndarray, float]:
    """One shot's b (F, C), judged relative to its sharpest region when the footage is soft.

    The focus map's threshold is absolute (a defocus of about 1 px at 640 px width). Soft footage
    — a diffusion filter, compression, an upscaled or hazy film — can keep even the focused
    region below it for a whole shot: tos_clip01's two-shot reads 0.15-0.39 on the sharp actor
    against <= 0.08 on the blurred rest. A shot is soft when no region reaches `theta` in
    `quantile` of its frames; its sharpest region's median level L (if >= `floor`: else the shot
    is simply all out of focus) is then what "in focus" means there, and b becomes min(1, b / L).
    Any shot in which some region reads in focus is left alone. Returns (b, L; L NaN = unchanged)."""
    b = np.asarray(b, dtype=float)
    if b.size == 0 or not np.isfinite(b).any():
        return b, math.nan
    cols = [b[np.isfinite(b[:, c]), c] for c in range(b.shape[1])]
    cols = [v for v in cols if v.size]
    if max(float(np.quantile(v, quantile)) for v in cols) >= theta:
        return b, math.nan
    level = max(float(np.median(v)) for v in cols)
    if level < floor:
        return b, math.nan
    return np.minimum(1.0, b / level), level


def drop_short_runs(B: np.ndarray, *, min_run: int) -> np.ndarray:
    """B (F, C) with every run of fewer than `min_run` consecutive labelled (finite) frames of a
    column set to NaN (also used on joint coordinates, core._track_subject). A region seen for a
    frame or two — a hand or a passing head at the edge, a detection that flickers — gives no usable
    label: no lens follows it, and tos_clip01's two one-frame foreground labels inside a shot that
    otherwise has none pulled the focus off the subject for half a second."""
    out = np.array(B, dtype=float, copy=True)
    if min_run <= 1 or out.size == 0:
        return out
    for c in range(out.shape[1]):
        ok = np.concatenate(([False], np.isfinite(out[:, c]), [False]))
        edges = np.flatnonzero(ok[1:] != ok[:-1])  # starts and ends (exclusive) of the runs
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a < min_run:
                out[a:b, c] = np.nan
    return out


def smooth_focus(b: np.ndarray, *, method: str = "hmm", fps: float = 24.0, switch_prob_24: float = 0.02,
                 sigma: float = 0.25, lam_24: float = 4.0, adaptive: bool = False) -> np.ndarray:
    """B (F, C) from b (F, C) with the chosen method; NaN b (no measurement) bridged where possible."""
    b = np.asarray(b, dtype=float)
    if b.shape[0] == 0:
        return b.copy()
    if method == "hmm":
        return hmm_posterior(b, switch_prob=switch_probability(switch_prob_24, fps), sigma=sigma, adaptive=adaptive)
    if method == "viterbi":
        return hmm_viterbi(b, switch_prob=switch_probability(switch_prob_24, fps), sigma=sigma)
    if method == "l2":
        return l2_smooth(b, lam=lam_24 * (fps / 24.0) ** 2)
    if method == "literal":
        return literal(b)
    raise ValueError(f"unknown focus method {method!r}; use hmm | viterbi | l2 | literal")
