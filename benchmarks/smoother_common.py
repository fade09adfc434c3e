"""Shared helpers of the smoother benchmarks (data paths, result files, statistics)."""
from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np

from cinetransfer.data import data_dir as shared_data_dir

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
CACHE = RESULTS / "cache"


def data_dir() -> Path:
    try:
        return shared_data_dir()
    except FileNotFoundError as e:
        raise SystemExit(str(e)) from None


def stats_ms(samples_s: list[float]) -> dict[str, float]:
    a = np.asarray(samples_s) * 1e3
    return {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)), "max_ms": float(a.max()),
            "n": int(a.size)}


def mean_std(err: np.ndarray) -> dict[str, float]:
    e = np.asarray(err, dtype=float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"mean": float("nan"), "std": float("nan"), "n": 0}
    return {"mean": float(e.mean()), "std": float(e.std()), "n": int(e.size)}


def machine() -> dict[str, Any]:
    try:
        commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {"commit": commit, "host": platform.node(), "cpu_count": os.cpu_count(), "python": platform.python_version(),
            "loadavg": os.getloadavg(), "time": time.strftime("%Y-%m-%dT%H:%M:%S")}


def write_result(name: str, payload: dict[str, Any]) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    p = RESULTS / f"{name}.json"
    p.write_text(json.dumps({"machine": machine(), **payload}, indent=2, default=float) + "\n")
    return p
