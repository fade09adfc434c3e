"""Which of a simulated run's extraction misses within the lens's reach no lens lets the extraction read.

    python benchmarks/focus_read_render.py RUN_DIR [--frames 27-43] [--json FILE]

The report judges reach by the one circle of confusion (where the focus estimator flips for the reference
texture); the extraction reads each region by where the estimator flips on that region's texture, at the
scale and with the blur the simulator draws. Per frame the report counts as an extraction miss within reach
(report.json `focus_misses`, kinds 'controller' and 'extraction'; or `--frames`), the frame's scene is drawn
again at the flight's pose (the vehicle states round the frame's stamp, interpolated; the truth's focal
length and simulation time) and, with its depths, blurred as the simulator blurs (sim/dof.py) at any lens:
- the verdict, by brute force: every setting of a grid over the lens's f-numbers (dense near the widest) and
  its whole focus range, then a finer grid round the best one, drawn and read with the extraction's rule
  (half the region's pixels read in focus on the detector's focus map; the regions of shared.focus_regions
  from the subject's drawn mask); 'read' where none reads every judged label as asked, naming the region
  nearest its label at the best setting (a window narrower than the finer grid could be missed);
- each judged region's flip, for the reason: the lens wide open, the focus put so that the region's median
  is b circles soft (in front of the focus for the foreground and the subject, behind it for the
  background), b bisected to where the extraction's reading of it flips; and the verdict those flips give
  through focus_reach's search (cinetransfer.report.focus_read), listed where it differs from the brute
  force's (`flips_disagree`): a region's flip measured alone depends on how soft its neighbours are.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import write_result  # noqa: E402

from cinetransfer.report import focus_reach as FR  # noqa: E402
from cinetransfer.report import focus_read as FD  # noqa: E402
from cinetransfer.report import reach_frames as RF  # noqa: E402
from cinetransfer.report.build import read_vehicle_states  # noqa: E402
from cinetransfer.report.truthfile import read_truths  # noqa: E402
from cinetransfer.runlog import RunReader  # noqa: E402
from cinetransfer.services.autopilot_bridge.sim.dof import apply_dof, sigma_px  # noqa: E402
from cinetransfer.services.autopilot_bridge.sim.gl_canvas import SURFACE_SUBJECT  # noqa: E402
from cinetransfer.services.autopilot_bridge.sim.renderer import View  # noqa: E402
from cinetransfer.services.autopilot_bridge.sim.scene import load_scene  # noqa: E402
from cinetransfer.services.detector.config import DetectorConfig  # noqa: E402
from cinetransfer.services.detector.focus import FocusEstimator  # noqa: E402
from cinetransfer.shared.focus_regions import feet_row, foreground_present, region_masks  # noqa: E402
from cinetransfer.shared.instructions import load_style_file  # noqa: E402

REGIONS = ("foreground", "subject", "background")
MISSED = ("controller", "extraction")
FLIP_RANGE = (0.3, 3.0)
FLIP_STEPS = 8
#: the brute force's grid: f-numbers from the widest (dense where the soft regions are softest), and
#: GRID_FOCUS focus distances over the lens's range (log-spaced)
GRID_F_NUMBERS = (1.0, 1.03, 1.06, 1.1, 1.15, 1.2, 1.3, 1.5, 2.0, 2.8, 4.0, 5.6)
GRID_FOCUS = 48
#: the finer grid round the best setting (f-numbers within 15 %, focus within 20 %)
FINE = (6, 16)


class Frame:
    """One frame drawn sharp at the flight's pose, read with the extraction's rule at any lens."""

    def __init__(self, renderer: Any, est: FocusEstimator, view: View, t_s: float) -> None:
        self.view, self.est = view, est
        self.bgr, self.depth, surface, _ = renderer.draw(view, t_s)
        self.subject = surface == SURFACE_SUBJECT
        self.foreground = foreground_present(feet_row(self.subject), self.subject.shape[0])

    def shares(self, f_number: float, focus_m: float) -> np.ndarray:
        """Per region, the share of its pixels the extraction reads in focus with the lens at this setting."""
        v = self.view
        img = apply_dof(self.bgr, sigma_px(self.depth, v.focal_mm, f_number, focus_m, v.sensor.width_mm, v.width))
        prob = self.est.estimate(img, self.subject).prob
        mh, mw = prob.shape
        small = cv2.resize(self.subject.astype(np.float32), (mw, mh), interpolation=cv2.INTER_AREA) >= 0.5
        regions = region_masks(small, feet_row(small), self.foreground)
        return np.array([np.count_nonzero((prob >= 0.5) & r) / r.sum() if r.any() else np.nan for r in regions])


def region_flip(fr: Frame, lens: Any, r: int, x: float) -> float:
    """The blur [circles] of region r's median at which the extraction's reading of it flips (module docstring)."""
    n = lens.f_number[0]
    behind = r == 2  # the background behind the focus, the foreground and the subject in front of it

    def sharp(b: float) -> bool:
        s = float(np.clip(FD.focus_for_blur(lens.focal_mm, n, x, b, behind, lens.coc_mm), *lens.focus_m))
        return bool(fr.shares(n, s)[r] >= 0.5)

    lo, hi = FLIP_RANGE
    if not sharp(lo):
        return lo
    if sharp(hi):
        return hi
    for _ in range(FLIP_STEPS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if sharp(mid) else (lo, mid)
    return 0.5 * (lo + hi)


def brute_force(fr: Frame, lens: Any, asked: np.ndarray, judged: np.ndarray) -> dict[str, Any]:
    """Every grid setting drawn and read, then a finer grid round the best one: how many read the judged labels
    as asked, and the best setting (its margin: the least distance of a judged region's share from flipping
    the wrong way; the region nearest flipping wrong)."""
    judged_r = np.flatnonzero(judged)
    found: dict[tuple[float, float], np.ndarray] = {}

    def read(n: float, s: float) -> None:
        found[(round(n, 4), round(s, 3))] = fr.shares(n, s)

    for n in GRID_F_NUMBERS:
        for s in np.geomspace(*lens.focus_m, GRID_FOCUS):
            read(n, float(s))
    margin = {k: min((sh[r] - 0.5) if asked[r] else (0.5 - sh[r]) for r in judged_r) for k, sh in found.items()}
    n0, s0 = max(margin, key=margin.get)
    for n in np.geomspace(max(lens.f_number[0], n0 / 1.15), min(lens.f_number[1], n0 * 1.15), FINE[0]):
        for s in np.geomspace(max(lens.focus_m[0], s0 / 1.2), min(lens.focus_m[1], s0 * 1.2), FINE[1]):
            read(float(n), float(s))
    good = sum(all((sh[r] >= 0.5) == bool(asked[r]) for r in judged_r) for sh in found.values())
    # per prefix of the order labels are granted (focus_reach.PRIORITY), the settings that read it as asked
    order = [r for r in FR.PRIORITY if judged[r]]
    prefix = [sum(all((sh[r] >= 0.5) == bool(asked[r]) for r in order[:k + 1]) for sh in found.values())
              for k in range(len(order))]
    margin = {k: min((sh[r] - 0.5) if asked[r] else (0.5 - sh[r]) for r in judged_r) for k, sh in found.items()}
    (n, s), sh = max(margin, key=margin.get), found[max(margin, key=margin.get)]
    worst = min(judged_r, key=lambda r: (sh[r] - 0.5) if asked[r] else (0.5 - sh[r]))
    return {"readable_settings": int(good), "settings": len(found),
            "readable_prefix": {REGIONS[r]: int(c) for r, c in zip(order, prefix)},
            "best": {"margin": round(float(margin[(n, s)]), 3), "f_number": n, "focus_m": s, "worst": REGIONS[worst],
                     "shares": [None if not np.isfinite(v) else round(float(v), 3) for v in sh]}}


def _view_at(states: list, stamp_ns: int, focal_mm: float, renderer: Any) -> View:
    """The camera at a frame's stamp: the vehicle states either side, interpolated."""
    t = np.array([s.stamp_ns for s in states], np.int64)
    k = int(np.clip(np.searchsorted(t, stamp_ns), 1, len(t) - 1))
    a, b = states[k - 1], states[k]
    w = float(np.clip((stamp_ns - a.stamp_ns) / max(b.stamp_ns - a.stamp_ns, 1), 0.0, 1.0))
    pos = (1 - w) * np.asarray(a.position_m) + w * np.asarray(b.position_m)
    ypr = np.asarray(a.camera_ypr_rad) + w * (np.angle(np.exp(1j * (np.asarray(b.camera_ypr_rad)
                                                                   - np.asarray(a.camera_ypr_rad)))))
    return View(position_m=pos, ypr_rad=ypr, focal_mm=focal_mm, focus_m=float(b.lens.focus_distance_m),
                f_number=float(b.lens.f_number), width=renderer.width, height=renderer.height, sensor=renderer.sensor)


