"""Camera-motion extraction against sources with known truth (NAME.mp4 + NAME.truth.json pairs:
benchmarks/camera_motion_sources.py makes them from static clips; a render with its camera poses
can write the same pair).

Each source goes through the real extraction (detector with people's masks, then the smoother's
per-shot smoothing and classes); its class is the class of the shot's median rates. Printed: the
class accuracy (goal >= 90 % of sources right) and per rate the relative error of the median
(goal within 20 % of the truth; rates whose truth is below the least move of a class are judged by
the class instead).

Also (`--clips [NAME ...]`): what the same extraction says of each bundled clip of ../shared/data
(or of those named), per shot, and the camera-motion stage's own cost per frame.

    .venv/bin/python benchmarks/eval_camera_motion.py [SOURCES] [--clips [NAME ...]]

SOURCES: a folder of pairs (default: made afresh from the static clips in a temporary folder).
Writes benchmarks/results/eval_camera_motion.json.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from cinetransfer.report.camera_motion import RATES, shot_motion, style_rates
from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.core import smooth_sequence
from cinetransfer.extract import extract_features
from cinetransfer.shared import camera_motion as cm
from cinetransfer.shared.instructions import shot_segments

try:
    from harness import stats, write_result
    from camera_motion_sources import DATA, make_all
except ImportError:  # imported as a package
    from benchmarks.harness import stats, write_result
    from benchmarks.camera_motion_sources import DATA, make_all

RATE_TOLERANCE = 0.20
CLASS_GOAL = 0.90


def _least_move(rate: str) -> float:
    """The smallest rate that counts as a move: below it the class, not the rate, is judged (a pan
    with a pitched camera turns it about its own roll axis a little too)."""
    return cm.ZOOM_MIN_PER_S if rate == "zoom_rate" else cm.ROTATION_MIN_DPS


def truth_row_classes(tr: dict) -> list[str]:
    """The class of each row of a source's truth (its per-frame rates and translation direction)."""
    def rate(name: str, k: int) -> float:
        v = tr[name][k]
        return math.nan if v is None else float(v)

    return [cm.classify(*(rate(n, k) for n in RATES), np.array(tr["translation_dir"][k], dtype=float))
            for k in range(len(tr["zoom_rate"]))]


def rows_agreeing(truth: list[str], got: list[str]) -> int:
    """How many rows after the first (whose motion crosses from no frame) read the truth's class."""
    return sum(a == b for a, b in zip(truth[1:], got[1:]))


def evaluate_source(video: Path, cfg: SmootherConfig) -> dict:
    """Extraction vs truth for one source."""
    tr = json.loads(video.with_suffix(".truth.json").read_text(encoding="utf-8"))
    t0 = time.monotonic()
    feats, source = extract_features(video, cfg)
    instr = smooth_sequence(feats, cfg, source=source, known_cuts=[]).instructions
    got = shot_motion(style_rates(instr), 0, len(instr.camera_motion_class))
    errors = {}
    for n in RATES:
        want = float(np.nanmedian(np.array(tr[n], dtype=float)))
        have = got.get(n)
        if abs(want) >= _least_move(n) and have is not None:
            errors[n] = abs(have - want) / abs(want)
    return {"name": video.stem, "truth_class": tr["class"], "class": got["class"],
            "right": got["class"] == tr["class"], "rates": {n: got.get(n) for n in RATES},
            "truth_rates": {n: float(np.nanmedian(np.array(tr[n], dtype=float))) for n in RATES},
            "rate_errors": errors, "rows": len(instr.camera_motion_class) - 1,
            "rows_agree": rows_agreeing(truth_row_classes(tr), list(instr.camera_motion_class)),
            "seconds": round(time.monotonic() - t0, 1)}


def clip_classes(clip: Path, cfg: SmootherConfig) -> dict:
    """What the extraction says of a real clip: per shot its class and rates, and how often each
    per-frame class occurs."""
    feats, source = extract_features(clip, cfg)
    instr = smooth_sequence(feats, cfg, source=source).instructions
    rates = style_rates(instr)
    return {"shots": [{"rows": [a, b], **shot_motion(rates, a, b)} for a, b in shot_segments(instr)],
            "frame_classes": dict(Counter(instr.camera_motion_class).most_common())}


