"""Exact solver of the box-constrained, confidence-weighted smoothing QP (pure numpy/scipy).

For every column c (a joint coordinate, a box component, a focus region) and frames f:

    min_x  sum_f w[f,c] (x[f,c] - y[f,c])^2  +  lam * sum_{f linked} (x[f+1,c] - x[f,c])^2
    s.t.   lo[c] <= x[f,c] <= hi[c]

The Hessian is tridiagonal per column. All columns are stacked into one block-tridiagonal
system (no coupling between columns, none across unlinked frame pairs) and solved with one
call to `scipy.linalg.solveh_banded` (banded Cholesky, O(F C)).

Bounds are handled by a primal-dual active-set loop (Hintermüller, Ito & Kunisch 2002): the
Hessian is a Stieltjes matrix (positive definite, non-positive off-diagonals), for which the
loop terminates after finitely many banded solves at the exact minimiser. When no bound is
active at the unconstrained solution, one solve is all it costs.

Frames with weight 0 (missing or low-confidence measurements) are bridged by the smoothness
term. A linked run of frames with no weight at all in a column is undetermined: its output is
NaN.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solveh_banded

MAX_ACTIVE_SET_ITERS = 100


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
           hi: float | np.ndarray = np.inf, link: np.ndarray | None = None) -> QPResult:
    """Solve the QP above. y, w: (F, C) (y may be NaN where w == 0); lam: scalar or (C,);
    lo, hi: scalars, (C,) or (F, C); link: (F-1,) bool, False cuts the smoothness term between
    frames f and f+1 (default: all linked)."""
    y = np.asarray(y, dtype=float)
    w = np.asarray(w, dtype=float)
    if y.ndim == 1:
        res = smooth(y[:, None], w[:, None], lam, lo=lo, hi=hi, link=link)
        return QPResult(res.x[:, 0], res.iterations, res.n_active)
    if y.shape != w.shape or y.ndim != 2:
        raise ValueError(f"y {y.shape} and w {w.shape} must both be (F, C)")
    F, C = y.shape
    if F == 0 or C == 0:
        return QPResult(np.zeros((F, C)), 0, 0)
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and >= 0")
    lam_c = np.broadcast_to(np.asarray(lam, dtype=float), (C,))
    if np.any(~np.isfinite(lam_c)) or np.any(lam_c < 0):
        raise ValueError("smoothness weight must be finite and >= 0")
    w = np.where(np.isfinite(y), w, 0.0)
    y0 = np.where(w > 0, y, 0.0)
    lo_fc, hi_fc = _as_fc(lo, F, C), _as_fc(hi, F, C)
    if np.any(lo_fc > hi_fc):
        raise ValueError("lower bound above upper bound")

    lk = np.ones(F - 1, dtype=bool) if link is None else np.asarray(link, dtype=bool)
    if lk.shape != (F - 1,):
        raise ValueError(f"link must have shape ({F - 1},)")
    # Column-major stacking: index i = c * F + f.
    e_fc = np.zeros((F, C))  # coupling between frame f and f+1 of column c (row f)
    e_fc[:-1] = -(lk[:, None] * lam_c[None, :])
    deg = np.zeros((F, C))
    deg[:-1] -= e_fc[:-1]
    deg[1:] -= e_fc[:-1]
    d_fc = w + deg
    # Undetermined runs: linked segments of a column with no weight at all.
    seg = np.concatenate([[0], np.cumsum(~lk)])  # segment id per frame
    n_seg = int(seg[-1]) + 1
    wsum = np.zeros((n_seg, C))
    np.add.at(wsum, seg, w)
    undetermined = (wsum[seg] <= 0)  # (F, C)
    if undetermined.any():
        d_fc = np.where(undetermined, 1.0, d_fc)
        e_fc = np.where(undetermined, 0.0, e_fc)  # a segment's links lie inside it
    rhs_fc = w * y0

    d0 = d_fc.T.reshape(-1)
    e0 = e_fc.T.reshape(-1)  # e0[i] couples i and i+1 (0 at column ends: e_fc[F-1] = 0)
    b0 = rhs_fc.T.reshape(-1)
    lo_v = lo_fc.T.reshape(-1)
    hi_v = hi_fc.T.reshape(-1)
    und = undetermined.T.reshape(-1)
    lo_v = np.where(und, -np.inf, lo_v)
    hi_v = np.where(und, np.inf, hi_v)
    n = d0.size

    def hess_times(x: np.ndarray) -> np.ndarray:
        out = d0 * x
        out[:-1] += e0[:-1] * x[1:]
        out[1:] += e0[:-1] * x[:-1]
        return out

    act_lo = np.zeros(n, dtype=bool)
    act_hi = np.zeros(n, dtype=bool)
    x = np.zeros(n)
    it = 0
    for it in range(1, MAX_ACTIVE_SET_ITERS + 1):
        fixed = act_lo | act_hi
        if fixed.any():
            xb = np.where(act_lo, lo_v, np.where(act_hi, hi_v, 0.0))
            d = np.where(fixed, 1.0, d0)
            b = b0.copy()
            # Move couplings to fixed neighbours into the right-hand side, then cut them.
            b[:-1] -= np.where(~fixed[:-1] & fixed[1:], e0[:-1] * xb[1:], 0.0)
            b[1:] -= np.where(~fixed[1:] & fixed[:-1], e0[:-1] * xb[:-1], 0.0)
            b = np.where(fixed, xb, b)
            e = e0.copy()
            e[:-1] = np.where(fixed[:-1] | fixed[1:], 0.0, e0[:-1])
        else:
            d, e, b = d0, e0, b0
        ab = np.empty((2, n))
        ab[0, 0] = 0.0
        ab[0, 1:] = e[:-1]
        ab[1] = d
        x = solveh_banded(ab, b, lower=False, check_finite=False)
        grad = hess_times(x) - b0
        # Multipliers: lower-active needs grad >= 0, upper-active needs grad <= 0.
        new_lo = np.where(act_lo, grad > 0, x < lo_v)
        new_hi = np.where(act_hi, grad < 0, x > hi_v)
        if np.array_equal(new_lo, act_lo) and np.array_equal(new_hi, act_hi):
            break
        act_lo, act_hi = new_lo, new_hi
    else:  # pragma: no cover - the loop is finite for Stieltjes matrices
        x = np.clip(x, lo_v, hi_v)
    x = np.where(und, np.nan, x)
    return QPResult(x.reshape(C, F).T.copy(), it, int(act_lo.sum() + act_hi.sum()))
