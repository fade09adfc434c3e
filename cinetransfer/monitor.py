"""`cinetransfer monitor [KEYEXPR]`: what is on the bus, and who is alive.

A live table of keys with rate, size, age and a one-line decoded summary, plus the nodes
whose liveliness tokens are present. `--json` streams every decoded message as one JSON line
(for scripts); `--once` collects for `--duration` seconds, prints one snapshot and exits.
`--foxglove` serves the same topics live over the Foxglove WebSocket protocol instead (images,
transforms and camera calibration included; cinetransfer/foxglove_live.py), on 127.0.0.1:`--port`;
on any other address only with an access token (`--token-file` or CINETRANSFER_FOXGLOVE_TOKEN).
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import os
import sys
import threading
import time
from typing import Any

import numpy as np
import zenoh

from cinetransfer.deploy import join
from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared.stopsignal import StopSignal

RATE_WINDOW_S = 5.0
TOKEN_ENV = "CINETRANSFER_FOXGLOVE_TOKEN"
DEFAULT_ROUTER = "tcp/127.0.0.1:7447"


def to_jsonable(obj: Any, max_array: int = 64) -> Any:
    """A decoded message as plain JSON values; large arrays become a shape/dtype summary."""
    if dataclasses.is_dataclass(obj):
        out = {"_type": type(obj).__name__} if hasattr(obj, "SCHEMA_VERSION") else {}
        for f in dataclasses.fields(obj):
            out[f.name] = to_jsonable(getattr(obj, f.name), max_array)
        return out
    if isinstance(obj, np.ndarray):
        if obj.size <= max_array:
            return np.where(np.isfinite(obj), obj, None).tolist() if obj.dtype.kind == "f" else obj.tolist()
        return {"shape": list(obj.shape), "dtype": str(obj.dtype)}
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, max_array) for v in obj]
    if isinstance(obj, dict):
        return {k: to_jsonable(v, max_array) for k, v in obj.items()}
    return obj


@dataclasses.dataclass
class KeyStats:
    count: int = 0
    errors: int = 0
    last_size: int = 0
    last_rx: float = 0.0
    summary: str = ""
    times: collections.deque = dataclasses.field(default_factory=lambda: collections.deque(maxlen=2000))

    def rate(self, now: float) -> float:
        recent = [t for t in self.times if now - t <= RATE_WINDOW_S]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6)


class Monitor:
    def __init__(self, session: zenoh.Session, keyexpr: str, json_out: bool = False) -> None:
        self.session, self.keyexpr, self.json_out = session, keyexpr, json_out
        self.stats: dict[str, KeyStats] = collections.defaultdict(KeyStats)
        self.alive: set[str] = set()
        self.lock = threading.Lock()
        self._subs = [session.declare_subscriber(keyexpr, self._on_sample)]
        alive_expr = f"{keys.ROOT}/*/alive/*"
        self._subs.append(session.liveliness().declare_subscriber(alive_expr, self._on_alive, history=True))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        with self.lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(str(sample.key_expr))
            else:
                self.alive.discard(str(sample.key_expr))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key, payload, now = str(sample.key_expr), sample.payload.to_bytes(), time.monotonic()
        try:
            msg = codec.decode(payload)
            summary, err = codec.summary(msg), False
        except codec.DecodeError as e:
            msg, summary, err = None, f"UNDECODABLE: {e}", True
        with self.lock:
            st = self.stats[key]
            st.count += 1
            st.errors += err
            st.last_size, st.last_rx, st.summary = len(payload), now, summary
            st.times.append(now)
        if self.json_out:
            line = {"key": key, "size": len(payload), "error": summary if err else None,
                    "msg": to_jsonable(msg) if msg is not None else None}
            sys.stdout.write(json.dumps(line) + "\n")
            sys.stdout.flush()

    def table(self) -> str:
        now = time.monotonic()
        with self.lock:
            rows = sorted(self.stats.items())
            alive = sorted(self.alive)
        lines = [f"{'key':<40} {'rate/s':>8} {'size':>10} {'age':>8} {'count':>7}  summary"]
        for key, st in rows:
            age = now - st.last_rx
            lines.append(f"{key:<40} {st.rate(now):8.1f} {_size(st.last_size):>10} {age:7.1f}s {st.count:7d}  "
                         f"{st.summary[:90]}")
        if not rows:
            lines.append("(no messages yet)")
        lines.append("")
        lines.append("alive: " + (", ".join(k.split("/")[1] + "/" + k.split("/")[-1] for k in alive) or "(none)"))
        silent = silent_keys(alive, {k for k, _ in rows})
        if silent:
            lines.append("SILENT (declared outputs of live nodes, nothing received): " + ", ".join(silent))
        return "\n".join(lines)

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


#: outputs that only exist in some modes or on events; their silence is no sign of trouble
EVENT_ONLY_RATE = 0.0


def silent_keys(alive_tokens: list[str] | set[str], seen: set[str]) -> list[str]:
    """Declared outputs (deploy/dataflow.yaml) of the live nodes that nothing was received on.
    Event-driven keys (rate 0 in the topic table) are left out: they are quiet by nature."""
    from cinetransfer.shared import dataflow

    flow = dataflow.load()
    out = []
    for token in sorted(alive_tokens):
        parts = token.split("/")
        if len(parts) != 4 or parts[3] not in flow.nodes:
            continue
        rig = parts[1]
        for t in flow.nodes[parts[3]].outputs:
            if t.rate_hz > EVENT_ONLY_RATE and t.key(rig) not in seen:
                out.append(t.key(rig))
    return list(dict.fromkeys(out))


def _size(n: int) -> str:
    for unit in ("B", "KB", "MB"):
        if n < 1024:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GB"


def observer_options(args: argparse.Namespace) -> zenoh_config.ZenohOptions:
    """With no endpoint or config file given, join a deployment (`local` by default: `deploy up
    local` listens on tcp/127.0.0.1:7447) as the read-only observer, with its credentials."""
    explicit = args.connect or args.listen or args.zenoh_config or os.environ.get(zenoh_config.ENV_CONFIG)
    if explicit and not args.deployment:
        return zenoh_config.options_from_args(args)

    try:
        return join.deployment_options(args.deployment or "local", args.identity or "observer")
    except ValueError:
        if args.deployment:
            raise
    # the local deployment never made credentials (never started, or not secure): a plain client
    # (no router there: a one-line error rather than an empty table)
    return zenoh_config.options_from_args(args, mode="client", connect=(DEFAULT_ROUTER,))


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer monitor", description=__doc__.splitlines()[0])
    p.add_argument("keyexpr", nargs="?", default=f"{keys.ROOT}/**", help="key expression (default %(default)s)")
    p.add_argument("--json", action="store_true", help="stream decoded messages as JSON lines")
    p.add_argument("--once", action="store_true", help="print one snapshot after --duration seconds and exit")
    p.add_argument("--duration", type=float, default=2.0, help="collection time for --once (default %(default)s s)")
    p.add_argument("--period", type=float, default=1.0, help="table refresh period (default %(default)s s)")
    p.add_argument("--foxglove", action="store_true",
                   help="serve the topics live over the Foxglove WebSocket protocol (open ws://HOST:PORT in Foxglove)")
    p.add_argument("--port", type=int, default=8765, help="Foxglove WebSocket port (default %(default)s)")
    p.add_argument("--host", default="127.0.0.1",
                   help="Foxglove WebSocket address (default %(default)s: this machine only; any other address "
                        "needs an access token)")
    p.add_argument("--token-file", default=None, metavar="FILE",
                   help=f"Foxglove access token (first line of FILE; or ${TOKEN_ENV}): clients connect with "
                        "ws://HOST:PORT/?token=TOKEN or 'Authorization: Bearer TOKEN'")
    p.add_argument("--foxglove-cert", default=None, metavar="PEM",
                   help="serve Foxglove over TLS (wss://) with this certificate (with --foxglove-key)")
    p.add_argument("--foxglove-key", default=None, metavar="PEM", help="the certificate's private key")
    p.add_argument("--deployment", default=None, metavar="CONFIG",
                   help="join this running deployment (config name or file) as the read-only 'observer' "
                        "(default, when no endpoint is given: local)")
    zenoh_config.add_arguments(p)
    args = p.parse_args(argv)
    try:
        opts = observer_options(args)
    except join.NotRunningError as e:  # nothing to watch: one line, like a router that does not answer
        print(f"cinetransfer monitor: {e}", file=sys.stderr)
        return 1
    except ValueError as e:  # a bad setting, not a bad flag: one line, no usage
        print(f"cinetransfer monitor: {e}", file=sys.stderr)
        return 2
    stop = StopSignal().install()  # a handler that sets an Event can deadlock (stopsignal.py)
    if args.foxglove:
        return _serve_foxglove(opts, args, stop)
    with zenoh_config.open_session(opts) as session:
        mon = Monitor(session, args.keyexpr, json_out=args.json)
        try:
            if args.once:
                stop.wait(args.duration)
                if not args.json:
                    print(mon.table())
            elif args.json:
                stop.wait()
            else:
                tty = sys.stdout.isatty()
                while not stop.wait(args.period):
                    if tty:
                        sys.stdout.write("\x1b[2J\x1b[H")
                    sys.stdout.write(mon.table() + "\n\n")
                    sys.stdout.flush()
        finally:
            mon.close()
    return 0


def foxglove_token(path: str | None) -> str | None:
    """The access token: the first line of `path`, else $CINETRANSFER_FOXGLOVE_TOKEN, else None."""
    if path:
        try:
            token = open(path, encoding="utf-8").readline().strip()
        except OSError as e:
            raise ValueError(f"cannot read the token file: {e}") from None
        if not token:
            raise ValueError(f"the token file {path} is empty")
        return token
    return os.environ.get(TOKEN_ENV, "").strip() or None


def _serve_foxglove(opts: zenoh_config.ZenohOptions, args: argparse.Namespace, stop: StopSignal) -> int:
    from cinetransfer.foxglove_front import check_exposure
    from cinetransfer.foxglove_live import FoxgloveLive

    try:
        token = foxglove_token(args.token_file)
        check_exposure(args.host, token)
        if bool(args.foxglove_cert) != bool(args.foxglove_key):
            raise ValueError("--foxglove-cert and --foxglove-key go together")
        tls = (args.foxglove_cert, args.foxglove_key) if args.foxglove_cert else None
    except ValueError as e:
        print(f"cinetransfer monitor: {e}", file=sys.stderr)
        return 2
    with zenoh_config.open_session(opts) as session:
        try:
            live = FoxgloveLive(session, args.keyexpr, host=args.host, port=args.port, token=token, tls=tls)
        except RuntimeError as e:  # the port is taken, say
            print(f"cinetransfer monitor: cannot serve Foxglove on {args.host}:{args.port}: {e}", file=sys.stderr)
            return 1
        except ValueError as e:  # a certificate that does not load
            print(f"cinetransfer monitor: {e}", file=sys.stderr)
            return 2
        scheme = "wss" if tls else "ws"
        print(f"serving {args.keyexpr} to Foxglove at {scheme}://{args.host}:{live.port} (Ctrl-C to stop)", flush=True)
        try:
            stop.wait()
        finally:
            live.close()
    return 0
