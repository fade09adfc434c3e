"""Per-joint weights on the image term (config joint_weights): how the planner trades joint
targets it cannot all meet on another body (docs/planner.md, "Another body")."""
import numpy as np
import pytest

from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.core import Planner
from cinetransfer.services.planner.kinematic_sim import KinematicSim
from cinetransfer.services.planner.scenarios import reference_instructions, standing_shot, wrong_start_scene
from cinetransfer.shared import messages as M

T0 = 1_700_000_000_000_000_000


def test_joint_weights_from_a_yaml_mapping_and_refused_when_bad():
    cfg = pc.from_dict({"joint_weights": {"left_hip": 4.0, "right_hip": 4}})
    assert cfg.joint_weight("left_hip") == 4.0 and cfg.joint_weight("left_shoulder") == 1.0
    with pytest.raises(pc.ConfigError, match="joint_weights"):
        pc.from_dict({"joint_weights": {"left_hipp": 1.0}})
    with pytest.raises(pc.ConfigError, match="joint_weights"):
        pc.from_dict({"joint_weights": {"left_hip": -1.0}})


def test_the_image_term_of_each_joint_is_scaled_by_its_weight():
    # given the same inputs, a planner with hips x4 puts 4 (and 0 for an uncontrolled joint) where
    # the default planner puts 1
    ins = reference_instructions(wrong_start_scene(), standing_shot(), duration_s=5.0)
    sim = KinematicSim(wrong_start_scene())
    masks = []
    for w in ({}, {"left_hip": 4.0, "right_hip": 4.0, "left_shoulder": 0.0}):
        p = Planner(pc.PlannerConfig(joint_weights=tuple(w.items())))
        p.command(M.Command(action="start"), T0)
        data, _ = p._stage_data(T0, ins, sim.vehicle_state(T0), sim.subject_state(T0))
        masks.append(np.asarray(data.mask))
    names = list(ins.joint_names)
    base, weighted = masks
    for e, name in enumerate(names):
        want = {"left_hip": 4.0, "right_hip": 4.0, "left_shoulder": 0.0}.get(name, 1.0)
        on = base[:, e] > 0
        assert on.any()
        np.testing.assert_allclose(weighted[on, e], want * base[on, e])
