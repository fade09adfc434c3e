"""Built-in simulator: the project's own detector finds the subject and its joints in rendered frames.

Runs the real detector (services/detector, MediaPipe pose) on a short flight in every bundled
scene: the camera moves sideways and zooms while the subject follows its script. A frame counts
when a skeleton's joints lie on the ground-truth joints (median error < 3 % of the image size).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.sim.backend import SimBackend
from cinetransfer.services.autopilot_bridge.sim.scene import load_scene, scene_names
from cinetransfer.shared import messages as M

N_FRAMES = 36


@pytest.mark.slow
@pytest.mark.parametrize("scene", [n for n in scene_names() if load_scene(n).world == "2.5d"])
def test_detector_finds_the_subject_and_joints_in_90_percent_of_frames(pose_detector, scene):
    pose_detector.reset()
    sim = SimBackend(scene, epoch_ns=0)
    sim.start()
    v = sim.scene.vehicle
    p0 = np.array(v.position_m)
    found, errors = 0, []
    for k in range(N_FRAMES):
        t = k / sim.fps
        sim.apply(M.Setpoint(position_m=p0 + [0.0, 1.5 * math.sin(0.5 * t), 0.0],
                             camera_ypr_rad=np.array(v.camera_ypr_rad),
                             lens=M.LensState(focal_length_mm=v.focal_length_mm * (1 + 0.1 * math.sin(t)),
                                              focus_distance_m=float("nan"), f_number=float("nan"))))
        sim.step(t)
        for fr, gt in zip(sim.frames(), sim.truths()):
            m = pose_detector.process(fr.image, fr.index, fr.stamp_ns + 1)
            h, w = fr.image.shape[:2]
            errs = [float(np.nanmedian(np.linalg.norm(sk.keypoints_px / [w, h] - gt.joints_norm, axis=1)))
                    for sk in m.skeletons]
            best = min(errs) if errs else math.inf
            errors.append(best)
            found += best < 0.03
    assert found >= 0.9 * N_FRAMES, f"{scene}: subject found in {found}/{N_FRAMES} frames; errors {errors}"
