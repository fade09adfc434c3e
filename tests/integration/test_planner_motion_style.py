"""Closed loop: the planner (real casadi SQP) flies the kinematic simulator (the one dynamics model)
to the side of the subject the style shows, and with the style's camera motion: a pan, a zoom and
a dolly zoom. Everything is measured on the simulator's true state with shared.camera."""
import dataclasses
import math

import numpy as np
import pytest

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.core import Planner
from cinetransfer.services.planner.kinematic_sim import KinematicScene, KinematicSim, Walk
from cinetransfer.services.planner.scenarios import (ReferenceShot, planner_maker, reference_instructions,
                                                     run_closed_loop, standing_shot)
from cinetransfer.shared import messages as M

CFG = pc.PlannerConfig()  # planner_maker lifts the wall-time budget: the simulated clock waits for the solver
JOINTS = ["left_shoulder", "right_shoulder", "left_hip", "right_hip"]
SUBJECT_FOCUS = (False, True, False)


def _styled(ins: M.Instructions, cls: str, *, pan=np.nan, zoom=np.nan, travel=(0.0, 0.0, 0.0)) -> M.Instructions:
    """`ins` with the style's camera-motion fields (per frame, as the style schema carries them)."""
    k = ins.image_targets.shape[0]
    nan = np.full(k, np.nan)
    return dataclasses.replace(ins, camera_motion_class=[cls] * k, pan_rate_dps=np.broadcast_to(pan, (k,)).copy(),
                               tilt_rate_dps=nan, roll_rate_dps=nan, zoom_rate=np.broadcast_to(zoom, (k,)).copy(),
                               translation_dir=np.tile(np.asarray(travel, dtype=float), (k, 1)))


@pytest.fixture(scope="module")
def planner_factory():
    return planner_maker(CFG)


def _fly(planner: Planner, sim: KinematicSim, ins: M.Instructions, duration_s: float) -> tuple[np.ndarray, list]:
    """Fly; per planner step (t, camera yaw, focal length, subject distance, image height of the torso)."""
    rec = []

    def on_step(i, sp):  # noqa: ANN001
        pts = sim.image_points(JOINTS)
        rec.append((sim.t_s, sim.ypr[0], sim.lens[0], float(np.linalg.norm(sim.p - sim.subject.centre())),
                    pts[2:, 1].mean() - pts[:2, 1].mean()))
        assert sp.mode == "track" and sp.valid, sp.solver_status
        assert np.linalg.norm(sp.velocity_mps) <= CFG.bounds.speed_max_mps + 1e-3
    log = run_closed_loop(planner, sim, ins, duration_s=duration_s, on_step=on_step)
    return np.array(rec), log.image_error


def _rate(rec: np.ndarray, col: int, t0: float, log: bool = False) -> float:
    """Mean rate of a recorded column from t0 to the end (of its log with `log`)."""
    i = int(np.searchsorted(rec[:, 0], t0))
    a, b = rec[i, col], rec[-1, col]
    return float((math.log(b / a) if log else b - a) / (rec[-1, 0] - rec[i, 0]))


def test_the_camera_flies_round_to_the_front_the_style_shows(planner_factory):
    # given a front-view style (filmed from in front of a subject facing the camera) and a subject
    # that faces away from the drone: the drone starts behind him
    ins = reference_instructions(KinematicScene(), standing_shot(), duration_s=16.0)
    scene = KinematicScene(name="behind", subject_heading_rad=0.0, vehicle_position_m=(-5.0, 0.3, 1.6))
    planner, sim = planner_factory(), KinematicSim(scene)
    assert sim.subject_state(0).heading_rad == pytest.approx(0.0)
    rec, err = _fly(planner, sim, ins, 12.0)
    # then it flies round to his front (bearing from the subject to the camera near his heading, 0)
    bearing = math.degrees(math.atan2(sim.p[1] - sim.subject.centre()[1], sim.p[0] - sim.subject.centre()[0]))
    assert abs(bearing) < 30.0, bearing
    assert planner.counters["left_right"] == "name" and planner.counters["side_of_subject"]
    # and frames him left by left as the style does
    assert np.median(err[-40:]) < 0.02
    # never closer than the minimum distance on the way (soft, kept)
    assert rec[:, 3].min() > CFG.bounds.min_subject_distance_m - 0.05


def test_without_a_heading_the_planner_keeps_the_side_it_sees(planner_factory):
    # given the same start, but a subject state without a heading (a cut-out that faces the camera)
    ins = reference_instructions(KinematicScene(), standing_shot(), duration_s=6.0)
    scene = KinematicScene(name="behind", subject_heading_rad=0.0, vehicle_position_m=(-5.0, 0.3, 1.6))
    planner, sim = planner_factory(), NoHeadingSim(scene)
    _fly(planner, sim, ins, 4.0)
    # then it matches left and right by image side and stays behind him
    assert planner.counters["left_right"] == "image_side" and not planner.counters["side_of_subject"]
    assert sim.p[0] < -2.0


