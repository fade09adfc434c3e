"""`cinetransfer record KEYEXPR -o RUN.mcap`: record a running rig, outside a transfer.

Everything matching KEYEXPR goes into an MCAP file through the writer a transfer's recording
uses (cinetransfer/runlog.py `RunWriter`: the same channels, schemas, H.264 frames and metadata), so
`info`, `echo`, `replay`, Foxglove and Rerun read it alike. It joins a deployment the way
`monitor` does (the read-only 'observer' of `--deployment`, local by default) unless an endpoint
is given, and records until Ctrl-C (or SIGTERM), `--duration` seconds or `--count` messages;
the file is then finished properly. The Zenoh callback only enqueues; one worker thread writes.
"""
from __future__ import annotations

import argparse
import queue
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from cinetransfer import monitor
from cinetransfer.deploy import join
from cinetransfer.shared import keys, zenoh_config
from cinetransfer.shared.stopsignal import StopSignal
from cinetransfer.runlog import RunWriter


class LiveRecording:
    """Writes every sample of `keyexpr` on `session` to `path` until `close()`."""

    def __init__(self, session: Any, keyexpr: str, path: Path, meta: dict[str, Any]) -> None:
        self.writer = RunWriter(path, meta)
        self.written = 0
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._done = threading.Condition()
        self._worker = threading.Thread(target=self._work, name="record", daemon=True)
        self._worker.start()
        self._sub = session.declare_subscriber(keyexpr, self._on)

    def _on(self, sample: Any) -> None:
        self._q.put((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))

    def _work(self) -> None:
        while (item := self._q.get()) is not None:
            self.writer.write(*item)
            with self._done:
                self.written += 1
                self._done.notify_all()

    def wait_count(self, n: int, stop: StopSignal) -> None:
        """Return once `n` messages are written or `stop` is set."""
        with self._done:
            while self.written < n and not stop.is_set():
                self._done.wait(0.2)

    def close(self) -> None:
        """Stop listening, write what was received, finish the file."""
        self._sub.undeclare()
        self._q.put(None)
        self._worker.join()
        self.writer.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cinetransfer record", description=__doc__.splitlines()[0])
    p.add_argument("keyexpr", nargs="?", default=keys.everything(),
                   help="key expression to record (default %(default)s: every rig)")
    p.add_argument("-o", "--output", required=True, metavar="RUN.mcap", help="the recording to write")
    p.add_argument("--duration", type=float, default=0.0, metavar="S", help="stop after S seconds (0 = until Ctrl-C)")
    p.add_argument("--count", type=int, default=0, metavar="N", help="stop after N messages (0 = no limit)")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.add_argument("--deployment", default=None, metavar="CONFIG",
                   help="join this running deployment as the read-only 'observer' (default, when no endpoint "
                        "is given: local)")
    zenoh_config.add_arguments(p)
    return p


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    out = Path(args.output)
    try:
        if out.exists() and not args.force:
            raise ValueError(f"{out} exists (--force overwrites it)")
        opts = monitor.observer_options(args)
    except join.NotRunningError as e:  # nothing to record: one line, exit 1, as monitor says it
        print(f"cinetransfer record: {e}", file=sys.stderr)
        return 1
    except ValueError as e:
        print(f"cinetransfer record: {e}", file=sys.stderr)
        return 2
    # not a threading.Event set from a handler: that hangs when the signal lands inside its wait()
    stop = StopSignal().install((signal.SIGINT, signal.SIGTERM))
    meta = {"source": "record", "keyexpr": args.keyexpr, "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    with zenoh_config.open_session(opts) as session:
        try:
            rec = LiveRecording(session, args.keyexpr, out, meta)
        except OSError as e:
            print(f"cinetransfer record: cannot write {out}: {e}", file=sys.stderr)
            return 2
        print(f"recording {args.keyexpr} to {out} (Ctrl-C to stop)", flush=True)
        if args.duration > 0:
            timer = threading.Timer(args.duration, stop.set)
            timer.daemon = True
            timer.start()
        try:
            if args.count > 0:
                rec.wait_count(args.count, stop)
            else:
                stop.wait()
        finally:
            rec.close()
    size = out.stat().st_size
    print(f"recorded {rec.written} messages of the rig ({rec.writer.errors} kept as raw bytes) to {out}: "
          f"{size / 1e6:.2f} MB")
    return 0
