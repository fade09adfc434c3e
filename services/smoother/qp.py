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
    lam_c, lam2_c = _checked_weights(w, lam, lam2, C)
    w = np.where(np.isfinite(y), w, 0.0)
    y0 = np.where(w > 0, y, 0.0)
    lo_fc, hi_fc = _as_fc(lo, F, C), _as_fc(hi, F, C)
    if np.any(lo_fc > hi_fc):
        raise ValueError("lower bound above upper bound")
    lk = _checked_links(link, F)
    d_fc, bands = hessian_bands(w, lk, lam_c, lam2_c)
    undetermined = undetermined_runs(w, lk)
    if undetermined.any():  # a segment's couplings lie inside it: cut them, fix x = 0 (reported NaN)
        d_fc = np.where(undetermined, 1.0, d_fc)
        bands = [np.where(undetermined, 0.0, u) for u in bands]
    qp = _BoxQP.stack(d_fc, bands, w * y0, np.where(undetermined, -np.inf, lo_fc),
                      np.where(undetermined, np.inf, hi_fc))
    x, it = _solve_box(qp)
    x = np.where(undetermined.T.reshape(-1), np.nan, x)
    n_act = int(np.count_nonzero((x <= qp.lo) | (x >= qp.hi)))
    return QPResult(x.reshape(C, F).T.copy(), it, n_act)


def _checked_weights(w: np.ndarray, lam, lam2, C: int) -> tuple[np.ndarray, np.ndarray]:
    """The smoothness weights per column (C,); ValueError for a negative or non-finite weight."""
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and >= 0")
    lam_c = np.broadcast_to(np.asarray(lam, dtype=float), (C,))
    lam2_c = np.broadcast_to(np.asarray(lam2, dtype=float), (C,))
    if np.any(~np.isfinite(lam_c)) or np.any(lam_c < 0) or np.any(~np.isfinite(lam2_c)) or np.any(lam2_c < 0):
        raise ValueError("smoothness weights must be finite and >= 0")
    return lam_c, lam2_c


def _checked_links(link: np.ndarray | None, F: int) -> np.ndarray:
    lk = np.ones(F - 1, dtype=bool) if link is None else np.asarray(link, dtype=bool)
    if lk.shape != (F - 1,):
        raise ValueError(f"link must have shape ({F - 1},)")
    return lk


