"""Moves cut from real static footage (a sliding, rotating or shrinking crop with exact truth) go
through the real extraction (detector with the people's masks, then the smoother) and come out
with the right class and rates within 20 %."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def sources():
    return load_benchmark("camera_motion_sources")


@pytest.mark.parametrize("name", ["static", "pan_right", "tilt_up", "roll_cw", "zoom_in"])
def test_a_crop_move_of_a_static_clip_is_classified_and_measured(sources, data, tmp_path, name):
    from cinetransfer.extract import extract_features
    from cinetransfer.report.camera_motion import RATES, shot_motion, style_rates
    from cinetransfer.services.smoother.config import SmootherConfig
    from cinetransfer.services.smoother.core import smooth_sequence

    move = next(m for m in sources.MOVES if m.name == name)
    video = sources.make_source(data / "sam2_juggle_1280x720.mp4", move, tmp_path, start=30, frames=30,
                                out_size=(480, 270))
    truth = json.loads(video.with_suffix(".truth.json").read_text())
    cfg = SmootherConfig()
    feats, src = extract_features(video, cfg)
    instr = smooth_sequence(feats, cfg, source=src, known_cuts=[]).instructions
    got = shot_motion(style_rates(instr), 0, len(instr.camera_motion_class))
    assert got["class"] == move.cls, got
    for n in RATES:
        want = float(np.nanmedian(np.array(truth[n], dtype=float)))
        if want:
            assert got[n] == pytest.approx(want, rel=0.2), n
