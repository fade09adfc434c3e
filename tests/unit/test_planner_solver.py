"""The NLP solvers (SQP real-time iteration, IPOPT): warm start, agreement, time budget, generated code."""
import os

import numpy as np
import pytest

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner import constraints as C
from cinetransfer.services.planner import model
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


def unbudgeted(solver: MpcSolver) -> MpcSolver:
    """The solver with its wall-time budget lifted, as the simulator's lockstep does: these tests judge
    iterations and optima, and a loaded machine must not turn them into budget stops."""
    solver.set_time_budget(None)
    return solver


@pytest.mark.parametrize("solver", ["sqp_rti", "ipopt"])
def test_warm_start_needs_fewer_iterations_than_cold(solver):
    cfg = pc.replace(pc.PlannerConfig(max_solve_time_s=1.0), **{"structure.solver": solver})
    data = stage_data(cfg)
    solver = unbudgeted(MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=1.0))
    cold = solver.solve(data)
    assert cold.ok and cold.iterations > 5
    # given the same problem 50 ms later, the shifted solution is a much better start
    warm = solver.solve(data, shift_s=0.05)
    assert warm.ok and warm.iterations < cold.iterations / 2
    np.testing.assert_allclose(warm.x[0], data.x0)  # the measured state is stage 0
    # and without warm start (the baseline's setting) every solve starts cold
    st = pc.replace(cfg, **{"structure.warm_start": False}).structure
    nowarm = unbudgeted(MpcSolver(st, cfg.bounds, cfg.weights, max_solve_time_s=1.0))
    r1, r2 = nowarm.solve(data), nowarm.solve(data, shift_s=0.05)
    assert r1.iterations == r2.iterations


def test_mx_baseline_and_sx_agree():
    # given the same problem built in MX (no expand, the CineMPC-like baseline) and in SX
    cfg = pc.replace(pc.PlannerConfig(max_solve_time_s=5.0), **{"structure.solver": "ipopt"})
    data = stage_data(cfg)
    sx = unbudgeted(MpcSolver(cfg.structure)).solve(data)
    mx = unbudgeted(MpcSolver(pc.replace(cfg, **{"structure.expand": False}).structure)).solve(data)
    # then both find the same optimum
    assert sx.ok and mx.ok
    assert mx.cost == pytest.approx(sx.cost, rel=1e-3)
    np.testing.assert_allclose(mx.x[1], sx.x[1], atol=1e-2)


def test_budget_exceeded_is_reported():
    # given a budget of one iteration, the solve stops early; without accepting suboptimal
    # iterates this is a failure (the planner then flies its tail / holds)
    cfg = pc.replace(pc.PlannerConfig(), **{"structure.max_iter": 1, "structure.max_iter_cold": 1,
                                            "structure.solver": "ipopt"})
    data = stage_data(cfg)
    r = unbudgeted(MpcSolver(cfg.structure, accept_suboptimal=False)).solve(data)
    assert not r.ok and "Maximum_Iterations_Exceeded" in r.status


@pytest.mark.parametrize("qp_solver", ["hpipm", "piqp", "qrqp"])
def test_sqp_converges_to_the_ipopt_optimum(qp_solver):
    # given one problem (the vehicle off the shot, N = 20), solved cold by the SQP and by IPOPT
    cfg = pc.replace(pc.PlannerConfig(), **{"structure.horizon_steps": 20, "structure.qp_solver": qp_solver})
    data = stage_data(cfg)
    sqp = unbudgeted(MpcSolver(cfg.structure)).solve(data)
    ref = unbudgeted(MpcSolver(pc.replace(cfg, **{"structure.solver": "ipopt"}).structure)).solve(data)
    # then the SQP iterates to the same optimum, feasible, with the measured state in front
    assert sqp.ok and ref.ok and sqp.status == "Solve_Succeeded", sqp.status
    assert sqp.cost == pytest.approx(ref.cost, rel=1e-4)
    np.testing.assert_allclose(sqp.x[1:4], ref.x[1:4], atol=1e-3)
    np.testing.assert_array_equal(sqp.x[0], data.x0)
    assert sqp.violation < 1e-6 and np.all(sqp.slack >= 0)
    assert 0 < sqp.iterations <= cfg.structure.sqp_iter_cold


