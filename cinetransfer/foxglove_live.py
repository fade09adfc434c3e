"""The rig's topics live in Foxglove: `cinetransfer monitor --foxglove [--port P]`.

A Foxglove WebSocket server (foxglove-sdk) carries the same channels a recording has
(cinetransfer/runlog.py `views`): our messages as JSON with their generated schemas, camera frames as
foxglove.CompressedImage (JPEG), poses as foxglove.FrameTransform, the lens as
foxglove.CameraCalibration. In Foxglove: Open connection -> Foxglove WebSocket ->
ws://127.0.0.1:8765.

Clients reach it through cinetransfer/foxglove_front.py, which accepts both subprotocol names
(`foxglove.sdk.v1` and `foxglove.websocket.v1`), off loopback requires an access token, and with
a certificate and key serves `wss://`.
Capabilities advertised: `time` (the vehicle's clock: each VehicleState's stamp, simulation time
in lockstep) and `connectionGraph` (the live nodes, from their liveliness tokens, with the keys
deploy/dataflow.yaml says they publish and subscribe).

The Zenoh callback only enqueues into a bounded drop-oldest queue; one worker thread translates
and logs, so a slow viewer never holds up the bus.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

from foxglove.websocket import ServerListener

from cinetransfer import runlog
from cinetransfer.shared import jsonmsg, keys
from cinetransfer.shared import messages as M

log = logging.getLogger("cinetransfer.monitor.foxglove")

QUEUE_LEN = 256
VEHICLE_SCHEMA = jsonmsg.schema_name(M.VehicleState)


class FoxgloveLive:
    """Serves everything matching `keyexpr` over the Foxglove WebSocket protocol."""

    def __init__(self, session: Any, keyexpr: str, *, host: str = "127.0.0.1", port: int = 8765,
                 jpeg_quality: int = runlog.JPEG_QUALITY, token: str | None = None,
                 tls: tuple[str, str] | None = None) -> None:
        import foxglove
        from foxglove.websocket import Capability

        from cinetransfer.foxglove_front import FoxgloveFront, check_exposure

        check_exposure(host, token)
        self._fg = foxglove
        self.ctx = foxglove.Context()
        self.graph = LiveGraph()
        self.server = foxglove.start_server(name="cinetransfer", host="127.0.0.1", port=0, context=self.ctx,
                                            capabilities=[Capability.Time, Capability.ConnectionGraph],
                                            server_listener=self.graph)
        self.graph.server = self.server
        try:
            self.front = FoxgloveFront(self.server.port, host=host, port=port, token=token, tls=tls)
        except (OSError, ValueError) as e:
            self.server.stop()
            if isinstance(e, ValueError):
                raise
            raise RuntimeError(str(e)) from e
        self.port = self.front.port
        self.jpeg_quality = jpeg_quality
        self._channels: dict[tuple[str, str, str], Any] = {}
        self._q: queue.Queue = queue.Queue(maxsize=QUEUE_LEN)
        self.dropped = 0
        self.logged = 0
        self._worker = threading.Thread(target=self._work, name="foxglove-live", daemon=True)
        self._worker.start()
        self._sub = session.declare_subscriber(keyexpr, self._on)
        self._alive = session.liveliness().declare_subscriber(f"{keys.ROOT}/*/alive/*", self.graph.on_alive,
                                                              history=True)

    def _on(self, sample: Any) -> None:
        item = (str(sample.key_expr), sample.payload.to_bytes(), time.time_ns())
        while True:
            try:
                self._q.put_nowait(item)
                return
            except queue.Full:
                try:
                    self._q.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def _channel(self, v: runlog.View) -> Any:
        ck = (v.topic, v.schema_name, v.message_encoding)
        ch = self._channels.get(ck)
        if ch is None:
            schema = self._fg.Schema(name=v.schema_name, encoding=v.schema_encoding, data=v.schema_data) \
                if v.schema_encoding else None
            ch = self._fg.Channel(v.topic, schema=schema, message_encoding=v.message_encoding, context=self.ctx,
                                  metadata={runlog.ROLE: v.role})
            self._channels[ck] = ch
        return ch

    def _work(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            key, payload, t_ns = item
            try:
                for v in runlog.views(key, payload, jpeg_quality=self.jpeg_quality):
                    self._channel(v).log(v.data, log_time=t_ns)
                    if v.schema_name == VEHICLE_SCHEMA and v.stamp_ns > 0:
                        self.server.broadcast_time(v.stamp_ns)
                self.logged += 1
            except Exception:  # noqa: BLE001 - one bad message must not end the live view
                log.exception("could not forward a message on %s", key)

    def close(self) -> None:
        self._sub.undeclare()
        self._alive.undeclare()
        self._q.put(None)
        self._worker.join(5.0)
        for ch in self._channels.values():
            ch.close()
        self.front.close()
        self.server.stop()


class LiveGraph(ServerListener):
    """The connection graph: which live node publishes and subscribes which key. Built from the
    liveliness tokens (ct/RIG/alive/NODE) and each node's declared inputs and outputs; sent to
    the clients that ask for it (Foxglove's Topic Graph panel; the server keeps the latest graph and
    sends it to each client that subscribes)."""

    def __init__(self) -> None:
        from cinetransfer.shared import dataflow

        self.flow = dataflow.load()
        self.alive: set[str] = set()
        self.server: Any = None
        self._lock = threading.Lock()

    def on_alive(self, sample: Any) -> None:
        import zenoh

        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(str(sample.key_expr))
            else:
                self.alive.discard(str(sample.key_expr))
        self.publish()

    def topics(self) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
        """({key: publishing nodes}, {key: subscribing nodes}) of the live nodes."""
        pubs: dict[str, set[str]] = {}
        subs: dict[str, set[str]] = {}
        with self._lock:
            tokens = sorted(self.alive)
        for token in tokens:
            parts = token.split("/")
            node = self.flow.nodes.get(parts[3]) if len(parts) == 4 else None
            if node is None:
                continue
            for t in node.outputs:
                pubs.setdefault(t.key(parts[1]), set()).add(f"{parts[1]}/{node.name}")
            for t in node.inputs:
                subs.setdefault(t.key(parts[1]), set()).add(f"{parts[1]}/{node.name}")
        return pubs, subs

    def publish(self) -> None:
        from foxglove.websocket import ConnectionGraph

        if self.server is None:
            return
        pubs, subs = self.topics()
        graph = ConnectionGraph()
        for key, ids in pubs.items():
            graph.set_published_topic(key, sorted(ids))
        for key, ids in subs.items():
            graph.set_subscribed_topic(key, sorted(ids))
        self.server.publish_connection_graph(graph)

    # foxglove.websocket.ServerListener: with a listener, the server answers a subscription with
    # the latest graph itself (publishing from inside this callback would deadlock the server)
    def on_connection_graph_subscribe(self) -> None:
        log.debug("a client subscribed to the connection graph")
