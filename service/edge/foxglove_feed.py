"""Live view in Foxglove: the daemon's (or a replay's) channels over the Foxglove WebSocket
protocol (``foxglove.websocket.v1``, served by the ``foxglove-sdk`` package).

Per actuator, the channels are the MCAP log's topics ``/fleet/{aircraft}/{actuator}/{meas,
est,residual,health,events}`` in the log's encodings: protobuf rows with the log's schemas
(``service.log.row_schema``: the FileDescriptorSet of ``servowatch.Meas``, ``.Est``, ...) and
``servowatch.Event`` rows for the events (``service.log.events``), with the log's message bytes, time-stamped with the sample
time, so a Foxglove layout works on a log and live alike (docs/dashboard.md).

A viewer never slows the monitor:

* :meth:`FoxgloveFeed.log_block` and :meth:`FoxgloveFeed.log` (the McapLogger calls the
  fan-out makes) return at once when no viewer subscribed to the topic: nothing is encoded;
* otherwise they queue the arrays (a reference, no copy, no encoding) in a bounded queue;
  messages that do not fit are dropped and counted (``dropped``, in ``servowatch status``);
* ``every`` N > 1 sends one message in N per topic (a Plot panel needs no more than a
  screen's worth; events always go, and N = 1 sends all);
* one feeder thread, every 25 ms, encodes the queued rows (the log's protobuf layout) and hands them
  to the SDK, whose server keeps a bounded backlog per client and drops a slow client's
  oldest messages (``message_backlog_size``); nothing waits on a socket.
"""

from __future__ import annotations

import json
import logging
import threading
from collections import deque
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from service.edge.foxglove_guard import GuardLimits, start_guarded
from service.log.events import EventLayout, encode_event
from service.log.proclog import MEAS_LOG_FIELDS
from service.log.rows import RowLayout
from service.log.writer import encode_message, row_schema
from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS
from service.wire import messages as m

__all__ = ["FoxgloveFeed", "LEAVES", "topic_schemas", "DEFAULT_QUEUE"]

log = logging.getLogger("servowatch.foxglove")

#: the per-actuator topic leaves served live, as in the MCAP log
LEAVES = ("meas", "est", "residual", "health", "events")
#: messages waiting for the feeder thread at most (beyond: dropped and counted)
DEFAULT_QUEUE = 20_000
_PERIOD_S = 0.025  # the feeder thread's period: what is queued is sent within this


def topic_schemas(aircraft: str, actuator: str) -> dict[str, RowLayout | dict[str, Any]]:
    """Topic -> what the MCAP log gives it, for the channels of one actuator: the protobuf
    row layout (``.message``, ``.schema``) of meas, est, residual and health, the
    ``servowatch.Event`` layout of events."""
    topic = {leaf: m.mcap_topic(aircraft, actuator, leaf) for leaf in LEAVES}
    return {
        topic["meas"]: row_schema(topic["meas"], MEAS_LOG_FIELDS, ("seq",)),
        topic["est"]: row_schema(topic["est"], EST_KEYS),
        topic["residual"]: row_schema(topic["residual"], RES_KEYS),
        topic["health"]: row_schema(topic["health"], HEALTH_KEYS),
        topic["events"]: EventLayout(),  # servowatch.Event rows (decision 0043)
    }


def encode_rows(
    topic: str,
    t: np.ndarray,
    names: tuple[str, ...],
    values: np.ndarray,
    int_fields: Iterable[str] = (),
) -> tuple[np.ndarray, list[bytes]]:
    """(log times [ns], protobuf bytes of each row): the messages ``McapLogger.log_block``
    writes for these rows on ``topic``."""
    tt = np.asarray(t, np.float64).reshape(-1)
    lts = np.maximum(np.rint(tt * 1e9), 0.0).astype(np.int64)
    enc = row_schema(topic, names, int_fields).encode(values)
    b, size = enc.tobytes(), enc.shape[1]
    return lts, [b[k : k + size] for k in range(0, len(b), size)]