def hessian_bands(w: np.ndarray, lk: np.ndarray, lam_c: np.ndarray,
                  lam2_c: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The band of the Hessian per column, (F, C) each: the diagonal and the upper bands (row f
    couples f and f+k): [u1] with first differences only, [u1, u2] with the second-difference term."""
    F, C = w.shape
    d = w.copy()
    u1 = np.zeros((F, C))
    l1 = lk[:, None] * lam_c[None, :]  # (F-1, C)
    u1[:-1] -= l1
    d[:-1] += l1
    d[1:] += l1
    if not (bool(np.any(lam2_c > 0)) and F >= 3):
        return d, [u1]
    u2 = np.zeros((F, C))
    t = (lk[:-1] & lk[1:])[:, None] * lam2_c[None, :]  # triplet centred on f = 1..F-2
    d[:-2] += t
    d[1:-1] += 4 * t
    d[2:] += t
    u1[:-2] -= 2 * t
    u1[1:-1] -= 2 * t
    u2[:-2] += t
    return d, [u1, u2]


def undetermined_runs(w: np.ndarray, lk: np.ndarray) -> np.ndarray:
    """(F, C) True where a frame lies in a linked run of frames with no weight at all in its column."""
    seg = np.concatenate([[0], np.cumsum(~lk)])  # segment id per frame
    wsum = np.zeros((int(seg[-1]) + 1, w.shape[1]))
    np.add.at(wsum, seg, w)
    return wsum[seg] <= 0


@dataclass(frozen=True)
class _BoxQP:
    """The stacked system: column after column (index i = c * F + f), couplings past a column's
    end 0; Hessian diagonal `d`, upper bands `us` (band k couples i and i+k), right-hand side `b`
    and the box lo <= x <= hi."""

    d: np.ndarray
    us: tuple[np.ndarray, ...]
    b: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def stack(cls, d_fc: np.ndarray, bands: list[np.ndarray], rhs_fc: np.ndarray, lo_fc: np.ndarray,
              hi_fc: np.ndarray) -> _BoxQP:
        def flat(a: np.ndarray) -> np.ndarray:
            return a.T.reshape(-1)

        return cls(flat(d_fc), tuple(flat(u) for u in bands), flat(rhs_fc), flat(lo_fc), flat(hi_fc))

    def hess_times(self, x: np.ndarray) -> np.ndarray:
        out = self.d * x
        for k, u in enumerate(self.us, start=1):
            out[:-k] += u[:-k] * x[k:]
            out[k:] += u[:-k] * x[:-k]
        return out

    def _solve(self, d: np.ndarray, uu: list[np.ndarray], b: np.ndarray) -> np.ndarray:
        bw, n = len(self.us), self.d.size
        ab = np.zeros((bw + 1, n))
        ab[bw] = d
        for k, u in enumerate(uu, start=1):
            ab[bw - k, k:] = u[:-k]
        return solveh_banded(ab, b, lower=False, check_finite=False)

    def solve_fixed(self, act_lo: np.ndarray, act_hi: np.ndarray) -> np.ndarray:
        """Minimiser with the variables of the two sets fixed at their bounds."""
        fixed = act_lo | act_hi
        if not fixed.any():
            return self._solve(self.d, list(self.us), self.b)
        xb = np.where(act_lo, self.lo, np.where(act_hi, self.hi, 0.0))
        d = np.where(fixed, 1.0, self.d)
        b = self.b.copy()
        uu = []
        for k, u in enumerate(self.us, start=1):
            # Move couplings to fixed neighbours into the right-hand side, then cut them.
            b[:-k] -= np.where(~fixed[:-k] & fixed[k:], u[:-k] * xb[k:], 0.0)
            b[k:] -= np.where(~fixed[k:] & fixed[:-k], u[:-k] * xb[:-k], 0.0)
            uc = u.copy()
            uc[:-k] = np.where(fixed[:-k] | fixed[k:], 0.0, u[:-k])
            uu.append(uc)
        return self._solve(d, uu, np.where(fixed, xb, b))


def _solve_box(qp: _BoxQP) -> tuple[np.ndarray, int]:
    """The exact minimiser in the box and the banded solves it took: the primal-dual active-set
    loop, finished by the primal method if it does not settle."""
    x, it, converged = _primal_dual_active_set(qp)
    if not converged:
        # The loop is finite for Stieltjes matrices (first differences only); with the
        # second-difference term it can cycle. Finish with the primal active-set method
        # (Nocedal & Wright, Alg. 16.3), which is finite for any positive definite Hessian.
        x, k = _primal_active_set(qp, np.clip(x, qp.lo, qp.hi))
        it += k
    return x, it


def _primal_dual_active_set(qp: _BoxQP) -> tuple[np.ndarray, int, bool]:
    """Hintermüller, Ito & Kunisch: the last iterate, the solves taken, and whether the active sets settled."""
    act_lo = np.zeros(qp.d.size, dtype=bool)
    act_hi = np.zeros(qp.d.size, dtype=bool)
    x = np.zeros(qp.d.size)
    it = 0
    for it in range(1, MAX_PDAS_ITERS + 1):
        x = qp.solve_fixed(act_lo, act_hi)
        grad = qp.hess_times(x) - qp.b
        # Multipliers: lower-active needs grad >= 0, upper-active needs grad <= 0.
        new_lo = np.where(act_lo, grad > 0, x < qp.lo)
        new_hi = np.where(act_hi, grad < 0, x > qp.hi)
        if np.array_equal(new_lo, act_lo) and np.array_equal(new_hi, act_hi):
            return x, it, True
        act_lo, act_hi = new_lo, new_hi
    return x, it, False


def _primal_active_set(qp: _BoxQP, x: np.ndarray) -> tuple[np.ndarray, int]:
    """Primal active-set method from a feasible x: exact minimiser and the solves it took."""
    b0, lo, hi = qp.b, qp.lo, qp.hi
    tol = 1e-12 * (1.0 + float(np.max(np.abs(b0))))
    act_lo = x <= lo
    act_hi = (x >= hi) & ~act_lo
    for it in range(1, MAX_PRIMAL_ITERS + 1):
        xs = qp.solve_fixed(act_lo, act_hi)
        p = xs - x
        free = ~(act_lo | act_hi)
        if np.max(np.abs(p[free]), initial=0.0) <= 1e-13 * (1.0 + np.max(np.abs(x))):
            grad = qp.hess_times(xs) - b0
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
