"""`cinetransfer plan style.json [--scene NAME]`: fly a style file in a simulator, in-process, no Zenoh.

The planner runs against
- the autopilot bridge's built-in simulator (`services/autopilot_bridge/sim`, a VehiclePort)
  when it is installed and NAME is one of its scenes (or a scene file), or
- the planner's own kinematic simulator (`kinematic_sim.py`) for NAME in its built-in scenes
  (standing, walking, approach; also reachable as 'kinematic:NAME').
Simulated time advances by one control period per solve (the solver never makes it late), and
achieved vs desired framing and depth of field are printed along the way, then summarised.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from typing import Any

import numpy as np

from cinetransfer.services.planner.core import Planner
from cinetransfer.services.planner.kinematic_sim import SCENES, KinematicSim
from cinetransfer.services.planner.scenarios import LoopLog, run_closed_loop
from cinetransfer.shared import camera as cam
from cinetransfer.shared import messages as M
from cinetransfer.shared.vehicle import VehicleProfile, add_vehicle_argument, load_vehicle
from cinetransfer.shared.instructions import StyleFileError, load_style


class BridgeSimAdapter:
    """The bridge's VehiclePort simulator seen through the small interface run_closed_loop uses."""

    def __init__(self, backend: Any) -> None:
        self.backend = backend
        self.t_s = 0.0
        backend.start()
        backend.step(0.0)

    def apply(self, sp: M.Setpoint) -> None:
        if sp.mode == "hold" or not sp.valid:
            self.backend.hold()
        else:
            self.backend.apply(sp)

    def step(self, duration_s: float) -> None:
        self.t_s += duration_s
        # on a microsecond grid, nudged by 2 ns: summed float periods can otherwise land a hair
        # before a frame time that the backend then renders "ahead of now"
        self.backend.step(round(self.t_s, 6) + 2e-9)
        self.backend.frames()  # the renderer's output is not needed here
        self.backend.truths()

    def vehicle_state(self, stamp_ns: int) -> M.VehicleState:
        return dataclasses.replace(self.backend.vehicle_state(), stamp_ns=stamp_ns)

    def subject_state(self, stamp_ns: int) -> M.SubjectState:
        s = self.backend.subject_state()
        if s is None:
            raise RuntimeError("the simulator backend does not report the subject")
        return dataclasses.replace(s, stamp_ns=stamp_ns)

    def close(self) -> None:
        self.backend.close()