def test_time_budget_can_be_set_and_lifted_at_run_time():
    cfg = pc.PlannerConfig()
    data = stage_data(cfg)
    solver = MpcSolver(cfg.structure, max_solve_time_s=0.04, max_cold_solve_time_s=0.25)
    assert solver.time_budget_s == 0.04
    # given a budget no solve can meet: a cold SQP stops after its first iteration (still a feasible,
    # usable plan), reports the budget status and that it was over budget, with wall and CPU time
    solver.set_time_budget(1e-9, cold_seconds=1e-9)
    r = solver.solve(data)
    assert r.ok and r.iterations == 1 and r.status == "Maximum_WallTime_Exceeded" and r.over_budget
    assert r.wall_s > 0 and r.cpu_s > 0 and r.violation < 1e-6
    # when the budget is lifted (simulation lockstep): it iterates to convergence and is never over budget
    solver.set_time_budget(None)
    assert solver.time_budget_s is None
    solver.reset()
    r = solver.solve(data)
    assert r.ok and r.status == "Solve_Succeeded" and r.iterations > 1 and not r.over_budget
    # and a budget set again applies to cold solves too (the larger of it and the last cold budget)
    solver.set_time_budget(0.04)
    assert solver.time_budget_s == 0.04 and solver.max_cold_solve_time_s == 0.04
    with pytest.raises(ValueError):
        solver.set_time_budget(-1.0)


def test_ipopt_time_budget_is_rebuilt_at_run_time():
    # given IPOPT with a budget no solve can meet: it stops for time (a failure unless feasible)
    cfg = pc.replace(pc.PlannerConfig(), **{"structure.solver": "ipopt"})
    data = stage_data(cfg)
    solver = MpcSolver(cfg.structure, max_solve_time_s=1e-6, max_cold_solve_time_s=1e-6, accept_suboptimal=False)
    r = solver.solve(data)
    assert not r.ok and "WallTime" in r.status and r.over_budget
    # when lifted, the same solve succeeds
    solver.set_time_budget(None)
    r = solver.solve(data)
    assert r.ok and r.status == "Solve_Succeeded" and not r.over_budget


def test_qp_failure_is_a_failed_solve_never_nan():
    # given a measured state that no input can bring into the bounds at stage 1 (|v| = 3 m/s > 2 + 0.12)
    cfg = pc.PlannerConfig()
    data = stage_data(cfg)
    data.x0 = data.x0.copy()
    data.x0[3] = 3.0
    r = unbudgeted(MpcSolver(cfg.structure)).solve(data)
    # then the solve fails (the planner flies its tail / holds), with a reason, and nothing is NaN-poisoned
    assert not r.ok and r.status.startswith("QP failed"), r.status


@pytest.mark.slow
@pytest.mark.parametrize("solver, copies, n_libs", [("ipopt", True, 1), ("sqp_rti", True, 2), ("sqp_rti", False, 3)])
def test_generated_code_is_compiled_once_and_cached(tmp_path, solver, copies, n_libs):
    # given codegen on and an empty cache: the first build compiles the shared library(ies)
    # (SQP: QP data + post-step; the block-diagonal form also its cold-start QP data)
    cfg = pc.replace(pc.PlannerConfig(max_solve_time_s=2.0),
                     **{"structure.codegen": True, "structure.cache_dir": str(tmp_path), "structure.solver": solver,
                        "structure.sqp_input_copies": copies,
                        "structure.compile_flags": ("-O0", "-fPIC", "-shared"), "structure.horizon_steps": 8})
    data = stage_data(cfg)
    s1 = unbudgeted(MpcSolver(cfg.structure))
    libs = sorted(tmp_path.glob("cinempc_*.so"))
    assert len(libs) == n_libs
    mtime = os.path.getmtime(libs[0])
    # when built again, the cached library is loaded (no compile: the same file, untouched)
    s2 = unbudgeted(MpcSolver(cfg.structure))
    assert os.path.getmtime(libs[0]) == mtime
    assert sorted(tmp_path.glob("cinempc_*.so")) == libs
    # then it solves like the in-memory SX solver
    ref = unbudgeted(MpcSolver(pc.replace(cfg, **{"structure.codegen": False}).structure)).solve(data)
    r1, r2 = s1.solve(data), s2.solve(data)
    assert r1.ok and r2.ok and ref.ok
    assert r1.cost == pytest.approx(ref.cost, rel=1e-6)
    np.testing.assert_allclose(r2.x, ref.x, atol=1e-5)


