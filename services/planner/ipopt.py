"""IPOPT on the planner's NLP, and its generated C.

IPOPT is the reference solver: a warm instance (multipliers in, small barrier) and a cold one.
With `Structure.codegen` the NLP functions (IPOPT's, or the SQP's QP data) are generated as C,
compiled once and the shared library cached under `cache_dir`, keyed by the structure, the casadi
version and the planner's NLP code.
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
from pathlib import Path

import casadi as ca
import numpy as np

from cinetransfer.services.planner import constraints as C
from cinetransfer.services.planner.config import Structure
from cinetransfer.services.planner.solve_result import BUDGET_STATUSES, OK_STATUSES, SolveResult

log = logging.getLogger("cinetransfer.planner")

#: the modules the generated code is built from (a change to any of them compiles anew)
NLP_SOURCES = ("model.py", "cost.py", "constraints.py", "solver.py", "sqp.py", "ipopt.py", "camera_motion.py",
               "side_of_subject.py", "config.py")  # config.py: the weights are parameters of the NLP


def structure_key(s: Structure) -> str:
    """Hash of what the generated code depends on: structure, casadi version, this package's code."""
    d = dataclasses.asdict(s)
    for k in ("cache_dir", "codegen", "compiler", "max_iter", "max_iter_cold", "tol", "warm_start",
              "sqp_iter", "sqp_iter_cold", "sqp_step_tol"):  # (qp_solver, sqp_input_copies: kept)
        d.pop(k, None)
    src = b""
    here = Path(__file__).resolve().parent
    for name in NLP_SOURCES:
        src += (here / name).read_bytes()
    h = hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode() + ca.__version__.encode() + src)
    return h.hexdigest()[:16]



def codegen_function(s: Structure, fun: ca.Function) -> ca.Function:
    """`fun` compiled to a shared library under cache_dir (once), loaded as an external."""
    key = structure_key(s)
    cache = Path(s.cache_dir)
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
            subprocess.run([s.compiler, *s.compile_flags, c_file, "-o", str(out)],
                           check=True, capture_output=True)
            os.replace(out, lib)
            log.info("compiled %s in %.1f s -> %s", fun.name(), time.perf_counter() - t, lib)
    return ca.external(fun.name(), str(lib))


def ipopt_options(s: Structure, *, warm: bool, budget_s: float) -> dict:
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


def codegen_solver(s: Structure, nlp: dict, opts: dict):  # noqa: ANN201
    key = structure_key(s)
    cache = Path(s.cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    lib = cache / f"cinempc_{key}.so"
    if not lib.exists():
        base = ca.nlpsol("cinempc", s.solver, nlp, {"ipopt": {"print_level": 0}, "print_time": False})
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
            subprocess.run([s.compiler, *s.compile_flags, os.path.join(tmp, c_name), "-o", str(out)],
                           check=True, capture_output=True)
            os.replace(out, lib)  # atomic: a concurrent process sees the whole library or none
            log.info("compiled planner NLP in %.1f s -> %s", time.perf_counter() - t, lib)
    return ca.nlpsol("cinempc", s.solver, str(lib), opts)


class IpoptMixin:
    """The IPOPT half of MpcSolver (its instances and its solve, on the solver's NLP and warm start)."""

    def _make_ipopt(self) -> None:
        # two instances of one NLP: warm-started solves (multipliers in, small barrier, the per-step
        # budget) and cold ones (IPOPT's default start, a larger budget: first solve, after a hold)
        s, nlp = self.s, self._nlp
        variants = {"cold": ipopt_options(s, warm=False, budget_s=self._budget_s(cold=True))}
        if s.warm_start:
            variants["warm"] = ipopt_options(s, warm=True, budget_s=self._budget_s(cold=False))
        self._solvers = {}
        for name, opts in variants.items():
            if s.codegen:
                self._solvers[name] = codegen_solver(s, nlp, opts)
            else:
                if not s.expand:
                    opts["expand"] = False
                self._solvers[name] = ca.nlpsol(f"cinempc_{name}", s.solver, nlp, opts)

    def _solve_ipopt(self, guess: np.ndarray, p: np.ndarray, lbw: np.ndarray, ubw: np.ndarray,
                     shift_s: float, t: float, c: float) -> SolveResult:
        """IPOPT from the (shifted) guess, warm-started with the shifted multipliers when there are some."""
        lay = self.layout
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
