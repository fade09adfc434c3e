"""Every focus choice filmed: sources with known focus choices transferred, focus agreement per region.

    python benchmarks/eval_focus_choices.py [--clip davis_parkour] [--choices ...] [--scene focus_hedge]
                                            [--work DIR] [--max-frames 0] [--json FILE]

Each choice of benchmarks/focus_sources.py (subject soft, background soft, rack focus halfway,
foreground sharp, all sharp) is made from the DAVIS clip and its masks, then flown with
`cinetransfer transfer SRC --scene focus_hedge` (real processes over Zenoh, simulation time). Printed
per source and region (foreground, subject, background):
- labels: the style extracted from the source against the known labels (how well the source was read);
- truth: the simulator's region focus (one definition of in focus: shared.camera.COC_MM) against
  the extracted style, as the report computes it;
- extraction: the style extracted from the output against the source's, as the report computes it;
- both again over the frames within the lens's reach (the report's `agreement_reachable`: the frames
  where no focus distance and f-number of the lens gives the source's label left out), and how many
  frames were left out, with the report's reason for each run of them (and for each run of frames
  within reach that the flight filmed otherwise by the truth, the settings that give the frame's labels
  together and how soft they leave the soft regions at best), and how many frames each
  reachable column counts: the extraction's counts frames where the truth sees no such region but
  both styles show one, judged for reach only where the truth kept that band's depths
  (docs/report.md; each frame's reason is in report.json's focus_misses).
With --read, each flown source's extraction misses within reach are drawn again at the flight's pose and
read at every lens setting of a grid (benchmarks/focus_read_render.py): the frames no setting lets the
extraction read as asked (kind 'read') are printed with their reason, and the extraction's agreement over
the reachable frames with those left out too (`extraction_readable`, beside the report's, which keeps them).
Goal: truth >= 0.90 and extraction >= 0.85 for every region present, over the reachable frames.
Writes benchmarks/results/eval_focus_choices.json.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import focus_read_render  # noqa: E402
import focus_sources  # noqa: E402
from harness import write_result  # noqa: E402

from cinetransfer.shared.instructions import load_style  # noqa: E402

HERE = Path(__file__).resolve().parent
REGIONS = ("foreground", "subject", "background")
TRUTH_MIN, EXTRACTION_MIN = 0.90, 0.85


def label_agreement(style_path: Path, labels_path: Path) -> dict[str, float | None]:
    """Per region: the fraction of frames where the source's extracted style says what the labels say."""
    ins = load_style(style_path)
    lab = np.asarray(json.loads(labels_path.read_text())["in_focus"], dtype=bool)
    got = np.asarray(ins.focus_in, dtype=bool)
    rows = np.arange(got.shape[0]) + int(ins.first_frame)
    ok = rows < lab.shape[0]
    return {r: float(np.mean(got[ok, i] == lab[rows[ok], i])) if ok.any() else None for i, r in enumerate(REGIONS)}


def transfer(src: Path, scene: str, out: Path, max_frames: int) -> dict:
    cmd = [sys.executable, "-m", "cinetransfer", "transfer", str(src), "--scene", scene, "-o", str(out),
           "--rig", f"ef_{src.stem}"[:30], *(["--max-frames", str(max_frames)] if max_frames else [])]
    t = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        return {"error": f"exit {r.returncode}: {r.stderr[-1500:]}"}
    rep = json.loads((out / "report.json").read_text())
    h = rep["headline"]
    return {"wall_s": round(time.monotonic() - t, 1), "goals_met": h["goals_met"],
            "truth": h["truth"].get("focus_agreement"), "extraction": h["extraction"].get("focus_agreement"),
            "truth_reachable": h["truth"].get("focus_agreement_reachable"),
            "extraction_reachable": h["extraction"].get("focus_agreement_reachable"),
            "unreachable_frames": (rep.get("focus_reach") or {}).get("unreachable_frames"),
            "unreachable_runs": (rep.get("focus_reach") or {}).get("runs"),
            "controller_runs": [r for r in (rep.get("focus_misses") or {}).get("runs") or []
                                if r["side"] == "truth" and r["kind"] == "controller"],
            "truth_reachable_frames": _reachable_frames(rep, "truth"),
            "extraction_reachable_frames": _reachable_frames(rep, "extraction")}


