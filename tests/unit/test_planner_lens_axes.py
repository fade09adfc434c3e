"""A lens axis the bridge reports unsupported (VehicleState.lens_unsupported) is planned fixed."""
import dataclasses

import numpy as np
import pytest

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.core import Planner
from cinetransfer.services.planner.kinematic_sim import KinematicSim
from cinetransfer.services.planner.lens_axes import pinned_bounds
from cinetransfer.services.planner.scenarios import reference_instructions, standing_shot, wrong_start_scene
from cinetransfer.shared import messages as M

T0 = 1_700_000_000_000_000_000


def test_pinned_bounds_narrow_only_the_named_axes():
    free = pc.Bounds()
    b = pinned_bounds(free, ("focal_length_mm", "no_such_axis"), np.array([85.0, 10.0, 4.0]))
    assert (b.focal_length_min_mm, b.focal_length_max_mm) == pytest.approx((84.915, 85.085))  # 85 -+ 0.1 %
    assert (b.focus_distance_min_m, b.focus_distance_max_m, b.f_number_min, b.f_number_max) == (0.5, 100.0, 1.0, 22.0)
    end = pinned_bounds(free, ("f_number",), np.array([85.0, 10.0, 0.5]))  # below the range: its end
    assert (end.f_number_min, end.f_number_max) == pytest.approx((1.0, 1.002))
    assert pinned_bounds(free, (), np.array([85.0, 10.0, 4.0])) is free


def test_the_planner_holds_an_unsupported_focal_length_and_frees_it_again():
    cfg = pc.PlannerConfig(max_solve_time_s=0.5)
    planner = Planner(cfg)
    planner.use_time_budget(None)  # no wall-clock limit: a loaded machine must not cut the solve short
    ins = reference_instructions(wrong_start_scene(), standing_shot(), duration_s=20.0)
    sim = KinematicSim(wrong_start_scene())
    planner.command(M.Command(action="start"), T0)
    vs = sim.vehicle_state(T0)
    fixed = dataclasses.replace(vs, lens=dataclasses.replace(vs.lens, focal_length_mm=float("nan")),
                                lens_unsupported=["focal_length_mm"])
    f0 = float(planner._last_lens[0])  # an unknown, unsupported focal length: the last planned one
    sp = planner.step(T0, ins, fixed, sim.subject_state(T0))
    assert sp.mode == "track"
    np.testing.assert_allclose(sp.horizon_lens[:, 0], f0, rtol=2e-3)
    b = planner.solver.bounds
    assert b.focal_length_max_mm - b.focal_length_min_mm == pytest.approx(2e-3 * f0)
    planner.step(T0 + 50_000_000, ins, dataclasses.replace(vs, stamp_ns=T0 + 50_000_000), sim.subject_state(T0))
    assert planner.solver.bounds == cfg.bounds
