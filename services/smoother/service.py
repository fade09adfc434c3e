"""The smoother node: Measurements in, Instructions out (streaming windows, then the whole sequence).

    cinetransfer smoother --rig R [--window 10] [--publish-period 0.25] [--end-idle 3] [zenoh flags]

Keys: subscribes `ct/{rig}/detector/measurement` (no-drop), `ct/{rig}/detector/end` (the
detector's StreamEnd after a source's last frame) and `ct/{rig}/smoother/command` (no-drop);
publishes `ct/{rig}/smoother/instructions`: streaming windows while measurements arrive, then the
whole sequence (final=True, with the source's SourceInfo). End of stream = the detector's
StreamEnd, a Command 'end' on the command key, `--end-idle` seconds without measurements, a
measurement of another source, or SIGINT/SIGTERM (the final result is published before exiting).
"""
from __future__ import annotations

import argparse
import dataclasses
import time

from cinetransfer.services.smoother.cli import add_config_arguments, config_from_args
from cinetransfer.services.smoother.config import ConfigError, SmootherConfig
from cinetransfer.services.smoother.core import SmootherInputError
from cinetransfer.services.smoother.stream import StreamState
from cinetransfer.shared import keys
from cinetransfer.shared import messages as M
from cinetransfer.shared.node import add_node_arguments, node_from_args

END_ACTIONS = ("end", "stop", "finish")


def build_parser() -> argparse.ArgumentParser:
    d = SmootherConfig()
    ap = argparse.ArgumentParser(prog="cinetransfer smoother", description="run the smoother node")
    add_node_arguments(ap)
    add_config_arguments(ap)
    ap.add_argument("--window", type=float, default=d.window_s, help="streaming window [s] (default %(default)s)")
    ap.add_argument("--history", type=float, default=d.history_s,
                    help="history used by each window solve [s] (default %(default)s)")
    ap.add_argument("--publish-period", type=float, default=d.publish_period_s,
                    help="at most one window per period [s], <= 0.5 (default %(default)s)")
    ap.add_argument("--end-idle", type=float, default=d.end_idle_s,
                    help="end of stream after this long without measurements [s]; 0 = only on command "
                         "(default %(default)s)")
    return ap


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = config_from_args(args).replace(window_s=args.window, history_s=max(args.history, args.window),
                                             publish_period_s=args.publish_period, end_idle_s=args.end_idle)
    except ConfigError as e:
        print(f"cinetransfer smoother: {e}")
        return 2
    node = node_from_args("smoother", args, config=cfg)
    state = StreamState(cfg)
    with node:
        inbox = node.subscribe(keys.MEASUREMENT, policy="no-drop")
        commands = node.subscribe(keys.SMOOTHER_COMMAND, policy="no-drop")
        ends = node.subscribe(keys.DETECTOR_END)
        pub = node.publisher(keys.INSTRUCTIONS)
        node.ready()
        last_pub = 0.0

        def finish(reason: str, source: M.SourceInfo | None = None) -> None:
            if not len(state):
                return
            try:
                with node.timed():
                    ins = state.final(source)
                pub.put(ins)
                node.log.info("end of stream (%s): published the whole sequence, %d frames", reason,
                              ins.image_targets.shape[0])
            except SmootherInputError as e:
                node.error(f"end of stream ({reason}): {e}", "final")
            state.reset()

        def update_counters() -> None:
            node.counters.update(dataclasses.asdict(state.counters))
            node.counters["held_frames"] = len(state)

        while node.running:
            node.wait(0.05)
            for cmd in commands.drain():
                action = str(cmd.action).lower()
                if action in END_ACTIONS:
                    # Take every measurement already queued before closing the sequence.
                    for m in inbox.drain():
                        with node.guard(inbox.key, "measurement"):
                            _ingest(node, state, m, finish)
                    with node.guard(commands.key, "command"):
                        finish(f"command {action!r}")
                elif action == "reset":
                    state.reset()
                else:
                    node.reject(f"unknown smoother command {cmd.action!r} (use 'end' or 'reset')")
            for end in ends.drain():
                with node.guard(ends.key, "end of stream"):
                    _await_stream(node, inbox, state, end, finish)
                    finish(f"end of stream: {end.reason}", source=end.source)
            for m in inbox.drain():
                # guard: a measurement the stream state trips over is rejected, the loop goes on
                with node.guard(inbox.key, "measurement"):
                    _ingest(node, state, m, finish)
            now = time.monotonic()
            if state.dirty and now - last_pub >= cfg.publish_period_s:
                with node.timed():
                    win = state.window()
                if win is not None:
                    pub.put(win)
                last_pub = now
            if cfg.end_idle_s > 0 and len(state) and inbox.age_s() > cfg.end_idle_s:
                finish("idle")
            update_counters()
        finish("shutdown")
        update_counters()
    return 0


def _await_stream(node, inbox, state: StreamState, end: M.StreamEnd, finish, wait_s: float = 5.0) -> None:
    """Take the stream's measurements still in flight (they travel on another key than its end)."""
    deadline = time.monotonic() + wait_s
    while node.running:
        for m in inbox.drain():
            _ingest(node, state, m, finish)
        if len(state) >= end.frames or time.monotonic() > deadline:
            break
        node.wait(0.05)
    if len(state) < end.frames:
        node.error(f"end of {end.source.path}: {len(state)} of {end.frames} measurements arrived", "final")


def _ingest(node, state: StreamState, m: M.Measurement, finish) -> None:
    if state.is_new_source(m):
        finish("new source")
    status = state.add(m)
    if status == "duplicate":
        node.rl.warning("dup", f"duplicate measurement of frame {m.frame_index} ignored")