class FoxgloveFeed:
    """A Foxglove WebSocket server on ``host:port`` (0: any free port, see :attr:`port`)
    fed by a thread of its own from a queue of at most ``queue_size`` messages; of the rows
    of a topic, one in ``every`` is sent (events: all); ``backlog``: messages the server
    buffers per client (the oldest dropped beyond).

    Use :meth:`add_actuator` once per actuator (advertises its channels), then
    :meth:`log_block` / :meth:`log` as on a ``McapLogger``; :meth:`status` for the status,
    :meth:`close` at the end. ``host`` must already be checked (``service.edge.listen``).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8765,
        *,
        queue_size: int = DEFAULT_QUEUE,
        backlog: int = 1024,
        every: int = 1,
        name: str = "servowatch",
        limits: GuardLimits | None = None,
    ) -> None:
        import foxglove

        if int(queue_size) < 1 or int(every) < 1:
            raise ValueError("queue_size and every must be >= 1")
        self.every = int(every)
        self._count: dict[str, int] = {}  # rows offered per topic (for ``every``)
        self.queue_size = int(queue_size)
        self.host = host
        self._fg = foxglove
        self._ctx = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._queue: deque = deque()
        self._lock = threading.Lock()
        self._queued = 0  # messages in the queue
        self.sent = 0
        self.dropped = 0
        self.errors = 0
        self._wake = threading.Event()
        self._stop = threading.Event()
        # the SDK's server behind a guard on host:port (Host, Origin, limits: foxglove_guard)
        self.server, self.guard = start_guarded(
            foxglove, host, port, limits, name=name, context=self._ctx,
            message_backlog_size=int(backlog),
        )  # fmt: skip
        self.port = self.guard.port
        self._thread = threading.Thread(target=self._run, name="foxglove-feed", daemon=True)
        self._thread.start()
        log.info("Foxglove WebSocket server on ws://%s:%d", host, self.port)

    # -- channels -------------------------------------------------------------------------
    def add_actuator(self, aircraft: str, actuator: str) -> None:
        """Advertise the channels of an actuator (once; later calls do nothing)."""
        for topic, schema in topic_schemas(aircraft, actuator).items():
            if topic in self._channels:
                continue
            if isinstance(schema, RowLayout | EventLayout):
                sc = self._fg.Schema(name=schema.message, encoding="protobuf", data=schema.schema)
                enc = "protobuf"
            else:
                sc = self._fg.Schema(
                    name=topic.rsplit("/", 1)[-1],
                    encoding="jsonschema",
                    data=json.dumps(schema).encode(),
                )
                enc = "json"
            self._channels[topic] = self._fg.Channel(
                topic, schema=sc, message_encoding=enc, context=self._ctx
            )

    def wants(self, topic: str) -> bool:
        """Is some client subscribed to ``topic``? (The SDK's own subscription state: no
        server listener, so no SDK thread ever waits for the GIL.)"""
        ch = self._channels.get(topic)
        return ch is not None and ch.has_sinks()

    # -- the McapLogger calls ------------------------------------------------------------
    def _put(self, n: int, item: tuple) -> None:
        with self._lock:
            if self._queued + n > self.queue_size:
                self.dropped += n
                return
            self._queued += n
            self._queue.append(item)

    def log_block(
        self,
        topic: str,
        t: np.ndarray,
        names: Iterable[str],
        values: np.ndarray,
        *,
        int_fields: Iterable[str] = (),
    ) -> None:
        """Rows of ``values`` on ``topic`` at times ``t`` [s], as ``McapLogger.log_block``
        (one in ``every``); the arrays must not change afterwards (queued, not copied)."""
        if not len(t) or not self.wants(topic):
            return
        if self.every > 1:
            c = self._count.get(topic, 0)
            self._count[topic] = c + len(t)
            k0 = -c % self.every
            if k0 >= len(t):
                return
            t, values = t[k0 :: self.every], values[k0 :: self.every]
        self._put(len(t), (topic, t, tuple(names), values, tuple(int_fields)))

    def log(self, topic: str, t: float, msg: Mapping[str, Any]) -> None:
        """One message on ``topic`` at time ``t`` [s], as ``McapLogger.log``."""
        if self.wants(topic):
            self._put(1, (topic, t, None, dict(msg), ()))

    def log_event(self, topic: str, t: float, event: Mapping[str, Any]) -> None:
        """One event on ``topic`` at ``t`` [s], as ``McapLogger.log_event`` (the same
        ``servowatch.Event`` bytes)."""
        if self.wants(topic):
            self._put(1, (topic, t, "event", dict(event), ()))

    # -- the feeder thread ---------------------------------------------------------------
    def _run(self) -> None:
        q = self._queue
        while not self._stop.is_set():
            # polled, not woken per block: one switch to this thread per period, not one
            # per block (the worker is not interrupted to hand over the GIL)
            self._wake.wait(_PERIOD_S)
            self._wake.clear()
            while q:
                topic, t, names, vals, ints = q.popleft()
                n = 1 if names is None or isinstance(names, str) else len(t)
                try:
                    self._send(topic, t, names, vals, ints)
                except Exception as e:  # never let a message kill the feeder
                    self.errors += 1
                    log.warning("foxglove feed: %s: %s", topic, e)
                with self._lock:
                    self._queued -= n

    def _send(self, topic: str, t: Any, names: Any, vals: Any, ints: tuple) -> None:
        ch = self._channels.get(topic)
        if ch is None:
            return
        if names is None or names == "event":  # one message, one event
            data = encode_event(vals) if names == "event" else encode_message(vals)
            ch.log(data, log_time=max(0, int(round(float(t) * 1e9))))
            self.sent += 1
            return
        lts, datas = encode_rows(topic, t, names, vals, ints)
        for lt, data in zip(lts.tolist(), datas, strict=True):
            ch.log(data, log_time=lt)
        self.sent += len(datas)

    # -- status and end ------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """Listen address, channels, subscribed topics, messages sent, queued and dropped."""
        with self._lock:
            queued = self._queued
        return {
            "listen": f"{self.host}:{self.port}",
            "channels": len(self._channels),
            "subscribed_topics": sum(ch.has_sinks() for ch in list(self._channels.values())),
            "sent": self.sent,
            "queued": queued,
            "queue_size": self.queue_size,
            "dropped": self.dropped,
            "errors": self.errors,
            "guard": self.guard.status(),
        }

    def close(self, timeout: float = 2.0) -> None:
        """Stop the feeder thread and the server (idempotent). The SDK's ``stop`` waits for
        each client's backlog to be sent, which a stuck client never takes: it runs in a
        thread of its own, waited for at most ``timeout`` seconds."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake.set()
        self._thread.join(5)

        def stop() -> None:
            try:
                self.server.stop()
            except Exception as e:
                log.debug("foxglove server stop: %s", e)

        self.guard.close()
        th = threading.Thread(target=stop, name="foxglove-stop", daemon=True)
        th.start()
        th.join(timeout)
        if th.is_alive():
            log.warning("Foxglove server: a client did not take its messages; not waiting")

    def __enter__(self) -> FoxgloveFeed:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
