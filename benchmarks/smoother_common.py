"""Shared helpers of the smoother benchmarks (data paths, error statistics; result files and
timing statistics come from harness.py)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from cinetransfer.data import data_dir as shared_data_dir

try:
    from harness import stats, write_result  # noqa: F401 - the scripts' statistics and result files
except ImportError:  # imported as the benchmarks package
    from benchmarks.harness import stats, write_result  # noqa: F401

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
CACHE = RESULTS / "cache"


def data_dir() -> Path:
    try:
        return shared_data_dir()
    except FileNotFoundError as e:
        raise SystemExit(str(e)) from None


def mean_std(err: np.ndarray) -> dict[str, float]:
    e = np.asarray(err, dtype=float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"mean": float("nan"), "std": float("nan"), "n": 0}
    return {"mean": float(e.mean()), "std": float(e.std()), "n": int(e.size)}