def state_truth(sim: Any, names: list[str]) -> tuple[np.ndarray, float, float, float]:
    """Framing and DoF from the reported states, through shared.camera (works for any simulator)."""
    vs, ss = sim.vehicle_state(0), sim.subject_state(0)
    jn = list(ss.joint_names)
    joints = np.array([ss.joints_m[jn.index(n)] if n in jn else [np.nan] * 3 for n in names], dtype=float)
    lens = vs.lens
    pts = cam.project_world(joints, vs.position_m, vs.camera_ypr_rad, lens.focal_length_mm)
    centre_names = [n for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip") if n in jn]
    centre = np.nanmean(np.array([ss.joints_m[jn.index(n)] for n in centre_names] or ss.joints_m), axis=0)
    depth = float(cam.world_to_camera(centre, vs.position_m, vs.camera_ypr_rad)[0])
    near, far = cam.dof_limits_m(lens.focal_length_mm, lens.f_number, lens.focus_distance_m)
    return pts, depth, near, far


def _bridge_scenes() -> tuple[Any, list[str]] | None:
    try:
        from cinetransfer.services.autopilot_bridge.sim import backend as sb  # noqa: F401
        from cinetransfer.services.autopilot_bridge.sim.scene import scene_names
    except ImportError:
        return None
    return sb, scene_names()


def make_sim(scene: str | None, subject: str | None = None,
             vehicle: VehicleProfile | None = None) -> tuple[Any, str]:
    """(simulator, description) for a scene name; see the module docstring for the rules.
    `subject`: another person from the bridge simulator's subject library (bridge scenes only);
    `vehicle`: the profile the simulator flies, bridge or kinematic (default: the default profile)."""
    if scene and scene.startswith("kinematic:"):
        name = scene.split(":", 1)[1]
        if name not in SCENES:
            raise ValueError(f"no kinematic scene {name!r}; built-in: {sorted(SCENES)}")
        return KinematicSim(SCENES[name], vehicle=vehicle), f"kinematic:{name}"
    bridge = _bridge_scenes()
    if bridge is not None:
        sb, names = bridge
        from pathlib import Path

        if scene is None and names:
            scene = "lawn_juggler" if "lawn_juggler" in names else names[0]
        if scene is not None and (scene in names or Path(scene).suffix in (".yaml", ".yml")):
            try:
                from cinetransfer.services.autopilot_bridge.sim.scene import with_vehicle

                sc = with_vehicle(sb.load_scene(scene, subject=subject), vehicle or load_vehicle())
                backend = sb.SimBackend(sc, render=False, truth=False)
            except TypeError:  # an older simulator without these options
                backend = sb.SimBackend(sb.load_scene(scene))
            who = f" ({backend.scene.subject.clip})" if subject else ""
            return BridgeSimAdapter(backend), f"bridge simulator:{scene}{who}"
    if subject:
        raise ValueError(f"--subject {subject!r} needs a bridge-simulator scene, not {scene!r}")
    scene = scene or "standing"
    if scene in SCENES:
        return KinematicSim(SCENES[scene], vehicle=vehicle), f"kinematic:{scene}"
    avail = sorted(SCENES) + (sorted(bridge[1]) if bridge else [])
    raise ValueError(f"unknown scene {scene!r}; available: {avail}")


def summarise(log: LoopLog, tol: float = 0.02) -> dict[str, Any]:
    err = np.asarray(log.image_error)
    t = np.asarray(log.t_s)
    agree = []
    for (fg, subj, bg), d, near, far in zip(log.focus_in, log.depth_m, log.near_m, log.far_m, strict=True):
        if subj:
            agree.append(near < d < far)
        elif bg:
            agree.append(math.isinf(far) and d < near)
        elif fg:
            agree.append(d > far)
    first_ok = next((float(ti) for ti, e in zip(t, err, strict=True) if e < tol), float("nan"))
    return {"steps": len(t), "duration_s": float(t[-1]) if len(t) else 0.0,
            "image_error_median": float(np.nanmedian(err)) if len(err) else float("nan"),
            "image_error_p95": float(np.nanpercentile(err, 95)) if len(err) else float("nan"),
            "fraction_within_tol": float(np.mean(err < tol)) if len(err) else 0.0, "first_within_tol_s": first_ok,
            "focus_agreement": float(np.mean(agree)) if agree else float("nan"),
            "solve_ms_median": float(np.nanmedian(log.solve_ms)) if log.solve_ms else float("nan"),
            "solve_ms_p95": float(np.nanpercentile(log.solve_ms, 95)) if log.solve_ms else float("nan"),
            "holds": int(sum(m == "hold" for m in log.mode)), "tracking_cost": log.tracking_cost()}


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer plan", description=__doc__.split("\n")[0])
    p.add_argument("style", help="style file (JSON written by 'cinetransfer smooth' / 'extract')")
    p.add_argument("--scene", default=None,
                   help="simulator scene: a bridge-simulator scene name/file, or a kinematic scene "
                        f"({', '.join(sorted(SCENES))}; 'kinematic:NAME' forces it). Default: the bridge "
                        "simulator's 'lawn_juggler' if installed, else kinematic 'standing'")
    p.add_argument("--subject", default=None, metavar="NAME",
                   help="bridge-simulator scenes: the filmed person from the subject library "
                        "(juggler, dancer, runner, walker; default: the scene's own)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="seconds to fly (default: the style)")
    p.add_argument("--config", metavar="YAML", default=None, help="planner parameters (as for 'cinetransfer planner')")
    add_vehicle_argument(p)
    p.add_argument("--rate", type=float, default=None, metavar="HZ", help="replanning rate (default 20)")
    p.add_argument("--horizon", type=int, default=None, metavar="N", help="horizon steps (default 15)")
    p.add_argument("--dt", type=float, default=None, metavar="S", help="horizon step (default 0.1)")
    p.add_argument("--every", type=float, default=0.5, metavar="S", help="print a line every S seconds")
    p.add_argument("--json", metavar="FILE", default=None, help="write the per-step log and summary as JSON")
    args = p.parse_args(argv)
    try:
        ins = load_style(args.style)
        from cinetransfer.services.planner.service import config_from_args

        ns = argparse.Namespace(config=args.config, section="planner", vehicle=args.vehicle,
                                **{"rate_hz": args.rate, "structure.horizon_steps": args.horizon,
                                   "structure.dt_s": args.dt})
        cfg = config_from_args(ns)
        # in-process the simulated clock waits for the solver: give it room (budget = 10 periods)
        cfg = dataclasses.replace(cfg, max_solve_time_s=max(cfg.max_solve_time_s, 10.0 / cfg.rate_hz))
        sim, what = make_sim(args.scene, subject=args.subject, vehicle=load_vehicle(args.vehicle))
    except (StyleFileError, ValueError, OSError) as e:  # ConfigError is a ValueError
        print(f"cinetransfer plan: {e}", file=sys.stderr)
        return 2
    k = ins.image_targets.shape[0]
    duration = args.duration or k / (ins.fps or 24.0)
    print(f"style: {args.style}  ({k} frames at {ins.fps:g} fps, joints {', '.join(ins.joint_names)})")
    print(f"simulator: {what}   planner: N={cfg.structure.horizon_steps} dt={cfg.structure.dt_s:g} s "
          f"at {cfg.rate_hz:g} Hz")
    t = time.perf_counter()
    planner = Planner(cfg)
    print(f"solver built in {time.perf_counter() - t:.2f} s")
    print(f"{'t[s]':>6} {'frame':>5} {'img err':>8} {'focus fg/sub/bg':>15} {'D_n*':>6} {'D_n':>6} {'d':>6} "
          f"{'D_f':>7} {'D_f*':>6} {'f[mm]':>6} {'mode':>5} {'ms':>6}")
    every = max(1, int(round(args.every / 0.05)))

    log = run_closed_loop(planner, sim, ins, duration_s=duration,
                          truth=None if isinstance(sim, KinematicSim) else state_truth)
    for i in range(0, len(log.t_s), every):
        fi = log.focus_in[i]
        dn, df = cam.desired_dof_limits(*fi, log.depth_m[i], ins.mu_m,
                                        defocus_when_none=cfg.structure.defocus_when_none)
        j = log.plan_index[i]
        sp = log.setpoints[j]

        def fmt(v: float, w: int) -> str:
            return f"{v:>{w}.2f}" if math.isfinite(v) else f"{'inf' if v > 0 else '-':>{w}}"
        print(f"{log.t_s[i]:6.2f} {log.frame[i]:5d} {log.image_error[i]:8.4f} "
              f"{''.join('X' if b else '.' for b in fi):>15} {fmt(dn, 6)} {fmt(log.near_m[i], 6)} "
              f"{log.depth_m[i]:6.2f} {fmt(log.far_m[i], 7)} {fmt(df, 6)} {sp.lens.focal_length_mm:6.1f} "
              f"{sp.mode:>5} {log.solve_ms[j]:6.1f}")
    s = summarise(log)
    print("summary: " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in s.items()))
    if args.json:
        def clean(v: Any) -> Any:
            return float(v) if math.isfinite(float(v)) else None

        out = {"summary": {k: clean(v) if isinstance(v, float) else v for k, v in s.items()}, "scene": what,
               "style": args.style, "log": {k: [clean(x) for x in v] for k, v in log.arrays().items()}}
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, allow_nan=False)
    if hasattr(sim, "close"):
        sim.close()
    return 0
