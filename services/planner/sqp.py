"""SQP real-time iteration on the planner's NLP (MpcSolver's default, `Structure.solver` "sqp_rti").

From the warm start, `sqp_iter` (1: the real-time iteration of acados) SQP steps, each one convex
QP — Gauss-Newton Hessian of the cost's residuals, exact gradient — in stage-wise form (x_0 a
parameter) for a structure-exploiting QP solver (HPIPM; or any casadi conic plugin), then slacks
made exact and an exact-penalty line search whose shortened steps keep the dynamics exact (states
rolled forward from the stepped inputs). Cold solves iterate to convergence.
"""
from __future__ import annotations

import math
import time

import casadi as ca
import numpy as np

from cinetransfer.services.planner import constraints as C
from cinetransfer.services.planner.ipopt import codegen_function
from cinetransfer.services.planner.model import roll_out
from cinetransfer.services.planner.solve_result import SolveResult


class QpForm:
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



class SqpMixin:
    """The SQP half of MpcSolver (QP forms built from its NLP; solves on its warm start and budget)."""

    def _build_sqp(self, w, v_copy, p, cost_v, g_ocp, resid, *, copies: bool, name: str) -> QpForm:  # noqa: ANN001
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
        form = QpForm()
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
                self._postfun = codegen_function(s, self._postfun)
        if s.codegen:
            form.qpfun = codegen_function(s, form.qpfun)
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

    def _solve_sqp(self, w: np.ndarray, p: np.ndarray, lbw: np.ndarray, ubw: np.ndarray,
                   shift_s: float, t: float, c: float) -> SolveResult:
        """SQP from the (shifted) guess: a real-time iteration when warm (sqp_iter QPs, 1 = RTI), iterations
        to convergence (up to sqp_iter_cold) when cold. Each QP is convex (Gauss-Newton Hessian) and
        keeps the linear dynamics and every hard bound exactly; the soft constraints' slacks are then
        set to their exact value, so every returned iterate is feasible. A step is shortened (halved,
        at most 4 times) while it does not decrease the exact-penalty merit f + mu |violation|; a
        shortened step's states are rolled forward from its inputs, so that it too keeps the dynamics
        from a warm start that does not (`_line_search`)."""
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

    def _qp_multipliers(self, form: QpForm, shift_s: float) -> tuple[np.ndarray | None, np.ndarray | None]:
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
        the slacks made exact there: (alpha, w, cost, constraints, merit). `dd`: gradient . step.

        A warm start need not keep the linear dynamics rows (states interpolated part of a stage
        along, a new measured state): the full step restores them exactly, a partial one only in
        part. So a partial step's states are rolled forward from its inputs (`_dynamics_exact`), and
        once the full step is refused, each step is measured against the higher merit of the start and
        its feasible counterpart (the start's inputs flown from x_0): the start's merit is that of a
        point no plan can fly, and a step no worse than what its inputs would fly is taken."""
        def trial(alpha: float) -> tuple[np.ndarray, float, np.ndarray, float]:
            w_step = np.clip(w + alpha * dw, lbw, ubw)
            if alpha < 1.0:
                w_step = self._dynamics_exact(w_step, lbw, ubw)
            w_try, f1, g1 = self._postfun(w_step, p)
            g1 = np.asarray(g1).reshape(-1)
            merit1 = float(f1) + self._penalty_mu * self._viol(g1)
            return w_try, f1, g1, merit1

        def decreases(merit1: float, ref: float, alpha: float) -> bool:
            # Armijo on the merit, up to rounding (at a converged point the step is ~0 and the merit flat)
            return merit1 <= ref + 1e-4 * alpha * min(dd, 0.0) + 1e-10 * (1.0 + abs(ref))

        alpha = 1.0
        w_try, f1, g1, merit1 = trial(alpha)
        if decreases(merit1, merit0, alpha):
            return alpha, w_try, f1, g1, merit1
        ref = max(merit0, trial(0.0)[3])
        while not decreases(merit1, ref, alpha) and alpha >= 0.1:
            alpha *= 0.5
            w_try, f1, g1, merit1 = trial(alpha)
        return alpha, w_try, f1, g1, merit1

    def _dynamics_exact(self, w: np.ndarray, lbw: np.ndarray, ubw: np.ndarray) -> np.ndarray:
        """w with its states rolled forward from x_0 through its inputs (model.roll_out): the linear
        dynamics rows then hold exactly, with every hard bound kept."""
        x, u, slack = self._split(w)
        x_lo, u_lo, _ = self._split(lbw)
        x_hi, u_hi, _ = self._split(ubw)
        a, b = self._ab_np
        x, u = roll_out(a, b, x[0], u, x_lo[1:], x_hi[1:], u_lo, u_hi)
        return self._join(x, u, slack)

    def _viol(self, gv: np.ndarray) -> float:
        """Sum of the constraint violations of g (L1)."""
        return float(np.sum(np.maximum(self._lbg - gv, 0) + np.maximum(gv - self._ubg, 0)))
