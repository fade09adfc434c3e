"""The NLP solver: warm start, runtime parameters, generated code cached across builds."""
import os
import time

import numpy as np
import pytest

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.core import Planner
from cinetransfer.services.planner.kinematic_sim import KinematicSim
from cinetransfer.services.planner.scenarios import reference_instructions, standing_shot, wrong_start_scene
from cinetransfer.services.planner.solver import MpcSolver
from cinetransfer.shared import messages as M

T0 = 1_700_000_000_000_000_000


def stage_data(cfg):
    scene = wrong_start_scene()
    ins = reference_instructions(scene, standing_shot(), duration_s=5.0)
    sim = KinematicSim(scene)
    p = Planner(cfg, solver=_Dummy(cfg))
    p.command(M.Command(action="start"), T0)
    data, _ = p._stage_data(T0, ins, sim.vehicle_state(T0), sim.subject_state(T0))
    return data


class _Dummy:
    """Stands in for the solver where only Planner._stage_data is used."""

    def __init__(self, cfg):
        self.bounds = cfg.bounds
        self.dt = cfg.structure.dt_s

    def reset(self):  # 'start' forgets the warm start; nothing to forget here
        pass


def test_warm_start_needs_fewer_iterations_than_cold():
    cfg = pc.PlannerConfig(max_solve_time_s=1.0)
    data = stage_data(cfg)
    solver = MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=1.0)
    cold = solver.solve(data)
    assert cold.ok and cold.iterations > 5
    # given the same problem 50 ms later, the shifted solution is a much better start
    warm = solver.solve(data, shift_s=0.05)
    assert warm.ok and warm.iterations < cold.iterations / 2
    np.testing.assert_allclose(warm.x[0], data.x0)  # the measured state is stage 0
    # and without warm start (the baseline's setting) every solve starts cold
    st = pc.replace(cfg, **{"structure.warm_start": False}).structure
    nowarm = MpcSolver(st, cfg.bounds, cfg.weights, max_solve_time_s=1.0)
    r1, r2 = nowarm.solve(data), nowarm.solve(data, shift_s=0.05)
    assert r1.iterations == r2.iterations


def test_mx_baseline_and_sx_agree():
    # given the same problem built in MX (no expand, the CineMPC-like baseline) and in SX
    cfg = pc.PlannerConfig(max_solve_time_s=5.0)
    data = stage_data(cfg)
    sx = MpcSolver(cfg.structure, max_solve_time_s=5.0).solve(data)
    mx = MpcSolver(pc.replace(cfg, **{"structure.expand": False}).structure, max_solve_time_s=5.0).solve(data)
    # then both find the same optimum
    assert sx.ok and mx.ok
    assert mx.cost == pytest.approx(sx.cost, rel=1e-3)
    np.testing.assert_allclose(mx.x[1], sx.x[1], atol=1e-2)


def test_budget_exceeded_is_reported():
    # given a budget of one iteration, the solve stops early; without accepting suboptimal
    # iterates this is a failure (the planner then flies its tail / holds)
    cfg = pc.replace(pc.PlannerConfig(), **{"structure.max_iter": 1, "structure.max_iter_cold": 1})
    data = stage_data(cfg)
    r = MpcSolver(cfg.structure, accept_suboptimal=False).solve(data)
    assert not r.ok and "Maximum_Iterations_Exceeded" in r.status


@pytest.mark.slow
def test_generated_code_is_compiled_once_and_cached(tmp_path):
    # given codegen on and an empty cache: the first build compiles a shared library
    cfg = pc.replace(pc.PlannerConfig(max_solve_time_s=2.0),
                     **{"structure.codegen": True, "structure.cache_dir": str(tmp_path),
                        "structure.compile_flags": ("-O0", "-fPIC", "-shared"), "structure.horizon_steps": 8})
    data = stage_data(cfg)
    s1 = MpcSolver(cfg.structure, max_solve_time_s=2.0)
    libs = list(tmp_path.glob("cinempc_*.so"))
    assert len(libs) == 1
    mtime = os.path.getmtime(libs[0])
    # when built again, the cached library is loaded (no compile: fast, same file)
    t = time.perf_counter()
    s2 = MpcSolver(cfg.structure, max_solve_time_s=2.0)
    assert time.perf_counter() - t < 5.0 and os.path.getmtime(libs[0]) == mtime
    assert list(tmp_path.glob("cinempc_*.so")) == libs
    # then it solves like the in-memory SX solver
    ref = MpcSolver(pc.replace(cfg, **{"structure.codegen": False}).structure, max_solve_time_s=2.0).solve(data)
    r1, r2 = s1.solve(data), s2.solve(data)
    assert r1.ok and r2.ok and ref.ok
    assert r1.cost == pytest.approx(ref.cost, rel=1e-6)
    np.testing.assert_allclose(r2.x, ref.x, atol=1e-6)
