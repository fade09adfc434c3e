"""Planner solve time and tracking quality: CineMPC-like baseline, IPOPT, SQP real-time iteration.

    python benchmarks/planner.py [--duration 10] [--quick] [--qp qrqp,hpipm,...] [--codegen]

Scenarios (kinematic simulator, vehicle starting off the shot): 'dolly' = subject walking at
0.4 m/s, reference shot a dolly zoom (4 -> 8 m, 40 -> 80 mm) with the focus moving from the
subject to the background half way (scenarios.dolly_zoom_shot); 'standing' = subject standing,
fixed medium shot, subject in focus. Every configuration flies the same scenarios; the simulated
clock waits for the solver (solve time is measured, not simulated, and no solve fails for time:
the budget is lifted with MpcSolver.set_time_budget(None), and each solve reports whether it
would have met the real-time budget); the simulator tracks the published horizon between setpoints.
Configurations:
- baseline (CineMPC-like): N = 5, dt = 0.4 s, IPOPT on the MX graph (no expand), cold start,
  replanning every 0.4 s (2.5 Hz);
- ipopt: today's IPOPT configuration (SX-expanded NLP, warm start from the shifted last solution,
  20 Hz) at N = 15 and N = 20 (dt 0.1 s): N = 20 is the tracking-cost reference;
- sqp_rti (the default): one Gauss-Newton SQP iteration per step from the shifted warm start
  (real-time iteration), QP in stage-wise form solved by HPIPM, at N = 20 and 15 (dt 0.1 s), 20 Hz;
  also with the block-diagonal QP form (sqp_input_copies=False: cross-stage input-change Hessian
  terms dropped, smaller QP stages) and, with --codegen, on generated C.
Reported per configuration and scenario: wall and CPU (thread) time per solve, median / p95 / max
over the steady part (first 5 solves excluded; a configuration with fewer than 100 such solves,
the 2.5 Hz baseline, flies its scenario again, up to 10 runs, and the times are pooled),
iterations, over-budget solves (vs 40 ms), the tracking cost on the simulator's true state
(mean over time of 200 * sum_e |im_e - im*_e|^2 + 5 * depth-of-field error, scenarios.LoopLog)
and the image error after 3 s. Then ratios to the
baseline and a verdict against the goal: N = 20, dt 0.1: wall p95 <= 5 ms, >= 10x faster
than the baseline at p95, tracking cost within 2 % of the IPOPT reference on every scenario.
CPU times are the better guide on a busy machine (the load average is printed).
Writes benchmarks/results/planner.json.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.core import Planner
from cinetransfer.services.planner.kinematic_sim import KinematicSim, Walk
from cinetransfer.services.planner.scenarios import dolly_zoom_shot, reference_instructions, run_closed_loop, \
    standing_shot, wrong_start_scene

try:
    from harness import stats, write_result
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import stats, write_result

SCENARIOS = ("dolly", "standing")

WARMUP = 5
#: a configuration whose run gives fewer timed solves than this (the 2.5 Hz baseline: 20 in 10 s)
#: flies its scenario again, and the times of all runs are pooled: the p95 of 20 samples is their
#: second largest, and it moved 18-22 ms between identical quiet runs
MIN_TIMED_SOLVES = 100
MAX_RUNS = 10
BUDGET_S = 0.04  # the real-time budget a solve is checked against (PlannerConfig.max_solve_time_s)
GOAL_P95_MS = 5.0
GOAL_SPEEDUP = 10.0
GOAL_COST_REL = 0.02


def scenario(name: str, duration_s: float):
    if name == "dolly":
        scene = wrong_start_scene([Walk(0.0, 1e9, (0.0, 0.4, 0.0))])
        return scene, reference_instructions(scene, dolly_zoom_shot(duration_s), duration_s=duration_s)
    scene = wrong_start_scene()
    return scene, reference_instructions(scene, standing_shot(), duration_s=duration_s)


def run(name: str, cfg: pc.PlannerConfig, scen: str, duration_s: float) -> dict:
    """One configuration on one scenario, flown until MIN_TIMED_SOLVES steady solves are timed
    (at most MAX_RUNS runs; every run is the same closed loop, so the figures other than times are
    the first run's)."""
    r = run_once(name, cfg, scen, duration_s)
    runs, wall, cpu = 1, list(r.pop("_wall")), list(r.pop("_cpu"))
    while len(wall) < MIN_TIMED_SOLVES and runs < MAX_RUNS:
        again = run_once(name, cfg, scen, duration_s)
        wall += again["_wall"]
        cpu += again["_cpu"]
        runs += 1
    r.update(runs=runs, timed_solves=len(wall), wall_ms=stats(wall), cpu_ms=stats(cpu),
             over_budget=int(np.sum(np.asarray(wall) > BUDGET_S * 1e3)))
    return r


def run_once(name: str, cfg: pc.PlannerConfig, scen: str, duration_s: float) -> dict:
    scene, ins = scenario(scen, duration_s)
    t = time.perf_counter()
    planner = Planner(cfg)
    build_s = time.perf_counter() - t
    planner.solver.set_time_budget(None)  # lockstep: time is measured, never a failure cause
    sim = KinematicSim(scene, follow_horizon=True)
    iters: list[int] = []
    wall: list[float] = []
    cpu: list[float] = []

    def on_step(i: int, sp: object) -> None:
        r = planner.last_result
        iters.append(int(planner.counters["iterations"]))
        wall.append(r.wall_s * 1e3 if r is not None else float("nan"))
        cpu.append(r.cpu_s * 1e3 if r is not None else float("nan"))
    log = run_closed_loop(planner, sim, ins, duration_s=duration_s, on_step=on_step)
    err = np.asarray(log.image_error)
    t_s = np.asarray(log.t_s)
    st = cfg.structure
    return {
        "name": name, "scenario": scen, "solver": st.solver, "qp_solver": st.qp_solver if st.solver != "ipopt" else "",
        "N": st.horizon_steps, "dt_s": st.dt_s, "rate_hz": cfg.rate_hz, "expand": st.expand,
        "warm_start": st.warm_start, "codegen": st.codegen, "build_s": build_s, "solves": len(wall),
        "first_solve_ms": float(wall[0]), "_wall": wall[WARMUP:], "_cpu": cpu[WARMUP:],
        "iterations_median": float(np.median(iters[WARMUP:])), "iterations_max": int(np.max(iters[WARMUP:])),
        "failures": int(planner.counters["failures"]), "holds": int(sum(m == "hold" for m in log.mode)),
        "tracking_cost": log.tracking_cost(),
        "image_error_median_after_3s": float(np.median(err[t_s >= 3.0])),
        "image_error_max_after_3s": float(np.max(err[t_s >= 3.0])),
    }


def configs(args: argparse.Namespace) -> list[tuple[str, pc.PlannerConfig]]:
    base = pc.PlannerConfig()

    def ours(n: int, dt: float, solver: str, rate: float = 20.0, **kw: object) -> pc.PlannerConfig:
        return pc.replace(base, rate_hz=rate, **{"structure.horizon_steps": n, "structure.dt_s": dt,
                                                 "structure.solver": solver, **kw})

    out = [
        ("baseline CineMPC-like N=5 dt=0.4 2.5Hz",
         pc.replace(base, rate_hz=2.5, **{"structure.horizon_steps": 5, "structure.dt_s": 0.4,
                                          "structure.expand": False, "structure.warm_start": False,
                                          "structure.solver": "ipopt"})),
        ("ipopt N=15 dt=0.1 (today)", ours(15, 0.1, "ipopt")),
        ("ipopt N=20 dt=0.1 (reference)", ours(20, 0.1, "ipopt")),
    ]
    for qp in args.qp.split(","):
        out.append((f"sqp_rti N=20 dt=0.1 {qp}", ours(20, 0.1, "sqp_rti", **{"structure.qp_solver": qp})))
    if "hpipm" in args.qp.split(","):
        out.append(("sqp_rti N=20 dt=0.1 hpipm block-diagonal",
                    ours(20, 0.1, "sqp_rti", **{"structure.qp_solver": "hpipm", "structure.sqp_input_copies": False})))
    if not args.quick:
        out.append((f"sqp_rti N=15 dt=0.1 {args.qp.split(',')[0]}",
                    ours(15, 0.1, "sqp_rti", **{"structure.qp_solver": args.qp.split(",")[0]})))
    if args.codegen:
        out.append((f"sqp_rti N=20 dt=0.1 {args.qp.split(',')[0]} codegen",
                    ours(20, 0.1, "sqp_rti", **{"structure.qp_solver": args.qp.split(",")[0],
                                                "structure.codegen": True})))
    return out


def _line(r: dict) -> str:
    w, c = r["wall_ms"], r["cpu_ms"]
    return (f"{r['name']:<40} {r['scenario']:<8} wall {w['median']:6.2f} {w['p95']:6.2f} {w['max']:6.2f} | cpu "
            f"{c['median']:6.2f} {c['p95']:6.2f} {c['max']:6.2f} ms | it {r['iterations_median']:3.0f}/"
            f"{r['iterations_max']:3d} | cost {r['tracking_cost']:.4f} "
            f"err>3s med {r['image_error_median_after_3s']:.4f}"
            f" max {r['image_error_max_after_3s']:.4f} | over {r['over_budget']} fail {r['failures']}"
            f" | {r['timed_solves']} timed in {r['runs']} run(s)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--duration", type=float, default=10.0, help="scenario length [s]")
    p.add_argument("--codegen", action="store_true", help="also time sqp_rti on generated C (compiles once)")
    p.add_argument("--quick", action="store_true", help="skip the extra runs (sqp_rti at N=15)")
    p.add_argument("--qp", default=pc.Structure().qp_solver,
                   help="comma-separated QP solvers of sqp_rti to time (first = the reported one)")
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "planner.json"))
    args = p.parse_args(argv)
    results = []
    print(f"{'configuration':<40} {'scenario':<8} wall med/p95/max | cpu med/p95/max | iterations med/max | "
          "tracking cost, image error after 3 s | solves over 40 ms, failures")
    for name, cfg in configs(args):
        for scen in SCENARIOS:
            r = run(name, cfg, scen, args.duration)
            results.append(r)
            print(_line(r), flush=True)
    base = {r["scenario"]: r for r in results if r["name"].startswith("baseline")}
    ref = {r["scenario"]: r for r in results if r["name"].startswith("ipopt N=20")}
    print("\nratios vs the CineMPC-like baseline (baseline / this: > 1 = faster), "
          "tracking cost vs the IPOPT reference:")
    for r in results:
        b = base[r["scenario"]]
        print(f"  {r['name']:<40} {r['scenario']:<8} "
              f"wall median x{b['wall_ms']['median'] / r['wall_ms']['median']:6.1f}"
              f" p95 x{b['wall_ms']['p95'] / r['wall_ms']['p95']:6.1f} | cpu median "
              f"x{b['cpu_ms']['median'] / r['cpu_ms']['median']:6.1f} "
              f"p95 x{b['cpu_ms']['p95'] / r['cpu_ms']['p95']:6.1f}"
              f" | tracking cost {r['tracking_cost'] / ref[r['scenario']]['tracking_cost'] - 1:+7.2%} vs IPOPT N=20")
    load = os.getloadavg()
    goal = {}
    for clock, key in (("wall", "wall_ms"), ("CPU", "cpu_ms")):
        met = []
        for name in dict.fromkeys(r["name"] for r in results if r["solver"] == "sqp_rti" and r["N"] == 20):
            rs = [r for r in results if r["name"] == name]
            ok = all(r[key]["p95"] <= GOAL_P95_MS
                     and base[r["scenario"]][key]["p95"] / r[key]["p95"] >= GOAL_SPEEDUP
                     and r["tracking_cost"] <= (1 + GOAL_COST_REL) * ref[r["scenario"]]["tracking_cost"]
                     and r["failures"] == 0 for r in rs)
            if ok:
                met.append(name)
        goal[clock] = met
        print(f"goal (N=20 dt=0.1, {clock} p95 <= {GOAL_P95_MS} ms, >= {GOAL_SPEEDUP:.0f}x baseline p95, tracking cost "
              f"<= IPOPT +{GOAL_COST_REL:.0%}, no failure, every scenario): "
              + ("MET by " + "; ".join(met) if met else "NOT met"))
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs"
          + (": wall times are inflated; CPU times are the better guide" if load[0] > 0.5 * (os.cpu_count() or 1)
             else ""))
    config = {"duration_s": args.duration, "warmup_solves_excluded": WARMUP,
              "config_default": dataclasses.asdict(pc.PlannerConfig())}
    print(f"wrote {write_result(args.out, {'config': config, 'results': results, 'goal_met_by': goal})}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
