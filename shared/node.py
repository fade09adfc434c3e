"""Node runtime: the plumbing every service shares.

    with Node("smoother", rig, zenoh_opts, config=cfg) as node:
        inbox = node.subscribe(keys.MEASUREMENT, maxlen=256)
        pub = node.publisher(keys.INSTRUCTIONS)
        node.ready()                      # liveliness token: slow set-up is finished
        while node.running:
            msg = inbox.get(timeout=0.1)  # decoded & validated, or None
            if msg is None:
                continue
            with node.timed():
                out = core.step(msg)
            pub.put(out)

What it gives a service:
- a Zenoh session opened from shared flags and closed on exit (a session left open can hang
  the interpreter at exit);
- SIGINT/SIGTERM → `node.running` becomes False → the service leaves its loop and exits 0
  (the handler only stores a flag: shared/stopsignal.py says why; waits poll it every 0.1 s);
- subscribers whose callbacks only enqueue raw payloads into bounded queues (drop-oldest for
  frames and states, no-drop for commands); decoding happens in the service thread, and a
  payload that fails to decode is counted as rejected, logged (rate-limited) and skipped;
- `node.guard(key)`: a block that handles one message, where any exception is counted as a
  rejection and logged with the key instead of ending the loop;
- publishers that stamp `seq` and count what they send;
- `node.consistent()`: a block (one control tick, say) during which no Health report is taken,
  so a report never holds half of a tick's counts (a rejection without its own counter);
- a liveliness token `ct/{rig}/alive/{node}` and a Health message every `health_period_s` on
  `ct/{rig}/health/{node}` (received, rejected, dropped, published, latency, last error, and
  node-specific counters);
- the effective config answered on the `ct/{rig}/{node}/config` query.
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import dataclasses
import json
import logging
import threading
import time
from typing import Any, Callable, Iterator

import zenoh

from cinetransfer.shared import codec, keys
from cinetransfer.shared import messages as M
from cinetransfer.shared.stopsignal import StopSignal
from cinetransfer.shared.zenoh_config import ZenohOptions, add_arguments, open_session, options_from_args

NO_DROP_CAP = 100_000  # a no-drop queue past this is a bug upstream; it then drops and says so


def add_node_arguments(parser: argparse.ArgumentParser, *, default_rig: str = "rig0") -> None:
    """Flags every node takes: rig, logging, health period, and the Zenoh flags."""
    parser.add_argument("--rig", default=default_rig, type=rig_name,
                        help="rig (vehicle) name used in keys (default %(default)s)")
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    parser.add_argument("--health-period", type=float, default=1.0, metavar="S",
                        help="seconds between Health messages (default %(default)s)")
    add_arguments(parser)


def rig_name(text: str) -> str:
    """argparse type of a rig name: one clear usage error instead of a traceback from the first key."""
    try:
        return keys.rig_name(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def setup_logging(level: str = "INFO") -> None:
    logging.basicConfig(level=getattr(logging, level), format="%(asctime)s %(levelname)s %(name)s: %(message)s")


class RateLimitedLog:
    """Logs a repeating warning at most once per `period_s`, with how many were suppressed."""

    def __init__(self, logger: logging.Logger, period_s: float = 5.0) -> None:
        self.logger, self.period_s = logger, period_s
        self._last: dict[str, float] = {}
        self._suppressed: collections.Counter[str] = collections.Counter()

    def warning(self, kind: str, msg: str) -> None:
        now = time.monotonic()
        if now - self._last.get(kind, -1e9) >= self.period_s:
            n = self._suppressed.pop(kind, 0)
            self.logger.warning("%s%s", msg, f" (+{n} similar suppressed)" if n else "")
            self._last[kind] = now
        else:
            self._suppressed[kind] += 1


class Inbox:
    """A bounded queue of raw payloads filled by a Zenoh callback, decoded on `get`."""

    def __init__(self, node: "Node", key: str, msg_type: type | None, maxlen: int, policy: str) -> None:
        if policy not in ("drop-oldest", "no-drop"):
            raise ValueError(f"queue policy {policy!r} must be 'drop-oldest' or 'no-drop'")
        self.node, self.key, self.msg_type, self.policy = node, key, msg_type, policy
        self.maxlen = maxlen if policy == "drop-oldest" else NO_DROP_CAP
        self._q: collections.deque[tuple[bytes, str, float]] = collections.deque()
        self.received = 0
        self.dropped = 0
        self.last_rx_mono: float | None = None
        self._sub: Any = None

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Runs on a Zenoh thread: enqueue only, never compute or call Zenoh.
        item = (sample.payload.to_bytes(), str(sample.key_expr), time.monotonic())
        with self.node._cond:
            if len(self._q) >= self.maxlen:
                self._q.popleft()
                self.dropped += 1
                self.node._dropped += 1
            self._q.append(item)
            self.received += 1
            self.node._received += 1
            self.last_rx_mono = item[2]
            self.node._cond.notify_all()

    def __len__(self) -> int:
        return len(self._q)

    def get_raw(self, timeout: float | None = 0.0) -> tuple[bytes, str, float] | None:
        """Oldest (payload, key, receive time) or None after `timeout` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self.node._cond:
            while not self._q:
                remaining = None if deadline is None else deadline - time.monotonic()
                if (remaining is not None and remaining <= 0) or not self.node.running:
                    return None
                self.node._cond.wait(0.1 if remaining is None else min(remaining, 0.1))
            return self._q.popleft()

    def get(self, timeout: float | None = 0.0) -> Any:
        """Oldest valid decoded message, or None. Malformed payloads are counted and skipped."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            item = self.get_raw(remaining)
            if item is None:
                return None
            msg = self.node.decode(item[0], self.msg_type, item[1])
            if msg is not None:
                return msg

    def get_all(self, timeout: float) -> list[Any]:
        """Wait up to `timeout` for something, then every queued valid message, oldest first."""
        first = self.get(timeout)
        return [] if first is None else [first, *self.drain()]

    def drain(self) -> list[Any]:
        """Every queued valid message, oldest first."""
        out = []
        while True:
            item = self.get_raw(0.0)
            if item is None:
                return out
            msg = self.node.decode(item[0], self.msg_type, item[1])
            if msg is not None:
                out.append(msg)

    def latest(self) -> Any:
        """The newest valid message in the queue (older ones are discarded), or None."""
        out = None
        for msg in self.drain():
            out = msg
        return out

    def age_s(self) -> float:
        """Seconds since the last sample arrived (inf if none yet)."""
        return float("inf") if self.last_rx_mono is None else time.monotonic() - self.last_rx_mono


class Presence:
    """Whether a named node of the rig is alive (its liveliness token), kept by a subscriber."""

    def __init__(self, session: zenoh.Session, rig: str, node: str) -> None:
        self.alive = False
        self.losses = 0  #: times the token went away (a restart between two looks still counts)
        self._sub = session.liveliness().declare_subscriber(keys.alive(rig, node), self._on, history=True)

    def _on(self, sample: zenoh.Sample) -> None:  # Zenoh thread: only flips a flag and counts
        self.alive = sample.kind == zenoh.SampleKind.PUT
        self.losses += not self.alive

    def undeclare(self) -> None:
        self._sub.undeclare()


class Publisher:
    """Encodes, stamps `seq` and publishes messages of one key."""

    def __init__(self, node: "Node", key: str, jpeg_quality: int | None, drop: bool) -> None:
        self.node, self.key, self.jpeg_quality = node, key, jpeg_quality
        cc = zenoh.CongestionControl.DROP if drop else zenoh.CongestionControl.BLOCK
        self._pub = node.session.declare_publisher(key, congestion_control=cc, express=True)
        self.seq = 0
        self.published = 0

    def put(self, msg: Any) -> None:
        if dataclasses.is_dataclass(msg):
            msg = dataclasses.replace(msg, seq=self.seq)
            payload = codec.encode(msg, jpeg_quality=self.jpeg_quality)
        else:
            payload = bytes(msg)  # raw bytes: tests of rejection, replay of recorded payloads
        self._pub.put(payload)
        self.seq += 1
        self.published += 1
        self.node._published += 1

    def undeclare(self) -> None:
        self._pub.undeclare()


class Node:
    """A service's session, queues, publishers, liveliness token and Health reporting."""

    def __init__(self, name: str, rig: str, zenoh_options: ZenohOptions, *, config: Any = None,
                 health_period_s: float = 1.0, install_signal_handlers: bool = True) -> None:
        self.name, self.rig, self.zopts, self.config = name, rig, zenoh_options, config
        keys.health(rig, name)  # validates both names early
        self.health_period_s = health_period_s
        self.log = logging.getLogger(f"cinetransfer.{name}")
        self.rl = RateLimitedLog(self.log)
        self.session: zenoh.Session | None = None
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._health_lock = threading.RLock()
        self._received = self._rejected = self._dropped = self._published = 0
        self._latencies: collections.deque[float] = collections.deque(maxlen=1000)
        self.last_error = ""
        self.counters: dict[str, Any] = {}
        #: simulation time of the newest clock tick this node has seen (None: no clock, wall time)
        self.clock_ns: int | None = None
        self.healthy = True
        self._inboxes: list[Inbox] = []
        self._publishers: list[Publisher] = []
        self._decls: list[Any] = []
        self._token: Any = None
        self._health_pub: Publisher | None = None
        self._health_thread: threading.Thread | None = None
        self._t0 = time.monotonic()
        self._install_signals = install_signal_handlers
        self._signals: StopSignal | None = None

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> "Node":
        if self._install_signals and threading.current_thread() is threading.main_thread():
            self._signals = StopSignal().install()
        self.session = open_session(self.zopts)
        self._health_pub = Publisher(self, keys.health(self.rig, self.name), None, drop=True)
        self._decls.append(self.session.declare_queryable(keys.config(self.rig, self.name), self._on_config_query))
        self._health_thread = threading.Thread(target=self._health_loop, name=f"{self.name}-health", daemon=True)
        self._health_thread.start()
        if self.config is not None:
            self.log.info("effective config: %s", self._config_json())
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
        if self._health_thread is not None:
            self._health_thread.join(timeout=2.0)
        try:
            if self._health_pub is not None:
                self._publish_health()
        except zenoh.ZError:
            pass
        for obj in [self._token, *self._decls, *(i._sub for i in self._inboxes), *self._publishers]:
            if obj is None:
                continue
            with contextlib.suppress(Exception):  # already gone on a dying session: nothing to undo
                obj.undeclare()
        if self.session is not None:
            self.session.close()
            self.session = None
        if self._signals is not None:
            self._signals.restore()
        self.log.info("stopped")

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    @property
    def running(self) -> bool:
        if self._signals is not None and self._signals.is_set() and not self._stop.is_set():
            self.log.info("received %s, shutting down", self._signals.name())  # here, not in the handler
            self.stop()
        return not self._stop.is_set()

    def sleep(self, seconds: float) -> bool:
        """Sleep unless stopped; returns `running`."""
        deadline = time.monotonic() + seconds
        while self.running and (left := deadline - time.monotonic()) > 0:
            self._stop.wait(min(left, 0.1))  # a signal only sets a flag: look at it every 0.1 s
        return self.running

    def sleep_until(self, seconds: float, wake: Callable[[], bool]) -> bool:
        """Sleep like `sleep`, but return as soon as `wake()` is true (a command must not wait for
        the end of a long pacing sleep): looked at on every message an inbox receives and at least
        every 0.1 s. Returns `running`."""
        deadline = time.monotonic() + seconds
        with self._cond:
            while self.running and not wake() and (left := deadline - time.monotonic()) > 0:
                self._cond.wait(min(left, 0.1))  # a signal only sets a flag: look at it every 0.1 s
        return self.running

    def ready(self) -> None:
        """Declare the liveliness token: call once slow set-up is done."""
        self._token = self.session.liveliness().declare_token(keys.alive(self.rig, self.name))
        self.log.info("ready as %s", keys.alive(self.rig, self.name))

    # ------------------------------------------------------------------ pub/sub
    def _resolve(self, topic: keys.Topic | str) -> tuple[str, type | None, str]:
        if isinstance(topic, keys.Topic):
            return topic.key(self.rig), topic.msg_type, topic.policy
        t = keys.topic_for_key(topic)
        return topic, (t.msg_type if t else None), (t.policy if t else "drop-oldest")

    def subscribe(self, topic: keys.Topic | str, *, msg_type: type | None = None, maxlen: int = 8,
                  policy: str | None = None) -> Inbox:
        key, tp, pol = self._resolve(topic)
        inbox = Inbox(self, key, msg_type or tp, maxlen, policy or pol)
        inbox._sub = self.session.declare_subscriber(key, inbox._on_sample)
        self._inboxes.append(inbox)
        return inbox

    def publisher(self, topic: keys.Topic | str, *, jpeg_quality: int | None = None,
                  block: bool | None = None) -> Publisher:
        """`block`: congestion control (default: drop for drop-oldest topics, block otherwise)."""
        key, _, pol = self._resolve(topic)
        drop = (pol == "drop-oldest") if block is None else not block
        pub = Publisher(self, key, jpeg_quality, drop=drop)
        self._publishers.append(pub)
        return pub

    def wait(self, timeout: float) -> None:
        """Block until any inbox receives something, the node stops, or `timeout` passes."""
        with self._cond:
            if self.running and not any(len(i) for i in self._inboxes):
                self._cond.wait(min(timeout, 0.1))  # callers loop; a signal is seen within 0.1 s

    def decode(self, payload: bytes, msg_type: type | None, key: str = "?") -> Any:
        try:
            return codec.decode(payload, msg_type)
        except codec.DecodeError as e:
            self.reject(f"{key}: {e}")
            return None

    @contextlib.contextmanager
    def guard(self, key: str, what: str = "message") -> Iterator[None]:
        """Handle one input guardedly: any Exception raised in the block is counted as a
        rejection, logged (rate-limited) with `key`, and swallowed, so the loop carries on.

            for cmd in cmd_in.drain():
                with node.guard(cmd_in.key, "command"):
                    handle(cmd)

        A bug in a handler then costs one message, not the service (STYLE §7); the traceback
        is kept at DEBUG level so it can still be found.
        """
        try:
            yield
        except Exception as e:
            self.log.debug("%s on %s", what, key, exc_info=True)
            self.reject(f"{key}: {what} failed: {type(e).__name__}: {str(e)[:200]}")

    def reject(self, reason: str) -> None:
        """Count and log (rate-limited) a rejected input; the node carries on."""
        with self._cond:
            self._rejected += 1
        self.last_error = reason
        self.rl.warning("reject", f"rejected message: {reason}")

    def error(self, reason: str, kind: str = "error") -> None:
        """Record a non-fatal processing error (rate-limited log)."""
        self.last_error = reason
        self.rl.warning(kind, reason)

    # ------------------------------------------------------------------ time
    def now_ns(self) -> int:
        """'Now' for stamps: the simulation clock when the node follows one, else the wall clock."""
        return M.now_ns() if self.clock_ns is None else self.clock_ns

    # ------------------------------------------------------------------ health
    @contextlib.contextmanager
    def timed(self) -> Iterator[None]:
        t = time.perf_counter()
        try:
            yield
        finally:
            self._latencies.append((time.perf_counter() - t) * 1e3)

    @contextlib.contextmanager
    def consistent(self) -> Iterator[None]:
        """No Health report is taken inside this block: counts updated together are reported together."""
        with self._health_lock:
            yield

    def record_latency_ms(self, ms: float) -> None:
        self._latencies.append(ms)

    def stats(self) -> dict[str, int]:
        return {"received": self._received, "rejected": self._rejected, "dropped": self._dropped,
                "published": self._published}

    def health(self) -> M.Health:
        lat = sorted(self._latencies)
        self._latencies.clear()
        p50 = lat[len(lat) // 2] if lat else float("nan")
        mx = lat[-1] if lat else float("nan")
        counters = {k: v for k, v in self.counters.items() if isinstance(v, (str, int, float, bool))}
        return M.Health(stamp_ns=self.now_ns(), valid=self.healthy, node=self.name,
                        uptime_s=time.monotonic() - self._t0, latency_ms_p50=p50, latency_ms_max=mx,
                        last_error=self.last_error[:500], counters=counters, **self.stats())

    def publish_health_now(self) -> None:
        """Publish Health at once (e.g. to acknowledge a command) instead of at the next period."""
        try:
            self._publish_health()
        except (zenoh.ZError, codec.CodecError) as e:
            self.error(f"health publish failed: {e}", "health")

    def _publish_health(self) -> None:
        assert self._health_pub is not None
        with self._health_lock:  # the periodic thread and publish_health_now() may meet
            h = self.health()
            self._health_pub.put(h)
            # Health messages themselves are not part of the node's published count.
            self._published -= 1

    def _health_loop(self) -> None:
        while not self._stop.wait(self.health_period_s):
            try:
                self._publish_health()
            except (zenoh.ZError, codec.CodecError) as e:
                self.error(f"health publish failed: {e}", "health")

    def _config_json(self) -> str:
        cfg = self.config
        if dataclasses.is_dataclass(cfg):
            cfg = dataclasses.asdict(cfg)
        return json.dumps(cfg, default=str, sort_keys=True)

    def _on_config_query(self, query: zenoh.Query) -> None:
        query.reply(keys.config(self.rig, self.name), self._config_json())


def node_from_args(name: str, args: argparse.Namespace, *, config: Any = None, **zenoh_defaults: Any) -> Node:
    """Node built from the flags of `add_node_arguments`."""
    setup_logging(args.log_level)
    return Node(name, args.rig, options_from_args(args, **zenoh_defaults), config=config,
                health_period_s=args.health_period)


def call_periodically(period_s: float, node: Node, fn: Callable[[], None], *,
                      until: Callable[[], bool] | None = None) -> None:
    """Run `fn` every `period_s` (drift-free) until the node stops (or `until()` is true)."""
    nxt = time.monotonic()
    while node.running and not (until is not None and until()):
        fn()
        nxt += period_s
        delay = nxt - time.monotonic()
        if delay < -period_s:  # fell far behind (e.g. suspended): resynchronise, don't burst
            nxt = time.monotonic()
            delay = 0.0
        node.sleep(max(0.0, delay))