def test_sqp_without_input_copies_keeps_the_optimum_on_warm_steps():
    # given the HPIPM SQP whose warm iterations drop the input-change cross-stage Hessian terms
    cfg = pc.replace(pc.PlannerConfig(), **{"structure.sqp_input_copies": False})
    data = stage_data(cfg)
    solver = unbudgeted(MpcSolver(cfg.structure))
    cold = solver.solve(data)
    assert cold.ok and cold.status == "Solve_Succeeded"
    # when it makes real-time iterations on the same problem, the plan stays feasible and optimal
    # (exact gradient: the optimum is a fixed point of the approximate-Hessian step)
    for _ in range(5):
        warm = solver.solve(data)
        assert warm.ok and warm.iterations == 1 and warm.violation < 1e-6
    assert warm.cost == pytest.approx(cold.cost, rel=1e-4)


def _off_its_dynamics(cfg):
    """A solver with a solved plan, and the same problem half a stage later with the drone's measured velocity
    (1, -1, 0.3) m/s off the plan: its shifted warm start keeps neither the new measured state nor, with
    states interpolated mid-stage, its own dynamics rows (L1 violation > 1)."""
    data = stage_data(cfg)
    solver = unbudgeted(MpcSolver(cfg.structure, cfg.bounds, cfg.weights))
    assert solver.solve(data).ok
    moved = stage_data(cfg)
    moved.x0 = data.x0.copy()
    moved.x0[solver.layout.V] += np.array([1.0, -1.0, 0.3])
    lbw, ubw = C.decision_bounds(solver.layout, solver.bounds, solver.n, moved.x0)
    guess = np.clip(solver.shifted_guess(moved.x0, 0.05), lbw, ubw)
    p = solver.pack(moved)
    assert solver._viol(np.asarray(solver._gfun(guess, p)).reshape(-1)) > 1.0
    return solver, moved, guess, p, lbw, ubw


def _assert_flyable(solver, x, u, lo=None, hi=None):
    """Every dynamics row exact, every value finite (and, given the bounds, inside them)."""
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(u))
    for k in range(solver.n):
        np.testing.assert_allclose(x[k + 1], model.step(solver.layout, x[k], u[k], solver.dt), atol=1e-9)
    if lo is not None:
        w = solver._join(x, u, np.zeros((solver.n, C.N_SOFT)))
        keep = np.isfinite(lo)
        assert np.all(w[keep] >= lo[keep] - 1e-12) and np.all(w[np.isfinite(hi)] <= hi[np.isfinite(hi)] + 1e-12)


def test_a_warm_start_off_its_dynamics_gives_a_feasible_plan():
    # given a warm start that violates its dynamics rows (the measured velocity off the plan, half a stage on)
    cfg = pc.PlannerConfig()
    solver, moved, _, _, lbw, ubw = _off_its_dynamics(cfg)
    # when the real-time iteration solves from it (its full step costs more than the infeasible start's merit,
    # which once cut the step and left the dynamics rows violated: a failed solve)
    r = solver.solve(moved, shift_s=0.05)
    # then the plan is returned, feasible: the dynamics exact, every bound kept, nothing NaN
    assert r.ok and r.iterations == 1 and r.violation < 1e-6, (r.status, r.violation)
    np.testing.assert_array_equal(r.x[0], moved.x0)
    _assert_flyable(solver, r.x, r.u, lbw, ubw)


def test_a_partial_step_from_a_start_off_its_dynamics_is_feasible():
    # given that warm start and a step that overshoots a feasible plan twice over (the merit refuses it in full)
    cfg = pc.PlannerConfig()
    solver, moved, guess, p, lbw, ubw = _off_its_dynamics(cfg)
    plan = solver.solve(moved, shift_s=0.05)
    target = solver._join(plan.x, plan.u, plan.slack)
    dw = 2.0 * (target - guess)
    f0, g0 = float(solver._ffun(guess, p)), np.asarray(solver._gfun(guess, p)).reshape(-1)
    merit0 = f0 + solver._penalty_mu * solver._viol(g0)
    # when the line search shortens it
    alpha, w, _, g, merit = solver._line_search(guess, dw, p, lbw, ubw, merit0, -1.0)
    # then the partial step's iterate keeps the dynamics and the bounds exactly (its states rolled from its
    # inputs), its constraints hold, and it is the plan itself (half of twice the way)
    assert alpha == 0.5
    assert solver._viol(g) < 1e-9 and np.isfinite(merit)
    x, u, slack = solver._split(np.asarray(w).reshape(-1))
    _assert_flyable(solver, x, u, lbw, ubw)
    assert np.all(slack >= 0)
    np.testing.assert_allclose(x, plan.x, atol=1e-6)


