"""`cinetransfer source`: the source clip enters the dataflow on its own key.

    cinetransfer source --rig R                       # long-running: plays files on 'play' commands
    cinetransfer source --rig R --video CLIP [--stop N]   # plays one file, then exits

A 'play' Command on ct/{rig}/source/command (args: path, optional stop = frames to play) plays
the file's frames on ct/{rig}/source/frame, then publishes a StreamEnd on ct/{rig}/source/end
(also on 'stop', or on a read error, with the reason). No frame is ever dropped: at most
`--window` frames may be ahead of the detector (credit flow control: a frame counts as done when
its measurement appears on ct/{rig}/detector/measurement), and the publisher blocks rather than
drops. Health counters: frames_sent, frames_acked, in_flight, state, source.
"""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Any

from cinetransfer.services.source.config import SourceConfig
from cinetransfer.services.source.credit import Credit
from cinetransfer.shared import keys, nodeconfig
from cinetransfer.shared import messages as M
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.node import Presence, add_node_arguments, node_from_args
from cinetransfer.shared.frame_sources import FrameSourceError, iter_frames, probe

NAME = "source"
log = logging.getLogger(f"cinetransfer.{NAME}")


class SourceError(RuntimeError):
    """A play request cannot be served (the message says why)."""


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cinetransfer source", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_node_arguments(ap)
    ap.add_argument("--video", metavar="PATH", help="play this file once at start, then exit")
    ap.add_argument("--stop", type=int, default=None, help="(--video) play only the first N frames")
    nodeconfig.add_config_arguments(ap, NAME)
    nodeconfig.add_settings_arguments(ap, SourceConfig, NAME)
    return ap


class Player:
    """Plays one file at a time onto the source key, paced by the detector's credit."""

    def __init__(self, node: Any, cfg: SourceConfig) -> None:
        self.node, self.cfg = node, cfg
        self.frame_pub = node.publisher(keys.SOURCE_FRAME, block=True)
        self.end_pub = node.publisher(keys.SOURCE_END)
        self.cmd_in = node.subscribe(keys.SOURCE_COMMAND)
        self.acks = node.subscribe(keys.MEASUREMENT, maxlen=100_000, policy="no-drop")
        self.detector = Presence(node.session, node.rig, "detector")
        node.counters.update(state="idle", frames_sent=0, frames_acked=0, in_flight=0, plays=0)

    def serve(self) -> None:
        while self.node.running:
            cmd = self.cmd_in.get(timeout=0.2)
            if cmd is None:
                continue
            if cmd.action == "play":
                self.play(cmd.args.get("path"), cmd.args.get("stop"))
            elif cmd.action != "stop":
                self.node.reject(f"unknown source command {cmd.action!r} (use 'play' or 'stop')")

    def play(self, path: Any, stop: Any) -> M.StreamEnd:
        """Play `path`; always ends with a StreamEnd (published and returned)."""
        info, sent, reason, ok = M.SourceInfo(path=str(path)), 0, "end of file", True
        try:
            path, stop = self._check_request(path, stop)
            info = self._probe(path)
            self._await_detector()
            sent, reason = self._stream(path, stop, info)
        except SourceError as e:
            reason, ok = f"error: {e}", False
            self.node.error(str(e), "play")
        end = M.StreamEnd(stamp_ns=M.now_ns(), valid=ok, source=info, frames=sent, reason=reason)
        self.end_pub.put(end)
        self.node.counters.update(state="idle", plays=self.node.counters["plays"] + 1)
        log.info("%s: %d frames sent (%s)", info.path, sent, reason)
        return end

    def _check_request(self, path: Any, stop: Any) -> tuple[Path, int | None]:
        if not isinstance(path, str) or not path:
            raise SourceError(f"play: 'path' must be a file path, got {path!r}")
        if stop is not None and (isinstance(stop, bool) or not isinstance(stop, int) or stop < 1):
            raise SourceError(f"play: 'stop' must be a frame count >= 1, got {stop!r}")
        p = Path(path)
        if not p.exists():
            raise SourceError(f"{p}: no such file on the source node's machine")
        return p, stop

    def _probe(self, path: Path) -> M.SourceInfo:
        try:
            return probe(path, hash_file=True)
        except (FrameSourceError, OSError) as e:
            raise SourceError(str(e)) from None

    def _await_detector(self) -> None:
        deadline = time.monotonic() + self.cfg.wait_detector_s
        while not self.detector.alive:
            if time.monotonic() > deadline or not self.node.running:
                raise SourceError(f"no detector alive on rig {self.node.rig!r} after {self.cfg.wait_detector_s:g} s")
            self.node.sleep(0.1)

    def _stream(self, path: Path, stop: int | None, info: M.SourceInfo) -> tuple[int, str]:
        credit = Credit(self.cfg.window)
        self.node.counters.update(state="playing", source=str(path))
        self.acks.drain()  # measurements of an earlier play are no credit for this one
        try:
            for f in iter_frames(path, stop=stop):
                if not self._wait_credit(credit, info.path):
                    return credit.sent, "stop requested" if self.node.running else "node stopping"
                self.frame_pub.put(M.Frame(stamp_ns=f.stamp_ns, source=info.path, index=f.index, fps=f.fps,
                                           image=f.image))
                credit.on_sent()
                self._count(credit)
        except FrameSourceError as e:
            raise SourceError(f"{path}: {e}") from None
        return credit.sent, "end of file"

    def _wait_credit(self, credit: Credit, source: str) -> bool:
        """Block until the next frame may go. False when a 'stop' came or the node stops."""
        last_progress = time.monotonic()
        while not credit.may_send():
            n = credit.acked
            for m in self.acks.drain():
                if m.source == source:
                    credit.ack(int(m.frame_index))
            self._count(credit)
            if credit.acked != n:
                last_progress = time.monotonic()
            elif time.monotonic() - last_progress > self.cfg.stall_s:
                raise SourceError(f"the detector acknowledged no frame for {self.cfg.stall_s:g} s")
            if self._stop_requested() or not self.node.running:
                return False
            self.node.wait(0.05)
        return not self._stop_requested()

    def _stop_requested(self) -> bool:
        for cmd in self.cmd_in.drain():
            if cmd.action == "stop":
                return True
            self.node.reject(f"source busy: {cmd.action!r} ignored while playing (send 'stop' first)")
        return False

    def _count(self, credit: Credit) -> None:
        self.node.counters.update(frames_sent=credit.sent, frames_acked=credit.acked, in_flight=credit.in_flight)

    def close(self) -> None:
        self.detector.undeclare()


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = nodeconfig.config_from_args(SourceConfig, args, NAME)
    except ConfigError as e:
        return report_config_error(e, "cinetransfer source")
    node = node_from_args(NAME, args)
    with node:
        player = Player(node, cfg)
        node.ready()
        try:
            if args.video:
                end = player.play(args.video, args.stop)
                return 0 if end.valid else 1
            player.serve()
        finally:
            player.close()
    return 0
