"""The subject heading the simulator publishes (sim/heading.py) and its schema version (SubjectState v2)."""
import math

import msgpack
import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend, load_scene
from cinetransfer.services.autopilot_bridge.sim.heading import subject_heading_rad
from cinetransfer.services.planner.kinematic_sim import KinematicScene, KinematicSim
from cinetransfer.shared import codec
from cinetransfer.shared import messages as M

NAMES = ["left_shoulder", "right_shoulder", "left_hip", "right_hip"]
# a body facing +y (heading pi/2): its left is world -x
FACING_Y = np.array([[-0.19, 0.0, 1.44], [0.19, 0.0, 1.44], [-0.11, 0.0, 0.95], [0.11, 0.0, 0.95]])


class Person3D:
    """A subject with a body yaw of its own (as a 3-D person placed in a scene has)."""

    faces_camera = False

    def __init__(self, yaw: float) -> None:
        self.yaw = yaw

    def heading_at(self, t_s: float) -> float:
        return self.yaw + 0.1 * t_s


class JointsOnly:
    """A subject that knows only its 3-D joints."""


def test_the_cut_out_that_faces_the_camera_publishes_no_heading():
    sim = SimBackend(load_scene("open_country_25d", subject="walker"), epoch_ns=0, render=False, truth=False)
    sim.start()
    sim.step(0.0)
    sim.step(0.5)
    assert math.isnan(sim.subject_state().heading_rad)


def test_a_subject_with_its_own_heading_publishes_it_else_the_one_its_joints_show():
    assert subject_heading_rad(Person3D(0.5), 2.0, NAMES, FACING_Y) == pytest.approx(0.7)
    assert subject_heading_rad(Person3D(float("nan")), 0.0, NAMES, FACING_Y) == pytest.approx(math.pi / 2)
    assert subject_heading_rad(JointsOnly(), 0.0, NAMES, FACING_Y) == pytest.approx(math.pi / 2)


def test_the_kinematic_subject_publishes_its_heading():
    sim = KinematicSim(KinematicScene(subject_heading_rad=0.4))
    assert sim.subject_state(0).heading_rad == pytest.approx(0.4)


def test_a_version_1_subject_state_decodes_with_the_heading_unknown():
    msg = M.SubjectState(subject_id="p", joints_m=FACING_Y, heading_rad=1.25)
    assert codec.decode(codec.encode(msg)).heading_rad == pytest.approx(1.25)
    _, header, blob = codec._split(codec.encode(msg))
    assert header["v"] == 2
    header["v"] = 1
    del header["d"]["heading_rad"]
    h = msgpack.packb(header, use_bin_type=True)
    head = codec._PREFIX.pack(codec.MAGIC, codec.FORMAT, len(h)) + h
    old = codec.decode(head + b"\0" * ((-len(head)) % codec._ALIGN) + bytes(blob))
    assert old.subject_id == "p" and math.isnan(old.heading_rad)
    np.testing.assert_allclose(old.joints_m, FACING_Y)
