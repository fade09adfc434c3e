"""`cinetransfer report RUN_DIR`: rebuild the fidelity report from the files of a run folder.

A run folder (written by `cinetransfer transfer`) holds:

    style.json          the source's style (required)
    output_style.json   the same extraction run on the recorded video (optional)
    output.mp4          the recorded video, H.264 (optional: frames figure and side-by-side video)
    run.mcap            the recording (optional: summarised in the report; a damaged or foreign
                        file is an error, exit 1)
    truth.msgpack       the simulator's GroundTruth per recorded frame (optional; see truthfile.py)
    meta.json           run metadata, printed in the report; its "source" names the source video

and receives report.html, report.json, fig_*.png and report_video.mp4 (or into -o OUTDIR).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

STYLE = "style.json"
OUTPUT_STYLE = "output_style.json"
OUTPUT_VIDEO = "output.mp4"
RECORDING = "run.mcap"
TRUTH = "truth.msgpack"
META = "meta.json"


def _find_source(run_dir: Path, meta: dict, given: str | None) -> Path | None:
    cands = [given] if given else [meta.get("source_video"), meta.get("source")]
    for c in cands:
        if not c:
            continue
        for p in (Path(str(c)), run_dir / str(c)):
            if p.is_file():
                return p
    return None


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="cinetransfer report",
                                 description="Build the fidelity report (report.html, report.json, fig_*.png) "
                                             "from a run folder.")
    ap.add_argument("run_dir", help="run folder (style.json, output_style.json, output.mp4, truth.msgpack, meta.json)")
    ap.add_argument("-o", "--outdir", help="write the report here instead of RUN_DIR")
    ap.add_argument("--source", help="source video (default: meta.json's 'source')")
    ap.add_argument("--no-embed", action="store_true",
                    help="link the PNGs from the HTML instead of embedding them")
    ap.add_argument("--log-level", default="WARNING")
    args = ap.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")

    run = Path(args.run_dir)
    if not (run / STYLE).is_file():
        print(f"cinetransfer report: {run / STYLE} not found (is {run} a run folder?)", file=sys.stderr)
        return 2
    meta: dict = {}
    if (run / META).is_file():
        try:
            meta = json.loads((run / META).read_text(encoding="utf-8"))
        except json.JSONDecodeError as e:
            print(f"cinetransfer report: {run / META} is not valid JSON ({e}); continuing without it",
                  file=sys.stderr)
        if not isinstance(meta, dict):
            meta = {}
    from cinetransfer.report.build import build_report
    from cinetransfer.report.truthfile import TruthFileError, read_truths

    truths = []
    if (run / TRUTH).is_file():
        try:
            truths = read_truths(run / TRUTH)
        except TruthFileError as e:
            print(f"cinetransfer report: {e}; the ground-truth half is left out", file=sys.stderr)
    out_style = run / OUTPUT_STYLE if (run / OUTPUT_STYLE).is_file() else None
    out_video = run / OUTPUT_VIDEO if (run / OUTPUT_VIDEO).is_file() else None
    source_video = _find_source(run, meta, args.source)
    outdir = Path(args.outdir) if args.outdir else run
    problem = _unwritable(outdir)
    if problem:  # before the figures: each would otherwise log its own traceback
        print(f"cinetransfer report: cannot write the report into {outdir}: {problem}", file=sys.stderr)
        return 1
    from cinetransfer.report.workers import FigureWorker

    try:
        with FigureWorker() as worker:  # the figures on the second core while this process does the rest
            summary = build_report(outdir, source_style=run / STYLE, output_style=out_style, truths=truths,
                                   source_video=source_video, output_video=out_video, meta=meta,
                                   embed_images=not args.no_embed, figure_worker=worker,
                                   recording=run / RECORDING if (run / RECORDING).is_file() else None)
    except ValueError as e:
        print(f"cinetransfer report: {e}", file=sys.stderr)
        return 1
    print(json.dumps(summary["headline"], indent=2))
    print(f"report: {(outdir / 'report.html').resolve()}")
    return 0


def _unwritable(outdir: Path) -> str | None:
    """Why no file can be made in `outdir` (made if missing), or None: a file is made and removed."""
    import tempfile

    try:
        outdir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=outdir):
            pass
    except OSError as e:
        return e.strerror or str(e)
    return None


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
