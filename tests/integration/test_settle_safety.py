"""The move between two takes (the settle phase) respects every limit and never crosses the subject.

Closed loop: the planner flies the kinematic simulator from the end of one shot to the first
frame of the next, whose framing is from the other side of the subject (the straight line
between the two camera positions runs through the subject). Every planner step is checked
against the planner's hard bounds and the bridge's envelope (speed, geofence, altitude band,
subject distance), and every segment the vehicle flies between two samples keeps its distance.
"""

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.services.autopilot_bridge.safety import SafetyLayer
from cinetransfer.services.planner import config as pc
from cinetransfer.services.planner.core import Planner, instructions_from_arrays
from cinetransfer.services.planner.kinematic_sim import KinematicScene, KinematicSim
from cinetransfer.services.planner.scenarios import ReferenceShot, reference_instructions, standing_shot
from cinetransfer.shared import messages as M

# left/right by name: shot B is a back view, and only then must the camera go round to film it
# (by image side, the default, the planner keeps filming the front with the targets mirrored)
CFG = pc.PlannerConfig(max_solve_time_s=0.5, left_right="name")
T0 = 1_700_000_000_000_000_000
SHOT_A_S, SETTLE_S = 3.0, 8.0
TOL = 1e-6
POSITION_CLAMPS = {"clamp_subject_distance", "clamp_geofence", "clamp_altitude"}


def _segment_distance(p: np.ndarray, q: np.ndarray, c: np.ndarray) -> float:
    """Smallest horizontal distance from c to the segment p -> q."""
    p, q, c = p[:2], q[:2], c[:2]
    d = q - p
    s = 0.0 if not d.any() else float(np.clip(np.dot(c - p, d) / np.dot(d, d), 0.0, 1.0))
    return float(np.linalg.norm(p + s * d - c))


def _two_shots(scene: KinematicScene) -> tuple[M.Instructions, int]:
    """Shot A: 5 m in front (standing_shot); shot B: 5 m behind the subject, looking back."""
    a = reference_instructions(scene, standing_shot(), duration_s=SHOT_A_S)
    behind = ReferenceShot(offset_m=lambda t: np.array([5.0, -0.5, 0.3]), focal_mm=lambda t: 60.0,
                           focus=lambda t: (False, True, False))
    b = reference_instructions(scene, behind, duration_s=10.0)
    k_a = a.image_targets.shape[0]
    ins = instructions_from_arrays(targets=np.concatenate([a.image_targets, b.image_targets]),
                                   joint_names=list(a.joint_names),
                                   focus_in=np.concatenate([a.focus_in, b.focus_in]), fps=a.fps, mu_m=a.mu_m)
    return ins, k_a


@pytest.mark.slow
def test_the_settle_move_to_the_far_side_keeps_every_limit_and_goes_around_the_subject():
    # given a vehicle filming shot A from 5 m in front of a standing subject, and a next shot
    # filmed from 5 m behind it
    scene = KinematicScene(name="settle", vehicle_position_m=(-5.0, 0.5, 1.6), camera_ypr_rad=(0.0, 0.0, 0.0),
                           lens=(60.0, 5.0, 4.0))
    ins, k_a = _two_shots(scene)
    planner, sim = Planner(CFG), KinematicSim(scene)
    planner.use_time_budget(None)  # the loop's clock waits for every solve: load must not cut one short
    safety, b = SafetyConfig(), CFG.bounds
    layer = SafetyLayer(safety)
    home = np.asarray(safety.home_m, dtype=float)
    subject = np.asarray(scene.subject_position_m, dtype=float)
    rate = CFG.rate_hz
    SUB = int(round(1.0 / rate / sim.dt_s))  # simulator steps per planner step
    planner.command(M.Command(action="start", args={"start_frame": 0}), T0)
    positions, framing = [], []
    n_a, n_settle = int(SHOT_A_S * rate), int(SETTLE_S * rate)
    for i in range(n_a + n_settle):
        now = T0 + int(round(i / rate * 1e9))
        if i == n_a:  # the take of shot B begins with its settle phase (as the transfer schedules it)
            planner.command(M.Command(action="start", args={"start_frame": k_a, "preroll_s": SETTLE_S}), now)
        sp = planner.step(now, ins, sim.vehicle_state(now), sim.subject_state(now))
        sim.apply(sp)
        for _ in range(SUB):  # the simulator's own steps: the flown path, finely sampled
            sim.step(sim.dt_s)
            positions.append(np.asarray(sim.vehicle_state(now).position_m, dtype=float).copy())
        if i >= n_a:
            # when settling: every setpoint inside the planner's hard bounds and the bridge's envelope
            assert sp.mode == "track" and sp.valid, sp.solver_status
            # the speed as a norm and the climb rate, as the safety layer and the vehicle bound them
            assert np.linalg.norm(sp.velocity_mps) <= b.speed_max_mps + TOL
            assert abs(sp.velocity_mps[2]) <= b.climb_max_mps + TOL
            # the bridge's safety layer takes it as planned: no position and no speed clamp
            res = layer.check(sp, subject_xy=subject[:2], vehicle_xy=sim.p[:2])
            assert res.accepted and not set(res.clamps) & (POSITION_CLAMPS | {"clamp_speed"}), res
            assert np.all(np.abs(sp.acceleration_mps2) <= b.accel_max_mps2 + TOL)
            assert np.linalg.norm(sp.position_m[:2] - home[:2]) <= safety.geofence_radius_m
            assert safety.altitude_min_m <= sp.position_m[2] - home[2] <= safety.altitude_max_m
            assert np.linalg.norm(sp.position_m[:2] - subject[:2]) >= safety.min_subject_distance_m
            assert np.max(planner.last_result.slack) < 1e-3  # soft limits (floor, distance, speed) kept too
            framing.append(float(np.max(np.linalg.norm(sim.image_points(ins.joint_names)
                                                        - ins.image_targets[k_a], axis=1))))
    # then the flown path never comes closer to the subject than the bridge allows (it went round)
    settle_path = positions[n_a * SUB:]
    closest = min(_segment_distance(p, q, subject) for p, q in zip(settle_path[:-1], settle_path[1:]))
    assert closest >= safety.min_subject_distance_m, closest
    speeds = np.linalg.norm(np.diff(np.asarray(settle_path), axis=0), axis=1) / sim.dt_s
    assert speeds.max() <= b.speed_max_mps + 1e-3
    # and it ends on the far side, framing shot B's first frame (measured: closest 4.8 m, final error 0.02)
    assert np.asarray(settle_path[-1])[0] > subject[0] + 3.0
    assert framing[-1] < 0.05, framing[-1]
