"""How many frames of a recorded run no lens moving at the vehicle's lens rates could give the source's
focus labels, next to what the flight gave (the truth's region_in_focus), and what the report's verdict
per frame (kind 'rate') excuses.

    python benchmarks/focus_rate_reach.py RUN_DIR [RUN_DIR ...] [--vehicle cinempc] [--grid] [--json FILE]

RUN_DIR: a transfer's output directory (report.json, truth.msgpack, style.json). Prints, per run, over the
frames the report judges (present, within each frame's own reach): the proven lower bound on the frames any
lens misses (focus_reach.rate_least_misses: cells a lens may be in, moving one cell further than the rates
allow), for the subject and background together and for every region; with --grid, on runs where the rates
bind, also the grid count rate_min_misses (an upper bound on the fewest, ~20 CPU s a run); the windows round
the label switches with the flight's misses against the bound; and the truth's focus agreement over the
reachable frames without and with the rates' verdict.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import write_result  # noqa: E402

from cinetransfer.report import focus_reach as FR  # noqa: E402
from cinetransfer.report import reach_frames as RF  # noqa: E402
from cinetransfer.report.truthfile import read_truths  # noqa: E402
from cinetransfer.shared.vehicle import load_vehicle  # noqa: E402


def _agreement(got: np.ndarray, asked: np.ndarray, judged: np.ndarray) -> dict:
    return {name: round(float((got[judged[:, r], r] == asked[judged[:, r], r]).mean()), 3) if judged[:, r].any()
            else None for r, name in enumerate(FR.REGIONS)}


def judge(run: Path, rates: FR.LensRates, grid: bool) -> dict:
    rep = json.loads((run / "report.json").read_text())
    style = json.loads((run / "style.json").read_text())["instructions"]
    rows = np.asarray(rep["per_frame"]["source_row"], int)
    t_s = np.asarray(rep["per_frame"]["t_s"], float)
    asked = np.asarray(style["focus_in"], bool)[rows]
    truths = read_truths(run / "truth.msgpack")
    by_frame = RF.truths_by_frame(truths, len(rows), min(int(t.frame_index) for t in truths))
    present = np.array([t.region_present if t is not None else np.zeros(3, bool) for t in by_frame], bool)
    got = np.array([t.region_in_focus if t is not None else np.zeros(3, bool) for t in by_frame], bool)
    cpu = time.process_time()
    per_frame = RF.reach(asked, present, by_frame)
    cpu_frame = time.process_time() - cpu
    judged = present & ~per_frame.unreachable
    cpu = time.process_time()
    with_rates = RF.reach(asked, present, by_frame, rates=rates)
    cpu_rates = time.process_time() - cpu - cpu_frame
    out = {"frames": len(rows), "switches": FR.label_switches(asked),
           "rate_windows": RF.window_rows(with_rates, t_s),
           "excused": {name: int((with_rates.unreachable & ~per_frame.unreachable)[:, r].sum())
                       for r, name in enumerate(FR.REGIONS)},
           "flown_misses": {name: int((judged[:, r] & (got[:, r] != asked[:, r])).sum())
                            for r, name in enumerate(FR.REGIONS)},
           "truth_agreement_reachable": {"per_frame_reach": _agreement(got, asked, judged),
                                         "with_rates": _agreement(got, asked, present & ~with_rates.unreachable)},
           "cpu_s": {"per_frame_reach": round(cpu_frame, 2), "rates_verdict": round(cpu_rates, 2)}}
    least = {}
    for name, regions in (("subject_and_background", (1, 2)), ("all", (0, 1, 2)),
                          *((n, (r,)) for r, n in enumerate(FR.REGIONS))):
        only = judged & np.isin(np.arange(3), regions)[None, :]
        least[name] = FR.rate_least_misses(*RF.rate_frames(asked, only, by_frame, rates))
    out["least_misses_lower_bound"] = least
    if grid and out["rate_windows"]:  # only where the rates bind: ~20 CPU s a run
        lenses = [RF.lens_of(t) if t is not None else None for t in by_frame]
        inv = np.array([np.asarray(t.region_inverse_depth, float) for t in by_frame])
        dt = float(np.median(np.diff(t_s)))
        out["least_misses_grid_upper_bound"] = {"subject_and_background": FR.rate_min_misses(
            lenses, asked, judged, inv, rates, dt, (1, 2))}
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--vehicle", default="cinempc")
    p.add_argument("--grid", action="store_true", help="also the grid's upper bound where the rates bind (slow)")
    p.add_argument("--json", type=Path, help="also write the results here")
    a = p.parse_args()
    lens = load_vehicle(a.vehicle).lens
    rates = FR.LensRates(lens.focus_rate_mps, lens.f_number_rate_ps)
    results = {}
    for run in a.runs:
        results[str(run)] = judge(run, rates, a.grid)
        print(run, json.dumps(results[str(run)]))
    if a.json:
        write_result(a.json, {"vehicle": a.vehicle, "rates": [rates.focus_mps, rates.f_number_ps],
                              "bound_cells": list(FR.RATE_BOUND_CELLS),
                              "grid_substeps": list(FR.RATE_SUBSTEPS), "results": results})


if __name__ == "__main__":
    main()