class NoHeadingSim(KinematicSim):
    """The kinematic simulator whose subject states carry no heading (as perception without one)."""

    def subject_state(self, stamp_ns: int) -> M.SubjectState:
        return dataclasses.replace(super().subject_state(stamp_ns), heading_rad=float("nan"))


def _pan_scene() -> tuple[M.Instructions, KinematicScene, float]:
    """A subject walking across at 0.87 m/s, filmed by a still camera 10 m away that pans to follow."""
    v = 10.0 * math.radians(5.0)
    walks = [Walk(0.0, 1e9, (0.0, -v, 0.0))]
    shot = ReferenceShot(offset_m=lambda t: np.array([-10.0, v * t, 0.3]), focal_mm=lambda t: 80.0,
                         focus=lambda t: SUBJECT_FOCUS)
    base = reference_instructions(KinematicScene(walks=walks), shot, duration_s=10.0)
    scene = KinematicScene(walks=walks, vehicle_position_m=(-10.0, 0.0, 1.5), lens=(80.0, 10.0, 4.0))
    return base, scene, v


def test_a_pan_is_flown_at_the_source_rate(planner_factory):
    base, scene, v = _pan_scene()
    tk = np.arange(base.image_targets.shape[0]) / base.fps
    pan_dps = -np.degrees(v / 10.0 / (1.0 + (v * tk / 10.0) ** 2))  # the source camera's yaw rate (to the right)
    source = -math.degrees(math.atan(v * 7.5 / 10.0) - math.atan(v * 2.0 / 10.0)) / 5.5  # its mean, 2 to 7.5 s
    rec, err = _fly(planner_factory(), KinematicSim(scene), _styled(base, "pan", pan=pan_dps), 7.5)
    flown = math.degrees(_rate(rec, 1, 2.0))
    assert flown == pytest.approx(source, rel=0.2), (flown, source)
    assert np.median(err[40:]) < 0.03
    # without the style's motion the drone follows the walker instead of panning
    rec, _ = _fly(planner_factory(), KinematicSim(scene), base, 7.5)
    assert abs(math.degrees(_rate(rec, 1, 2.0))) < 0.4 * abs(source)


def test_a_zoom_is_flown_with_the_lens_at_the_source_rate(planner_factory):
    # given a still source camera zooming in at d ln f/dt = 0.1 /s
    shot = ReferenceShot(offset_m=lambda t: np.array([-5.0, 0.5, 0.3]), focal_mm=lambda t: 40.0 * math.exp(0.1 * t),
                         focus=lambda t: SUBJECT_FOCUS)
    ins = _styled(reference_instructions(KinematicScene(), shot, duration_s=10.0), "zoom_in", zoom=0.1)
    sim = KinematicSim(KinematicScene(vehicle_position_m=(-5.0, 0.5, 1.5), lens=(40.0, 5.0, 4.0)))
    rec, err = _fly(planner_factory(), sim, ins, 7.5)
    # then the lens zooms at that rate (framing alone dollied in instead: 0.072 /s, distance falling)
    assert _rate(rec, 2, 2.0, log=True) == pytest.approx(0.1, rel=0.2)
    assert abs(_rate(rec, 3, 2.0, log=True)) < 0.02
    assert np.median(err[40:]) < 0.03


def test_a_dolly_zoom_changes_focal_length_and_distance_together_and_holds_the_size(planner_factory):
    # given a still framing (4 m, 40 mm) and a dolly-zoom class: zoom in at 0.1 /s while backing away
    shot = ReferenceShot(offset_m=lambda t: np.array([-4.0, 0.5, 0.3]), focal_mm=lambda t: 40.0,
                         focus=lambda t: SUBJECT_FOCUS)
    ins = _styled(reference_instructions(KinematicScene(), shot, duration_s=10.0), "dolly_zoom", zoom=0.1,
                  travel=(0.0, 0.0, -1.0))
    sim = KinematicSim(KinematicScene(vehicle_position_m=(-4.0, 0.5, 1.5), lens=(40.0, 4.0, 4.0)))
    rec, err = _fly(planner_factory(), sim, ins, 7.5)
    # then focal length and distance both grow at the rate (40 -> ~85 mm, 4 -> ~8.4 m) ...
    assert _rate(rec, 2, 2.0, log=True) == pytest.approx(0.1, rel=0.2)
    assert _rate(rec, 3, 2.0, log=True) == pytest.approx(0.1, rel=0.2)
    assert rec[-1, 2] > 1.8 * 40.0 and rec[-1, 3] > 1.8 * 4.0
    # ... while the torso's image height holds within 3 %
    h = rec[int(np.searchsorted(rec[:, 0], 1.0)):, 4]
    assert h.max() / h.min() < 1.03, (h.min(), h.max())
    assert np.median(err[20:]) < 0.02
