"""`cinetransfer planner`: the CineMPC planner as a Zenoh node.

In:  keys.INSTRUCTIONS (Instructions, no-drop; the newest set is followed),
     keys.VEHICLE_STATE, keys.SUBJECT_STATE (latest wins),
     keys.PLANNER_COMMAND (Command: start / pause / resume / hold / stop, no-drop).
Out: keys.SETPOINT (Setpoint with the planned horizon) at a fixed rate (config.rate_hz), one
     solve per setpoint; Health counters: state, instruction_frame, solver_status, solve_ms, ...

The solver is built (or its generated code loaded from cache) and warmed up before the node
declares itself ready.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import Any

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.core import Planner
from cinetransfer.shared import keys
from cinetransfer.shared import messages as M
from cinetransfer.shared.node import add_node_arguments, call_periodically, node_from_args

log = logging.getLogger("cinetransfer.planner")


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="YAML", default=None,
                   help="YAML file with planner parameters (a 'planner:' section or the fields at top level)")
    p.add_argument("--rate", type=float, default=None, metavar="HZ", help="setpoints per second (default 20)")
    p.add_argument("--horizon", type=int, default=None, metavar="N", help="horizon steps (default 15)")
    p.add_argument("--dt", type=float, default=None, metavar="S", help="horizon step [s] (default 0.1)")
    p.add_argument("--codegen", action="store_true", default=None,
                   help="generate and compile the NLP in C (cached under the cache dir)")
    p.add_argument("--cache-dir", default=None, help="where generated solvers are cached")
    p.add_argument("--max-solve-time", type=float, default=None, metavar="S", help="IPOPT wall-time budget per solve")
    p.add_argument("--autostart", action="store_true", default=None,
                   help="start recording when the first instructions arrive (else wait for a 'start' command)")


def config_from_args(args: argparse.Namespace) -> pc.PlannerConfig:
    """Code defaults, then the YAML file, then flags (STYLE §5)."""
    base: dict[str, Any] = {}
    if args.config:
        import yaml

        doc = yaml.safe_load(Path(args.config).read_text()) or {}
        base = doc.get("planner", doc) if isinstance(doc, dict) else {}
    cfg = pc.from_dict(base)
    upd: dict[str, Any] = {}
    if args.rate is not None:
        upd["rate_hz"] = args.rate
    if args.horizon is not None:
        upd["structure.horizon_steps"] = args.horizon
    if args.dt is not None:
        upd["structure.dt_s"] = args.dt
    if args.codegen:
        upd["structure.codegen"] = True
    if args.cache_dir:
        upd["structure.cache_dir"] = args.cache_dir
    if args.max_solve_time is not None:
        upd["max_solve_time_s"] = args.max_solve_time
    if args.autostart:
        upd["autostart"] = True
    return pc.replace(cfg, **upd).validate()


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer planner", description=__doc__.split("\n")[0])
    add_node_arguments(p)
    add_config_arguments(p)
    args = p.parse_args(argv)
    try:
        cfg = config_from_args(args)
    except (pc.ConfigError, OSError, ValueError, TypeError) as e:
        print(f"cinetransfer planner: {e}", file=sys.stderr)
        return 2
    node = node_from_args("planner", args, config=cfg)
    with node:
        t = time.perf_counter()
        planner = Planner(cfg)
        log.info("solver ready in %.2f s (N=%d, dt=%.3f s, codegen=%s)", time.perf_counter() - t,
                 cfg.structure.horizon_steps, cfg.structure.dt_s, cfg.structure.codegen)
        ins_in = node.subscribe(keys.INSTRUCTIONS, maxlen=64)
        veh_in = node.subscribe(keys.VEHICLE_STATE, maxlen=4)
        sub_in = node.subscribe(keys.SUBJECT_STATE, maxlen=4)
        cmd_in = node.subscribe(keys.PLANNER_COMMAND)
        pub = node.publisher(keys.SETPOINT)
        latest: dict[str, Any] = {"ins": None, "veh": None, "sub": None}
        node.counters.update(planner.counters)
        node.ready()

        def tick() -> None:
            now = M.now_ns()
            for cmd in cmd_in.drain():
                with node.guard(cmd_in.key, "command"):  # one bad command never ends the loop
                    if not planner.command(cmd, now):
                        node.reject(f"unknown or malformed planner command {cmd.action!r}")
            for ins in ins_in.drain():
                if ins.image_targets.shape[0] == 0:
                    node.reject("instructions with no frames")
                    continue
                why = planner.refuse_instructions(ins)
                if why:
                    node.reject(f"instructions refused: {why}")
                    continue
                latest["ins"] = ins
            v = veh_in.latest()
            if v is not None:
                latest["veh"] = v
            s = sub_in.latest()
            if s is not None:
                latest["sub"] = s
            with node.timed():
                sp = planner.step(now, latest["ins"], latest["veh"], latest["sub"])
            pub.put(sp)
            node.counters.update(planner.counters)
            node.healthy = bool(sp.valid)
            if not sp.valid:
                node.error(f"setpoint invalid: {sp.solver_status}", "invalid")

        call_periodically(1.0 / cfg.rate_hz, node, tick)
    return 0


__all__ = ["main", "config_from_args"]
