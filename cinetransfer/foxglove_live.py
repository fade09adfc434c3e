"""The rig's topics live in Foxglove: `cinetransfer monitor --foxglove [--port P]`.

A Foxglove WebSocket server (foxglove-sdk, on 127.0.0.1 by default) carries the same channels a
recording has (cinetransfer/runlog.py `views`): our messages as JSON with their generated schemas,
camera frames as foxglove.CompressedImage (JPEG), poses as foxglove.FrameTransform, the lens as
foxglove.CameraCalibration. In Foxglove: Open connection -> Foxglove WebSocket ->
ws://127.0.0.1:8765.

The Zenoh callback only enqueues into a bounded drop-oldest queue; one worker thread translates
and logs, so a slow viewer never holds up the bus.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

from cinetransfer import runlog

log = logging.getLogger("cinetransfer.monitor.foxglove")

QUEUE_LEN = 256


class FoxgloveLive:
    """Serves everything matching `keyexpr` over the Foxglove WebSocket protocol."""

    def __init__(self, session: Any, keyexpr: str, *, host: str = "127.0.0.1", port: int = 8765,
                 jpeg_quality: int = runlog.JPEG_QUALITY) -> None:
        import foxglove

        self._fg = foxglove
        self.ctx = foxglove.Context()
        self.server = foxglove.start_server(name="cinetransfer", host=host, port=port, context=self.ctx)
        self.port = self.server.port
        self.jpeg_quality = jpeg_quality
        self._channels: dict[tuple[str, str, str], Any] = {}
        self._q: queue.Queue = queue.Queue(maxsize=QUEUE_LEN)
        self.dropped = 0
        self.logged = 0
        self._worker = threading.Thread(target=self._work, name="foxglove-live", daemon=True)
        self._worker.start()
        self._sub = session.declare_subscriber(keyexpr, self._on)

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
                self.logged += 1
            except Exception:  # noqa: BLE001 - one bad message must not end the live view
                log.exception("could not forward a message on %s", key)

    def close(self) -> None:
        self._sub.undeclare()
        self._q.put(None)
        self._worker.join(5.0)
        for ch in self._channels.values():
            ch.close()
        self.server.stop()
