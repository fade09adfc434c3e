"""Exact solver of the box-constrained, confidence-weighted smoothing QP (pure numpy/scipy).

For every column c (a joint coordinate, a box component, a focus region) and frames f:

    min_x  sum_f w[f,c] (x[f,c] - y[f,c])^2  +  lam * sum_{f linked} (x[f+1,c] - x[f,c])^2
                                             + lam2 * sum_{f linked} (x[f+1,c] - 2 x[f,c] + x[f-1,c])^2
    s.t.   lo[c] <= x[f,c] <= hi[c]

The Hessian is tridiagonal per column (pentadiagonal with lam2 > 0). All columns are stacked into one block-tridiagonal
system (no coupling between columns, none across unlinked frame pairs) and solved with one
call to `scipy.linalg.solveh_banded` (banded Cholesky, O(F C)).

Bounds are handled by a primal-dual active-set loop (Hintermüller, Ito & Kunisch 2002): with
first differences only the Hessian is a Stieltjes matrix (positive definite, non-positive
off-diagonals), for which the loop terminates after finitely many banded solves at the exact
minimiser. With the second-difference term it may cycle; then the primal active-set method
(finite for any positive definite Hessian) finishes from where it stopped. When no bound is
active at the unconstrained solution, one solve is all it costs.

Frames with weight 0 (missing or low-confidence measurements) are bridged by the smoothness
term. A linked run of frames with no weight at all in a column is undetermined: its output is
NaN.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solveh_banded

MAX_PDAS_ITERS = 30  # primal-dual steps before switching to the primal method
MAX_PRIMAL_ITERS = 100_000


@dataclass(frozen=True)
class QPResult:
    x: np.ndarray  # (F, C) minimiser; NaN where undetermined
    iterations: int  # banded solves used
    n_active: int  # bounds active at the solution


def _as_fc(v: float | np.ndarray, F: int, C: int) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.ndim == 0:
        return np.full((F, C), float(a))
    if a.ndim == 1:
        if a.shape[0] != C:
            raise ValueError(f"bound of shape {a.shape} does not match {C} columns")
        return np.broadcast_to(a, (F, C)).copy()
    if a.shape != (F, C):
        raise ValueError(f"bound of shape {a.shape} does not match ({F}, {C})")
    return a.astype(float, copy=True)


def smooth(y: np.ndarray, w: np.ndarray, lam: float | np.ndarray, *, lo: float | np.ndarray = -np.inf,
           hi: float | np.ndarray = np.inf, link: np.ndarray | None = None, lam2: float | np.ndarray = 0.0,
           ) -> QPResult:
    """Solve the QP above. y, w: (F, C) (y may be NaN where w == 0); lam: scalar or (C,);
    lo, hi: scalars, (C,) or (F, C); link: (F-1,) bool, False cuts the smoothness terms between
    frames f and f+1 (default: all linked). `lam2` > 0 adds a second-difference (acceleration)
    term lam2 * sum (x[f+1] - 2 x[f] + x[f-1])^2 over linked triplets (pentadiagonal system)."""
    y = np.asarray(y, dtype=float)
    w = np.asarray(w, dtype=float)
    if y.ndim == 1:
        res = smooth(y[:, None], w[:, None], lam, lo=lo, hi=hi, link=link, lam2=lam2)
        return QPResult(res.x[:, 0], res.iterations, res.n_active)
    if y.shape != w.shape or y.ndim != 2:
        raise ValueError(f"y {y.shape} and w {w.shape} must both be (F, C)")
    F, C = y.shape
    if F == 0 or C == 0:
        return QPResult(np.zeros((F, C)), 0, 0)
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and >= 0")
    lam_c = np.broadcast_to(np.asarray(lam, dtype=float), (C,))
    lam2_c = np.broadcast_to(np.asarray(lam2, dtype=float), (C,))
    if np.any(~np.isfinite(lam_c)) or np.any(lam_c < 0) or np.any(~np.isfinite(lam2_c)) or np.any(lam2_c < 0):
        raise ValueError("smoothness weights must be finite and >= 0")
    w = np.where(np.isfinite(y), w, 0.0)
    y0 = np.where(w > 0, y, 0.0)
    lo_fc, hi_fc = _as_fc(lo, F, C), _as_fc(hi, F, C)
    if np.any(lo_fc > hi_fc):
        raise ValueError("lower bound above upper bound")

    lk = np.ones(F - 1, dtype=bool) if link is None else np.asarray(link, dtype=bool)
    if lk.shape != (F - 1,):
        raise ValueError(f"link must have shape ({F - 1},)")
    # Band of the Hessian per column (row f couples f and f+k): d (diagonal), u1, u2.
    d_fc = w.copy()
    u1 = np.zeros((F, C))
    u2 = np.zeros((F, C))
    l1 = lk[:, None] * lam_c[None, :]  # (F-1, C)
    u1[:-1] -= l1
    d_fc[:-1] += l1
    d_fc[1:] += l1
    second = bool(np.any(lam2_c > 0)) and F >= 3
    if second:
        t = (lk[:-1] & lk[1:])[:, None] * lam2_c[None, :]  # triplet centred on f = 1..F-2
        d_fc[:-2] += t
        d_fc[1:-1] += 4 * t
        d_fc[2:] += t
        u1[:-2] -= 2 * t
        u1[1:-1] -= 2 * t
        u2[:-2] += t
    # Undetermined runs: linked segments of a column with no weight at all.
    seg = np.concatenate([[0], np.cumsum(~lk)])  # segment id per frame
    n_seg = int(seg[-1]) + 1
    wsum = np.zeros((n_seg, C))
    np.add.at(wsum, seg, w)
    undetermined = (wsum[seg] <= 0)  # (F, C)
    if undetermined.any():  # a segment's couplings lie inside it: cut them, fix x = 0 (reported NaN)
        d_fc = np.where(undetermined, 1.0, d_fc)
        u1 = np.where(undetermined, 0.0, u1)
        u2 = np.where(undetermined, 0.0, u2)
    rhs_fc = w * y0

    # Column-major stacking: index i = c * F + f; couplings past a column's end are 0.
    d0 = d_fc.T.reshape(-1)
    us = [u1.T.reshape(-1)] + ([u2.T.reshape(-1)] if second else [])
    b0 = rhs_fc.T.reshape(-1)
    und = undetermined.T.reshape(-1)
    lo_v = np.where(und, -np.inf, lo_fc.T.reshape(-1))
    hi_v = np.where(und, np.inf, hi_fc.T.reshape(-1))
    n = d0.size
    bw = len(us)

    def hess_times(x: np.ndarray) -> np.ndarray:
        out = d0 * x
        for k, u in enumerate(us, start=1):
            out[:-k] += u[:-k] * x[k:]
            out[k:] += u[:-k] * x[:-k]
        return out

    def solve(d: np.ndarray, uu: list[np.ndarray], b: np.ndarray) -> np.ndarray:
        ab = np.zeros((bw + 1, n))
        ab[bw] = d
        for k, u in enumerate(uu, start=1):
            ab[bw - k, k:] = u[:-k]
        return solveh_banded(ab, b, lower=False, check_finite=False)

    def solve_fixed(act_lo: np.ndarray, act_hi: np.ndarray) -> np.ndarray:
        """Minimiser with the variables of the two sets fixed at their bounds."""
        fixed = act_lo | act_hi
        if not fixed.any():
            return solve(d0, us, b0)
        xb = np.where(act_lo, lo_v, np.where(act_hi, hi_v, 0.0))
        d = np.where(fixed, 1.0, d0)
        b = b0.copy()
        uu = []
        for k, u in enumerate(us, start=1):
            # Move couplings to fixed neighbours into the right-hand side, then cut them.
            b[:-k] -= np.where(~fixed[:-k] & fixed[k:], u[:-k] * xb[k:], 0.0)
            b[k:] -= np.where(~fixed[k:] & fixed[:-k], u[:-k] * xb[:-k], 0.0)
            uc = u.copy()
            uc[:-k] = np.where(fixed[:-k] | fixed[k:], 0.0, u[:-k])
            uu.append(uc)
        return solve(d, uu, np.where(fixed, xb, b))

    act_lo = np.zeros(n, dtype=bool)
    act_hi = np.zeros(n, dtype=bool)
    x = np.zeros(n)
    it = 0
    converged = False
    for it in range(1, MAX_PDAS_ITERS + 1):
        x = solve_fixed(act_lo, act_hi)
        grad = hess_times(x) - b0
        # Multipliers: lower-active needs grad >= 0, upper-active needs grad <= 0.
        new_lo = np.where(act_lo, grad > 0, x < lo_v)
        new_hi = np.where(act_hi, grad < 0, x > hi_v)
        if np.array_equal(new_lo, act_lo) and np.array_equal(new_hi, act_hi):
            converged = True
            break
        act_lo, act_hi = new_lo, new_hi
    if not converged:
        # The loop above is finite for Stieltjes matrices (first differences only); with the
        # second-difference term it can cycle. Finish with the primal active-set method
        # (Nocedal & Wright, Alg. 16.3), which is finite for any positive definite Hessian.
        x, k = _primal_active_set(solve_fixed, hess_times, b0, lo_v, hi_v, np.clip(x, lo_v, hi_v))
        it += k
    x = np.where(und, np.nan, x)
    n_act = int(np.count_nonzero((x <= lo_v) | (x >= hi_v)))
    return QPResult(x.reshape(C, F).T.copy(), it, n_act)


def _primal_active_set(solve_fixed, hess_times, b0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                       x: np.ndarray) -> tuple[np.ndarray, int]:
    """Primal active-set method from a feasible x: exact minimiser and the solves it took."""
    tol = 1e-12 * (1.0 + float(np.max(np.abs(b0))))
    act_lo = x <= lo
    act_hi = (x >= hi) & ~act_lo
    for it in range(1, MAX_PRIMAL_ITERS + 1):
        xs = solve_fixed(act_lo, act_hi)
        p = xs - x
        free = ~(act_lo | act_hi)
        if np.max(np.abs(p[free]), initial=0.0) <= 1e-13 * (1.0 + np.max(np.abs(x))):
            grad = hess_times(xs) - b0
            lam = np.where(act_lo, grad, np.where(act_hi, -grad, np.inf))
            j = int(np.argmin(lam))
            if lam[j] >= -tol:
                return xs, it
            act_lo[j] = act_hi[j] = False  # release the most violated bound
            x = xs
            continue
        # Longest step towards xs that stays feasible; a blocking bound joins the active set.
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(free & (p < 0), (lo - x) / p, np.where(free & (p > 0), (hi - x) / p, np.inf))
        j = int(np.argmin(r))
        alpha = min(1.0, float(r[j]))
        x = x + alpha * p
        if alpha < 1.0:
            if p[j] < 0:
                act_lo[j], x[j] = True, lo[j]
            else:
                act_hi[j], x[j] = True, hi[j]
    raise RuntimeError("box-constrained QP: the active-set method did not terminate")  # pragma: no cover
