"""The quick in-process flight of a style's camera motion (benchmarks/camera_motion_flight.py): the
real planner (casadi SQP) flies the kinematic simulator on the transfer's schedule, and the output's
classes come from the camera's poses as the report's truth reads them."""
import dataclasses

import numpy as np
import pytest

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.kinematic_sim import KinematicScene, KinematicSim, Walk
from cinetransfer.services.planner.scenarios import (ReferenceShot, planner_maker, reference_instructions,
                                                     standing_shot)
from conftest import load_benchmark

CFG = pc.PlannerConfig()  # planner_maker lifts the wall-time budget


@pytest.fixture(scope="module")
def flight():
    return load_benchmark("camera_motion_flight")


@pytest.fixture(scope="module")
def make_planner():
    return planner_maker(CFG)


def _classed(ins, cls: str):  # noqa: ANN001, ANN202
    k = ins.image_targets.shape[0]
    nan = np.full(k, np.nan)
    return dataclasses.replace(ins, camera_motion_class=[cls] * k, pan_rate_dps=nan, tilt_rate_dps=nan,
                               roll_rate_dps=nan, zoom_rate=nan, translation_dir=np.zeros((k, 3)))


def test_a_still_subject_filmed_still_reads_static_on_every_row(flight, make_planner):
    # given a standing subject framed as the style asks from where the drone starts
    ins = _classed(reference_instructions(KinematicScene(), standing_shot(), duration_s=2.0), "static")
    sim = KinematicSim(KinematicScene(vehicle_position_m=(-5.0, 0.5, 1.5), lens=(60.0, 5.0, 4.0)))
    r = flight.fly(ins, make_planner(), sim, preroll_s=2.0)
    # then every row of the output is static, framed to within a hundredth of the image
    assert r["output"] == ["static"] * 48 and r["agreement"] == 1.0
    assert r["joint_error"] < 0.01 and r["failed_steps"] == 0


def test_a_walker_followed_by_a_turning_camera_reads_pan(flight, make_planner):
    # given a subject walking across 10 m away and a style filmed from a still camera that pans after him
    walks = [Walk(0.0, 1e9, (0.0, -0.9, 0.0))]
    shot = ReferenceShot(offset_m=lambda t: np.array([-10.0, 0.9 * (t + 2.0), 0.3]), focal_mm=lambda t: 60.0,
                         focus=lambda t: (False, True, False))
    ins = _classed(reference_instructions(KinematicScene(walks=walks), shot, duration_s=2.0), "pan")
    sim = KinematicSim(KinematicScene(walks=walks, vehicle_position_m=(-10.0, 0.0, 1.5), lens=(60.0, 10.0, 4.0)))
    r = flight.fly(ins, make_planner(), sim, preroll_s=2.0)
    # then the output turns (pan, about -5 deg/s) on most rows; the summary counts the classes
    assert r["output"].count("pan") >= 24, r["output"]
    assert np.nanmedian(r["pan_dps"]) < -1.5
    assert flight.class_counts(["pan", "pan", "static"]) == "pan x2, static x1"
