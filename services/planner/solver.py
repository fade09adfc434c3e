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

Solvers (`Structure.solver`):
- "sqp_rti" (default): from the warm start, `sqp_iter` (1: the real-time iteration of acados)
  SQP steps, each one convex QP — Gauss-Newton Hessian of the cost's residuals, exact gradient —
  in stage-wise form (x_0 a parameter) for a structure-exploiting QP solver (HPIPM; or any casadi
  conic plugin), then slacks made exact and an exact-penalty line search. Cold solves iterate to
  convergence. See _build_sqp / _solve_sqp.
- "ipopt": the reference; a warm instance (multipliers in, small barrier) and a cold one.
The wall-time budget can be set or lifted at run time (set_time_budget); every SolveResult
reports wall_s, cpu_s (this thread) and over_budget.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from cinetransfer.services.planner import constraints as C
from cinetransfer.services.planner import cost as J
from cinetransfer.services.planner.config import WEIGHT_NAMES, Bounds, Structure, Weights
from cinetransfer.services.planner.model import Layout, discrete_matrices, input_bounds

log = logging.getLogger("cinetransfer.planner")

N_DOF = 7  # per stage: w_near mask, g_near, w_far mask, g_far, far_one_sided, near_one_sided,
#           the far limit's circle-of-confusion ratio (cost.defocus_ratio)
OK_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
BUDGET_STATUSES = ("Maximum_Iterations_Exceeded", "Maximum_WallTime_Exceeded", "Maximum_CpuTime_Exceeded")


@dataclass
class StageData:
    """The runtime data of one solve (everything but weights and bounds)."""

    x0: np.ndarray  # measured state (nx,)
    u_prev: np.ndarray  # input applied before (nu,) (for the input-change cost)
    joints_w: np.ndarray  # (E_max, 3) world positions of the controlled joints now (0 where unused)
    subject_centre_w: np.ndarray  # (3,) subject centre now (for distance, look and DoF depth)
    subject_velocity: np.ndarray  # (3,) [m/s], joints predicted at constant velocity
    targets: np.ndarray  # (N, E_max, 2) normalised image targets at stages 1..N (0 where unused)
    mask: np.ndarray  # (N, E_max) 1 = controlled joint at that stage, else 0
    dof: np.ndarray  # (N, N_DOF) see cost.reciprocal_targets and cost.defocus_ratio
    distance_ref: np.ndarray  # (N,) subject distance used to scale the DoF errors [m]


@dataclass
class SolveResult:
    ok: bool
    status: str
    x: np.ndarray  # (N+1, nx) planned states, x[0] = measured (possibly clamped) state
    u: np.ndarray  # (N, nu) planned inputs
    slack: np.ndarray  # (N, C.N_SOFT) soft-constraint violations (floor, ceiling, distance, speed)
    cost: float
    iterations: int
    wall_s: float
    violation: float  # max constraint violation of the returned iterate
    cpu_s: float = float("nan")  # CPU time of this thread in the solve (robust to a loaded machine)
    over_budget: bool = False  # wall_s exceeded the time budget (never, when the budget is lifted)
    extras: dict = field(default_factory=dict)


class _QpForm:
    """One QP form of the SQP: its data function, QP solver, and the map between w and z."""

    perm: np.ndarray
    nz: int
    u_in_z: np.ndarray
    v_in_z: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    qpfun: ca.Function
    qp: ca.Function

    def w_to_z(self, w: np.ndarray, nx: int) -> np.ndarray:
        z = np.empty(self.nz)
        z[self.perm] = w[nx:]
        z[self.v_in_z] = z[self.u_in_z]
        return z


class ParamLayout:
    """Offsets of the pieces of the parameter vector p."""

    def __init__(self, s: Structure) -> None:
        lay = Layout(s.control_roll)
        e, n = s.max_joints, s.horizon_steps
        sizes = [("u_prev", lay.nu), ("joints", 3 * e), ("centre", 3), ("subj_vel", 3),
                 ("targets", n * e * 2), ("mask", n * e), ("dof", n * N_DOF), ("dref", n),
                 ("weights", len(WEIGHT_NAMES)), ("u_scale", lay.nu), ("v_scale", 1), ("soft", C.N_SOFT)]
        self.slices: dict[str, slice] = {}
        off = 0
        for name, size in sizes:
            self.slices[name] = slice(off, off + size)
            off += size
        self.size = off


