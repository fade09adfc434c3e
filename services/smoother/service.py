"""The smoother node: Measurements in, Instructions out (streaming windows, then the whole sequence).

    cinetransfer smoother --rig R [--window 10] [--publish-period 0.25] [--end-idle 3] [zenoh flags]

Keys: subscribes `ct/{rig}/detector/measurement` (no-drop), `ct/{rig}/detector/end` (the
detector's StreamEnd after a source's last frame) and `ct/{rig}/smoother/command` (no-drop);
publishes `ct/{rig}/smoother/instructions`: streaming windows while measurements arrive (none with
`--publish-period 0`), then the whole sequence (final=True, with the source's SourceInfo). End of
stream = the detector's StreamEnd, a Command 'end' on the command key, `--end-idle` seconds without
measurements, a measurement of another source, or SIGINT/SIGTERM (the final result is published
before exiting).
"""
from __future__ import annotations

import argparse
import dataclasses
import time

from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.core import SmootherInputError
from cinetransfer.services.smoother.stream import StreamState, window_due
from cinetransfer.shared import keys, nodeconfig
from cinetransfer.shared import messages as M
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.node import add_node_arguments, node_from_args

END_ACTIONS = ("end", "stop", "finish")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cinetransfer smoother", description="run the smoother node")
    add_node_arguments(ap)
    nodeconfig.add_config_arguments(ap, "smoother")
    nodeconfig.add_settings_arguments(ap, SmootherConfig, "smoother")
    return ap


def node_config(args: argparse.Namespace) -> SmootherConfig:
    """Code defaults, then the node's settings (shared/nodeconfig.py), then flags."""
    if args.window_s is not None:  # a longer window takes the history with it
        base = nodeconfig.settings_from(SmootherConfig, nodeconfig.args_section(args, "smoother"), "smoother")
        args.history_s = max(args.history_s or base.history_s, args.window_s)
    return nodeconfig.config_from_args(SmootherConfig, args, "smoother")


class SmootherLoop:
    """The node's loop: commands, stream ends and measurements in; windows and whole sequences out."""

    def __init__(self, node, cfg: SmootherConfig) -> None:
        self.node, self.cfg = node, cfg
        self.state = StreamState(cfg)
        self.inbox = node.subscribe(keys.MEASUREMENT, policy="no-drop")
        self.commands = node.subscribe(keys.SMOOTHER_COMMAND, policy="no-drop")
        self.ends = node.subscribe(keys.DETECTOR_END)
        self.pub = node.publisher(keys.INSTRUCTIONS)
        self.last_pub = 0.0

    def finish(self, reason: str, source: M.SourceInfo | None = None) -> None:
        node, state = self.node, self.state
        if not len(state):
            return
        try:
            with node.timed():
                ins = state.final(source)
            self.pub.put(ins)
            node.log.info("end of stream (%s): published the whole sequence, %d frames", reason,
                          ins.image_targets.shape[0])
        except SmootherInputError as e:
            node.error(f"end of stream ({reason}): {e}", "final")
        state.reset()

    def update_counters(self) -> None:
        self.node.counters.update(dataclasses.asdict(self.state.counters))
        self.node.counters["held_frames"] = len(self.state)

    def ingest_queued(self) -> None:
        for m in self.inbox.drain():
            # guard: a measurement the stream state trips over is rejected, the loop goes on
            with self.node.guard(self.inbox.key, "measurement"):
                _ingest(self.node, self.state, m, self.finish)

    def handle_commands(self) -> None:
        for cmd in self.commands.drain():
            action = str(cmd.action).lower()
            if action in END_ACTIONS:
                self.ingest_queued()  # every measurement already queued belongs to the sequence
                with self.node.guard(self.commands.key, "command"):
                    self.finish(f"command {action!r}")
            elif action == "reset":
                self.state.reset()
            else:
                self.node.reject(f"unknown smoother command {cmd.action!r} (use 'end' or 'reset')")

    def handle_ends(self) -> None:
        for end in self.ends.drain():
            with self.node.guard(self.ends.key, "end of stream"):
                _await_stream(self.node, self.inbox, self.state, end, self.finish)
                self.finish(f"end of stream: {end.reason}", source=end.source)

    def publish_window(self) -> None:
        now = time.monotonic()
        if window_due(now, self.last_pub, self.cfg.publish_period_s, dirty=self.state.dirty):
            with self.node.timed():
                win = self.state.window()
            if win is not None:
                self.pub.put(win)
            self.last_pub = now

    def run(self) -> None:
        node, cfg = self.node, self.cfg
        while node.running:
            node.wait(0.05)
            self.handle_commands()
            self.handle_ends()
            self.ingest_queued()
            self.publish_window()
            if cfg.end_idle_s > 0 and len(self.state) and self.inbox.age_s() > cfg.end_idle_s:
                self.finish("idle")
            self.update_counters()
        self.finish("shutdown")
        self.update_counters()


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = node_config(args)
    except ConfigError as e:
        return report_config_error(e, "cinetransfer smoother")
    node = node_from_args("smoother", args, config=cfg)
    with node:
        loop = SmootherLoop(node, cfg)
        node.ready()
        loop.run()
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
