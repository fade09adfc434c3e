"""The CineMPC nonlinear program, built once with casadi; solved by SQP real-time iteration or IPOPT.

Multiple shooting over N stages of dt: decision vector [x_0, (u_k, x_{k+1}, slack_k) k < N],
x_0 fixed to the measured state through its bounds. Everything that changes between solves is a
runtime value — the measured state, the previous input, the subject's joints and velocity, the
image targets and their masks, the depth-of-field targets, the weights, the bounds — so a solve
never rebuilds anything. With `Structure.expand` the problem is built directly in SX (what
`expand: True` gives, without building an MX graph first); `expand=False` builds it in MX, as
a CineMPC-like baseline. `Structure.codegen` generates C for the NLP functions, compiles it
once and caches the shared library under `cache_dir`, keyed by the structure and this code.

Warm start: the last solution, shifted by the time elapsed since it was computed (states
interpolated, inputs held piecewise constant, multipliers shifted by whole stages), with the
new measured state in front.

Modules: the stages of the NLP (dynamics, soft constraints, cost terms, the SQP's residuals)
are built in cost.py; the solvers (`Structure.solver`) are sqp.py ("sqp_rti", the default: SQP
real-time iteration on stage-wise QPs) and ipopt.py ("ipopt", the reference; and the generated C
of either); StageData and SolveResult are in solve_result.py. This module holds the NLP together:
parameters, warm start, time budget, and the dispatch of a solve.

The wall-time budget can be set or lifted at run time (set_time_budget); every SolveResult
reports wall_s, cpu_s (this thread) and over_budget.
"""
from __future__ import annotations

import math
import time

import casadi as ca
import numpy as np

from cinetransfer.services.planner import constraints as C
from cinetransfer.services.planner import cost as J
from cinetransfer.services.planner import obstacles as OB
from cinetransfer.services.planner.config import Bounds, Structure, Weights
from cinetransfer.services.planner.cost import N_DOF, ParamLayout
from cinetransfer.services.planner.ipopt import IpoptMixin
from cinetransfer.services.planner.model import Layout, discrete_matrices, input_bounds
from cinetransfer.services.planner.solve_result import SolveResult, StageData
from cinetransfer.services.planner.sqp import SqpMixin

__all__ = ["MpcSolver", "N_DOF", "ParamLayout", "SolveResult", "StageData"]


