"""Planner core: commands and timing, input checks, the failure policy (tail, then hold), no NaN."""
import dataclasses
import math

import numpy as np
import pytest

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.camera_motion import MOTION_MASKS
from cinetransfer.services.planner.core import (LEAD_HOLD_BLUR, LEAD_HOLD_WEIGHT, LENS_MOTION_COLUMNS,
                                                RACK_LEAD_SHARE, Plan, Planner, _fps, absent_regions, held_lead_dof,
                                                held_subject_labels, instructions_from_arrays, lens_for_focus_rows,
                                                pins_field_before_soft_background, planned_focus_rows,
                                                later_shot_previewed, predict_subject, rack_settle_rows,
                                                rack_switch_ahead, shot_choice_held, unmeasured_subject_rows)
from cinetransfer.services.planner.focus_field import SHARP_SUBJECT_BLUR
from cinetransfer.services.planner.kinematic_sim import KinematicSim
from cinetransfer.services.planner.scenarios import reference_instructions, standing_shot, wrong_start_scene
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M
from cinetransfer.shared import camera as cam

T0 = 1_700_000_000_000_000_000
S = 1_000_000_000


@pytest.fixture(scope="module")
def planner_cfg():
    return pc.PlannerConfig(max_solve_time_s=0.5)


@pytest.fixture(scope="module")
def shared_solver(planner_cfg):
    from cinetransfer.services.planner.solver import MpcSolver
    solver = MpcSolver(planner_cfg.structure, planner_cfg.bounds, planner_cfg.weights, max_solve_time_s=0.5)
    # no wall-clock limit, as in the simulator's lockstep: these tests judge what a solve finds, and a
    # loaded machine must not turn a solve into a budget stop (a different, earlier iterate)
    solver.set_time_budget(None)
    return solver


@pytest.fixture
def planner(planner_cfg, shared_solver):
    shared_solver.set_bounds(planner_cfg.bounds)
    shared_solver.reset()
    return Planner(planner_cfg, solver=shared_solver)


@pytest.fixture(scope="module")
def instructions():
    return reference_instructions(wrong_start_scene(), standing_shot(), duration_s=20.0)


def assert_finite(sp: M.Setpoint):
    codec.decode(codec.encode(sp), M.Setpoint)  # the codec rejects non-finite values where not allowed
    lens = (sp.lens.focal_length_mm, sp.lens.focus_distance_m, sp.lens.f_number)
    assert all(math.isfinite(v) for v in lens), lens


def test_commands_drive_the_recording_clock(planner):
    # given a planner, 'start' starts the clock, 'pause' freezes it, 'resume' continues it
    assert planner.state == "idle" and planner.recording_time_s(T0) == 0.0
    assert planner.command(M.Command(action="start", args={"start_frame": 10}), T0)
    assert planner.recording_time_s(T0 + 2 * S) == pytest.approx(2.0)
    planner.command(M.Command(action="pause"), T0 + 2 * S)
    assert planner.state == "paused" and planner.recording_time_s(T0 + 5 * S) == pytest.approx(2.0)
    planner.command(M.Command(action="resume"), T0 + 5 * S)
    assert planner.recording_time_s(T0 + 6 * S) == pytest.approx(3.0)
    # and instruction frame k = start_frame + floor(t * fps)
    ins = instructions_from_arrays(targets=np.full((100, 1, 2), 0.5), joint_names=["nose"], fps=24.0)
    rows, frame = planner._rows(T0 + 6 * S, ins, 3, 0.1)
    assert frame == 10 + 72 and rows == [min(10 + int(24 * (3.0 + 0.1 * k)), 99) for k in (1, 2, 3)]
    # and 'stop' resets, unknown actions are refused and counted
    planner.command(M.Command(action="stop"), T0 + 7 * S)
    assert planner.state == "stopped" and planner.recording_time_s(T0 + 8 * S) == 0.0
    assert not planner.command(M.Command(action="fly-away"), T0)
    assert not planner.command(M.Command(action="start", args={"start_frame": -3}), T0)
    assert planner.counters["bad_commands"] == 2 and planner.counters["state"] == "stopped"


def test_holds_until_started_and_without_inputs(planner, instructions):
    sim = KinematicSim(wrong_start_scene())
    # given no 'start': a valid hold at the current pose
    sp = planner.step(T0, instructions, sim.vehicle_state(T0), sim.subject_state(T0))
    assert sp.mode == "hold" and sp.valid and np.allclose(sp.position_m, sim.p)
    assert_finite(sp)
    planner.command(M.Command(action="start"), T0)
    # when the vehicle state is stale, or the subject is missing: an invalid hold, never NaN
    sp = planner.step(T0 + 2 * S, instructions, sim.vehicle_state(T0), sim.subject_state(T0 + 2 * S))
    assert sp.mode == "hold" and not sp.valid
    sp = planner.step(T0, instructions, sim.vehicle_state(T0), None)
    assert sp.mode == "hold" and not sp.valid and "subject" in sp.solver_status
    sp = planner.step(T0, None, None, None)
    assert sp.mode == "hold" and not sp.valid
    assert_finite(sp)
    # and a subject whose joints are all unknown is bad input, not a crash
    ss = sim.subject_state(T0)
    bad = M.SubjectState(stamp_ns=T0, joints_m=np.full_like(ss.joints_m, np.nan), joint_names=ss.joint_names)
    sp = planner.step(T0, instructions, sim.vehicle_state(T0), bad)
    assert sp.mode == "hold" and not sp.valid and "bad input" in sp.solver_status
    # then with everything present, it tracks
    sp = planner.step(T0, instructions, sim.vehicle_state(T0), sim.subject_state(T0))
    assert sp.mode == "track" and sp.valid and sp.horizon_position_m.shape == (16, 3)
    assert_finite(sp)


def test_infeasible_config_yields_hold_not_crash(planner_cfg, instructions):
    # given a configuration the vehicle cannot satisfy (focal length >= 200 mm while the lens is at
    # 40 mm and zooms at most 20 mm/s): the solver fails, and the planner holds
    cfg = pc.replace(planner_cfg, **{"bounds.focal_length_min_mm": 200.0})
    planner = Planner(cfg)
    planner.use_time_budget(None)  # it must fail by infeasibility, not by a loaded machine's budget stop
    sim = KinematicSim(wrong_start_scene())
    planner.command(M.Command(action="start"), T0)
    for i in range(3):
        now = T0 + i * S // 20
        sp = planner.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
        assert sp.mode == "hold" and not sp.valid and "failed" in sp.solver_status
        assert np.allclose(sp.position_m, sim.p) and np.allclose(sp.velocity_mps, 0)
        assert_finite(sp)
    assert planner.counters["failures"] == 3 and planner.counters["holds"] == 1


def test_failure_flies_the_tail_then_holds(planner, planner_cfg, instructions):
    # given a planner tracking well
    sim = KinematicSim(wrong_start_scene())
    planner.command(M.Command(action="start"), T0)
    now = T0
    for _ in range(20):
        sp = planner.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
        sim.apply(sp)
        sim.step(0.05)
        now += S // 20
    assert sp.mode == "track" and planner.counters["failures"] == 0
    good = planner._plan
    # when the bounds change at run time to something infeasible (no rebuild)
    planner.set_bounds(pc.Bounds(focal_length_min_mm=400.0))
    modes = []
    for _ in range(30):
        sp = planner.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
        assert_finite(sp)
        modes.append(sp.mode)
        if sp.mode == "track":
            # then it keeps flying the last good plan (not a new one) ...
            assert "flying last plan" in sp.solver_status and sp.valid
            x, _ = good.at((now - good.t0_ns) * 1e-9 + planner_cfg.setpoint_lead_s)
            np.testing.assert_allclose(sp.position_m, x[0:3])
        sim.apply(sp)
        sim.step(0.05)
        now += S // 20
    # ... for at most tail_max_s, then holds (invalid), and stays in hold
    n_tail = modes.index("hold")
    assert 1 <= n_tail <= planner_cfg.tail_max_s * 20 + 1
    assert all(m == "hold" for m in modes[n_tail:])
    assert planner.counters["consecutive_failures"] == 30 and planner.counters["holds"] == 1
    # and when the bounds are sane again it recovers from a cold start
    planner.set_bounds(pc.Bounds())
    sp = planner.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
    assert sp.mode == "track" and sp.valid and planner.counters["consecutive_failures"] == 0


def test_weights_change_without_rebuild(planner, instructions):
    # given a running planner, new weights take effect at the next solve with the same solver object
    sim = KinematicSim(wrong_start_scene())
    planner.command(M.Command(action="start"), T0)
    solver = planner.solver
    planner.step(T0, instructions, sim.vehicle_state(T0), sim.subject_state(T0))
    c1 = planner.last_result.cost
    planner.solver.reset()
    planner._plan = None
    planner.set_weights(pc.Weights(image=2000.0))
    planner.step(T0, instructions, sim.vehicle_state(T0), sim.subject_state(T0))
    assert planner.solver is solver and planner.last_result.cost > 2 * c1