def _reachable_frames(rep: dict, side: str) -> dict[str, int | None]:
    """Per region, how many frames the `side`'s reachable agreement is taken over. The two columns count
    different frames: the extraction's are those where both styles show the region, less the frames the
    truth judges out of reach, so they include frames where the truth sees no such region (judged only where
    it kept the band's depths)."""
    focus = (rep.get(side) or {}).get("focus") or {}
    return {r: (focus.get(r) or {}).get("n_frames_reachable") for r in REGIONS}


def read_verdicts(out: Path) -> dict:
    """focus_read_render's verdicts on a run, and per region the extraction's agreement over the reachable frames
    with the frames it calls unreadable for that region left out too (only those the extraction missed, so that
    the agreeing frames stay counted)."""
    res = focus_read_render.judge_run(out)
    focus = (json.loads((out / "report.json").read_text()).get("extraction") or {}).get("focus") or {}
    res["extraction_readable"] = {}
    for r in REGIONS:
        agree, n = (focus.get(r) or {}).get("agreement_reachable"), (focus.get(r) or {}).get("n_frames_reachable")
        gone = sum(1 for x in res["frames"] if r in x["unreadable"] and r in x["missed"])
        res["extraction_readable"][r] = (round(agree * n) / (n - gone)) if agree is not None and n and n > gone \
            else None
    return res


def _fmt(v: float | None) -> str:
    return "  n/a" if v is None else f"{v:5.2f}"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clip", choices=sorted(focus_sources.CLIPS), default="davis_parkour")
    ap.add_argument("--choices", nargs="+", choices=focus_sources.CHOICES, default=list(focus_sources.CHOICES))
    ap.add_argument("--scene", default="focus_hedge")
    ap.add_argument("--work", type=Path, default=Path("runs/eval_focus_choices"))
    ap.add_argument("--max-frames", type=int, default=0)
    ap.add_argument("--read", action="store_true", help="judge the extraction's misses within reach by drawing "
                                                        "them at every lens setting (14-16 CPU s a frame)")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "eval_focus_choices.json", help="results file")
    args = ap.parse_args(argv)
    results = {}
    print(f"{'source':34s} {'region':10s} labels  truth  extraction  | reachable frames: truth  extraction  (out)"
          "  [frames: truth / extraction]")
    for choice in args.choices:
        src = focus_sources.make(args.clip, choice, args.work / "sources")
        out = args.work / src.stem
        res = transfer(src, args.scene, out, args.max_frames)
        if "error" not in res:
            res["labels"] = label_agreement(out / "style.json", src.with_suffix(".labels.json"))
            if args.read:
                res["read"] = read_verdicts(out)
        results[src.stem] = res
        if "error" in res:
            print(f"{src.stem:34s} failed: {res['error'].splitlines()[-1] if res['error'] else ''}")
            continue
        for r in REGIONS:
            t, e = res["truth"].get(r), res["extraction"].get(r)
            tr, er = (res.get("truth_reachable") or {}).get(r), (res.get("extraction_reachable") or {}).get(r)
            met = (tr is None or tr >= TRUTH_MIN) and (er is None or er >= EXTRACTION_MIN)
            out_n = (res.get("unreachable_frames") or {}).get(r, 0)
            nt = (res.get("truth_reachable_frames") or {}).get(r)
            ne = (res.get("extraction_reachable_frames") or {}).get(r)
            print(f"{src.stem:34s} {r:10s} {_fmt(res['labels'][r])}  {_fmt(t)}  {_fmt(e)}       |"
                  f"                  {_fmt(tr)}  {_fmt(er)}       ({out_n})  [{nt} / {ne}]"
                  f"  {'ok' if met else 'MISSED'}")
        for run in res.get("unreachable_runs") or []:
            last = f" ... {run['reason_last']}" if run.get("reason_last") else ""
            print(f"    out of reach: {run['region']} frames {run['first_frame']}-{run['last_frame']}: "
                  f"{run['reason']}{last}")
        for run in res.get("controller_runs") or []:
            print(f"    within reach, filmed otherwise: {run['region']} frames {run['first_frame']}-"
                  f"{run['last_frame']}: {run['reason']}")
        for r, frames in ((res.get("read") or {}).get("unreadable") or {}).items():
            if frames:
                print(f"    no lens lets the extraction read {r} as asked in frames {frames}; extraction over the "
                      f"reachable frames without them: {_fmt(res['read']['extraction_readable'][r])}")
    write_result(args.json, {"clip": args.clip, "scene": args.scene,
                             "goal": {"truth_min": TRUTH_MIN, "extraction_min": EXTRACTION_MIN}, "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