def stage_cost_ms(clip: Path, frames: int = 60) -> dict:
    """CPU time [ms] of the camera-motion stage per frame of a clip (no people: every corner kept)."""
    from cinetransfer.services.detector.camera_motion import CameraMotionTracker
    from cinetransfer.shared.frame_sources import iter_frames

    tr, cpu = CameraMotionTracker(), []
    for f in iter_frames(str(clip), stop=frames):
        t = time.process_time()
        tr.update(f.image, [], source="cost", frame_index=f.index)
        cpu.append(1000.0 * (time.process_time() - t))
    return stats(cpu[1:], digits=2)


def evaluate_sources(folder: Path, cfg: SmootherConfig) -> tuple[list[dict], dict]:
    videos = sorted(p for p in folder.glob("*.mp4") if p.with_suffix(".truth.json").is_file())
    results = []
    for v in videos:
        r = evaluate_source(v, cfg)
        results.append(r)
        errs = " ".join(f"{n.split('_')[0]} {e:.0%}" for n, e in r["rate_errors"].items())
        print(f"{r['name']:28s} truth {r['truth_class']:12s} got {r['class']:14s} "
              f"{'ok ' if r['right'] else 'BAD'} rows {r['rows_agree']}/{r['rows']} {errs}", flush=True)
    right = sum(r["right"] for r in results) / len(results) if results else math.nan
    errs = [e for r in results for e in r["rate_errors"].values()]
    within = sum(e <= RATE_TOLERANCE for e in errs) / len(errs) if errs else math.nan
    summary = {"sources": len(results), "class_accuracy": round(right, 4), "class_goal": CLASS_GOAL,
               "rates_within_tolerance": round(within, 4), "rate_tolerance": RATE_TOLERANCE,
               "rate_relative_error": stats(errs, digits=4),
               "rows_agree": sum(r["rows_agree"] for r in results), "rows": sum(r["rows"] for r in results)}
    return results, summary


def _bundled_clips(names: list[str]) -> list[Path]:
    """The bundled clips of ../shared/data, all or those named (a name not found is an error)."""
    clips = sorted(p for p in DATA.iterdir() if p.suffix in (".mp4", ".avi"))
    missing = sorted(set(names) - {p.name for p in clips})
    if missing:
        raise SystemExit(f"eval_camera_motion: no bundled clip {missing}; known: {[p.name for p in clips]}")
    return [p for p in clips if not names or p.name in names]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sources", type=Path, nargs="?", default=None,
                    help="folder of NAME.mp4 + NAME.truth.json pairs (default: made from the static clips)")
    ap.add_argument("--clips", nargs="*", default=None, metavar="NAME",
                    help="also classify the bundled clips of ../shared/data (all, or those named)")
    ap.add_argument("--result", default="eval_camera_motion", help="result name or path (default %(default)s)")
    args = ap.parse_args(argv)
    cfg = SmootherConfig()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.sources
        if folder is None:
            folder = Path(tmp)
            make_all(folder)
        if not any(folder.glob("*.truth.json")):
            print(f"eval_camera_motion: no NAME.mp4 + NAME.truth.json pairs in {folder}", file=sys.stderr)
            return 2
        results, summary = evaluate_sources(folder, cfg)
    print(f"\nclass right in {summary['class_accuracy']:.0%} of {summary['sources']} sources (goal >= "
          f"{CLASS_GOAL:.0%}); rates within {RATE_TOLERANCE:.0%}: {summary['rates_within_tolerance']:.0%} "
          f"(relative error median {summary['rate_relative_error']['median']:.1%}, max "
          f"{summary['rate_relative_error']['max']:.1%}); rows reading the truth's class: "
          f"{summary['rows_agree']} of {summary['rows']}")
    out = {"summary": summary, "stage_cpu_ms_1280x720": stage_cost_ms(DATA / "sam2_juggle_1280x720.mp4"),
           "per_source": {r["name"]: {k: r[k] for k in ("truth_class", "class", "rates", "rate_errors", "rows",
                                                         "rows_agree")}
                          for r in results}}
    if args.clips is not None:
        out["clips"] = {}
        for clip in _bundled_clips(args.clips):
            out["clips"][clip.name] = clip_classes(clip, cfg)
            print(clip.name, [s["class"] for s in out["clips"][clip.name]["shots"]], flush=True)
    print(f"wrote {write_result(args.result, out)}")
    return 0 if summary["class_accuracy"] >= CLASS_GOAL and summary["rates_within_tolerance"] >= 0.9 else 1


if __name__ == "__main__":
    sys.exit(main())
