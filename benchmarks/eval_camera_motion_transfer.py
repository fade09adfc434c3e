"""The transfer of each rendered camera move: does the output camera move as the source's did?

Each source of benchmarks/camera_motion_3d_sources.py (a move rendered in the 3-D world with the
walker crossing the yard) is transferred with the real command (`cinetransfer transfer SOURCE
--scene SCENE`, every node, the simulator, the report) and its report.json is read: per shot the
source's and the output's class, the share of rows whose output class matches the source's
(`camera_motion.shots[].agreement`, goal >= 0.8, pooled over the shots by rows) and the framing
goals (the joint-error goals by extraction and by truth, which must stay met).

    .venv/bin/python benchmarks/camera_motion_3d_sources.py -o /tmp/cm3d
    .venv/bin/python benchmarks/eval_camera_motion_transfer.py /tmp/cm3d -o /tmp/cm3d_runs [--only pan_left]

A transfer takes minutes on a loaded machine: `--only` picks moves by name; a run folder that
already holds a report.json is read again rather than flown again (`--again` flies it anew).
`--preroll S` is passed to the transfer. The sources are filmed from 1 s into the courtyard's
walker loop (11.67 s long); with the transfer's default 5 s pre-roll the output's take films him
elsewhere on the loop (walking away, then turning), a subject motion no camera move of the source
can frame. `--preroll 12.667` starts the take at the same point of his loop, so the output's
subject moves as the source's did and only the camera is under test, but he walks a whole loop
(four turns) in that pre-roll and the drone starts the take wherever chasing him left it.
`--mark --preroll S` lets him wait on his mark for the S s pre-roll instead, as an actor does
(camera_motion_mark.py): the drone settles on the first frame's framing round a subject who stands.
`--crop-subject --preroll S` is the same for the crop sources (camera_motion_sources.py, cut from
static footage): the source's style is extracted first (`cinetransfer extract`), and the scene's
subject becomes the walker moving in the world as the source's person moved in the static footage
(camera_motion_crop_subject.py), after waiting on his mark for the pre-roll.
benchmarks/camera_motion_flight.py flies the same styles in-process in seconds (no rendering).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

try:
    from camera_motion_crop_subject import write_crop_scene
    from camera_motion_mark import write_mark_scene
    from harness import write_result
except ImportError:  # imported as a package
    from benchmarks.camera_motion_crop_subject import write_crop_scene
    from benchmarks.camera_motion_mark import write_mark_scene
    from benchmarks.harness import write_result

AGREEMENT_GOAL = 0.8
SCENE = "courtyard"
#: the report's goals that say whether the framing was kept
FRAMING_GOALS = ("extraction_joint_error", "truth_joint_error")


def pooled_agreement(shots: list[dict[str, Any]]) -> float | None:
    """Share of rows whose output class matches the source's over every shot (weighted by rows)."""
    num = den = 0.0
    for s in shots:
        a = s.get("agreement")
        if a is None:
            continue
        rows = int(s["rows"][1]) - int(s["rows"][0])
        num, den = num + a * rows, den + rows
    return round(num / den, 4) if den else None


def judge_report(report: dict[str, Any]) -> dict[str, Any]:
    """What one transfer's report.json says of its camera motion and framing."""
    cm = report.get("camera_motion") or {}
    shots = cm.get("shots") or []
    goals = (report.get("headline") or {}).get("goals") or {}
    framing = {g: goals.get(g, "missing") for g in FRAMING_GOALS}
    agreement = pooled_agreement(shots)
    return {"source_class": [(s.get("source") or {}).get("class") for s in shots],
            "output_class": [(s.get("output") or {}).get("class") for s in shots],
            "truth_class": [(s.get("truth") or {}).get("class") for s in shots],
            "agreement": agreement, "goals_met": (report.get("headline") or {}).get("goals_met"),
            "framing": framing,
            "met": agreement is not None and agreement >= AGREEMENT_GOAL and all(v == "met" for v in framing.values())}


def transfer(source: Path, run: Path, scene: str, again: bool, preroll_s: float | None = None) -> dict[str, Any]:
    """Fly one source (unless its run already has a report) and judge its report."""
    report = run / "report.json"
    if again or not report.is_file():
        cmd = [sys.executable, "-m", "cinetransfer", "transfer", str(source), "--scene", scene, "-o", str(run)]
        cmd += [] if preroll_s is None else ["--preroll", f"{preroll_s:g}"]
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0 or not report.is_file():
            tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
            return {"error": f"transfer exited {done.returncode}: {tail[0]}", "met": False}
    return judge_report(json.loads(report.read_text(encoding="utf-8")))


