"""benchmarks/eval_camera_motion.py compares a source's rows with its per-frame truth, against a
hand-made truth file's contents."""
from __future__ import annotations

import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def ev():
    return load_benchmark("eval_camera_motion")


def test_each_rows_truth_class_and_the_rows_that_agree(ev):
    """Row 0 has no motion (None), row 1 pans at 2 deg/s (over the 1.5 that counts), row 2 rises
    (camera y down: up is -y) and row 3 stands still; the first row is never counted."""
    tr = {"pan_rate_dps": [None, 2.0, 0.0, 0.0], "tilt_rate_dps": [None, 0.0, 0.0, 0.0],
          "roll_rate_dps": [None, 0.0, 0.0, 0.0], "zoom_rate": [None, 0.0, 0.0, 0.0],
          "translation_dir": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.0]]}
    truth = ev.truth_row_classes(tr)
    assert truth[1:] == ["pan", "pedestal", "static"]
    assert ev.rows_agreeing(truth, ["pan", "pan", "tilt+roll", "static"]) == 2
