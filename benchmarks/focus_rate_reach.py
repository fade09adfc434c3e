"""How many frames of a recorded run no lens moving at the vehicle's lens rates could give the source's
focus labels (focus_reach.rate_unreachable), next to what the flight gave (the truth's region_in_focus).

    python benchmarks/focus_rate_reach.py RUN_DIR [RUN_DIR ...] [--vehicle cinempc] [--json FILE]

RUN_DIR: a transfer's output directory (report.json, truth.msgpack, style.json). Prints, per run, the
fewest frames any lens moving at the rates misses (each region alone, and the subject and background
together) over the frames the report judges (present, within each frame's own reach), the truth
agreement that leaves at best, and how many the flight missed.
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


def judge(run: Path, rates: FR.LensRates) -> dict:
    rep = json.loads((run / "report.json").read_text())
    style = json.loads((run / "style.json").read_text())["instructions"]
    rows = np.asarray(rep["per_frame"]["source_row"], int)
    t_s = np.asarray(rep["per_frame"]["t_s"], float)
    asked = np.asarray(style["focus_in"], bool)[rows]
    truths = read_truths(run / "truth.msgpack")
    by_frame = RF.truths_by_frame(truths, len(rows), min(int(t.frame_index) for t in truths))
    present = np.array([t.region_present if t is not None else np.zeros(3, bool) for t in by_frame], bool)
    per_frame = RF.reach(asked, present, by_frame).unreachable
    lenses = [RF._lens_of(t) if t is not None else None for t in by_frame]
    inv = np.array([np.asarray(t.region_inverse_depth, float) for t in by_frame])
    judged = present & ~per_frame
    dt = float(np.median(np.diff(t_s)))
    got = np.array([t.region_in_focus if t is not None else np.zeros(3, bool) for t in by_frame], bool)
    switches = np.flatnonzero((asked[1:] != asked[:-1]).any(axis=1)) + 1
    cpu = time.process_time()
    least = {"subject_and_background": FR.rate_min_misses(lenses, asked, judged, inv, rates, dt, (1, 2))}
    out = {"frames": len(rows), "switches": switches.tolist(), "least_misses": least}
    for r, name in enumerate(FR.REGIONS):
        least[name] = FR.rate_min_misses(lenses, asked, judged, inv, rates, dt, (r,))
        agree = (got[:, r] == asked[:, r])[judged[:, r]]
        out[name] = {"judged": int(judged[:, r].sum()), "flown_misses": int((~agree).sum()),
                     "best_agreement": round(1 - least[name] / max(1, int(judged[:, r].sum())), 3)}
    both = judged[:, 1] & judged[:, 2]
    wrong = (got[:, 1] != asked[:, 1]) | (got[:, 2] != asked[:, 2])
    out["flown_misses_subject_or_background"] = int((both & wrong).sum())
    out["cpu_s"] = round(time.process_time() - cpu, 2)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--vehicle", default="cinempc")
    p.add_argument("--json", type=Path, help="also write the results here")
    a = p.parse_args()
    lens = load_vehicle(a.vehicle).lens
    rates = FR.LensRates(lens.focus_rate_mps, lens.f_number_rate_ps)
    results = {}
    for run in a.runs:
        results[str(run)] = judge(run, rates)
        print(run, json.dumps(results[str(run)]))
    if a.json:
        write_result(a.json, {"vehicle": a.vehicle, "rates": [rates.focus_mps, rates.f_number_ps],
                              "grid_substeps": list(FR.RATE_SUBSTEPS), "results": results})


if __name__ == "__main__":
    main()