def test_a_plan_keeps_the_clearance_from_an_obstacle_on_its_way():
    """An obstacle where the unhindered plan passes: the plan goes round it, its surface at least the clearance
    from every planned position (the soft constraint's exact penalty holds it exactly)."""
    from cinetransfer.services.planner.obstacles import obstacle_params
    from cinetransfer.shared.obstacles import Obstacle

    cfg = pc.replace(pc.PlannerConfig(max_solve_time_s=1.0), **{"bounds.min_obstacle_distance_m": 0.5})
    data = stage_data(cfg)
    free = unbudgeted(MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=1.0)).solve(data)
    assert free.ok
    path = free.x[:, 0:3]
    k = int(np.argmax(np.linalg.norm(path[:, :2] - path[0, :2], axis=1) > 0.9))  # 0.9 m along the way
    assert k > 0
    tree = Obstacle(float(path[k, 0]), float(path[k, 1]), 0.2, 0.0, 5.0)
    data.obstacles = obstacle_params([tree], path[0], clearance_m=0.5, reach_m=10.0)
    kept = unbudgeted(MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=1.0)).solve(data)
    assert kept.ok
    axis = np.linalg.norm(kept.x[1:, :2] - (tree.x_m, tree.y_m), axis=1)
    assert axis.min() >= 0.7 - 1e-3, axis.min()
    assert np.linalg.norm(free.x[1:, :2] - (tree.x_m, tree.y_m), axis=1).min() < 0.1  # it was in the way


def test_each_stage_keeps_its_own_obstacle_slots():
    """Slots per stage: one set given for every stage is the same NLP as the set repeated per stage, and an
    obstacle held only from stage k on is kept clear at those stages while the earlier ones pass where they
    would (a stage reading another stage's slots would fail one or the other)."""
    from cinetransfer.services.planner.obstacles import STAGE_SIZE, obstacle_params
    from cinetransfer.shared.obstacles import Obstacle

    cfg = pc.replace(pc.PlannerConfig(max_solve_time_s=1.0), **{"bounds.min_obstacle_distance_m": 0.5})
    n = cfg.structure.horizon_steps
    data = stage_data(cfg)
    free = unbudgeted(MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=1.0)).solve(data)
    path = free.x[:, 0:3]
    k = int(np.argmax(np.linalg.norm(path[:, :2] - path[0, :2], axis=1) > 0.9))
    assert 1 < k < n
    tree = Obstacle(float(path[k, 0]), float(path[k, 1]), 0.2, 0.0, 5.0)
    one = obstacle_params([tree], path[0], clearance_m=0.5, reach_m=10.0)
    data.obstacles = one
    shared = unbudgeted(MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=1.0)).solve(data)
    data.obstacles = np.tile(one, (n, 1))
    tiled = unbudgeted(MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=1.0)).solve(data)
    np.testing.assert_array_equal(shared.x, tiled.x)
    late = np.zeros((n, STAGE_SIZE))
    late[k - 1:] = one  # row j holds stage j + 1 (x_{j+1}): stage k and after
    data.obstacles = late
    res = unbudgeted(MpcSolver(cfg.structure, cfg.bounds, cfg.weights, max_solve_time_s=1.0)).solve(data)
    assert res.ok
    axis = np.linalg.norm(res.x[1:, :2] - (tree.x_m, tree.y_m), axis=1)
    assert axis[k - 1:].min() >= 0.7 - 1e-3, axis
    # the unconstrained early stages keep nearer the free path than the plan held clear at every stage does
    early = slice(1, k)
    assert (np.abs(res.x[early, :3] - free.x[early, :3]).max()
            < np.abs(shared.x[early, :3] - free.x[early, :3]).max()), (res.x[early, :3], shared.x[early, :3])