def judge_run(run: Path, frames: list[int] | None = None) -> dict[str, Any]:
    from cinetransfer.services.autopilot_bridge.sim.renderer3d import WorldRenderer

    rep = json.loads((run / "report.json").read_text())
    meta = json.loads((run / "meta.json").read_text())
    pf = rep["per_frame"]
    kinds = pf["focus_miss_kind"]["extraction"]
    n_frames = len(pf["t_s"])
    if frames is None:
        frames = [i for i in range(n_frames) if any(kinds[r][i] in MISSED for r in REGIONS)]
    truths = read_truths(run / "truth.msgpack")
    by_frame = RF.truths_by_frame(truths, n_frames, min(int(t.frame_index) for t in truths))
    states = [s for s in read_vehicle_states(RunReader(run / "run.mcap")) if s.stamp_ns >= meta["epoch_ns"]]
    asked_rows = np.asarray(load_style_file(run / "style.json").instructions.focus_in, bool)
    cap = cv2.VideoCapture(str(run / "output.mp4"))
    size = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    cap.release()
    renderer = WorldRenderer(load_scene(meta["scene"], meta.get("subject")), *size)
    est = FocusEstimator(DetectorConfig())
    rows = []
    for i in frames:
        t = by_frame[i]
        lens = RF.lens_of(t) if t is not None else None
        if lens is None:
            continue
        cpu = time.process_time()
        inv = np.asarray(t.region_inverse_depth, float)
        asked = asked_rows[int(pf["source_row"][i])]
        reach = [pf["focus_unreachable"][r][i] for r in REGIONS]
        judged = np.asarray(t.region_present, bool) & np.array([x is None for x in reach]) & np.isfinite(inv).all(1)
        fr = Frame(renderer, est, _view_at(states, int(t.stamp_ns), float(t.focal_length_mm), renderer),
                   (int(t.stamp_ns) - meta["epoch_ns"]) * 1e-9)
        flips = np.ones(3)
        for r in np.flatnonzero(judged):
            flips[r] = region_flip(fr, lens, int(r), float(np.median(inv[r])))
        by_flips = FD.unreadable_labels(lens, asked, judged, inv, flips)
        rows.append({"frame": i, "missed": [r for r in REGIONS if kinds[r][i] in MISSED],
                     "asked": [bool(a) for a in asked], "judged": [bool(j) for j in judged],
                     "flips": {REGIONS[r]: round(float(flips[r]), 3) for r in np.flatnonzero(judged)},
                     "by_flips": {REGIONS[u.region]: u.reason for u in by_flips},
                     "brute_force": brute_force(fr, lens, asked, judged), "cpu_s": round(time.process_time() - cpu, 1)})
        print(json.dumps(rows[-1]), flush=True)
    return summarise(rows)