def test_scheduled_start_applies_at_its_exact_time_with_a_preroll(planner):
    # given a 'start' scheduled at T0 + 1 s with a 0.5 s pre-roll, received at T0
    cmd = M.Command(action="start", args={"start_frame": 0, "preroll_s": 0.5, "at_ns": T0 + S})
    assert planner.command(cmd, T0)
    assert planner.state == "idle" and planner.counters["scheduled"] == 1
    assert planner.counters["scheduled_at_ns"] == T0 + S
    # when a step comes after its time (a late tick), it applies as of its own time, not the tick's
    planner._apply_due(T0 + S + S // 7)
    assert planner.state == "recording" and planner.counters["scheduled"] == 0
    # then the instruction clock starts after the pre-roll, exactly: negative during the pre-roll
    assert planner.recording_time_s(T0 + S) == pytest.approx(-0.5)
    assert planner.recording_time_s(T0 + S + S // 2) == pytest.approx(0.0)
    assert planner.recording_time_s(T0 + 2 * S) == pytest.approx(0.5)
    # and during the pre-roll the planner frames the start frame
    ins = instructions_from_arrays(targets=np.full((100, 1, 2), 0.5), joint_names=["nose"], fps=24.0)
    _, frame = planner._rows(T0 + S, ins, 3, 0.1)
    assert frame == 0
    # and a malformed schedule is refused and counted
    assert not planner.command(M.Command(action="start", args={"at_ns": "soon"}), T0)
    assert not planner.command(M.Command(action="start", args={"preroll_s": -1.0}), T0)


def test_a_later_takes_settle_frames_its_first_frame_not_the_shot_before(planner):
    # given a take of a later shot (start frame 40) with a 3 s settle, started at T0
    ins = instructions_from_arrays(targets=np.full((100, 1, 2), 0.5), joint_names=["nose"], fps=24.0)
    assert planner.command(M.Command(action="start", args={"start_frame": 40, "preroll_s": 3.0}), T0)
    # when the planner looks ahead from the settle's start, 1 s before its end and 0.1 s before it
    early, frame = planner._rows(T0, ins, 3, 0.1)
    late, _ = planner._rows(T0 + int(2.9 * S), ins, 3, 0.1)
    # then every stage still in the settle frames row 40 (never rows 40 - 72 ... of the shot before),
    # and the stages past its end look into the take: 40 + floor(24 x (k x 0.1 - 0.1))
    assert frame == 40 and early == [40, 40, 40]
    assert late == [40, 42, 44]


def test_a_takes_horizon_stops_at_its_last_frame(planner):
    # given a take of rows 40-49 (the next shot, from row 50, is another take), no pre-roll
    ins = instructions_from_arrays(targets=np.full((100, 1, 2), 0.5), joint_names=["nose"], fps=24.0)
    assert planner.command(M.Command(action="start", args={"start_frame": 40, "end_frame": 50}), T0)
    # when the planner looks 0.1 / 0.2 / 0.3 / 0.4 s ahead from 0.2 s into the take (frame 44)
    rows, frame = planner._rows(T0 + S // 5, ins, 4, 0.1)
    # then the stages follow 40 + floor(24 x (0.2 + 0.1 k)) = 47, 49, then stay on the take's last
    # frame 49 instead of looking into the next shot (52, 54)
    assert frame == 44 and rows == [47, 49, 49, 49]
    # and without an end the horizon runs on into the next shot, as a single take does
    assert planner.command(M.Command(action="start", args={"start_frame": 40}), T0)
    assert planner._rows(T0 + S // 5, ins, 4, 0.1)[0] == [47, 49, 52, 54]
    # and an end at or before the start is refused and counted
    assert not planner.command(M.Command(action="start", args={"start_frame": 40, "end_frame": 40}), T0)


def test_same_ticks_give_the_same_setpoints_whatever_came_before(planner_cfg, instructions):
    # given two planners with different histories before a scheduled start (one has been solving)
    def run(history_steps: int) -> list[np.ndarray]:
        p = Planner(planner_cfg)
        p.use_time_budget(None)  # as in simulation time: no wall-clock limit can cut a solve short
        sim = KinematicSim(wrong_start_scene())
        p.command(M.Command(action="start"), T0 - 10 * S)
        for i in range(history_steps):
            now = T0 - S + i * S // 20
            p.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
        p.command(M.Command(action="start", args={"start_frame": 0, "preroll_s": 0.2, "at_ns": T0}), T0 - S // 2)
        sim = KinematicSim(wrong_start_scene())  # the simulation starts over at T0
        out = []
        for i in range(12):
            now = T0 + i * S // 20
            sp = p.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
            sim.apply(sp)
            sim.step(0.05)
            out.append(np.concatenate([sp.position_m, sp.camera_ypr_rad]))
        return out

    # when both are stepped through the same ticks after the start
    a, b = run(0), run(8)
    # then their setpoints agree: a take starts cold, so the flight depends only on its inputs
    np.testing.assert_allclose(np.array(a), np.array(b), atol=1e-9)

@pytest.mark.parametrize("value", [np.nan, 1e6, -1e6])
def test_instructions_with_no_or_absurd_targets_are_refused_and_held(planner, instructions, value):
    """A style whose targets are all NaN or at ±1e6 used to fly in 'track' mode."""
    import dataclasses

    bad = dataclasses.replace(instructions, image_targets=np.full_like(instructions.image_targets, value))
    assert planner.refuse_instructions(bad)  # the service counts this as a rejection
    assert planner.counters["instructions_refused"] == 1
    assert planner.refuse_instructions(instructions) == ""
    sim = KinematicSim(wrong_start_scene())
    planner.command(M.Command(action="start"), T0)
    sp = planner.step(T0, bad, sim.vehicle_state(T0), sim.subject_state(T0))
    assert sp.mode == "hold" and not sp.valid and "refused" in sp.solver_status
    assert_finite(sp)


def test_absent_regions_are_the_unlabelled_ones():
    ins = instructions_from_arrays(targets=np.zeros((2, 1, 2)), joint_names=["nose"],
                                   focus_in=[[False, True, True], [True, True, True]])
    smoothed = np.array([[np.nan, 0.9, 1.0], [1.0, 0.8, np.nan]], dtype=np.float32)
    # a frame whose subject was bridged has no measured fraction but labels from its neighbours
    raw = np.full((2, 3), np.nan, dtype=np.float32)
    np.testing.assert_array_equal(absent_regions(dataclasses.replace(ins, focus_smoothed=smoothed, focus_raw=raw)),
                                  [[True, False, False], [False, False, True]])
    # no smoothed B: nothing is known to be absent
    np.testing.assert_array_equal(absent_regions(dataclasses.replace(ins, focus_smoothed=None)), np.zeros((2, 3), bool))


def test_a_row_without_focus_labels_leaves_the_lens_free(planner, instructions):
    # given a style whose second half has no focus label at all (a shot the focus map could not read)
    k = instructions.image_targets.shape[0]
    sm = np.asarray(instructions.focus_smoothed, dtype=np.float32).copy()
    sm[k // 2:] = np.nan
    ins = dataclasses.replace(instructions, focus_smoothed=sm,
                              focus_in=np.where(np.isfinite(sm), instructions.focus_in, False))
    sim = KinematicSim(wrong_start_scene())
    x0 = planner._measured_state(T0, sim.vehicle_state(T0))
    subj = predict_subject(sim.subject_state(T0), T0)
    dof, _ = planner._dof_targets(T0, ins, [0, k - 1], 0, x0, subj)
    # then the labelled row has depth-of-field targets and the unlabelled one none (weights 0)
    assert dof[0, 0] + dof[0, 2] > 0
    np.testing.assert_array_equal(dof[1, :6], np.zeros(6))


def test_only_the_background_in_focus_keeps_the_subject_out_by_the_near_limit(planner, instructions):
    # given a style that wants only the background in focus and shows no foreground
    k = instructions.image_targets.shape[0]
    sm = np.tile(np.array([np.nan, 0.0, 1.0], dtype=np.float32), (k, 1))
    ins = dataclasses.replace(instructions, focus_smoothed=sm, focus_raw=sm,
                              focus_in=np.tile([False, False, True], (k, 1)))
    sim = KinematicSim(wrong_start_scene())
    x0 = planner._measured_state(T0, sim.vehicle_state(T0))
    subj = predict_subject(sim.subject_state(T0), T0)
    dof, dref = planner._dof_targets(T0, ins, [0, 1], 0, x0, subj)
    st = planner.cfg.structure
    # then the near limit aims beyond the subject, just past his back (the keep-out of his own depth,
    # 0.3 m by default, not mu = 1 m: the shot asks for it from its first row, no rack), two-sided although
    # no foreground is shown (one-sided it would let the limit come nearer, the subject back in focus),
    # with the larger circle (settled from the first row: settled_subject_blur, by default the visible circle)
    assert planner.cfg.subject_keep_out_m == 0.3 and ins.mu_m == 1.0
    assert dof[0, 0] == 1.0 and dof[0, 1] == pytest.approx(1.0 / (dref[0] + 0.3))
    assert dof[0, 5] == 0.0
    assert planner.cfg.settled_subject_blur == st.defocus_coc_ratio == 1.5
    assert dof[0, 7] == pytest.approx(st.defocus_coc_ratio / st.sharp_coc_ratio)
    # and the far limit at infinity is the one circle's (no rack: settled from the first row)
    assert dof[0, 4] == 1.0 and dof[0, 3] == 0.0 and dof[0, 6] == pytest.approx(1.0 / st.sharp_coc_ratio)
    # and a settled blur of 1.4 circles asks the near limit of 1.4 circles past his back
    less = Planner(dataclasses.replace(planner.cfg, settled_subject_blur=1.4), solver=planner.solver)
    assert less._dof_targets(T0, ins, [0, 1], 0, x0, subj)[0][0, 7] == pytest.approx(1.4 / st.sharp_coc_ratio)
    with pytest.raises(Exception, match="settled_subject_blur"):
        dataclasses.replace(planner.cfg, settled_subject_blur=0.9).validate()
    # and without a keep-out (0) mu past his centre
    by_mu = Planner(dataclasses.replace(planner.cfg, subject_keep_out_m=0.0), solver=planner.solver)
    dof, dref = by_mu._dof_targets(T0, ins, [0, 1], 0, x0, subj)
    assert dof[0, 0] == 1.0 and dof[0, 1] == pytest.approx(1.0 / (dref[0] + ins.mu_m))


def test_a_settled_soft_subject_is_asked_less_blur_where_the_ground_behind_him_is_near(planner):
    from cinetransfer.services.planner import focus_field as FF
    from cinetransfer.services.planner.separation import APERTURE_MARGIN

    # given the planner's camera and subject at the start of the wrong-start scene, and the ground he stands on
    sim = KinematicSim(wrong_start_scene())
    x0 = planner._measured_state(T0, sim.vehicle_state(T0))
    subj = predict_subject(sim.subject_state(T0), T0)
    view = planner._ground_view(x0, subj, 0.0)
    assert view is not None
    ground = FF.ground_behind_inv_m(view[0], FF.GROUND_BEHIND_SHARE, **view[1])
    assert ground > 0
    spread = FF.narrowest_spread(view[1]["focal_mm"], APERTURE_MARGIN * planner.solver.bounds.f_number_min,
                                 planner.cfg.structure.coc_mm)
    back = float(cam.world_to_camera(subj.centre, x0[planner.layout.P],
                                     np.array(planner.layout.angles(x0), float))[0]) + 0.3
    # then the blur asked is the one that starts the sharp zone at that ground, within [1.3, 1.5]
    got = planner._settled_blur(x0, subj, 0.0, back)
    assert got == pytest.approx(FF.settled_subject_blur(back, ground, spread=spread, most=1.5))
    assert FF.LEAST_SOFT_SUBJECT_BLUR <= got <= planner.cfg.settled_subject_blur == 1.5
    # and a back far beyond that ground (the zone would start behind it at any blur) is asked the least
    assert planner._settled_blur(x0, subj, 0.0, 10.0 / ground) == pytest.approx(FF.LEAST_SOFT_SUBJECT_BLUR)
    # and with the option off, settled_subject_blur whatever the ground
    off = Planner(dataclasses.replace(planner.cfg, settled_blur_from_ground=False), solver=planner.solver)
    assert off._settled_blur(x0, subj, 0.0, 10.0 / ground) == 1.5


def _rack_at_row_10(planner, instructions):
    """(instructions racking from the subject to the background at row 10, 24 rows a second; the measured
    state; the predicted subject; keep_out_settle_s in rows) from the wrong-start scene."""
    k = instructions.image_targets.shape[0]
    focus = np.tile([False, True, False], (k, 1))
    focus[10:] = (False, False, True)
    sm = np.where(focus, 1.0, 0.0).astype(np.float32)
    sm[:, 0] = np.nan
    ins = dataclasses.replace(instructions, focus_smoothed=sm, focus_raw=sm, focus_in=focus, fps=24.0)
    sim = KinematicSim(wrong_start_scene())
    x0 = planner._measured_state(T0, sim.vehicle_state(T0))
    subj = predict_subject(sim.subject_state(T0), T0)
    return ins, x0, subj, int(round(planner.cfg.keep_out_settle_s * 24.0))


def test_right_after_a_rack_onto_the_background_the_subject_is_kept_out_by_mu(planner, instructions):
    # given a style that racks from the subject to the background at row 10 (24 rows a second)
    assert instructions.image_targets.shape[0] > 10 + 48
    ins, x0, subj, settle = _rack_at_row_10(planner, instructions)
    dof, dref = planner._dof_targets(T0, ins, [10, 10 + settle - 1, 10 + settle], 10, x0, subj)
    # then the rows of the first keep_out_settle_s after the switch aim the near limit mu past his centre
    # with the sharpness circle's far limit at infinity, the later ones just past his back with the one
    # circle's
    np.testing.assert_allclose(dof[:, 1], 1.0 / (dref + np.array([1.0, 1.0, 0.3])), rtol=1e-9)
    np.testing.assert_allclose(dof[:, 6], [1.0, 1.0, 1.0 / planner.cfg.structure.sharp_coc_ratio])


def test_the_soft_subjects_near_limit_weighs_more_while_a_rack_settles(planner, instructions):
    # given a style that racks from the subject to the background at row 10 (24 rows a second)
    ins, x0, subj, settle = _rack_at_row_10(planner, instructions)
    rows = [10, 10 + settle - 1, 10 + settle]
    heavy = Planner(dataclasses.replace(planner.cfg, rack_settle_near_weight=2.0), solver=planner.solver)
    # when followed from the switch on with the near limit weighted twice while a rack settles
    dof, _ = heavy._dof_targets(T0, ins, rows, 10, x0, subj)
    # then the rows of keep_out_settle_s after the switch weigh the near limit twice, the settled row after
    # them once
    np.testing.assert_allclose(dof[:, 0], [2.0, 2.0, 1.0])
    # and followed from row 0, 10 rows before the switch (0.42 s, more than the lead here: these stages
    # preview it) nothing is weighted
    dof, _ = heavy._dof_targets(T0, ins, rows, 0, x0, subj)
    np.testing.assert_allclose(dof[:, 0], [1.0, 1.0, 1.0])
    # and by default (1: off) every row weighs as before
    assert planner.cfg.rack_settle_near_weight == 1.0
    np.testing.assert_allclose(planner._dof_targets(T0, ins, rows, 10, x0, subj)[0][:, 0], [1.0, 1.0, 1.0])
    with pytest.raises(Exception, match="rack_settle_near_weight"):
        dataclasses.replace(planner.cfg, rack_settle_near_weight=0.5).validate()


def test_a_lead_stage_before_a_rack_onto_the_background_holds_the_subject():
    # given a subject 20 m away held at 0.9 circles, the planning circle 3/8 of the one circle, weighed twice
    row = held_lead_dof(20.0, blur=0.9, sharp_coc_ratio=0.375, weight=2.0)
    # then the near limit of the 0.9 circle (2.4 planning circles) aims at his centre, 1/20 m, one-sided (at or
    # nearer), weighed twice, and the far limit is left free
    np.testing.assert_allclose(row, [2.0, 0.05, 0.0, 0.0, 0.0, 1.0, 1.0, 2.4])


def test_the_lead_of_a_rack_onto_the_background_keeps_the_subject_sharp(planner, instructions):
    # given a style that racks from the subject to the background at row 10 (24 rows a second; the lead here
    # 0.27 s: row 9 is a lead stage, 0.04 s before the switch, inside rack_lead_hold_s 0.25 s), followed from row 9
    ins, x0, subj, _ = _rack_at_row_10(planner, instructions)
    dof, dref = planner._dof_targets(T0, ins, [9, 10], 9, x0, subj)
    # then the lead stage holds him at LEAD_HOLD_BLUR (0.7 circles: 0.7 / 0.375 = 1.8667 planning circles),
    # weighed LEAD_HOLD_WEIGHT (2) times, with the far limit free, and the switch's own stage asks him soft: mu
    # (1 m) past his centre on the visible circle (ratio 4)
    assert (LEAD_HOLD_BLUR, LEAD_HOLD_WEIGHT) == (0.7, 2.0)
    np.testing.assert_allclose(dof[0], [2.0, 1.0 / dref[0], 0.0, 0.0, 0.0, 1.0, 1.0, 0.7 / 0.375])
    np.testing.assert_allclose(dof[1, [1, 7]], [1.0 / (dref[1] + 1.0), 4.0])
    # and with the option off the lead stage plans the switch as made, as the switch's own stage
    off = Planner(dataclasses.replace(planner.cfg, rack_lead_hold_s=0.0), solver=planner.solver)
    np.testing.assert_allclose(off._dof_targets(T0, ins, [9, 10], 9, x0, subj)[0][0], dof[1])
    # and so does a lead stage further ahead than rack_lead_hold_s (row 9 with a hold of 0.03 s, under a row)
    short = Planner(dataclasses.replace(planner.cfg, rack_lead_hold_s=0.03), solver=planner.solver)
    np.testing.assert_allclose(short._dof_targets(T0, ins, [9, 10], 9, x0, subj)[0][0], dof[1])
    # and a rack onto nothing sharp keeps its lead planned soft: no background to bring in
    focus = np.array(ins.focus_in)
    focus[10:] = (False, False, False)
    none = dataclasses.replace(ins, focus_in=focus)
    held = planner._dof_targets(T0, none, [9, 10], 9, x0, subj)[0]
    np.testing.assert_allclose(held, off._dof_targets(T0, none, [9, 10], 9, x0, subj)[0])


def _roll_after(level: float, tilt_deg: float) -> float:
    """|camera roll| [deg] after 3 s of flying a standing shot whose targets are turned by tilt_deg."""
    from cinetransfer.services.planner.scenarios import run_closed_loop

    cfg = pc.PlannerConfig(max_solve_time_s=0.5, structure=pc.Structure(control_roll=True),
                           weights=pc.Weights(level=level))
    base = reference_instructions(wrong_start_scene(), standing_shot(), duration_s=3.0)
    tg = np.asarray(base.image_targets, dtype=float)
    c = np.nanmean(tg, axis=1, keepdims=True)
    a = math.radians(tilt_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    tilted = dataclasses.replace(base, image_targets=((tg - c) @ rot.T + c).astype(np.float32))
    planner = Planner(cfg)
    planner.use_time_budget(None)  # the loop's clock waits for every solve: load must not cut one short
    log = run_closed_loop(planner, KinematicSim(wrong_start_scene()), tilted, duration_s=3.0)
    return abs(math.degrees(float(log.setpoints[-1].camera_ypr_rad[2])))


def test_roll_follows_a_tilted_style_and_the_level_weight_keeps_the_horizon():
    # given a style whose subject is turned by 10 degrees in the image, and camera roll controlled
    free, default, level = _roll_after(0.0, 10.0), _roll_after(pc.Weights().level, 10.0), _roll_after(1e4, 10.0)
    # then without the level cost the camera rolls to match it; the default weight rolls less, a huge one not at all
    assert free > 5.0
    assert level < 0.5 < default < free


@pytest.mark.parametrize("jump_s", [-600.0, 600.0])
def test_a_clock_jump_resets_the_warm_start_instead_of_failing(planner, instructions, jump_s):
    # given a planner tracking on a clock (a few solves: it has a plan to warm-start from)
    sim = KinematicSim(wrong_start_scene())
    planner.command(M.Command(action="start"), T0)
    for i in range(3):
        now = T0 + i * S // 20
        sp = planner.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
    assert sp.mode == "track" and planner.counters.get("warm_start_resets", 0) == 0
    # when the clock jumps (a bridge restart puts the simulation 600 s back; a pause, far ahead)
    now = T0 + int(jump_s * S)
    sim = KinematicSim(wrong_start_scene())
    sp = planner.step(now, instructions, sim.vehicle_state(now), sim.subject_state(now))
    # then the step solves from a cold start (it used to raise IndexError on the way back)
    assert sp.stamp_ns == now and sp.mode == "track" and sp.valid, sp.solver_status
    assert_finite(sp)
    assert planner.counters["warm_start_resets"] == 1


def test_style_rows_are_planned_as_one_depth_of_field_gives_them():
    # given rows asking fg and bg sharp with the subject soft (no one interval of depth), and others
    from cinetransfer.services.planner.core import realisable_rows
    rows = np.array([[True, False, True], [True, True, True], [False, False, True], [True, False, False]])
    # then only the impossible row changes: its foreground gives way, as the report grants labels
    assert realisable_rows(rows).tolist() == [[False, False, True], [True, True, True], [False, False, True],
                                              [True, False, False]]


def _labels_seen_from(planner, instructions, labels, position_m, pitch_rad):
    """The instructions asking `labels` (fg, subject, bg) in focus on every row, and the planner's measured
    state and subject prediction with the camera at `position_m`, pitched `pitch_rad`."""
    k = instructions.image_targets.shape[0]
    sm = np.tile(np.asarray(labels, dtype=np.float32), (k, 1))
    ins = dataclasses.replace(instructions, focus_smoothed=sm, focus_raw=sm, focus_in=np.tile(labels, (k, 1)))
    scene = dataclasses.replace(wrong_start_scene(), vehicle_position_m=position_m,
                                camera_ypr_rad=(0.0, pitch_rad, 0.0))
    sim = KinematicSim(scene)
    return ins, planner._measured_state(T0, sim.vehicle_state(T0)), predict_subject(sim.subject_state(T0), T0)


def test_only_the_foreground_sharp_aims_at_the_ground_the_band_shows(planner, instructions):
    from cinetransfer.services.planner.focus_field import ANKLE_HEIGHT_M
    from cinetransfer.shared import camera as cam

    # given a style that wants only the foreground (the band below the feet) in focus, every region present,
    # and a camera 7 m behind the subject, 2.5 m up, pitched 0.2 rad down at 40 mm: his feet at row ~0.9
    ins, x0, subj = _labels_seen_from(planner, instructions, (True, False, False), (-7.0, 0.0, 2.5), -0.2)
    dof, dref = planner._dof_targets(T0, ins, [0], 0, x0, subj)
    lay, st, b = planner.layout, planner.cfg.structure, planner.solver.bounds
    # then by ray and plane: the bottom row's ray from the camera meets the ground below the ankles at
    # depth t along the axis
    ground = min(subj.joints[subj.names.index(n), 2] for n in ("left_ankle", "right_ankle")) - ANKLE_HEIGHT_M
    ray = cam.rotation_ypr(*lay.angles(x0)) @ np.array([1.0, 0.0, -0.5 * st.sensor_height_mm / x0[lay.F]])
    t = (ground - x0[lay.P][2]) / ray[2]
    assert planner._foreground_band(x0, subj, 0.0).bottom_m == pytest.approx(t, rel=1e-9)
    # and the focus is where the subject is blurred by b of the one circle c = c_s / sharp_coc_ratio at the
    # aperture planned for (1.2 A_min, sigma = 1000 A c_s / f^2 per metre): 1/s = 1/d + b sigma / ratio,
    # with the near limit of c_s at 1/s + sigma and the far limit of the visible circle (4 c_s) at 1/s - 4 sigma;
    # b puts the one circle's far edge (b - 1 circles in front of him) a quarter of the way into the band from
    # his depth to the bottom row's ground, within 1.1-1.3 circles
    sigma = 1000.0 * 1.2 * b.f_number_min * st.plan_coc_mm / x0[lay.F] ** 2
    band_circles = (1.0 / t - 1.0 / dref[0]) / (sigma / st.sharp_coc_ratio)
    blur = min(max(1.0 + 0.25 * band_circles, 1.1), 1.3)
    # (at 40 mm 7 m away the band is shallow, under 0.4 circles deep: the least, 1.1 circles)
    assert band_circles < 0.4 and blur == 1.1
    x_s = 1.0 / dref[0] + blur * sigma / st.sharp_coc_ratio
    assert t > 0 and dof[0, 0] == 1.0 and dof[0, 6] == pytest.approx(4.0)
    assert dof[0, 1] == pytest.approx(x_s + sigma, rel=1e-6)
    assert dof[0, 3] == pytest.approx(x_s - 4.0 * sigma, rel=1e-6)


def test_the_pre_roll_asks_no_camera_motion(planner, instructions):
    # given a static style (every row holds the camera still) and a take with a 0.5 s pre-roll
    k = instructions.image_targets.shape[0]
    ins = dataclasses.replace(instructions, camera_motion_class=["static"] * k)
    sim = KinematicSim(wrong_start_scene())
    assert planner.command(M.Command(action="start", args={"start_frame": 0, "preroll_s": 0.5}), T0)
    # when the horizon (15 stages of 0.1 s) is staged 0.25 s into the pre-roll
    now = T0 + S // 4
    data, _ = planner._stage_data(now, ins, sim.vehicle_state(now), sim.subject_state(now))
    # then the stages 0.35 - 0.45 s ahead are in the pre-roll (not filmed: only the framing settles)
    # and ask nothing of the camera's motion (the side of the subject is framing); the take's stages
    # ask the static row's hold
    asked = data.motion[:, MOTION_MASKS].any(axis=1)
    assert planner._settle_stages(now, 15, 0.1).tolist() == [True, True] + [False] * 13
    assert not asked[:2].any() and asked[2:].all()
    assert not planner._settle_stages(T0 + S, 15, 0.1).any()
    # but round a subject already walking (1 m/s) the take's holds apply in the pre-roll too: no settle
    # can place the camera round him, and chasing him there left it in a worse place
    walking = dataclasses.replace(sim.subject_state(now), velocity_mps=np.array([1.0, 0.0, 0.0]))
    data, _ = planner._stage_data(now, ins, sim.vehicle_state(now), walking)
    assert data.motion[:, MOTION_MASKS].any(axis=1).all()


def test_the_rows_that_may_plan_a_rack_away_from_the_subject_ahead():
    # given a shot: subject sharp (0-5), only the background (6-11), the subject sharp again (12-13)
    sharp, bg = [0, 1, 0], [0, 0, 1]
    focus = np.array([sharp] * 6 + [bg] * 6 + [sharp] * 2, dtype=bool)
    absent = np.zeros(focus.shape, dtype=bool)
    # then with a lead of 2 rows and a hold of 6, rows 4-5 may plan the switch's row 6; the rack back is not led
    assert rack_switch_ahead(focus, absent, 2, 6).tolist() == [-1] * 4 + [6, 6] + [-1] * 8
    # and a choice held for fewer rows than the hold (a brief excursion), a lead of 0, a new shot at the
    # switch or an unlabelled row before it lead nothing
    assert (rack_switch_ahead(focus, absent, 2, 7) == -1).all()
    assert (rack_switch_ahead(focus, absent, 0, 6) == -1).all()
    starts = np.zeros(len(focus), dtype=bool)
    starts[6] = True
    assert (rack_switch_ahead(focus, absent, 2, 6, starts) == -1).all()
    unlabelled = absent.copy()
    unlabelled[5] = True
    assert (rack_switch_ahead(focus, unlabelled, 2, 6) == -1).all()
    # and a lead stops at the start of the shot
    starts[6], starts[5] = False, True
    assert rack_switch_ahead(focus, absent, 3, 6, starts).tolist()[:7] == [-1] * 5 + [6, -1]


def test_the_rows_a_rack_away_from_the_subject_settles_over():
    # given a shot: subject sharp (0-5), only the background (6-11), the subject sharp again (12-13)
    sharp, bg = [0, 1, 0], [0, 0, 1]
    focus = np.array([sharp] * 6 + [bg] * 6 + [sharp] * 2, dtype=bool)
    absent = np.zeros(focus.shape, dtype=bool)
    # then with a settle of 3 rows and a hold of 6, rows 6-8 settle; the rack back settles nothing
    assert np.flatnonzero(rack_settle_rows(focus, absent, 3, 6)).tolist() == [6, 7, 8]
    # and a choice held for fewer rows than the hold, or switched at a cut (another shot's choice), settles nothing
    assert not rack_settle_rows(focus, absent, 3, 7).any()
    starts = np.zeros(len(focus), dtype=bool)
    starts[6] = True
    assert not rack_settle_rows(focus, absent, 3, 6, starts).any()


def test_the_rows_round_a_switch_of_the_subjects_label_give_the_zoom_way():
    # given rows: subject sharp (0-3), only the background (4-5), unlabelled (6), only the foreground (7),
    # all sharp (8)
    focus = np.array([[0, 1, 0]] * 4 + [[0, 0, 1]] * 2 + [[0, 0, 0], [1, 0, 0], [1, 1, 1]], dtype=bool)
    absent = np.zeros((9, 3), dtype=bool)
    absent[6] = True
    # then the switches between labelled rows (at 4 and 8; not round the unlabelled row) take the lead's rows
    # before them and the settle's from them
    assert lens_for_focus_rows(focus, absent, 2, 1).tolist() == [0, 0, 1, 1, 1, 0, 1, 1, 1]
    assert lens_for_focus_rows(focus, absent, 0, 2).tolist() == [0, 0, 0, 0, 1, 1, 0, 0, 1]
    # and a switch where a new shot starts (its own take) is no rack; a lead or settle stops at a shot's edge
    starts = np.zeros(9, dtype=bool)
    starts[4] = True
    assert lens_for_focus_rows(focus, absent, 2, 1, starts).tolist() == [0, 0, 0, 0, 0, 0, 1, 1, 1]
    starts[4], starts[7] = False, True
    assert lens_for_focus_rows(focus, absent, 2, 1, starts).tolist() == [0, 0, 1, 1, 1, 0, 0, 1, 1]
    # and a shot that keeps the subject soft throughout flies its zoom; a negative lead (the option off) too
    assert not lens_for_focus_rows(focus[4:6], absent[4:6], 2, 1).any()
    assert not lens_for_focus_rows(focus, absent, -1, 1).any()


def test_a_subject_the_source_does_not_measure_keeps_his_last_label():
    # given a subject sharp (rows 0-3) who leaves the frame (rows 4-6: his region absent, the background
    # still labelled sharp, so his label reads False) and a row with nothing labelled (7)
    sub_bg, bg = [0, 1, 1], [0, 0, 1]
    focus = np.array([sub_bg] * 4 + [bg] * 3 + [[0, 0, 0]], dtype=bool)
    absent = np.zeros((8, 3), dtype=bool)
    absent[4:7, 1] = True
    absent[7] = True
    # then his label is held over the rows that lost him, and the unlabelled row stays as it is
    want = np.array([sub_bg] * 7 + [[0, 0, 0]], dtype=bool)
    assert np.array_equal(held_subject_labels(focus, absent), want)
    # so the planner films no rack there: no soft subject planned, no zoom giving way
    assert np.array_equal(planned_focus_rows(focus, absent, 2), want)
    assert not lens_for_focus_rows(planned_focus_rows(focus, absent, 2), absent, 2, 1).any()
    # read as measured, the same rows were a rack onto the background (the zoom gave way round row 4)
    assert lens_for_focus_rows(focus, absent, 2, 1)[2:5].all()
    # and rows before the first that measures him take that first label
    first = np.array([bg, bg, [1, 0, 1], [1, 0, 1]], dtype=bool)
    gone = np.zeros((4, 3), dtype=bool)
    gone[:2, 1] = True
    assert held_subject_labels(first, gone)[:, 1].tolist() == [False, False, False, False]
    gone_soft = np.array([bg, bg, sub_bg, sub_bg], dtype=bool)
    assert held_subject_labels(gone_soft, gone)[:, 1].tolist() == [True, True, True, True]


def test_a_subject_the_source_does_not_measure_asks_no_near_limit(planner, instructions):
    # given a style whose subject is sharp with the background (rows 0-9), then unmeasured while the background
    # is still labelled sharp (rows 10-19: his label held sharp), then unmeasured with the foreground sharp too
    # (rows 20-29), then nothing labelled at all (30 on)
    k = instructions.image_targets.shape[0]
    assert k > 31
    sm = np.tile(np.array([np.nan, 1.0, 1.0], dtype=np.float32), (k, 1))
    sm[10:, 1] = np.nan
    sm[20:30, 0] = 1.0
    sm[30:] = np.nan
    focus = np.where(np.isfinite(sm), sm > 0.5, False)
    ins = dataclasses.replace(instructions, focus_smoothed=sm, focus_raw=sm, focus_in=focus)
    absent = absent_regions(ins)
    assert unmeasured_subject_rows(absent).tolist() == [False] * 10 + [True] * 20 + [False] * (k - 30)
    assert planned_focus_rows(focus, absent, 2)[10:20, 1].all()  # held: no rack read there
    sim = KinematicSim(wrong_start_scene())
    x0 = planner._measured_state(T0, sim.vehicle_state(T0))
    subj = predict_subject(sim.subject_state(T0), T0)
    dof, dref = planner._dof_targets(T0, ins, [5, 15, 25], 5, x0, subj)
    st = planner.cfg.structure
    # then the measured row keeps him sharp: the near limit mu in front of him, the far limit at infinity
    assert dof[0, 0] == 1.0 and dof[0, 1] == pytest.approx(1.0 / (dref[0] - ins.mu_m))
    # and the row that does not measure him leaves the near limit free, and its far limit (one-sided) reaches
    # the ground behind him the planned camera sees rather than infinity: with nothing pinning the focus, a
    # far limit at infinity was met by stopping down
    ground = planner._ground_behind_inv_m(x0, subj, 2 * st.dt_s)  # the second stage's, from x0 (no plan yet)
    assert ground is not None and ground > 0
    assert dof[1, 0] == 0.0 and dof[1, 1] == 0.0
    assert dof[1, 2] == 1.0 and dof[1, 4] == 1.0 and dof[1, 3] == pytest.approx(ground)
    # and a sharp foreground still asks its near limit
    assert dof[2, 0] == 1.0 and dof[2, 1] == pytest.approx(1.0 / st.near_foreground_m)
    # and with the option off the held label is asked of his depth with the far limit at infinity (the f/9 of
    # the docs)
    off = Planner(dataclasses.replace(planner.cfg, unmeasured_subject_near_free=False), solver=planner.solver)
    dof_off, dref_off = off._dof_targets(T0, ins, [15], 5, x0, subj)
    assert dof_off[0, 0] == 1.0 and dof_off[0, 1] == pytest.approx(1.0 / (dref_off[0] - ins.mu_m))
    assert dof_off[0, 3] == pytest.approx(-st.far_margin_inv_m)


def test_a_soft_background_pins_the_near_limit_with_no_foreground(planner, instructions):
    # given a style asking only the subject sharp before a soft background, with no foreground in the source
    k = instructions.image_targets.shape[0]
    sm = np.tile(np.array([np.nan, 1.0, 0.0], dtype=np.float32), (k, 1))
    ins = dataclasses.replace(instructions, focus_smoothed=sm, focus_raw=sm,
                              focus_in=np.where(np.isfinite(sm), sm > 0.5, False))
    absent = absent_regions(ins)
    subject_only = np.array([False, True, False])
    assert pins_field_before_soft_background(subject_only, absent[0])
    # (and not with the background sharp, absent, or with him soft)
    assert not pins_field_before_soft_background(np.array([False, True, True]), absent[0])
    assert not pins_field_before_soft_background(subject_only, np.array([True, False, True]))
    assert not pins_field_before_soft_background(np.array([False, False, True]), absent[0])
    sim = KinematicSim(wrong_start_scene())
    x0 = planner._measured_state(T0, sim.vehicle_state(T0))
    subj = predict_subject(sim.subject_state(T0), T0)
    dof, dref = planner._dof_targets(T0, ins, [0], 0, x0, subj)
    d, mu = dref[0], ins.mu_m
    # then both limits are asked two-sided of the one sharpness circle: the field is pinned round him (one-sided,
    # any f-number whose field ended at d + mu cost the same)
    assert dof[0, 0] == 1.0 and dof[0, 5] == 0.0 and dof[0, 2] == 1.0 and dof[0, 4] == 0.0
    assert dof[0, 6] == 1.0 and dof[0, 7] == 1.0
    # and the field d -+ mu stands in front of him by the margin, its width in inverse depth kept
    focal = float(x0[planner.layout.F])
    shift = planner._soft_background_ahead_inv_m(focal)
    assert shift == pytest.approx(SHARP_SUBJECT_BLUR * planner._planned_spread(focal))
    assert shift > 0
    assert dof[0, 1] == pytest.approx(1.0 / (d - mu) + shift)
    assert dof[0, 3] == pytest.approx(1.0 / (d + mu) + shift)
    # and with the option off the near limit is one-sided and centred on him, as for any row without a foreground
    off = Planner(dataclasses.replace(planner.cfg, soft_background_pins_near=False), solver=planner.solver)
    dof_off, _ = off._dof_targets(T0, ins, [0], 0, x0, subj)
    assert dof_off[0, 5] == 1.0
    assert dof_off[0, 1] == pytest.approx(1.0 / (d - mu)) and dof_off[0, 3] == pytest.approx(1.0 / (d + mu))


def test_a_borderline_foreground_label_asks_its_near_limit_as_little(planner, instructions):
    # given a style asking the foreground and the subject sharp, the foreground's B just above theta in row 0
    k = instructions.image_targets.shape[0]
    sm = np.tile(np.array([1.0, 1.0, 0.0], dtype=np.float32), (k, 1))
    sm[0, 0] = instructions.theta + 0.005
    ins = dataclasses.replace(instructions, focus_smoothed=sm, focus_raw=sm, focus_in=sm > instructions.theta)
    sim = KinematicSim(wrong_start_scene())
    x0 = planner._measured_state(T0, sim.vehicle_state(T0))
    subj = predict_subject(sim.subject_state(T0), T0)
    dof, _ = planner._dof_targets(T0, ins, [0, 1], 0, x0, subj)
    # then both ask the near limit at 1 m, the borderline row at 0.005 / 0.1 of the weight, the plain one in full
    st = planner.cfg.structure
    assert dof[0, 1] == dof[1, 1] == pytest.approx(1.0 / st.near_foreground_m)
    assert dof[0, 0] == pytest.approx(0.05) and dof[1, 0] == 1.0


def test_a_subject_label_is_never_held_across_a_cut():
    # given a shot with the subject sharp (rows 0-2) cut to one asking nothing sharp (rows 3-7) whose
    # first rows do not measure him (3-5) and whose last do, soft (6-7)
    sub_bg, none = [0, 1, 1], [0, 0, 0]
    focus = np.array([sub_bg] * 3 + [none] * 5, dtype=bool)
    absent = np.zeros((8, 3), dtype=bool)
    absent[3:6, 1] = True
    cut = np.zeros(8, dtype=bool)
    cut[[0, 3]] = True
    # then the new shot's rows take his label from that shot (soft), so it asks nothing sharp throughout
    assert held_subject_labels(focus, absent, cut)[:, 1].tolist() == [True] * 3 + [False] * 5
    planned = planned_focus_rows(focus, absent, 2, cut)
    assert not planned[3:].any()
    # and no rack is read inside it (the zoom would give way and the background be left to itself)
    assert not lens_for_focus_rows(planned, absent, 8, 0, cut)[3:].any()
    # without the cut the earlier shot's sharp label was held over rows 3-5: a rack at row 6
    assert held_subject_labels(focus, absent)[3:6, 1].all()
    assert lens_for_focus_rows(planned_focus_rows(focus, absent, 2), absent, 8, 0, cut)[3:6].all()
    # a shot that never measures him keeps its rows as they are
    never = absent.copy()
    never[6:, 1] = True
    assert held_subject_labels(focus, never, cut)[3:, 1].tolist() == [False] * 5


def test_a_zoom_gives_way_round_a_rack_focus(planner, instructions):
    # given a style zooming out throughout (a handheld source camera), racking from the subject to the
    # background at row 40 (24 rows a second)
    k = instructions.image_targets.shape[0]
    assert k > 120
    focus = np.tile([False, True, False], (k, 1))
    focus[40:] = (False, False, True)
    sm = np.where(focus, 1.0, 0.0).astype(np.float32)
    sm[:, 0] = np.nan
    ins = dataclasses.replace(instructions, focus_smoothed=sm, focus_raw=sm, focus_in=focus, fps=24.0,
                              camera_motion_class=["pan+zoom_out"] * k, zoom_rate=np.full(k, -0.2),
                              pan_rate_dps=np.full(k, 5.0))
    sim = KinematicSim(wrong_start_scene())
    assert planner.command(M.Command(action="start", args={"start_frame": 0}), T0)
    lead, settle = (int(round(s * 24.0)) for s in (planner.cfg.zoom_yield_lead_s, planner.cfg.keep_out_settle_s))
    assert (lead, settle) == (36, 36)
    # when the horizon is staged from rows 0, 20 and 80
    for first_row in (0, 20, 80):
        now = T0 + int(first_row / 24.0 * S)
        data, _ = planner._stage_data(now, ins, sim.vehicle_state(now), sim.subject_state(now))
        rows = np.array(planner._rows(now, ins, 15, 0.1)[0])
        # then the zoom (and standing still along the axis) is asked only of stages outside the lead before
        # the switch and the settle after it; the pan is asked of every stage
        flown = (rows < 40 - lead) | (rows >= 40 + settle)
        assert flown.any() != (first_row == 20)
        zoom = data.motion[:, LENS_MOTION_COLUMNS].any(axis=1)
        assert (zoom == flown).all(), (rows, zoom)
        assert (data.motion[:, 6] == 1.0).all()
        assert planner.counters["zoom_yields_to_focus"] is bool((~flown).any())
    # and with the option off the zoom is asked of every stage
    off = Planner(dataclasses.replace(planner.cfg, zoom_yields_to_focus=False), solver=planner.solver)
    assert off.command(M.Command(action="start", args={"start_frame": 0}), T0)
    now = T0 + int(20 / 24.0 * S)
    data, _ = off._stage_data(now, ins, sim.vehicle_state(now), sim.subject_state(now))
    assert data.motion[:, LENS_MOTION_COLUMNS].any(axis=1).all()


def test_only_the_subject_sharp_takes_the_focus_the_scene_map_gives_the_three_labels(planner, instructions):
    from cinetransfer.services.planner.focus_field import FULL_TOGETHER_BLUR, SHARP_SUBJECT_BLUR, focus_ahead_inv_m

    # given only the subject sharp, a soft foreground and background shown, the camera 9 m behind him, 1 m up,
    # pitched 0.05 rad down, and a map with a hedge 3 m in front of the camera (0.6 m high, across the view) and a
    # backdrop 30 m behind him
    ins, x0, subj = _labels_seen_from(planner, instructions, (False, True, False), (-9.0, 0.0, 1.0), -0.05)
    hedge, backdrop = [-6.0, 50.0, -6.0, -50.0, 0.0, 0.6], [30.0, 200.0, 30.0, -200.0, 0.0, 40.0]
    mapped = Planner(dataclasses.replace(planner.cfg, surfaces_m=(hedge, backdrop)), solver=planner.solver)
    dof, dref = mapped._dof_targets(T0, ins, [0], 0, x0, subj)
    lay, st, b = planner.layout, planner.cfg.structure, planner.solver.bounds
    # then the band's median is the hedge (3 cos 0.05 m along the axis at the camera's height, nearer below it)
    # and the background's the backdrop (39 cos 0.05 m)
    fg, bg, fg_flip, bg_flip = mapped._map_medians(x0, subj, st.dt_s)
    assert 1.0 / fg == pytest.approx(3.0 * np.cos(0.05), abs=0.1)
    assert 1.0 / bg == pytest.approx(39.0 * np.cos(0.05), abs=0.5)
    # each with the one circle's flip, none given; a hedge given its flip hands it on
    assert (fg_flip, bg_flip) == (1.0, 1.0)
    flipped = Planner(dataclasses.replace(planner.cfg, surfaces_m=([*hedge, 1.3], backdrop)), solver=planner.solver)
    assert flipped._map_medians(x0, subj, st.dt_s)[2:] == (1.3, 1.0)
    # and where both are equally soft (1/s = 0.178 /m, 5.6 m) lies farther in front of him (1/d = 0.111 /m) than
    # the quarter circle he may carry, so the focus stands a quarter circle of the widest aperture in front of
    # him (1000 A c / f^2 per metre), the backdrop then 1.28 circles soft: d -+ mu move by that
    spread = 1000.0 * b.f_number_min * st.coc_mm / x0[lay.F] ** 2
    shift = SHARP_SUBJECT_BLUR * spread
    assert (1.0 / dref[0] + shift - bg) / spread > FULL_TOGETHER_BLUR
    assert dof[0, 1] == pytest.approx(1.0 / (dref[0] - ins.mu_m) + shift)
    assert dof[0, 3] == pytest.approx(1.0 / (dref[0] + ins.mu_m) + shift)
    # which is not the move the ground alone gives
    band = planner._foreground_band(x0, subj, st.dt_s)
    assert shift != pytest.approx(focus_ahead_inv_m(dref[0], band, fg_absent=False, spread=1.2 * spread))
    # and a map whose hedge stands beside the view, with no backdrop, leaves the ground's rule
    aside = Planner(dataclasses.replace(planner.cfg, surfaces_m=([-6.0, 40.0, -6.0, 50.0, 0.0, 0.6],)),
                    solver=planner.solver)
    np.testing.assert_allclose(aside._dof_targets(T0, ins, [0], 0, x0, subj)[0],
                               planner._dof_targets(T0, ins, [0], 0, x0, subj)[0])


def test_only_the_subject_sharp_moves_the_field_in_front_of_him(planner, instructions):
    from cinetransfer.services.planner import focus_field as FF
    from cinetransfer.services.planner.focus_field import focus_ahead_inv_m

    # given a style that wants only the subject sharp, a soft foreground and background shown,
    # and a camera 9 m behind the subject, 2 m up, pitched 0.15 rad down: his feet low in the frame
    ins, x0, subj = _labels_seen_from(planner, instructions, (False, True, False), (-9.0, 0.0, 2.0), -0.15)
    k = len(ins.focus_in)
    dof, dref = planner._dof_targets(T0, ins, [0], 0, x0, subj)
    lay, st, b = planner.layout, planner.cfg.structure, planner.solver.bounds
    # then d -+ mu move nearer by what focus_ahead_inv_m gives for the
    # band seen from the planned camera, with the one circle's spread at the aperture planned for (1.2 A_min,
    # 1000 A c / f^2 per metre)
    spread = 1000.0 * 1.2 * b.f_number_min * st.coc_mm / x0[lay.F] ** 2
    band = planner._foreground_band(x0, subj, st.dt_s)
    shift = focus_ahead_inv_m(dref[0], band, fg_absent=False, spread=spread)
    assert shift > 0.0
    assert dof[0, 0] == 1.0 and dof[0, 2] == 1.0
    assert dof[0, 1] == pytest.approx(1.0 / (dref[0] - ins.mu_m) + shift)
    assert dof[0, 3] == pytest.approx(1.0 / (dref[0] + ins.mu_m) + shift)
    # and with the option off, centred on him as before
    off = Planner(dataclasses.replace(planner.cfg, subject_only_focus_ahead=False), solver=planner.solver)
    dof, dref = off._dof_targets(T0, ins, [0], 0, x0, subj)
    assert dof[0, 1] == pytest.approx(1.0 / (dref[0] - ins.mu_m))
    assert dof[0, 3] == pytest.approx(1.0 / (dref[0] + ins.mu_m))
    # and in a shot that racks to the background at row 40 (the subject then soft to the end): in front of him
    # before the switch by what the ground behind him asks (_rack_ahead_inv_m, below), and with the rack planned
    # ahead (rack_lead_max_s), from where half the focus's travel from him to one circle behind
    # (_subject_travel_s: 1/s = 1/d - sigma at the aperture planned for, at the lens's rate; the lens's far end
    # where that lies beyond it) takes longer than the time left, at most rack_lead_max_s, planned as the
    # switch's row, made: as once the switch is followed (its near limit's circle the visible one, its far target
    # kept), not previewed
    sw = 40
    # (the lead's last rack_lead_hold_s hold him sharp instead: off here, where the lead itself is judged)
    led = Planner(dataclasses.replace(planner.cfg, rack_lead_max_s=1.5, rack_lead_background_gate=False,
                                      rack_lead_hold_s=0.0), solver=planner.solver)
    assert k - sw >= led.cfg.rack_lead_min_hold_s * _fps(ins)
    focus = np.tile([False, True, False], (k, 1))
    focus[sw:] = (False, False, True)
    rack = dataclasses.replace(ins, focus_in=focus, focus_smoothed=np.where(focus, 1.0, 0.0).astype(np.float32))
    travel = led._subject_travel_s(dref[0], x0[lay.F])
    x1 = 1.0 / dref[0] - 1000.0 * 1.2 * b.f_number_min * st.coc_mm / x0[lay.F] ** 2
    s1 = min(1.0 / x1, b.focus_distance_max_m) if x1 > 0 else b.focus_distance_max_m
    assert travel == pytest.approx((s1 - dref[0]) / b.focus_rate_mps)
    j = min(int(RACK_LEAD_SHARE * travel * _fps(ins)), int(round(1.5 * _fps(ins))))
    assert 1 < j < sw - 1
    dof, dref = led._dof_targets(T0, rack, [0, sw - j - 1], 0, x0, subj)
    before = [led._rack_ahead_inv_m(x0, subj, (i + 1) * st.dt_s, float(dref[i])) for i in range(2)]
    assert min(before) > 0.0
    np.testing.assert_allclose(dof[:, 1], 1.0 / (dref - ins.mu_m) + before, rtol=1e-9)
    np.testing.assert_allclose(dof[:, 3], 1.0 / (dref + ins.mu_m) + before, rtol=1e-9)
    lead_row = led._dof_targets(T0, rack, [sw - j], 0, x0, subj)[0]
    previewed = led._dof_targets(T0, rack, [sw], 0, x0, subj)[0]
    made = led._dof_targets(T0, rack, [sw], sw, x0, subj)[0]
    np.testing.assert_allclose(lead_row, made, rtol=1e-12)
    assert made[0, 7] > previewed[0, 7] == 1.0 and made[0, 2] > previewed[0, 2] == 0.0
    # and the stages past the switch in that horizon plan it as made too, not previewed
    horizon = led._dof_targets(T0, rack, [sw - j, sw + 2], 0, x0, subj)[0]
    np.testing.assert_allclose(horizon[1], led._dof_targets(T0, rack, [sw, sw + 2], sw, x0, subj)[0][1], rtol=1e-12)
    assert horizon[1, 7] > led._dof_targets(T0, rack, [sw, sw + 2], 0, x0, subj)[0][1, 7]
    # and so do a horizon's stages that all lie past the switch while the row followed now is still inside the
    # lead (no stage left to be its lead stage); with the row followed now before the lead, they preview it
    past = led._dof_targets(T0, rack, [sw, sw + 2], sw - j, x0, subj)[0]
    np.testing.assert_allclose(past, led._dof_targets(T0, rack, [sw, sw + 2], sw, x0, subj)[0], rtol=1e-12)
    early = led._dof_targets(T0, rack, [sw, sw + 2], sw - j - 1, x0, subj)[0]
    assert (past[:, 7] > 1.0).all() and (early[:, 7] == 1.0).all() and (early[:, 2] == 0.0).all()
    # and gated by the background (rack_lead_background_gate), given 20 m behind him: inside the one circle's field
    # with the focus on him (1/d - sigma < 1/(d + 20), the field's far limit beyond it), so sharp before the
    # switch whatever the lead, and the lead is the travel's, as ungated
    sigma = 1000.0 * 1.2 * b.f_number_min * st.coc_mm / x0[lay.F] ** 2
    assert 1.0 / dref[0] - sigma < 1.0 / (dref[0] + 20.0)
    near_bg = Planner(dataclasses.replace(led.cfg, background_behind_m=20.0, rack_lead_background_gate=True),
                      solver=planner.solver)
    np.testing.assert_allclose(near_bg._dof_targets(T0, rack, [sw - j], 0, x0, subj)[0], lead_row, rtol=1e-12)
    # and given 1000 m behind him, outside that field: planned as the switch's row only as long before it as the
    # focus takes from him to where the field's far limit reaches the background, 1/s = 1/(d + 1000) + sigma
    # (focus_field.rack_lead_cap_s), at the lens's rate
    gated = Planner(dataclasses.replace(led.cfg, background_behind_m=1000.0, rack_lead_background_gate=True),
                    solver=planner.solver)
    cap = (1.0 / (1.0 / (dref[0] + 1000.0) + sigma) - dref[0]) / b.focus_rate_mps
    j_cap = int(cap * _fps(ins))
    assert 0 < j_cap < j
    np.testing.assert_allclose(gated._dof_targets(T0, rack, [sw - j_cap], 0, x0, subj)[0], lead_row, rtol=1e-12)
    dof, dref = gated._dof_targets(T0, rack, [sw - j_cap - 1], 0, x0, subj)
    assert dof[0, 1] == pytest.approx(1.0 / (dref[0] - ins.mu_m) + gated._rack_ahead_inv_m(x0, subj, st.dt_s, dref[0]))
    # and with the background's distance unknown, the ground behind him the planned camera sees
    # (ground_behind_inv_m at GROUND_BEHIND_SHARE) stands for it; with no ankle seen, no ground and no lead
    seen = Planner(dataclasses.replace(planner.cfg, rack_lead_max_s=1.5), solver=planner.solver)
    d0 = float(dref[0])
    view = seen._ground_view(x0, subj, st.dt_s)
    ground = FF.ground_behind_inv_m(view[0], FF.GROUND_BEHIND_SHARE, **view[1])
    lead = min(RACK_LEAD_SHARE * seen._subject_travel_s(d0, x0[lay.F]),
               FF.rack_lead_cap_s(d0, ground, spread=sigma, rate_mps=b.focus_rate_mps))
    assert seen._rack_lead_s(x0, subj, st.dt_s, d0) == pytest.approx(lead)
    no_feet = dataclasses.replace(subj, finite=np.zeros_like(subj.finite))
    assert seen._rack_lead_s(x0, no_feet, st.dt_s, d0) == 0.0
    # and with the lead off, in front of him up to the switch
    off = Planner(dataclasses.replace(planner.cfg, rack_lead_max_s=0.0), solver=planner.solver)
    dof, dref = off._dof_targets(T0, rack, [sw - 1], 0, x0, subj)
    assert dof[0, 1] == pytest.approx(1.0 / (dref[0] - ins.mu_m) + off._rack_ahead_inv_m(x0, subj, st.dt_s, dref[0]))
    # and there the focus stands in front of him until the ground behind him (ground_behind_inv_m at
    # GROUND_BEHIND_SHARE) is SOFT_BAND_BLUR circles soft, at most rack_ahead_max_circles (focus_field.rack_ahead_inv_m)
    d0 = float(dref[0])
    view = off._ground_view(x0, subj, st.dt_s)
    ground = FF.ground_behind_inv_m(view[0], FF.GROUND_BEHIND_SHARE, **view[1])
    assert off._rack_ahead_inv_m(x0, subj, st.dt_s, d0) == pytest.approx(FF.rack_ahead_inv_m(
        d0, ground, spread=sigma, background_blur=FF.SOFT_BAND_BLUR, most=off.cfg.rack_ahead_max_circles))
    # and with rack_ahead_max_circles 0, centred on him as before, and with no ankle seen no move either
    centred = Planner(dataclasses.replace(planner.cfg, rack_lead_max_s=0.0, rack_ahead_max_circles=0.0),
                      solver=planner.solver)
    dof, dref = centred._dof_targets(T0, rack, [sw - 1], 0, x0, subj)
    assert dof[0, 1] == pytest.approx(1.0 / (dref[0] - ins.mu_m))
    assert off._rack_ahead_inv_m(x0, no_feet, st.dt_s, d0) == 0.0


def test_the_pre_roll_of_a_truck_asks_a_side_its_travel_keeps_clear(planner, instructions):
    # given a truck to the right (5 deg/s round the subject, 4 s: 2.5 m at his 7.3 m) and a post 2 m along
    # it from where the camera starts, bearing 164 deg round the subject
    k = instructions.image_targets.shape[0]
    ins = dataclasses.replace(instructions, camera_motion_class=["truck"] * k, pan_rate_dps=np.full(k, 5.0),
                              tilt_rate_dps=np.zeros(k), roll_rate_dps=np.zeros(k), zoom_rate=np.zeros(k),
                              translation_dir=np.tile([1.0, 0.0, 0.0], (k, 1)),
                              subject_box=np.tile([0.45, 0.3, 0.55, 0.7], (k, 1)))
    sim = KinematicSim(wrong_start_scene())
    start = M.Command(action="start", args={"start_frame": 0, "end_frame": 96, "preroll_s": 1.0})
    now = T0 + S // 4
    sides = {}
    for name, posts in (("none", []), ("post", [[-7.55, 0.08, 0.1, 0.0, 4.0]])):
        p = Planner(dataclasses.replace(planner.cfg, obstacles_m=posts), solver=planner.solver)
        assert p.command(start, T0)
        data, _ = p._stage_data(now, ins, sim.vehicle_state(now), sim.subject_state(now))
        sides[name] = (data.motion[:, :3], p._settle_stages(now, 15, 0.1), p.counters.get("truck_clear_side_deg"))
    side, settle, turn = sides["post"]
    # then with the post the pre-roll's stages ask a bearing turned away from it (the way past the post is
    # closed), asked 45 deg beyond the clear one, as the side term is free within 45 deg; the take's
    # stages are left to the style
    assert settle[:7].all() and not settle[8:].any()
    assert (side[settle, 2] == 1.0).all() and -90.0 <= turn < 0.0
    asked = math.degrees(math.atan2(side[0, 1], side[0, 0]))
    assert asked == pytest.approx(164.0 + turn - 45.0, abs=1.0)
    np.testing.assert_array_equal(side[~settle], sides["none"][0][~settle])
    # and without it the pre-roll keeps the side the style asks (this style's rows show the subject's
    # front or back), turned by nothing
    assert sides["none"][2] == 0.0 and not np.allclose(side[settle], sides["none"][0][settle])


def test_a_later_shot_in_the_take_is_previewed_only_from_the_last_labelled_row():
    # given a take of three shots: rows 0-4 (labelled to row 3), 5-6 (no label: a morph), 7-8 (labelled)
    absent = np.zeros((9, 3), dtype=bool)
    absent[4] = absent[5] = absent[6] = True
    starts = np.zeros(9, dtype=bool)
    starts[[5, 7]] = True
    held = shot_choice_held(absent, starts)
    assert held[0].tolist() == [1, 1, 1, 1, 1, 2, 2, 3, 3]
    assert held[1].tolist() == [3, 3, 3, 3, 3, -1, -1, 8, 8]
    # then the shot followed now is always previewed, a later one only from its last labelled row on
    assert later_shot_previewed(held, 0, 4)
    assert not later_shot_previewed(held, 0, 7) and not later_shot_previewed(held, 2, 5)
    assert later_shot_previewed(held, 3, 7) and later_shot_previewed(held, 4, 8)
    # and from a shot that labels nothing at once
    assert later_shot_previewed(held, 5, 7)
    # and a shot shorter than min_rows holds nothing back: the 2-row shot 7-8 previews what follows at once
    assert shot_choice_held(absent, starts, min_rows=3)[1].tolist() == [3, 3, 3, 3, 3, -1, -1, -1, -1]
    # and with no cuts every row is one shot
    one = shot_choice_held(absent, None)
    assert not later_shot_previewed(held, 1, 8) and later_shot_previewed(one, 1, 8)


def test_a_later_shot_asks_nothing_of_the_lens_before_the_cut(planner, instructions):
    # given a style asking only the subject sharp, then a cut to a shot asking everything sharp
    k = instructions.image_targets.shape[0]
    sm = np.tile(np.array([np.nan, 1.0, 0.0], dtype=np.float32), (k, 1))
    sm[20:] = (1.0, 1.0, 1.0)
    starts = np.zeros(k, dtype=bool)
    starts[20] = True
    ins = dataclasses.replace(instructions, focus_smoothed=sm, focus_raw=sm, shot_start=starts,
                              focus_in=np.where(np.isfinite(sm), sm > 0.5, False))
    sim = KinematicSim(wrong_start_scene())
    x0 = planner._measured_state(T0, sim.vehicle_state(T0))
    subj = predict_subject(sim.subject_state(T0), T0)
    # then from row 10 the stage past the cut asks nothing (weights 0, the circles' ratios 1), the one before it
    # asks the subject's field
    dof, _ = planner._dof_targets(T0, ins, [15, 22], 10, x0, subj)
    assert dof[0, 0] == 1.0 and dof[0, 2] == 1.0
    assert dof[1].tolist() == [0.0] * 6 + [1.0, 1.0]
    # and from the shot's last row on it asks its own: the near limit at the near foreground, far at infinity
    dof, _ = planner._dof_targets(T0, ins, [22], 19, x0, subj)
    st = planner.cfg.structure
    assert dof[0, 0] == 1.0 and dof[0, 1] == pytest.approx(1.0 / st.near_foreground_m)
    # and with the option off as before
    off = Planner(dataclasses.replace(planner.cfg, later_shot_after_choice=False), solver=planner.solver)
    dof_off, _ = off._dof_targets(T0, ins, [22], 10, x0, subj)
    assert dof_off[0].tolist() == dof[0].tolist()


def test_each_stage_keeps_a_crown_out_at_the_last_plan_s_height(planner, instructions):
    # given a crown 0.5 m over the camera, its axis 1 m away (radius 0.5 m, clearance 1 m): every stage
    # at the measured height keeps 0.5 + sqrt(1 - 0.5^2) = 1.366 m from its axis
    sim = KinematicSim(wrong_start_scene())
    vs = sim.vehicle_state(T0)
    x, y, z = (float(v) for v in vs.position_m)
    crown = [[x + 1.0, y, 0.5, z + 0.5, z + 3.0]]
    cfg = pc.replace(planner.cfg, obstacles_m=crown, **{"bounds.min_obstacle_distance_m": 1.0})
    p = Planner(cfg, solver=planner.solver)
    assert p.command(M.Command(action="start", args={"start_frame": 0, "end_frame": 96, "preroll_s": 1.0}), T0)
    data, _ = p._stage_data(T0, instructions, vs, sim.subject_state(T0))
    n = cfg.structure.horizon_steps
    np.testing.assert_allclose(data.obstacles[:, :3], np.tile([x + 1.0, y, 0.5 + math.sqrt(0.75)], (n, 1)))
    # when the last plan climbs 0.05 m a stage (0.5 m/s), stage k is 0.5 - 0.05 k under the band: 0.5 +
    # sqrt(1 - (0.5 - 0.05 k)^2), from 1.393 m at stage 1 to the full 1.5 m from stage 10 on
    states = np.tile(data.x0, (n + 1, 1))
    states[:, 2] = z + 0.05 * np.arange(n + 1)
    p._plan = Plan(T0, states, np.zeros((n, p.layout.nu)), cfg.structure.dt_s, "Solve_Succeeded", 0)
    data, _ = p._stage_data(T0, instructions, vs, sim.subject_state(T0))
    gap = np.maximum(0.5 - 0.05 * np.arange(1, n + 1), 0.0)
    np.testing.assert_allclose(data.obstacles[:, 2], 0.5 + np.sqrt(1.0 - gap ** 2))
    assert data.obstacles[0, 2] == pytest.approx(1.393, abs=1e-3) and data.obstacles[9, 2] == pytest.approx(1.5)