@dataclass
class _NlpTerms:
    """What the stages of the NLP add up to: cost, constraint rows (NLP and stage-wise QP forms),
    Gauss-Newton residuals, and the input-change residuals (exact; majorised)."""

    cost: object = 0
    g: list = field(default_factory=list)
    g_ocp: list = field(default_factory=list)
    resid: list = field(default_factory=list)
    du_exact: list = field(default_factory=list)
    du_major: list = field(default_factory=list)


@dataclass(frozen=True)
class _NlpParams:
    """The pieces of the parameter vector p, as symbols (see ParamLayout)."""

    u_prev: object
    joints0: object  #: (3, E): column j = joint j
    centre0: object
    vel: object
    targets: object
    mask: object
    dof: object
    dref: object
    wts: dict
    u_scale: object
    v_scale: object
    soft: object  #: the soft constraints' limits (constraints.soft_limits)

    @classmethod
    def of(cls, p, sl: dict[str, slice], e: int) -> _NlpParams:
        return cls(u_prev=p[sl["u_prev"]], joints0=ca.reshape(p[sl["joints"]], 3, e), centre0=p[sl["centre"]],
                   vel=p[sl["subj_vel"]], targets=p[sl["targets"]], mask=p[sl["mask"]], dof=p[sl["dof"]],
                   dref=p[sl["dref"]], wts={name: p[sl["weights"]][i] for i, name in enumerate(WEIGHT_NAMES)},
                   u_scale=p[sl["u_scale"]], v_scale=p[sl["v_scale"]][0], soft=p[sl["soft"]])


def _structure_key(s: Structure) -> str:
    """Hash of what the generated code depends on: structure, casadi version, this package's code."""
    d = dataclasses.asdict(s)
    for k in ("cache_dir", "codegen", "compiler", "max_iter", "max_iter_cold", "tol", "warm_start",
              "sqp_iter", "sqp_iter_cold", "sqp_step_tol"):  # (qp_solver, sqp_input_copies: kept)
        d.pop(k, None)
    src = b""
    here = Path(__file__).resolve().parent
    for name in ("model.py", "cost.py", "constraints.py", "solver.py"):
        src += (here / name).read_bytes()
    h = hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode() + ca.__version__.encode() + src)
    return h.hexdigest()[:16]


