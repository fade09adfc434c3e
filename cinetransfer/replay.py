"""`cinetransfer replay RUN.mcap`: republish a recorded run on Zenoh, with its original timing.

For monitoring and re-plotting: `cinetransfer monitor` (or any node) sees the recorded keys
as if the run were live: every message of the rig goes out on its key in our codec again
(frames rebuilt from their JPEG, so lossy; see docs/recording.md). `--rig` rewrites the rig
segment of every key so that a replay never collides with a live vehicle; `--speed` scales time;
`--only` keeps keys containing a string.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time

from tqdm import tqdm

from cinetransfer.shared import keys, zenoh_config
from cinetransfer.shared.node import setup_logging
from cinetransfer.shared.runlog import RunFormatError, RunReader

log = logging.getLogger("cinetransfer.replay")


def rewrite_rig(key: str, rig: str | None) -> str:
    if not rig:
        return key
    parts = key.split("/")
    if len(parts) >= 3 and parts[0] == keys.ROOT:
        parts[1] = rig
    return "/".join(parts)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer replay", description=__doc__.splitlines()[0])
    p.add_argument("log", help="a recording (OUTDIR/run.mcap written by `cinetransfer transfer`)")
    p.add_argument("--rig", default="replay",
                   help="rig name to publish under (default %(default)s; '' keeps the recorded one)")
    p.add_argument("--speed", type=float, default=1.0, help="time scale (2 = twice as fast; 0 = as fast as possible)")
    p.add_argument("--only", action="append", default=[], help="replay only keys containing this (repeatable)")
    p.add_argument("--loop", action="store_true", help="start again at the end")
    p.add_argument("--salvage", action="store_true",
                   help="a recording cut inside a record: replay the messages before the cut instead of refusing")
    p.add_argument("--log-level", default="INFO")
    zenoh_config.add_arguments(p)
    args = p.parse_args(argv)
    setup_logging(args.log_level)
    try:
        run = RunReader(args.log, salvage=args.salvage)
        opts = zenoh_config.options_from_args(args)
    except (OSError, RunFormatError, ValueError) as e:
        print(f"cinetransfer replay: {e}", file=sys.stderr)
        return 2
    if not run.info.complete:
        log.warning("%s has no summary (the run was interrupted): replaying the %d messages it holds",
                    args.log, run.info.messages)
    log.info("replaying %s (%s)", args.log, run.meta.get("description", run.meta.get("source", "")))
    sent = 0
    with zenoh_config.open_session(opts) as s:
        pubs: dict[str, object] = {}
        try:
            while True:
                t_first = None
                t0 = time.monotonic()
                for t_ns, key, payload in tqdm(run.messages(), desc="replay", unit="msg", disable=None):
                    if args.only and not any(o in key for o in args.only):
                        continue
                    if t_first is None:
                        t_first = t_ns
                    if args.speed > 0:
                        due = t0 + (t_ns - t_first) / 1e9 / args.speed
                        delay = due - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    k = rewrite_rig(key, args.rig)
                    if k not in pubs:
                        pubs[k] = s.declare_publisher(k)
                    pubs[k].put(payload)
                    sent += 1
                if not args.loop:
                    break
        except KeyboardInterrupt:
            log.info("interrupted")
        except RunFormatError as e:
            print(f"cinetransfer replay: {e}", file=sys.stderr)
            return 2
        finally:
            for pub in pubs.values():
                pub.undeclare()
    log.info("replayed %d messages%s", sent, f" ({run.skipped} left out: they did not fit their schema)"
             if run.skipped else "")
    return 0
