"""`cinetransfer replay RUN.mcap`: republish a recorded run on Zenoh, with its original timing.

For monitoring and re-plotting: `cinetransfer monitor` (or any node) sees the recorded keys
as if the run were live: every message of the rig goes out on its key in our codec again
(frames rebuilt from their JPEG, so lossy; see docs/recording.md). `--rig` rewrites the rig
segment of every key so that a replay never collides with a live vehicle; `--speed` scales time;
`--only` keeps keys containing a string; `--start`/`--end` replay a window (seconds from the
recording's first message, as `cinetransfer info` and `echo` count them).
"""
from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time

import zenoh
from tqdm import tqdm

from cinetransfer.shared import keys, zenoh_config
from cinetransfer.shared.node import setup_logging
from cinetransfer.runlog import RunFormatError, RunReader

log = logging.getLogger("cinetransfer.replay")


def rewrite_rig(key: str, rig: str | None) -> str:
    if not rig:
        return key
    parts = key.split("/")
    if len(parts) >= 3 and parts[0] == keys.ROOT:
        parts[1] = rig
    return "/".join(parts)



def _speed(text: str) -> float:
    """--speed: a finite number >= 0 (a negative or NaN pace has no meaning)."""
    import math

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return v

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cinetransfer replay", description=__doc__.splitlines()[0])
    p.add_argument("log", help="a recording (OUTDIR/run.mcap written by `cinetransfer transfer`)")
    p.add_argument("--rig", default="replay",
                   help="rig name to publish under (default %(default)s; '' keeps the recorded one)")
    p.add_argument("--speed", type=_speed, default=1.0, help="time scale (2 = twice as fast; 0 = as fast as possible)")
    p.add_argument("--only", action="append", default=[], help="replay only keys containing this (repeatable)")
    p.add_argument("--start", type=float, default=0.0, metavar="S",
                   help="begin S seconds after the recording's first message (default %(default)s)")
    p.add_argument("--end", type=float, default=None, metavar="S",
                   help="stop S seconds after the recording's first message (default: its end)")
    p.add_argument("--loop", action="store_true", help="start again at the end (of the window)")
    p.add_argument("--salvage", action="store_true",
                   help="a recording cut inside a record: replay the messages before the cut instead of refusing")
    p.add_argument("--log-level", default="INFO")
    zenoh_config.add_arguments(p)
    return p


class _Publishers:
    """One publisher per (rewritten) key, declared on first use. Congestion control blocks: a
    replay republishes every recorded message, where the live default drops what a slow subscriber
    cannot take (a loaded machine lost 1-11 of 48 camera frames of a replay at --speed 4, the last
    one among them at times)."""

    def __init__(self, session, rig: str | None) -> None:
        self.session, self.rig = session, rig
        self.pubs: dict[str, object] = {}
        self.sent = 0

    def put(self, key: str, payload: bytes) -> None:
        k = rewrite_rig(key, self.rig)
        if k not in self.pubs:
            self.pubs[k] = self.session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
        self.pubs[k].put(payload)
        self.sent += 1

    def undeclare(self) -> None:
        for pub in self.pubs.values():
            pub.undeclare()


def stop_on_signals() -> threading.Event:
    """An event that SIGINT and SIGTERM set. The replay looks at it between messages: a flag set by
    a handler cannot be lost, where a KeyboardInterrupt can be dropped by whatever code it lands in
    (a looping replay once kept playing 15 s after its SIGINT, on a loaded machine)."""
    stop = threading.Event()

    def handler(signum: int, frame: object) -> None:  # noqa: ARG001 - signal's handler signature
        stop.set()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)
    return stop


def _play_once(run: RunReader, out: _Publishers, *, only: list[str], speed: float, start: float = 0.0,
               end: float | None = None, stop: threading.Event | None = None) -> None:
    """Publish the recording's messages (those whose key contains one of `only`, if given, logged
    between `start` and `end` seconds after its first message) once, at `speed` times their
    recorded pace (0: as fast as possible); return early once `stop` is set."""
    stop = stop or threading.Event()
    t_first, t0 = None, 0.0
    for t_ns, key, payload in tqdm(run.messages(), desc="replay", unit="msg", disable=None):
        if stop.is_set():
            return
        t_rel = (t_ns - run.info.start_ns) / 1e9
        if end is not None and t_rel > end:
            break
        if t_rel < start or (only and not any(o in key for o in only)):
            continue
        if t_first is None:  # the pace counts from the window's first message, not from reading up to it
            t_first, t0 = t_ns, time.monotonic()
        if speed > 0:
            delay = t0 + (t_ns - t_first) / 1e9 / speed - time.monotonic()
            if delay > 0 and stop.wait(delay):
                return
        out.put(key, payload)


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    setup_logging(args.log_level)
    try:
        run = RunReader(args.log, salvage=args.salvage)
        opts = zenoh_config.options_from_args(args)
        if args.end is not None and args.end < args.start:
            raise ValueError(f"--end {args.end} comes before --start {args.start}")
    except (OSError, RunFormatError, ValueError) as e:
        print(f"cinetransfer replay: {e}", file=sys.stderr)
        return 2
    if not run.info.complete:
        log.warning("%s has no summary (the run was interrupted): replaying the %d messages it holds",
                    args.log, run.info.messages)
    log.info("replaying %s (%s)", args.log, run.meta.get("description", run.meta.get("source", "")))
    stop = stop_on_signals()
    with zenoh_config.open_session(opts) as s:
        out = _Publishers(s, args.rig)
        try:
            window = {"only": args.only, "speed": args.speed, "start": args.start, "end": args.end, "stop": stop}
            _play_once(run, out, **window)
            while args.loop and not stop.is_set():
                _play_once(run, out, **window)
            if stop.is_set():
                log.info("interrupted")
        except RunFormatError as e:
            print(f"cinetransfer replay: {e}", file=sys.stderr)
            return 2
        finally:
            out.undeclare()
    log.info("replayed %d messages%s", out.sent, f" ({run.skipped} left out: they did not fit their schema)"
             if run.skipped else "")
    return 0