def verdict(row: dict[str, Any]) -> dict[str, str]:
    """The frame's region no drawn setting lets the extraction read as asked together with the ones granted
    before it (kind 'read'; the reach's order: subject, background, foreground): none where some setting reads
    every judged label as asked."""
    b = row["brute_force"]
    if b["readable_settings"]:
        return {}
    best, asked = b["best"], row["asked"]
    order = [r for r in FR.PRIORITY if row["judged"][r]]
    r = next((REGIONS.index(k) for k, c in b["readable_prefix"].items() if c == 0), order[-1])
    labels = ", ".join(f"{REGIONS[k]} {'sharp' if asked[k] else 'soft'}" for k in order[:order.index(r) + 1])
    flips = ", ".join(f"{k} {v:.2f}" for k, v in row["flips"].items())
    shares = ", ".join(f"{REGIONS[k]} {best['shares'][k]:.0%}" for k in order)
    return {REGIONS[r]: (f"{labels}: no lens setting of {b['settings']} drawn at the flight's pose lets the "
                         f"extraction read them together; the closest, f/{best['f_number']:.3g} focused "
                         f"{best['focus_m']:.3g} m, reads {shares} sharp (the estimator flips, one region at a "
                         f"time, at {flips} circles)")}


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    for x in rows:
        x["unreadable"] = verdict(x)
        x["flips_disagree"] = bool(x["by_flips"]) != bool(x["unreadable"])
    return {"frames": rows, "unreadable": {r: [x["frame"] for x in rows if r in x["unreadable"]] for r in REGIONS},
            "readable": [x["frame"] for x in rows if not x["unreadable"]],
            "flips_disagree": [x["frame"] for x in rows if x["flips_disagree"]]}


def _frames(text: str | None) -> list[int] | None:
    if not text:
        return None
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out.extend(range(int(a), int(b or a) + 1))
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--frames", help="e.g. 27-43 (default: the extraction's misses within reach)")
    ap.add_argument("--json", type=Path, help="results file (benchmarks/results/...)")
    args = ap.parse_args(argv)
    res = judge_run(args.run, _frames(args.frames))
    print(f"unreadable: {res['unreadable']}; readable: {res['readable']}; the flips' verdict differs in "
          f"{res['flips_disagree']}")
    if args.json:
        write_result(args.json, {"run": str(args.run), **res})
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
