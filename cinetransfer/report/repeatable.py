"""What two takes of the same command must share: report.json without when, where or how fast.

The same take twice (same clip, scene, subject, settings) films the same frames and measures the
same figures; only the facts below may differ, because they depend on the wall clock or on where
the run was written. The benchmark and the repeatability test compare takes through this.
"""
from __future__ import annotations

import json
from pathlib import Path

#: report.json keys that say when, where or how fast, not what was measured
VOLATILE = ("generated", "report_s", "meta", "inputs", "recording_file", "video")
#: the take's facts counted in wall time (a real-time run would have cut those solves short; how
#: long the planner was silent): machine load changes them, not the take
WALL_TIME = ("over_budget_solves", "planner_silence_s")


def report_figures(out: Path) -> dict:
    """OUTDIR/report.json without what says when, where or how fast (paths name OUTDIR)."""
    text = (Path(out) / "report.json").read_text().replace(str(out), "OUTDIR")
    return without_wall_time({k: v for k, v in json.loads(text).items() if k not in VOLATILE})


def without_wall_time(v):
    """`v` (nested dicts and lists) without the keys in WALL_TIME."""
    if isinstance(v, dict):
        return {k: without_wall_time(x) for k, x in v.items() if k not in WALL_TIME}
    if isinstance(v, list):
        return [without_wall_time(x) for x in v]
    return v