class MpcSolver(SqpMixin, IpoptMixin):
    """Builds the NLP once; `solve(data)` runs IPOPT with the current weights and bounds."""

    def __init__(self, structure: Structure, bounds: Bounds | None = None, weights: Weights | None = None, *,
                 max_solve_time_s: float = 0.05, max_cold_solve_time_s: float | None = None,
                 feasibility_tol: float = 1e-4, accept_suboptimal: bool = True) -> None:
        self.s = structure.validate()
        self.layout = Layout(structure.control_roll)
        self.n = structure.horizon_steps
        self.dt = structure.dt_s
        self.e = structure.max_joints
        self.pl = ParamLayout(structure)
        self.max_solve_time_s: float | None = max_solve_time_s
        self.max_cold_solve_time_s = max(max_solve_time_s, max_cold_solve_time_s or 0.0)
        self._nominal_budget = (self.max_solve_time_s, self.max_cold_solve_time_s)  # restored by set_time_budget
        self.feasibility_tol = feasibility_tol
        self.accept_suboptimal = accept_suboptimal
        self.bounds = (bounds or Bounds()).validate()
        self.weights = (weights or Weights()).validate()
        t = time.perf_counter()
        self._build()
        self.build_s = time.perf_counter() - t
        self._guess: np.ndarray | None = None
        self._lam_x: np.ndarray | None = None
        self._lam_g: np.ndarray | None = None
        self._last: SolveResult | None = None
        self._lbg, self._ubg = C.constraint_bounds(self.layout, self.n)
        self._penalty_mu = 10.0  # exact-penalty weight of the SQP's merit (grows with the multipliers)

    # ------------------------------------------------------------------ build
    @property
    def nw(self) -> int:
        return self.layout.nx + self.n * (self.layout.nu + self.layout.nx + C.N_SOFT)

    def _build(self) -> None:
        s, lay, n = self.s, self.layout, self.n
        sym = ca.SX if s.expand else ca.MX
        w = sym.sym("w", self.nw)
        p = sym.sym("p", self.pl.size)
        par = J.NlpParams.of(p, self.pl.slices, self.e)
        self._ab_np = discrete_matrices(lay, self.dt)
        self._ab_dm = tuple(ca.DM(m) for m in self._ab_np)
        nx, nu = lay.nx, lay.nu
        blk = nu + nx + C.N_SOFT
        sqp = s.solver == "sqp_rti"
        # A stage-wise QP (HPIPM) cannot couple u_{k-1} and u_k, which the input-change cost does: either the
        # QP carries input copies as states (exact Gauss-Newton Hessian, stages of 19 + 11 variables: the
        # default) or, for warm iterations, that cost's cross-stage Hessian terms are dropped (block-diagonal;
        # the gradient stays exact, so the optimum is the same; about half the QP time, but slower convergence
        # along the weakly determined directions: a larger steady framing error in the benchmark). For the
        # SQP the previous input of stage k >= 1 is written as v_k (= u_{k-1}); the NLP's cost substitutes it.
        aug = sqp
        majorise = sqp and s.qp_solver == "hpipm"
        v_copy = sym.sym("v", max(n - 1, 0) * lay.nu)
        terms = J.StageBuilder(s, lay, self.dt, self._ab_dm).terms(w, par, v_copy, aug=aug, majorise=majorise)
        gvec = ca.vertcat(*terms.g)
        cost = cost_v = terms.cost
        if aug and n > 1:  # the NLP's own cost: v_k = u_{k-1}
            cost = ca.substitute(cost, v_copy, ca.vertcat(*[w[nx + k * blk:nx + k * blk + nu] for k in range(n - 1)]))
        nlp = {"x": w, "p": p, "f": cost, "g": gvec}
        self._gfun = ca.Function("g", [w, p], [gvec])
        self._ffun = ca.Function("f", [w, p], [cost])
        self._nlp = nlp
        self.last_stats: dict = {}
        if sqp:
            g_ocp = ca.vertcat(*terms.g_ocp)
            exact = self._build_sqp(w, v_copy, p, cost_v, g_ocp, ca.vertcat(*terms.resid, *terms.du_exact),
                                    copies=s.qp_solver == "hpipm", name="exact")
            self._sqp = {"cold": exact, "warm": exact}
            if majorise and not s.sqp_input_copies:
                self._sqp["warm"] = self._build_sqp(w, v_copy, p, cost_v, g_ocp,
                                                    ca.vertcat(*terms.resid, *terms.du_major), copies=False,
                                                    name="major")
        else:
            self._make_ipopt()

    def _budget_s(self, *, cold: bool) -> float:
        """Wall-time budget of a solve [s]; inf when lifted (set_time_budget(None))."""
        if self.max_solve_time_s is None:
            return math.inf
        return self.max_cold_solve_time_s if cold else self.max_solve_time_s

    def set_time_budget(self, seconds: float | None, cold_seconds: float | None = None) -> None:
        """Set the wall-time budget of a warm-started solve (and of a cold one: default max(seconds,
        the current cold budget)), or lift both with None (simulation lockstep: a solve then never
        fails for time, and SolveResult.wall_s / over_budget tell whether it would have met real time).
        IPOPT's instances are rebuilt (its options are fixed at creation; ~0.1 s); the SQP reads it per solve."""
        if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
            raise ValueError(f"time budget must be a finite value > 0 or None, got {seconds!r}")
        if seconds is None:
            self.max_solve_time_s = None  # the finite pair stays in _nominal_budget
        else:
            self.max_solve_time_s = float(seconds)
            self.max_cold_solve_time_s = max(float(seconds), float(cold_seconds) if cold_seconds is not None
                                             else self._nominal_budget[1])
            self._nominal_budget = (self.max_solve_time_s, self.max_cold_solve_time_s)
        if self.s.solver == "ipopt":
            self._make_ipopt()

    @property
    def time_budget_s(self) -> float | None:
        """The warm-solve wall-time budget [s], None when lifted."""
        return self.max_solve_time_s

    # ------------------------------------------------------------------ runtime parameters
    def set_weights(self, weights: Weights) -> None:
        self.weights = weights.validate()

    def set_bounds(self, bounds: Bounds) -> None:
        self.bounds = bounds.validate()

    def reset(self) -> None:
        """Forget the warm start (after a failure or a jump in the state)."""
        self._guess = self._lam_x = self._lam_g = None
        self._last = None

    def pack(self, data: StageData) -> np.ndarray:
        lay, sl = self.layout, self.pl.slices
        p = np.zeros(self.pl.size)
        p[sl["u_prev"]] = data.u_prev
        p[sl["joints"]] = np.asarray(data.joints_w, dtype=float).reshape(-1)  # (E, 3) row-major = 3 x E columns
        p[sl["centre"]] = data.subject_centre_w
        p[sl["subj_vel"]] = data.subject_velocity
        p[sl["targets"]] = np.asarray(data.targets, dtype=float).reshape(-1)
        p[sl["mask"]] = np.asarray(data.mask, dtype=float).reshape(-1)
        p[sl["dof"]] = np.asarray(data.dof, dtype=float).reshape(-1)
        p[sl["dref"]] = data.distance_ref
        if data.motion is not None:
            p[sl["motion"]] = np.asarray(data.motion, dtype=float).reshape(-1)
        p[sl["weights"]] = self.weights.as_vector()
        _, uhi = input_bounds(lay, self.bounds)
        p[sl["u_scale"]] = 1.0 / uhi
        p[sl["v_scale"]] = 1.0 / self.bounds.speed_max_mps
        p[sl["soft"]] = C.soft_limits(self.bounds, data.min_distance_m)
        if data.obstacles is not None:  # one set of slots holds at every stage
            p[sl["obstacles"]] = np.broadcast_to(np.asarray(data.obstacles, dtype=float),
                                                 (self.n, OB.STAGE_SIZE)).reshape(-1)
        if not np.all(np.isfinite(p)):
            raise ValueError("non-finite solver parameter")
        return p

    # ------------------------------------------------------------------ warm start
    def _split(self, wv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        lay, n = self.layout, self.n
        nx, nu = lay.nx, lay.nu
        blk = wv[nx:].reshape(n, nu + nx + C.N_SOFT)
        x = np.vstack([wv[:nx], blk[:, nu:nu + nx]])
        return x, blk[:, :nu].copy(), blk[:, nu + nx:].copy()

    def _join(self, x: np.ndarray, u: np.ndarray, sl: np.ndarray) -> np.ndarray:
        return np.concatenate([x[0], np.hstack([u, x[1:], sl]).reshape(-1)])

    def cold_guess(self, x0: np.ndarray) -> np.ndarray:
        """x0 held over the horizon (zero velocity), zero inputs: CineMPC's kind of start."""
        lay = self.layout
        xs = np.tile(x0, (self.n + 1, 1))
        xs[1:, lay.V] = 0.0
        return self._join(xs, np.zeros((self.n, lay.nu)), np.zeros((self.n, C.N_SOFT)))

    def shifted_guess(self, x0: np.ndarray, shift_s: float) -> np.ndarray | None:
        if self._last is None:
            return None
        last = self._last
        t_old = np.arange(self.n + 1) * self.dt
        t_new = shift_s + t_old
        xs = np.empty_like(last.x)
        for i in range(last.x.shape[1]):
            xs[:, i] = np.interp(t_new, t_old, last.x[:, i])
        # beyond the old horizon: continue with the last input through the model
        a_mat, b_mat = discrete_matrices(self.layout, self.dt)
        idx = np.minimum((t_new[:-1] / self.dt).astype(int), self.n - 1)
        us = last.u[idx]
        ss = last.slack[idx]
        for k in range(self.n):
            if t_new[k + 1] > t_old[-1]:
                xs[k + 1] = a_mat @ xs[k] + b_mat @ us[k]
        xs[0] = x0
        return self._join(xs, us, ss)

    # ------------------------------------------------------------------ solve
    def solve(self, data: StageData, *, shift_s: float = 0.0) -> SolveResult:
        """Solve once. `shift_s` = time since the last successful solve (for the warm start)."""
        t, c = time.perf_counter(), time.thread_time()  # the whole solve: packing and warm start included
        lay = self.layout
        x0 = np.asarray(data.x0, dtype=float)
        p = self.pack(data)
        lbw, ubw = C.decision_bounds(lay, self.bounds, self.n, x0)
        guess = self.shifted_guess(x0, shift_s) if self.s.warm_start else None
        if guess is None:
            guess = self.cold_guess(x0)
        guess = np.clip(guess, lbw, ubw)
        if self.s.solver == "sqp_rti":
            return self._solve_sqp(guess, p, lbw, ubw, shift_s, t, c)
        return self._solve_ipopt(guess, p, lbw, ubw, shift_s, t, c)

    def evaluate_cost(self, data: StageData, x: np.ndarray, u: np.ndarray, slack: np.ndarray | None = None) -> float:
        """The NLP cost of a given trajectory (for comparisons)."""
        sl = np.zeros((self.n, C.N_SOFT)) if slack is None else slack
        return float(self._ffun(self._join(x, u, sl), self.pack(data)))