class MpcSolver:
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
        par = _NlpParams.of(p, self.pl.slices, self.e)
        self._ab_dm = tuple(ca.DM(m) for m in discrete_matrices(lay, self.dt))
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
        terms = _NlpTerms()
        x_prev = w[0:nx]
        u_last = par.u_prev
        for k in range(n):
            off = nx + k * blk
            u, x, slack = w[off:off + nu], w[off + nu:off + nu + nx], w[off + nu + nx:off + blk]
            self._add_stage(terms, k, par, x_prev=x_prev, u_last=u_last, u=u, x=x, slack=slack, majorise=majorise)
            x_prev, u_last = x, (v_copy[k * nu:(k + 1) * nu] if aug and k < n - 1 else u)
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

    def _input_groups(self) -> tuple[list[int], list[int], list[int]]:
        """Indices of the input vector: accelerations, camera rates, lens rates."""
        lay = self.layout
        return list(range(0, 3)), list(range(3, lay.F_RATE)), list(range(lay.F_RATE, lay.nu))

    def _add_stage(self, terms: _NlpTerms, k: int, par: _NlpParams, *, x_prev, u_last, u, x, slack,
                   majorise: bool) -> None:
        """Stage k+1 of the NLP: its dynamics and soft constraints (in both forms), its cost and,
        for the SQP, its Gauss-Newton residuals."""
        s, lay, dt = self.s, self.layout, self.dt
        a_dm, b_dm = self._ab_dm
        tk = (k + 1) * dt
        terms.g.append(x - (ca.mtimes(a_dm, x_prev) + ca.mtimes(b_dm, u)))
        centre = par.centre0 + par.vel * tk
        terms.g.append(C.soft_constraints(x, slack, centre, par.soft))
        # the same rows in the stage-wise form of the QP (x_{k+1} through the dynamics; equal wherever
        # the dynamics hold, which every SQP iterate after the first satisfies exactly)
        x_pred = ca.mtimes(a_dm, x_prev) + ca.mtimes(b_dm, u)
        terms.g_ocp += [x_pred - x, C.soft_constraints(x_pred, slack, centre, par.soft)]

        yaw, pitch, roll = lay.angles(x)
        cam = x[lay.P]
        r = J.rotation_ypr(yaw, pitch, roll)
        f_mm = x[lay.F]
        im = self._image_term(terms, k, par, r=r, cam=cam, f_mm=f_mm, tk=tk)
        cc = ca.mtimes(r.T, centre - cam)
        d = par.dof[k * N_DOF:(k + 1) * N_DOF]
        inv_n, inv_f = J.inverse_dof_limits(f_mm, x[lay.A], x[lay.S], s.coc_mm)
        inv_f = J.far_limit_for_circle(inv_n, inv_f, d[6])
        wts = par.wts
        jdof = J.dof_cost(inv_n, inv_f, par.dref[k], w_near=d[0] * wts["dof_near"], g_near=d[1],
                          w_far=d[2] * wts["dof_far"], g_far=d[3], far_one_sided=d[4], near_one_sided=d[5])
        un = u * par.u_scale
        du_n = (u - u_last) * par.u_scale
        vn = (x[lay.V] - par.vel) * par.v_scale  # relative to the subject: follow, don't wander
        acc_idx, cam_idx, lens_idx = self._input_groups()
        stage = (wts["image"] * im + wts["look"] * J.look_cost(cc) + jdof
                 + wts["accel"] * ca.sumsqr(un[acc_idx]) + wts["camera_rate"] * ca.sumsqr(un[cam_idx])
                 + wts["lens_rate"] * ca.sumsqr(un[lens_idx])
                 + wts["accel_change"] * ca.sumsqr(du_n[acc_idx])
                 + wts["camera_rate_change"] * ca.sumsqr(du_n[cam_idx])
                 + wts["lens_rate_change"] * ca.sumsqr(du_n[lens_idx])
                 + wts["velocity"] * ca.sumsqr(vn)
                 + wts["soft_constraint"] * (ca.sum1(slack) + ca.sumsqr(slack))
                 + wts["level"] * roll * roll)
        terms.cost += dt * stage
        if s.solver != "ipopt":
            e_n, e_f = J.dof_residuals(inv_n, inv_f, par.dref[k], g_near=d[1], g_far=d[3], far_one_sided=d[4],
                                      near_one_sided=d[5])
            terms.resid += [ca.sqrt(0.5 * dt * wts["look"]) * J.look_residual(cc),
                            ca.sqrt(dt * d[0] * wts["dof_near"]) * e_n, ca.sqrt(dt * d[2] * wts["dof_far"]) * e_f]
            if lay.control_roll:
                terms.resid.append(ca.sqrt(dt * wts["level"]) * roll)
            self._add_input_residuals(terms, wts, un=un, du_n=du_n, vn=vn, slack=slack,
                                      majorised=(u * par.u_scale, u_last * par.u_scale) if majorise and k > 0
                                      else None)

    def _image_term(self, terms: _NlpTerms, k: int, par: _NlpParams, *, r, cam, f_mm, tk):
        """The image cost of stage k+1: the predicted joints projected through the planned camera,
        against their targets (weighted by the mask); for the SQP, their residuals too."""
        s, e, dt = self.s, self.e, self.dt
        im = 0
        for j in range(e):
            pj = par.joints0[:, j] + par.vel * tk
            pc = ca.mtimes(r.T, pj - cam)
            ti = (k * e + j) * 2
            err2 = J.joint_image_error(pc, par.targets[ti], par.targets[ti + 1], f_mm, s.sensor_width_mm,
                                       s.sensor_height_mm, theta0_rad=math.radians(s.pinhole_half_angle_deg))
            im += par.mask[k * e + j] * err2
            if s.solver != "ipopt":
                ru, rv = J.joint_image_residual(pc, par.targets[ti], par.targets[ti + 1], f_mm, s.sensor_width_mm,
                                                s.sensor_height_mm,
                                                theta0_rad=math.radians(s.pinhole_half_angle_deg))
                sw = ca.sqrt(dt * par.wts["image"] * par.mask[k * e + j])
                terms.resid += [sw * ru, sw * rv]
        return im

    def _add_input_residuals(self, terms: _NlpTerms, wts: dict, *, un, du_n, vn, slack,
                             majorised: tuple | None) -> None:
        """Residuals of the input, velocity and slack costs; the input-change ones exact, and
        majorised (`majorised` = (u, u_last) scaled: each side on its own) for HPIPM's warm iterations."""
        dt = self.dt
        acc_idx, cam_idx, lens_idx = self._input_groups()
        terms_ = [("accel", un[acc_idx]), ("camera_rate", un[cam_idx]), ("lens_rate", un[lens_idx]),
                  ("velocity", vn), ("soft_constraint", slack)]
        exact = [("accel_change", du_n[acc_idx]), ("camera_rate_change", du_n[cam_idx]),
                 ("lens_rate_change", du_n[lens_idx])]
        major = exact
        if majorised is not None:
            major = [(name, vec[idx]) for name, idx in (("accel_change", acc_idx),
                                                        ("camera_rate_change", cam_idx),
                                                        ("lens_rate_change", lens_idx))
                     for vec in majorised]
        terms.resid += [ca.sqrt(dt * wts[name]) * vec for name, vec in terms_]
        terms.du_exact += [ca.sqrt(dt * wts[name]) * vec for name, vec in exact]
        terms.du_major += [ca.sqrt(dt * wts[name]) * vec for name, vec in major]

    def _make_ipopt(self) -> None:
        # two instances of one NLP: warm-started solves (multipliers in, small barrier, the per-step
        # budget) and cold ones (IPOPT's default start, a larger budget: first solve, after a hold)
        s, nlp = self.s, self._nlp
        variants = {"cold": self._ipopt_options(warm=False, budget_s=self._budget_s(cold=True))}
        if s.warm_start:
            variants["warm"] = self._ipopt_options(warm=True, budget_s=self._budget_s(cold=False))
        self._solvers = {}
        for name, opts in variants.items():
            if s.codegen:
                self._solvers[name] = self._codegen_solver(nlp, opts)
            else:
                if not s.expand:
                    opts["expand"] = False
                self._solvers[name] = ca.nlpsol(f"cinempc_{name}", s.solver, nlp, opts)

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

    # ------------------------------------------------------------------ SQP (real-time iteration)
    def _build_sqp(self, w, v_copy, p, cost_v, g_ocp, resid, *, copies: bool, name: str) -> "_QpForm":  # noqa: ANN001
        """QP data of one SQP iteration, in the stage-wise (optimal-control) form structured QP solvers take.

        QP variables z = [(u_k, slack_k, x_{k+1}[, v_{k+1}]) for k < N], with `copies` v_{k+1} = u_k, a copy
        of the input as a state (so the exact input-change cost couples no two stages); x_0 is the measured
        state, a parameter. Constraints: [(A x_k + B u_k - x_{k+1}[, u_k - v_{k+1}], soft_k(A x_k + B u_k,
        slack_k)) for k < N]. Hessian: Gauss-Newton 2 J_r' J_r of the residuals (positive semi-definite:
        every QP is convex); gradient: the exact cost's. `cost_v` and `resid` are written with v_k for
        u_{k-1} (k >= 1); without copies v_k is u_{k-1} itself."""
        s, lay, n = self.s, self.layout, self.n
        nx, nu, ns = lay.nx, lay.nu, C.N_SOFT
        nv = nu if copies else 0
        bz = nu + ns + nx + nv  # QP variables per stage
        z = ca.SX.sym("z", n * bz)
        x0 = ca.SX.sym("x0", nx)
        w_pieces, v_pieces, g_rows, perm = [x0], [], [], []
        for k in range(n):
            zk = z[k * bz:(k + 1) * bz]
            u, sl, x, v = zk[0:nu], zk[nu:nu + ns], zk[nu + ns:nu + ns + nx], zk[nu + ns + nx:]
            w_pieces += [u, x, sl]
            if k < n - 1:
                v_pieces.append(v if nv else u)
            perm += [k * bz + i for i in range(nu)] + [k * bz + nu + ns + i for i in range(nx)] \
                + [k * bz + nu + i for i in range(ns)]
        form = _QpForm()
        form.perm = np.asarray(perm)  # w[nx:] = z[perm]
        form.nz = n * bz
        form.u_in_z = np.concatenate([np.arange(k * bz, k * bz + nu) for k in range(n)]) if nv else np.zeros(0, int)
        form.v_in_z = np.concatenate([np.arange(k * bz + nu + ns + nx, (k + 1) * bz) for k in range(n)]) \
            if nv else np.zeros(0, int)
        w_of_z, v_of_z = ca.vertcat(*w_pieces), ca.vertcat(*v_pieces)
        subst = ca.Function("subst", [w, v_copy, p], [cost_v, g_ocp, resid])
        cost_z, g_z, r_z = subst(w_of_z, v_of_z, p)
        gb = nx + ns
        for k in range(n):
            zk = z[k * bz:(k + 1) * bz]
            g_rows += [g_z[k * gb:k * gb + nx], zk[0:nv] - zk[nu + ns + nx:], g_z[k * gb + nx:(k + 1) * gb]]
        g_z = ca.vertcat(*g_rows)
        lo = np.concatenate([np.zeros(nx + nv), np.zeros(ns)])
        hi = np.concatenate([np.zeros(nx + nv), np.full(ns, np.inf)])
        form.lbg, form.ubg = np.tile(lo, n), np.tile(hi, n)
        pz = ca.vertcat(p, x0)
        jr = ca.jacobian(r_z, z)
        hess = 2 * ca.mtimes(jr.T, jr)
        grad = ca.gradient(cost_z, z)
        jg = ca.jacobian(g_z, z)
        form.qpfun = ca.Function(f"qp_data_{name}", [z, pz], [hess, grad, g_z, jg, cost_z])
        if not hasattr(self, "_postfun"):
            # after a step: each soft constraint's slack raised to the least value that satisfies it, then
            # the cost and constraints there (one call)
            g_w = self._nlp["g"]
            gsoft = ca.reshape(g_w, nx + ns, n)[nx:, :]  # (ns, n): soft rows, >= 0
            raise_by = ca.reshape(ca.fmax(-gsoft, 0), ns * n, 1)
            add = ca.SX.zeros(w.shape[0])
            for j, i in enumerate(nx + k * (nu + nx + ns) + nu + nx + i for k in range(n) for i in range(ns)):
                add[i] = raise_by[j]
            f_fix, g_fix = ca.Function("fg", [w, p], [self._nlp["f"], g_w])(w + add, p)
            self._postfun = ca.Function("post", [w, p], [w + add, f_fix, g_fix])
            if s.codegen:
                self._postfun = self._codegen_function(self._postfun)
        if s.codegen:
            form.qpfun = self._codegen_function(form.qpfun)
        qp = {"h": hess.sparsity(), "a": jg.sparsity()}
        opts = self._qp_options()
        if s.qp_solver == "hpipm":
            opts.update({"N": n, "nx": [0] + [nx + nv] * n, "nu": [nu + ns] * n + [0], "ng": [ns] * n + [0],
                         "inf": 1e6})
        form.qp = ca.conic(f"cinempc_qp_{name}", s.qp_solver, qp, opts)
        self._solvers = {}
        return form

    def _qp_options(self) -> dict:
        name = self.s.qp_solver
        if name == "qrqp":
            return {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False,
                    "max_iter": 2000}
        if name == "hpipm":
            # speed_abs: the IPM without its residual checks; interleaved loaded A/B of the benchmark: SQP
            # CPU p95 1.92-2.05 ms vs 2.17-2.24 ms with "speed", tracking cost equal to 1e-5; every plan
            # is still checked for feasibility (feasibility_tol) before it is used
            return {"hpipm": {"mode": "speed_abs", "iter_max": 100, "res_g_max": 1e-8, "res_b_max": 1e-8,
                              "res_d_max": 1e-8, "res_m_max": 1e-8}, "error_on_fail": False}
        if name == "piqp":
            return {"piqp": {"eps_abs": 1e-7, "eps_rel": 1e-8, "verbose": False}, "error_on_fail": False}
        if name == "osqp":
            return {"osqp": {"verbose": False, "eps_abs": 1e-7, "eps_rel": 1e-7, "polish": True,
                             "max_iter": 20000}, "error_on_fail": False}
        if name == "qpoases":
            return {"printLevel": "none", "sparse": True, "error_on_fail": False}
        return {"error_on_fail": False}

    def _codegen_function(self, fun: ca.Function) -> ca.Function:
        """`fun` compiled to a shared library under cache_dir (once), loaded as an external."""
        key = _structure_key(self.s)
        cache = Path(self.s.cache_dir)
        cache.mkdir(parents=True, exist_ok=True)
        lib = cache / f"cinempc_{fun.name()}_{key}.so"
        if not lib.exists():
            with tempfile.TemporaryDirectory(dir=cache) as tmp:
                c_file = os.path.join(tmp, f"{fun.name()}.c")
                cwd = os.getcwd()
                try:
                    os.chdir(tmp)
                    fun.generate(f"{fun.name()}.c")
                finally:
                    os.chdir(cwd)
                t = time.perf_counter()
                out = Path(tmp) / (lib.name + ".part")
                subprocess.run([self.s.compiler, *self.s.compile_flags, c_file, "-o", str(out)],
                               check=True, capture_output=True)
                os.replace(out, lib)
                log.info("compiled %s in %.1f s -> %s", fun.name(), time.perf_counter() - t, lib)
        return ca.external(fun.name(), str(lib))

    def _ipopt_options(self, *, warm: bool, budget_s: float) -> dict:
        s = self.s
        ip = {"print_level": 0, "sb": "yes", "max_iter": s.max_iter, "tol": s.tol,
              "acceptable_tol": 1e-3, "acceptable_iter": 5,
              "max_wall_time": float(budget_s) if math.isfinite(budget_s) else 1e20,
              "mu_strategy": "adaptive", "linear_solver": "mumps"}
        if warm:
            ip.update({"warm_start_init_point": "yes", "warm_start_bound_push": 1e-6,
                       "warm_start_mult_bound_push": 1e-6, "warm_start_slack_bound_push": 1e-6,
                       "mu_init": 1e-3})
        else:
            ip["max_iter"] = s.max_iter_cold
        return {"ipopt": ip, "print_time": False, "error_on_fail": False}

    def _codegen_solver(self, nlp: dict, opts: dict):  # noqa: ANN202
        key = _structure_key(self.s)
        cache = Path(self.s.cache_dir)
        cache.mkdir(parents=True, exist_ok=True)
        lib = cache / f"cinempc_{key}.so"
        if not lib.exists():
            base = ca.nlpsol("cinempc", self.s.solver, nlp, {"ipopt": {"print_level": 0}, "print_time": False})
            with tempfile.TemporaryDirectory(dir=cache) as tmp:
                c_name = f"cinempc_{key}.c"
                cwd = os.getcwd()
                try:
                    os.chdir(tmp)
                    base.generate_dependencies(c_name)
                finally:
                    os.chdir(cwd)
                t = time.perf_counter()
                out = Path(tmp) / (lib.name + ".part")
                subprocess.run([self.s.compiler, *self.s.compile_flags, os.path.join(tmp, c_name), "-o", str(out)],
                               check=True, capture_output=True)
                os.replace(out, lib)  # atomic: a concurrent process sees the whole library or none
                log.info("compiled planner NLP in %.1f s -> %s", time.perf_counter() - t, lib)
        return ca.nlpsol("cinempc", self.s.solver, str(lib), opts)

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
        p[sl["weights"]] = self.weights.as_vector()
        _, uhi = input_bounds(lay, self.bounds)
        p[sl["u_scale"]] = 1.0 / uhi
        p[sl["v_scale"]] = 1.0 / self.bounds.speed_max_mps
        p[sl["soft"]] = C.soft_limits(self.bounds)
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

    def _shift_multipliers(self, shift_steps: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        if self._lam_x is None or self._lam_g is None:
            return None, None
        if shift_steps <= 0:
            return self._lam_x, self._lam_g
        nx, blk = self.layout.nx, self.layout.nu + self.layout.nx + C.N_SOFT
        gblk = self.layout.nx + C.N_SOFT
        lx = self._lam_x[nx:].reshape(self.n, blk)
        lg = self._lam_g.reshape(self.n, gblk)
        m = min(shift_steps, self.n - 1)
        lx = np.vstack([lx[m:], np.repeat(lx[-1:], m, axis=0)])
        lg = np.vstack([lg[m:], np.repeat(lg[-1:], m, axis=0)])
        return np.concatenate([self._lam_x[:nx], lx.reshape(-1)]), lg.reshape(-1)

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
        args = {"x0": guess, "p": p, "lbx": lbw, "ubx": ubw, "lbg": self._lbg, "ubg": self._ubg}
        solver = self._solvers["cold"]
        if self.s.warm_start and self._last is not None:
            lam_x, lam_g = self._shift_multipliers(int(round(shift_s / self.dt)))
            if lam_x is not None:
                args["lam_x0"], args["lam_g0"] = lam_x, lam_g
                solver = self._solvers["warm"]
        sol = solver(**args)
        wall, cpu = time.perf_counter() - t, time.thread_time() - c
        stats = solver.stats()
        self.last_stats = stats
        status = str(stats.get("return_status", "unknown"))
        wv = np.asarray(sol["x"]).reshape(-1)
        gv = np.asarray(sol["g"]).reshape(-1)
        viol = float(np.max(np.maximum(self._lbg - gv, 0) + np.maximum(gv - self._ubg, 0))) if gv.size else 0.0
        viol = max(viol, float(np.max(np.maximum(lbw - wv, 0) + np.maximum(wv - ubw, 0))))
        finite = bool(np.all(np.isfinite(wv)) and math.isfinite(viol))
        ok = finite and (status in OK_STATUSES
                         or (self.accept_suboptimal and status in BUDGET_STATUSES and viol <= self.feasibility_tol))
        if ok and status not in OK_STATUSES:
            status = f"suboptimal ({status})"
        x, u, slack = self._split(wv) if finite else (np.full((self.n + 1, lay.nx), np.nan),
                                                      np.full((self.n, lay.nu), np.nan),
                                                      np.full((self.n, C.N_SOFT), np.nan))
        res = SolveResult(ok=ok, status=status, x=x, u=u, slack=slack,
                          cost=float(sol["f"]) if finite else math.inf,
                          iterations=int(stats.get("iter_count", -1)), wall_s=wall, violation=viol, cpu_s=cpu,
                          over_budget=wall > self._budget_s(cold=solver is self._solvers["cold"]))
        if ok:
            self._last = res
            self._guess = wv
            self._lam_x = np.asarray(sol["lam_x"]).reshape(-1)
            self._lam_g = np.asarray(sol["lam_g"]).reshape(-1)
        return res

    def _solve_sqp(self, w: np.ndarray, p: np.ndarray, lbw: np.ndarray, ubw: np.ndarray,
                   shift_s: float, t: float, c: float) -> SolveResult:
        """SQP from the (shifted) guess: a real-time iteration when warm (sqp_iter QPs, 1 = RTI), iterations
        to convergence (up to sqp_iter_cold) when cold. Each QP is convex (Gauss-Newton Hessian) and
        keeps the linear dynamics and every hard bound exactly; the soft constraints' slacks are then
        set to their exact value, so every returned iterate is feasible. A step is shortened (halved,
        at most 4 times) while it does not decrease the exact-penalty merit f + mu |violation|."""
        lay, s = self.layout, self.s
        warm = s.warm_start and self._last is not None
        max_it = s.sqp_iter if warm else s.sqp_iter_cold
        budget = self._budget_s(cold=not warm)
        form = self._sqp["warm" if warm else "cold"]
        lam_x, lam_a = self._qp_multipliers(form, shift_s) if warm else (None, None)
        perm, nx = form.perm, lay.nx
        pz = np.concatenate([p, w[:nx]])
        lbz, ubz = form.w_to_z(lbw, nx), form.w_to_z(ubw, nx)
        status, it, qp_iters, step = "not started", 0, 0, math.inf
        g_w = None
        while it < max_it:
            z = form.w_to_z(w, nx)
            hess, grad, gv, jg, f0 = form.qpfun(z, pz)
            gv = np.asarray(gv).reshape(-1)
            if it == 0:
                f0 = float(f0)
                merit0 = f0 + self._penalty_mu * float(np.sum(np.maximum(form.lbg - gv, 0)
                                                              + np.maximum(gv - form.ubg, 0)))
            args = {"h": hess, "g": grad, "a": jg, "lba": form.lbg - gv, "uba": form.ubg - gv,
                    "lbx": lbz - z, "ubx": ubz - z, "x0": np.zeros_like(z)}
            if lam_x is not None:
                args["lam_x0"], args["lam_a0"] = lam_x, lam_a
            sol = form.qp(**args)
            qst = form.qp.stats()
            qp_iters += int(qst.get("iter_count", 0) or 0)
            dz = np.asarray(sol["x"]).reshape(-1)
            dw = np.zeros_like(w)
            dw[nx:] = dz[perm]
            if not (qst.get("success", False) and np.all(np.isfinite(dw))):
                status = f"QP failed ({qst.get('return_status', 'unknown')})"
                break
            lam_x = np.asarray(sol["lam_x"]).reshape(-1)
            lam_a = np.asarray(sol["lam_a"]).reshape(-1)
            self._penalty_mu = max(self._penalty_mu, 2.0 * float(np.max(np.abs(lam_a), initial=0.0)))
            alpha, w_try, f1, g1, merit1 = self._line_search(w, dw, p, lbw, ubw, merit0,
                                                             float(np.dot(np.asarray(grad).reshape(-1), dz)))
            w, merit0, f0, g_w = np.asarray(w_try).reshape(-1), merit1, float(f1), g1
            it += 1
            step = float(np.max(np.abs(alpha * dw) / (1.0 + np.abs(w))))
            if step <= s.sqp_step_tol:
                status = "Solve_Succeeded"
                break
            status = "real-time iteration" if warm else "Maximum_Iterations_Exceeded"
            elapsed = time.perf_counter() - t
            if elapsed * (it + 1) / it > budget:  # the next iteration would not fit
                if it < max_it:
                    status = "Maximum_WallTime_Exceeded"
                break
        finite = bool(it >= 1 and np.all(np.isfinite(w)) and math.isfinite(f0))
        viol = math.inf if g_w is None else max(self._viol(g_w), float(np.max(np.maximum(lbw - w, 0)
                                                                                + np.maximum(w - ubw, 0))))
        wall, cpu = time.perf_counter() - t, time.thread_time() - c
        ok = finite and viol <= self.feasibility_tol
        x, u, slack = self._split(w)
        res = SolveResult(ok=ok, status=status, x=x, u=u, slack=slack, cost=float(f0) if finite else math.inf,
                          iterations=it, wall_s=wall, violation=viol, cpu_s=cpu, over_budget=wall > budget,
                          extras={"qp_iterations": qp_iters, "step": step, "alpha": alpha if it else 0.0})
        self.last_stats = {"return_status": status, "iter_count": it, "qp_iter_count": qp_iters}
        if ok:
            self._last = res
            self._guess = w
            self._lam_x, self._lam_g = lam_x, lam_a
        return res

    def _qp_multipliers(self, form: _QpForm, shift_s: float) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The last solve's QP multipliers shifted by the whole stages elapsed (the last stage's
        repeated), to warm-start the QP; (None, None) when there are none for this form."""
        if self._lam_x is None or self._lam_x.size != form.nz:
            return None, None
        m = min(int(round(shift_s / self.dt)), self.n - 1)
        lx, la = self._lam_x.reshape(self.n, -1), self._lam_g.reshape(self.n, -1)
        if m > 0:
            lx = np.vstack([lx[m:], np.repeat(lx[-1:], m, axis=0)])
            la = np.vstack([la[m:], np.repeat(la[-1:], m, axis=0)])
        return lx.reshape(-1), la.reshape(-1)

    def _line_search(self, w: np.ndarray, dw: np.ndarray, p: np.ndarray, lbw: np.ndarray, ubw: np.ndarray,
                     merit0: float, dd: float) -> tuple[float, np.ndarray, float, np.ndarray, float]:
        """The step along dw (halved at most 4 times) that decreases the exact-penalty merit, with
        the slacks made exact there: (alpha, w, cost, constraints, merit). `dd`: gradient . step."""
        alpha = 1.0
        for _ in range(5):
            w_try, f1, g1 = self._postfun(np.clip(w + alpha * dw, lbw, ubw), p)
            g1 = np.asarray(g1).reshape(-1)
            merit1 = float(f1) + self._penalty_mu * self._viol(g1)
            # Armijo on the merit, up to rounding (at a converged point the step is ~0 and the merit flat)
            if merit1 <= merit0 + 1e-4 * alpha * min(dd, 0.0) + 1e-10 * (1.0 + abs(merit0)) or alpha < 0.1:
                break
            alpha *= 0.5
        return alpha, w_try, f1, g1, merit1

    def _viol(self, gv: np.ndarray) -> float:
        """Sum of the constraint violations of g (L1)."""
        return float(np.sum(np.maximum(self._lbg - gv, 0) + np.maximum(gv - self._ubg, 0)))

    def evaluate_cost(self, data: StageData, x: np.ndarray, u: np.ndarray, slack: np.ndarray | None = None) -> float:
        """The NLP cost of a given trajectory (for comparisons)."""
        sl = np.zeros((self.n, C.N_SOFT)) if slack is None else slack
        return float(self._ffun(self._join(x, u, sl), self.pack(data)))
