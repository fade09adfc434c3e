"""`cinetransfer transfer SOURCE_VIDEO --scene SCENE -o OUTDIR`: the whole job.

1. bring up the dataflow as separate processes over Zenoh      → OUTDIR/deploy/*.log
   (a router, source, detector, smoother, planner, autopilot bridge with the simulator) — or
   join a running deployment: `--deployment local` (after `deploy up local`; or `ground` for a
   ground/onboard split), or `--connect tcp/HOST:PORT` with `--identity operator --secrets DIR`
2. play the source clip into it: source -> detector -> smoother; the smoother's final
   whole-sequence instructions are the style                   → OUTDIR/style.json
   (`--style FILE` skips this and publishes the file's instructions instead)
3. fly the take in simulation time: the simulation restarts at a
   fresh time zero, the planner starts exactly then (pre-roll on frame 0, then the
   instructions), and the bridge steps only when the planner's setpoint for the step has
   arrived, so every camera frame exists and machine load cannot change the result
   (`--realtime`: the wall clock instead; skipped frames are repeated, counted, reported)
   and record every message (MCAP, docs/recording.md)          → OUTDIR/run.mcap
   and the camera's frames, frame k = instruction frame k      → OUTDIR/output.mp4 (H.264)
4. stop: the planner stops, the bridge holds; Ctrl-C at any time does the same and keeps
   what was recorded
5. evaluate: the same extraction on the output video           → OUTDIR/output_style.json
   compared with the source and with the simulator's truth    → OUTDIR/report.html, report.json

This module is the command and its steps in order; the deployment is cinetransfer/job.py, the
extraction cinetransfer/extraction.py, the flight and its takes cinetransfer/flight.py.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import logging
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

import zenoh

from cinetransfer.deploy.config import load_config
from cinetransfer.extraction import EXTRACTION_NODES, cached_style, source_style
from cinetransfer.flight import check_take, fly, take_meta
from cinetransfer.flight import merge_short as merge_short  # re-exported: callers import the schedule from here
from cinetransfer.flight import shot_schedule as shot_schedule
from cinetransfer.job import TransferError, deployment, run_cli, wait_alive
from cinetransfer.lease import TakeLease
from cinetransfer.live_output import LiveOutputStyle
from cinetransfer.recorder import LOW_SPACE_BYTES, RESERVE_BYTES, Recorder, drop_reserve, make_reserve
from cinetransfer.report.workers import FigureWorker
from cinetransfer.shared import keys
from cinetransfer.shared import messages as M
from cinetransfer.shared import zenoh_config
from cinetransfer.shared.atomic import atomic_write
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.node import setup_logging
from cinetransfer.shared.vehicle import add_vehicle_argument
from cinetransfer.whole_import import import_whole
from cinetransfer.stage_cpu import StageClock
from cinetransfer.take import MissingFramesError

log = logging.getLogger("cinetransfer.transfer")
#: exit code of a run whose take was degraded (held too long, lost its planner): everything is
#: recorded and reported, but the flight is not the instructions' (docs/transfer.md, exit codes)
EXIT_DEGRADED = 3
#: the nodes that fly the take
FLIGHT_NODES = {"planner", "autopilot_bridge"}


def _subjects() -> list[str]:
    from cinetransfer.services.autopilot_bridge.sim.scene import subject_names

    return subject_names()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cinetransfer transfer", description=__doc__.splitlines()[0])
    p.add_argument("source", help="source video (anything OpenCV decodes)")
    p.add_argument("--scene", default="open_country", help="simulator scene name or YAML file (default %(default)s)")
    p.add_argument("--subject", default=None, metavar="NAME",
                   help=f"the filmed person, from the subject library: {', '.join(_subjects())} "
                        "(default: the scene's own)")
    p.add_argument("-o", "--outdir", required=True, help="output folder")
    add_vehicle_argument(p)
    p.add_argument("--rig", default=None,
                   help="rig name (default: the deployment's rig with --deployment, else 'transfer')")
    p.add_argument("--preroll", type=float, default=5.0,
                   help="seconds (simulated) to settle on frame 0 before recording (default %(default)s)")
    p.add_argument("--max-frames", type=int, default=0, help="use only the first N frames of the source (0 = all)")
    p.add_argument("--style", help="use this style.json instead of extracting one")
    p.add_argument("--no-cache", action="store_true",
                   help="extract the source's style again even if this clip was extracted with the same settings "
                        "and code before, and do not keep it (the cache: $CT_CACHE_DIR/styles, docs/transfer.md)")
    p.add_argument("--pace", type=float, default=0.0, metavar="X",
                   help="simulated seconds per wall second during the take (default 0 = as fast as the machine "
                        "allows; 1 = watch it in real time). The result is the same either way")
    p.add_argument("--settle", type=float, default=3.0, metavar="S",
                   help="seconds (simulated) to re-frame between the takes of a multi-shot source "
                        "(default %(default)s)")
    p.add_argument("--min-take", type=float, default=0.5, metavar="S",
                   help="a shot shorter than this is filmed on in the take before it (default %(default)s s)")
    p.add_argument("--one-take", action="store_true",
                   help="fly a multi-shot source as one continuous take (for comparison) instead of one take per shot")
    p.add_argument("--realtime", action="store_true",
                   help="fly on the wall clock (simulator skips late frames; repeats are counted and reported) "
                        "instead of simulation time in lockstep")
    p.add_argument("--stall-timeout", type=float, default=300.0, metavar="S",
                   help="fail when no frame arrives (in simulation time: nor a simulation step, as in the "
                        "pre-roll) for this many wall seconds (default %(default)s)")
    p.add_argument("--deployment", metavar="CONFIG", default=None,
                   help="join this running deployment (config name or file, e.g. local, or ground for a split "
                        "one) as the operator, with its credentials, instead of starting one")
    p.add_argument("--no-eval", action="store_true", help="skip extraction on the output and the report")
    p.add_argument("--log-level", default="INFO")
    zenoh_config.add_arguments(p)
    return p


#: the report's heaviest import in this process (cvxpy for the truth floor: 1.2 CPU s), done while
#: the take is filmed: the bridge's renderer paces the flight and this process mostly waits for
#: frames. matplotlib's figure modules are not among them: the figure process (report/workers.py)
#: imports them and draws; this process needs them only if that process dies (0.35-0.39 CPU s saved)
REPORT_IMPORTS = ("cvxpy",)


def warm_imports(names: tuple[str, ...]) -> None:
    """Import `names` now (on a background thread) so that the report does not wait for them;
    one that fails is left to fail where it is used, with its own message."""
    for name in names:
        try:
            import_whole(name)  # a part-way failure must not leave half a package behind for the report
        except Exception as e:  # noqa: BLE001 - only a head start: the report imports it again
            log.debug("warm import of %s failed: %s", name, e)


def floor_ahead(style_path: Path, truths: list, meta: dict) -> cf.Future:
    """The report's truth floor (report/floor.py, frames aligned by index), on a thread from now,
    from the style as the report reads it."""
    def floor():
        from cinetransfer.report.floor import run_floor
        from cinetransfer.report.style import load_style_any

        return run_floor(load_style_any(style_path)[0], truths, meta, aligned_by_index=True)

    pool = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="floor")
    try:
        return pool.submit(floor)
    finally:
        pool.shutdown(wait=False)


def write_json(path: Path, data: dict) -> None:
    """Temp file then rename: a reader (or a crash) never sees half a file."""
    with atomic_write(path) as fh:
        json.dump(data, fh, indent=2, default=str)


def _job(args, src: Path, out: Path, meta: dict, clock: StageClock, live: dict, stopping: list
         ) -> tuple[Path, M.Instructions, Recorder]:
    """Bring up (or join) the deployment, extract the style on it, fly the take (its frames
    measured as they are recorded: live["output"], unless --no-eval), bring it down."""
    cache = cached_style(args, src)  # own deployment: known before any node starts
    known = bool(args.style) or cache.path is not None
    clock.end("cache_lookup_s")
    with deployment(args, out, extraction=not known, stopping=stopping) as opts, \
            zenoh_config.open_session(opts) as session, \
            TakeLease(session, args.rig):  # one take at a time on the rig: a second one is refused here
        # the flight's nodes go on starting while the style is extracted
        wait_alive(session, args.rig, FLIGHT_NODES if known else set(EXTRACTION_NODES), 180)
        clock.end("start_nodes_s")
        style_path, style, origin, det = source_style(args, src, out, session, cache)
        meta["style_origin"] = origin
        meta["detectors"] = {"source": det}  # the output's: once it is measured (_output_style)
        clock.end("extract_source_s")
        wait_alive(session, args.rig, FLIGHT_NODES, 180)
        measurer = live["output"] = None if args.no_eval else LiveOutputStyle(out / "output.mp4", style.fps)
        if not args.no_eval:
            threading.Thread(target=warm_imports, args=(REPORT_IMPORTS,), name="warm-imports", daemon=True).start()
            live["figures"] = FigureWorker()  # starts now: its imports are done by the time the report draws
        rec = fly(style, outdir=out, session=session, rig=args.rig, preroll_s=args.preroll,
                  realtime=args.realtime, stall_s=args.stall_timeout, meta=meta,
                  publish_instructions=origin != "extracted", settle_s=args.settle, one_take=args.one_take,
                  pace=args.pace, min_take_s=args.min_take, on_frame=measurer.feed if measurer else None)
        clock.end("flight_s")
        meta["health"] = {n: {"received": h.received, "rejected": h.rejected, "dropped": h.dropped,
                              "published": h.published, "counters": h.counters}
                          for n, h in rec.health.items()}
    return style_path, style, rec


def _output_style(out: Path, meta: dict, rec: Recorder, live: LiveOutputStyle | None,
                  clock: StageClock) -> Path | None:
    """OUTDIR/output_style.json: from the frames measured while filming when that worked, else by
    `cinetransfer extract` on output.mp4 (None when both failed: the report says so)."""
    out_style = out / "output_style.json"
    # the output of per-shot takes is edited at the takes' first rows: its shots are known
    takes = meta.get("takes") or []
    cuts = [int(t["first_row"]) for t in takes[1:]] if len(takes) > 1 else None
    if live is not None and live.finish(out_style, n_frames=int(meta.get("recorded_frames") or 0),
                                        cuts=cuts):
        meta["output_measured"] = "while filming (the camera's frames, before H.264)"
        _output_detector(meta, live.detector)
        clock.end("extract_output_s")
        return out_style
    try:
        run_cli(["extract", str(out / "output.mp4"), "-o", str(out_style),
                 *(["--cuts", ",".join(map(str, cuts))] if cuts else [])], "extraction on the output")
        meta["output_measured"] = "after the flight, from output.mp4"
        _output_detector(meta, style_detector(out_style))
    except TransferError as e:
        log.error("%s", e)
        out_style = None
    clock.end("extract_output_s")
    return out_style


def style_detector(path: Path) -> dict | None:
    """Which backend measured a style file `cinetransfer extract` wrote (its diagnostics' "detector")."""
    from cinetransfer.shared.instructions import StyleFileError, load_style_file

    try:
        det = load_style_file(path).diagnostics.get("detector")
    except (StyleFileError, OSError):
        return None
    return det if isinstance(det, dict) else None


def _output_detector(meta: dict, det: dict | None) -> None:
    """Record the output pass's detector backend in meta.json, and say it once when it is a fallback."""
    from cinetransfer import detector_backend

    meta.setdefault("detectors", {})["output"] = det
    if detector_backend.is_fallback(det):
        log.warning("%s", detector_backend.warning("output style", det, ", so the report's output measures "
                                                   "are not the box-first detector's"))


def _evaluate(out: Path, src: Path, style_path: Path, rec: Recorder, meta: dict, live: dict,
              clock: StageClock, states: list | None = None) -> dict:
    out_style = _output_style(out, meta, rec, live.get("output"), clock)
    figures = live.get("figures")
    from cinetransfer.report import build_report

    summary = build_report(out, source_style=style_path, output_style=out_style, truths=rec.truths,
                           source_video=src, output_video=out / "output.mp4", meta=meta,
                           recording=out / "run.mcap", figure_worker=figures, floor_ahead=live.get("floor"),
                           vehicle_states=states)
    if figures is not None:  # ended before the stage's CPU is read: its figures count in the report's
        figures.close(wait=True)
    clock.end("report_s")
    return summary


def _argument_problem(args, src: Path) -> str | None:
    """What is wrong with the command line before anything starts (None: nothing)."""
    if not src.is_file():
        return f"source video {src} does not exist"
    if Path(args.outdir).exists() and not Path(args.outdir).is_dir():
        return f"-o {args.outdir}: exists and is not a folder"
    if not (0.0 <= args.pace <= 1000.0 and args.settle >= 0.0 and args.preroll >= 0.0):
        return "--pace must be in 0..1000, --settle and --preroll >= 0"
    if args.subject and (args.deployment or getattr(args, "connect", None)):
        return ("--subject needs the transfer's own deployment; a running bridge films "
                "the subject it was started with (autopilot_bridge --subject NAME)")
    return _style_problem(args.style)


def _style_problem(style: str | None) -> str | None:
    """A --style file that cannot be flown (unreadable, off the schema, fps outside the camera's
    range, nothing to fly) is refused before a node starts, not after."""
    if not style:
        return None
    from cinetransfer.shared.instructions import load_style

    try:
        load_style(style)
    except OSError as e:
        return f"--style {style}: {e.strerror or e}"
    except ValueError as e:
        return f"--style {e}"
    return None


def _resolve_rig(args) -> str | None:
    """The rig: --rig, else the joined deployment's own (`deploy up local` runs rig0), else 'transfer'.
    Returns what is wrong (a --rig that is not the deployment's, an unknown deployment) or None."""
    try:
        keys.rig_name(args.rig or "transfer")
    except ValueError as e:
        return f"--rig: {e}"
    if not args.deployment:
        args.rig = args.rig or "transfer"
        return None
    try:
        rig = load_config(args.deployment).rig
    except (ConfigError, OSError) as e:
        return f"--deployment {args.deployment}: {e}"
    if args.rig and args.rig != rig:
        return f"--rig {args.rig} is not the rig of deployment {args.deployment} ({rig}); leave --rig out"
    args.rig = rig
    return None


def _save_take(out: Path, style: M.Instructions, rec: Recorder, meta: dict, realtime: bool) -> list | None:
    """What the take holds (meta.json, with each take's settle time and the state of its files)
    and its truth (truth.msgpack). Returns the recording's vehicle states when it was read back
    (the report's camera motion needs them: run.mcap is read once), else None."""
    meta.update(take_meta(rec, style, realtime))
    meta["files"] = recorded_files(out, int(style.image_targets.shape[0]), read_back=rec.failure is not None)
    states = None
    if meta.get("takes") and meta.get("epoch_ns") is not None and meta["files"]["run.mcap"] in READABLE:
        from cinetransfer import take_faults
        from cinetransfer.shared import keys as K

        facts = take_faults.read_facts(out / "run.mcap", meta["rig"])
        faults = take_faults.take_faults(out / "run.mcap", meta["rig"], meta["takes"], epoch_ns=int(meta["epoch_ns"]),
                                         fps=float(style.fps), facts=facts)
        meta["faults"] = take_faults.summary(faults)
        states = [m for _, m in facts[K.VEHICLE_STATE.key(meta["rig"])]]
    if meta.get("takes"):
        from cinetransfer.shots import settle_report

        meta["takes"] = settle_report(style, meta["takes"], rec.timeline_truths)
    from cinetransfer.report.truthfile import write_truths

    write_truths(out / "truth.msgpack", rec.truths)
    write_json(out / "meta.json", meta)
    return states


def _transfer(args, src: Path, out: Path, meta: dict, t_start: float) -> int:
    """The job's steps in order: deployment and flight, the take saved and judged, the evaluation."""
    timings: dict[str, float] = {"before_s": time.monotonic() - t_start}  # the output folder and its reserve
    clock = StageClock(timings, None if args.deployment or args.connect else out / "deploy")
    live: dict = {}  # the output measured while filming, once the flight starts
    stopping: list = []  # the own deployment, stopping in the background while the take is evaluated
    failed = True
    try:
        outcome = _take_and_evaluate(args, src, out, meta, clock, live, stopping)
        failed = False
    finally:
        _wind_down(live, stopping, quiet=failed)  # after an error, that error is the one reported
    if outcome is NO_EVAL:  # judged once the nodes are down: the verdict is the command's last line
        return _degraded(meta)
    if isinstance(outcome, int):
        return outcome
    clock.end("wind_down_s")
    timings["total_s"] = time.monotonic() - t_start
    meta.update(timings=timings, stage_cpu_s=clock.cpu.stages, credit=_credit(src))
    write_json(out / "meta.json", meta)
    print(json.dumps(outcome.get("headline", outcome), indent=2, default=str)[:3000])
    print(f"\nreport: {(out / 'report.html').resolve()}  ({timings['total_s']:.0f} s in all)")
    return _degraded(meta)


#: what `_take_and_evaluate` returns for a take recorded with --no-eval
NO_EVAL = "recorded, not evaluated"


def _take_and_evaluate(args, src: Path, out: Path, meta: dict, clock: StageClock, live: dict,
                       stopping: list) -> dict | int | str:
    """The report's summary, or the exit code of a run that ends before its evaluation."""
    try:
        style_path, style, rec = _job(args, src, out, meta, clock, live, stopping)
    except TransferError as e:
        if getattr(e, "flight", None) is None:
            raise
        meta["error"] = str(e)  # the flight failed: keep what it recorded, and say what that is
        try:
            _save_take(out, *e.flight, meta, args.realtime)
        except OSError as se:  # (a full disk: the error that stopped the flight is the one to tell)
            raise TransferError(f"{e}; meta.json and truth.msgpack not written: {_one_line(se)}") from None
        raise TransferError(f"{e}; {_files_said(meta['files'])}") from None
    if not args.no_eval and not rec.interrupted:
        # the report's truth floor needs no output style: it is computed while the output's frames
        # are still being measured
        live["floor"] = floor_ahead(style_path, list(rec.truths), dict(meta))
    states = _save_take(out, style, rec, meta, args.realtime)
    clock.end("save_take_s")
    if meta["interrupted"]:
        print(f"recorded {meta['recorded_frames']} frames to {out / 'output.mp4'} (interrupted)")
        return 130
    check_take(meta, rec, args.realtime)
    if args.no_eval:
        print(f"recorded {meta['recorded_frames']} frames to {out / 'output.mp4'} (no evaluation)")
        return NO_EVAL
    return _evaluate(out, src, style_path, rec, meta, live, clock, states)


def _wind_down(live: dict, stopping: list, *, quiet: bool) -> None:
    """Stop measuring the output (finished already, or nothing is evaluated) and wait until the
    own deployment has stopped: the command ends with its nodes."""
    if live.get("output") is not None:
        live["output"].cancel()
    if live.get("figures") is not None:
        live["figures"].close()
    for down in stopping:
        try:
            down.wait()
        except TransferError as e:
            if not quiet:
                raise
            log.error("%s", e)


READABLE = ("complete", "readable, without its summary")  #: run.mcap states that read without --salvage


def recorded_files(out: Path, n_slots: int, *, read_back: bool = True) -> dict[str, str]:
    """What output.mp4 and run.mcap hold, read back from the disk: 'complete', 'partial: N of K
    frames', 'missing (...)', 'unreadable: ...'; for the recording also READABLE or 'needs --salvage'.
    `read_back=False`: run.mcap was closed without an error, and is not read again (it can be large)."""
    from cinetransfer.runlog import RunFormatError, RunReader
    from cinetransfer.shared.video import probe

    video, mcap = out / "output.mp4", out / "run.mcap"
    files = {"output.mp4": "missing (the take's first frame was never recorded)",
             "run.mcap": "missing"}
    if video.is_file():
        try:
            n = probe(video)["frames"]
            files["output.mp4"] = "complete" if n >= n_slots else f"partial: {n} of {n_slots} frames"
        except Exception as e:  # noqa: BLE001 - whatever the demuxer says: the file cannot be watched
            files["output.mp4"] = f"unreadable: {e}"
    if mcap.is_file() and not read_back:
        files["run.mcap"] = "complete"
    elif mcap.is_file():
        try:
            files["run.mcap"] = "complete" if RunReader(mcap).info.complete else "readable, without its summary"
        except (RunFormatError, OSError) as e:
            files["run.mcap"] = f"needs --salvage: {e}"
    return files


def _files_said(files: dict[str, str]) -> str:
    return "; ".join(f"{name} {state}" for name, state in files.items())


def _degraded(meta: dict) -> int:
    """EXIT_DEGRADED, with one line saying why, when a take was not flown as instructed; else 0."""
    faults = meta.get("faults") or {}
    if not faults.get("degraded"):
        return 0
    print(f"cinetransfer transfer: degraded take, goals not met: {'; '.join(faults['reasons'])}", file=sys.stderr)
    return EXIT_DEGRADED


def _terminate(_signum, _frame) -> None:
    raise KeyboardInterrupt  # SIGTERM (a CI timeout, `kill`): stop the vehicle and the nodes as Ctrl-C does


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    # Ctrl-C must stop the vehicle however the command was started: a shell script that runs it in
    # the background (`cmd &`) hands it SIGINT ignored, and Python then installs no handler at all
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _terminate)
    setup_logging(args.log_level)
    src, out = Path(args.source), Path(args.outdir)
    problem = _argument_problem(args, src) or _resolve_rig(args)
    people = _people(src, args) if not problem else {}
    problem = problem or people.pop("problem", None)
    if problem:  # refused before anything is made: no folder, no process
        print(f"cinetransfer transfer: {problem}", file=sys.stderr)
        return 2
    created = not out.exists()
    t_start = time.monotonic()
    meta: dict = {"source": str(src), "scene": args.scene, "rig": args.rig, **people,
                  **({"vehicle": args.vehicle} if getattr(args, "vehicle", None) else {}),  # the report's lens rates
                  "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    try:
        out.mkdir(parents=True, exist_ok=True)
        _reserve_room(out)
        return _transfer(args, src, out, meta, t_start)
    except (TransferError, MissingFramesError, ValueError, OSError, zenoh.ZError) as e:
        print(f"cinetransfer transfer: {_one_line(e)}", file=sys.stderr)
        drop_reserve(out)
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # a run refused before it wrote anything leaves nothing behind
        return 1
    except KeyboardInterrupt:  # outside the flight (extraction, start-up): nothing is flying yet
        print(f"cinetransfer transfer: interrupted; what was written is in {out}", file=sys.stderr)
        return 130
    finally:
        drop_reserve(out)


def _reserve_room(out: Path) -> None:
    """The recording's reserve, set aside before any node starts: a disk without that much room is
    refused at once, and the nodes' logs and the extraction cannot eat the room the recording
    needs to close readable on a full disk."""
    try:
        make_reserve(out)
    except OSError as e:
        drop_reserve(out)
        free = shutil.disk_usage(out).free
        raise TransferError(f"-o {out}: {e.strerror or e}: {free / 2**20:.1f} MB free; a transfer sets "
                            f"{RESERVE_BYTES >> 20} MB aside to close its recording on a full disk and stops "
                            f"recording below {LOW_SPACE_BYTES >> 20} MB free") from None


def _one_line(e: BaseException) -> str:
    """An OSError names what failed and where; anything else says itself."""
    if isinstance(e, OSError) and e.strerror:
        return f"{e.strerror}: {e.filename}" if e.filename else e.strerror
    return str(e)


def _people(src: Path, args) -> dict:
    """Who is in the source clip and who is filmed (the scene's subject or --subject)."""
    from cinetransfer.services.autopilot_bridge.sim.scene import SceneError, load_scene, subject_info

    try:
        sub = load_scene(args.scene, subject=args.subject).subject.clip
        info = subject_info(sub)
    except SceneError as e:
        return {"problem": str(e)}
    same = src.name == info.get("source")
    return {"subject": sub, "target_person": info.get("person", sub), "target_source": info.get("source", ""),
            "target_credit": info.get("credit", ""), "same_person_as_source": same}


def _credit(src: Path) -> str:
    """The credit line of a bundled clip from its MANIFEST (empty for other videos)."""
    manifest = src.resolve().parent / "MANIFEST.md"
    if not manifest.is_file():
        return ""
    for line in manifest.read_text().splitlines():
        if line.startswith("|") and f"`{src.name}`" in line:
            cells = [c.strip() for c in line.strip("|").split("|")]
            return f"{src.name}: {cells[3]}" if len(cells) > 3 else ""
    return ""