def crop_scene(source: Path, run: Path, scene: str, wait_s: float) -> Path:
    """The scene of one crop source: its style extracted (once per run folder), then the walker set
    moving as its person did."""
    style = run / "source_style.json"
    if not style.is_file():
        run.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "cinetransfer", "extract", str(source), "-o", str(style), "--quiet"]
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0 or not style.is_file():
            raise RuntimeError(f"extract exited {done.returncode}: {(done.stderr or done.stdout).strip()[-200:]}")
    truth = json.loads(source.with_suffix(".truth.json").read_text(encoding="utf-8"))
    return write_crop_scene(run / "scene.yaml", truth, style, wait_s=wait_s, scene=scene)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sources", type=Path, help="folder of the rendered NAME.mp4 + NAME.truth.json pairs")
    ap.add_argument("-o", "--runs", type=Path, required=True, help="folder for one transfer run per source")
    ap.add_argument("--scene", default=SCENE, help="scene the moves are flown in (default %(default)s)")
    ap.add_argument("--only", nargs="*", default=None, help="names (or parts of names) of the moves to fly")
    ap.add_argument("--again", action="store_true", help="fly runs that already have a report again")
    ap.add_argument("--preroll", type=float, default=None, metavar="S",
                    help="the transfer's pre-roll [s] (default: the transfer's own)")
    ap.add_argument("--mark", action="store_true",
                    help="the walker waits on his mark for the pre-roll (camera_motion_mark.py; needs --preroll)")
    ap.add_argument("--crop-subject", action="store_true",
                    help="crop sources: the subject moves as the source's person did (camera_motion_crop_subject.py; "
                         "needs --preroll)")
    ap.add_argument("--result", default="eval_camera_motion_transfer", help="result name or path")
    args = ap.parse_args(argv)
    if (args.mark or args.crop_subject) and args.preroll is None:
        opt = "--mark" if args.mark else "--crop-subject"
        print(f"eval_camera_motion_transfer: {opt} needs --preroll (how long the walker waits)", file=sys.stderr)
        return 2
    if args.mark and args.crop_subject:
        print("eval_camera_motion_transfer: --mark is for the rendered moves, --crop-subject for the crops",
              file=sys.stderr)
        return 2
    videos = sorted(p for p in args.sources.glob("*.mp4") if p.with_suffix(".truth.json").is_file())
    if args.only:
        videos = [v for v in videos if any(o in v.stem for o in args.only)]
    if not videos:
        print(f"eval_camera_motion_transfer: no rendered sources to fly in {args.sources}", file=sys.stderr)
        return 2
    results = {}
    for v in videos:
        scene = args.scene
        if args.mark:
            scene = str(write_mark_scene(args.runs / v.stem / "scene.yaml", wait_s=args.preroll, scene=args.scene))
        if args.crop_subject:  # a run read again keeps the scene it was flown in
            flown = not args.again and (args.runs / v.stem / "report.json").is_file()
            scene = str(args.runs / v.stem / "scene.yaml") if flown else str(
                crop_scene(v, args.runs / v.stem, args.scene, args.preroll))
        r = transfer(v, args.runs / v.stem, scene, args.again, args.preroll)
        results[v.stem] = r
        if "error" in r:
            print(f"{v.stem:26s} {r['error']}", flush=True)
            continue
        agr = "-" if r["agreement"] is None else f"{r['agreement']:.2f}"
        print(f"{v.stem:26s} source {'/'.join(map(str, r['source_class'])):12s} output "
              f"{'/'.join(map(str, r['output_class'])):16s} agreement {agr:>5s} goals {r['goals_met']} framing "
              f"{'met' if all(x == 'met' for x in r['framing'].values()) else 'MISSED'} "
              f"{'ok' if r['met'] else 'NOT MET'}", flush=True)
    met = sum(r["met"] for r in results.values())
    print(f"\n{met} of {len(results)} moves flown with output class agreement >= {AGREEMENT_GOAL} and the framing "
          f"goals met")
    out = {"scene": args.scene, "mark": args.mark, "crop_subject": args.crop_subject, "preroll_s": args.preroll,
           "agreement_goal": AGREEMENT_GOAL,
           "moves_met": met, "per_source": results}
    print(f"wrote {write_result(args.result, out)}")
    return 0 if met == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
