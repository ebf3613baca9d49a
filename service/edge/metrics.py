"""The daemon's OpenMetrics endpoint (``servowatch run --metrics HOST:PORT``, ``[metrics]``).

A Prometheus server scrapes ``GET /metrics``. Nothing is counted for it on the sample path:
one custom collector (:class:`StatusCollector`) reads the daemon's status snapshot
(``Daemon.status()``, the same as ``servowatch status`` gets over Zenoh) at scrape time and
turns it into metric families, so a sample costs the same with or without the endpoint.
The labels are the daemon's ``station`` and ``shard`` and, per unit, ``aircraft`` and
``actuator`` (and ``kind`` for an alarm): the series are bounded by the units the daemon
owns (at most ``service.daemon.intake.MAX_ACTUATORS``).

The server follows the fleet page's rules (docs/security.md, "HTTP"): loopback unless
``allow_remote``, and unless ``allow_remote`` a request whose Host header is not a loopback
name of this server is answered 421 (a DNS-rebinding page cannot read it); GET and HEAD
only. The metric names are listed in :data:`METRICS` (docs/dashboard.md, "Prometheus").

A scrape cannot starve the monitor (issue 50): the exposition is built at most once per
``max_age_s`` (1 s) by one thread, and every scrape in between is served that body, so any
number of scrapers cost the daemon one build a second; at most ``max_connections`` (8)
connections are served at once and ``max_per_s`` (10) a second, one request each (beyond:
503 and closed, without a thread), and one idle for ``idle_s`` (5 s) is closed. A unit whose names are not of the grammar
(``service.names``) gets no series.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Iterator
from http import HTTPStatus
from http.server import ThreadingHTTPServer
from typing import Any
from urllib.parse import urlsplit

from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
from prometheus_client.exposition import choose_encoder
from prometheus_client.registry import Collector, CollectorRegistry

from service.edge.fleet import condition_of
from service.edge.httpguard import GuardedHandler, loopback_names
from service.names import is_name

__all__ = ["METRICS", "MetricsServer", "StatusCollector", "collect_status"]

log = logging.getLogger("servowatch.metrics")

PREFIX = "servowatch_"

#: every metric family the endpoint serves: name (without the ``_total`` of a counter's
#: sample, with the ``_bucket``/``_sum``/``_count`` of the histogram left out) -> (type, help)
METRICS: dict[str, tuple[str, str]] = {
    # per daemon (labels station, shard)
    "info": ("gauge", "1, with the monitor model and the service state as labels"),
    "degraded": ("gauge", "1 when the MCAP log failed (samples no longer recorded), else 0"),
    "uptime_seconds": ("gauge", "seconds since the daemon started"),
    "units": ("gauge", "units this daemon monitors"),
    "silent_units": ("gauge", "units silent for longer than silence_s"),
    "samples": ("counter", "accepted samples, all units"),
    "dropped": ("counter", "messages dropped by the full receive queue"),
    "bad": ("counter", "samples refused as bad input (malformed, schema, clock, ...)"),
    "gaps": ("counter", "samples missing according to sequence numbers"),
    "missed": ("counter", "samples lost in transport that Zenoh could not recover"),
    "errors": ("counter", "internal errors counted (worker, monitor, outputs, callbacks)"),
    "queue_messages": ("gauge", "messages waiting in the receive queue"),
    "queue_high_messages": ("gauge", "the receive queue's high-water mark"),
    "queue_capacity_messages": ("gauge", "the receive queue's length"),
    "busy_ratio": ("gauge", "fraction of the uptime the worker was busy"),
    "latency_seconds": ("histogram", "receipt of a sample to its health output [s]"),
    "log_bytes": ("gauge", "bytes of the MCAP log files this daemon has written"),
    "log_failed": ("gauge", "1 when the MCAP log failed, else 0"),
    "log_kept_bytes": ("gauge", "bytes of this daemon's log files kept ([log] retention)"),
    "log_kept_files": ("gauge", "this daemon's log files kept ([log] retention)"),
    "log_deleted_bytes": ("counter", "bytes of log files the retention deleted"),
    "log_deleted_files": (
        "counter",
        "log files the retention deleted ([log] keep_bytes, keep_days)",
    ),
    "store_written": ("counter", "operating periods written to the health store"),
    "store_errors": ("counter", "failed writes to the health store"),
    "store_pending": ("gauge", "batches waiting for the health store writer"),
    "store_failed": ("gauge", "1 when the health store could not be opened, else 0"),
    "group_members": ("gauge", "members of the daemon's monitor group"),
    "group_takeovers": ("counter", "units this member took over from another"),
    "group_released": ("counter", "units this member handed to another"),
    "group_held_units": ("gauge", "units whose samples this member holds for a takeover"),
    "group_unmonitored_units": ("gauge", "units with measurements and no member's health"),
    "foxglove_subscribed_channels": (
        "gauge",
        "Foxglove channels at least one client subscribed to (the SDK counts no clients)",
    ),
    "foxglove_clients": ("gauge", "viewers connected to the live feed (through its guard)"),
    "foxglove_buffered_bytes": ("gauge", "bytes the live feed's guard holds for its viewers"),
    "foxglove_listener_ok": ("gauge", "1 while the live feed's listener accepts, else 0"),
    "foxglove_sent": ("counter", "messages sent to the Foxglove server"),
    "foxglove_dropped": ("counter", "Foxglove messages dropped by the full feeder queue"),
    # per unit (labels station, shard, aircraft, actuator)
    "unit_leak_ratio": ("gauge", "C_Lk over the unit's baseline C_Lk (the leak indicator)"),
    "unit_supply_ratio": ("gauge", "supply pressure P_SR over its rated value"),
    "unit_c_lk": ("gauge", "estimated internal leakage coefficient C_Lk [m^3/(s Pa)]"),
    "unit_c_lk_sigma": ("gauge", "1-sigma of C_Lk [m^3/(s Pa)]"),
    "unit_c_lk_pooled": (
        "gauge",
        "the pooled C_Lk within its observability limit (shown beside the indicator, "
        "not driving it) [m^3/(s Pa)]",
    ),
    "unit_c_lk_pooled_sigma": ("gauge", "1-sigma of the pooled C_Lk [m^3/(s Pa)]"),
    "unit_nis_in_band_ratio": (
        "gauge",
        "fraction of the outputs of the open operating period whose NIS lies in its 95 % band",
    ),
    "unit_alarm": ("gauge", "1 while the alarm of this kind (leak, supply) is raised, else 0"),
    "unit_silent": ("gauge", "1 when the unit has been silent for longer than silence_s"),
    "unit_commissioned": ("gauge", "1 when the unit has a baseline in the store, else 0"),
    "unit_baseline_version": ("gauge", "version of the baseline the unit is monitored on"),
    "unit_samples": ("counter", "accepted samples of the unit"),
    "unit_bad": ("counter", "samples of the unit refused as bad input"),
    "unit_gaps": ("counter", "samples of the unit missing according to sequence numbers"),
    "unit_dropped": ("counter", "messages of the unit dropped by the full receive queue"),
    "unit_rul_median_flights": ("gauge", "stored RUL median [flights] (history counts flights)"),
    "unit_rul_median_days": ("gauge", "stored RUL median [calendar days] where known"),
    "unit_rul_median_hours": ("gauge", "stored RUL median [operating hours] where known"),
    "unit_failed": (
        "gauge",
        "1 when the unit's latest stored C_Lk ratio is past its failure threshold",
    ),
}

_ALARM_KINDS = ("leak", "supply")


def _num(v: Any) -> float | None:
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, int | float) and math.isfinite(v):
        return float(v)
    return None


def _log_bytes(paths: Any) -> float:
    total = 0
    for p in paths or ():
        with contextlib.suppress(OSError):  # rotated away or not created yet
            total += os.stat(p).st_size
    return float(total)


class _Families:
    """The metric families of one scrape, made on first use."""

    def __init__(self, base: list[str]) -> None:
        self.base = base
        self.f: dict[str, Metric] = {}

    def add(self, name: str, value: Any, labels: list[str] = (), extra: list[str] = ()) -> None:
        """One sample of family ``name`` (``METRICS``); None/NaN values are left out."""
        v = _num(value)
        if v is None:
            return
        fam = self.f.get(name)
        if fam is None:
            kind, help_ = METRICS[name]
            cls = CounterMetricFamily if kind == "counter" else GaugeMetricFamily
            fam = self.f[name] = cls(PREFIX + name, help_, labels=[*self.base, *extra])
        fam.add_metric(labels, v)


def collect_status(st: dict[str, Any]) -> list[Metric]:
    """The metric families of one daemon status snapshot (``Daemon.status()``)."""
    base = ["station", "shard"]
    d = [str(st.get("station")), str(st.get("shard"))]
    f = _Families(base)
    info = GaugeMetricFamily(PREFIX + "info", METRICS["info"][1], labels=[*base, "model", "state"])
    info.add_metric([*d, str(st.get("model")), str(st.get("state"))], 1.0)
    f.f["info"] = info
    f.add("degraded", st.get("state") == "degraded", d)
    f.add("uptime_seconds", st.get("uptime_s"), d)
    acts = st.get("actuators") or {}
    f.add("units", len(acts), d)
    f.add("silent_units", len(st.get("silent") or ()), d)
    for name in ("samples", "dropped", "bad", "missed", "errors"):
        f.add(name, st.get(name), d)
    f.add("gaps", sum(int(a.get("gaps") or 0) for a in acts.values()), d)
    f.add("queue_messages", st.get("queue"), d)
    f.add("queue_high_messages", st.get("queue_high"), d)
    f.add("queue_capacity_messages", st.get("queue_size"), d)
    f.add("busy_ratio", st.get("busy_fraction"), d)
    h = st.get("latency_hist")
    if h:
        counts = [int(c) for c in h["counts"]]
        bounds = [format(b, "g") for b in h["le_s"]] + ["+Inf"]
        cum, acc = [], 0
        for b, c in zip(bounds, counts, strict=True):
            acc += c
            cum.append((b, acc))
        lat = HistogramMetricFamily(
            PREFIX + "latency_seconds", METRICS["latency_seconds"][1], labels=base
        )
        lat.add_metric(d, cum, float(h["sum_s"]))
        f.f["latency_seconds"] = lat
    f.add("log_bytes", _log_bytes(st.get("log")), d)
    f.add("log_failed", bool(st.get("log_failure")), d)
    r = st.get("log_retention")
    if isinstance(r, dict):
        for name in ("kept_bytes", "kept_files", "deleted_bytes", "deleted_files"):
            f.add("log_" + name, r.get(name), d)
    s = st.get("store")
    if s:
        f.add("store_written", s.get("written"), d)
        f.add("store_errors", s.get("errors"), d)
        f.add("store_pending", s.get("pending"), d)
        f.add("store_failed", bool(s.get("failure")), d)
    g = st.get("group")
    if g:
        f.add("group_members", len(g.get("members") or ()), d)
        f.add("group_takeovers", g.get("takeovers"), d)
        f.add("group_released", g.get("released"), d)
        f.add("group_held_units", g.get("held_units"), d)
        f.add("group_unmonitored_units", len(g.get("unmonitored") or ()), d)
    fx = st.get("foxglove")
    if fx:
        f.add("foxglove_subscribed_channels", fx.get("subscribed_topics"), d)
        fg = fx.get("guard") if isinstance(fx.get("guard"), dict) else {}
        f.add("foxglove_clients", fg.get("connections"), d)
        f.add("foxglove_buffered_bytes", fg.get("buffered_bytes"), d)
        if "listener" in fg:
            f.add("foxglove_listener_ok", 1.0 if fg.get("listener") == "ok" else 0.0, d)
        f.add("foxglove_sent", fx.get("sent"), d)
        f.add("foxglove_dropped", fx.get("dropped"), d)
    unit = ["aircraft", "actuator"]
    for a in acts.values():
        if not (is_name(a.get("aircraft")) and is_name(a.get("actuator"))):
            continue  # a label of the grammar only (bounded, and what every reader accepts)
        u = [*d, str(a.get("aircraft")), str(a.get("actuator"))]
        est, health = a.get("est") or {}, a.get("health") or {}
        f.add("unit_leak_ratio", health.get("leak_ratio"), u, unit)
        f.add("unit_supply_ratio", health.get("supply_ratio"), u, unit)
        f.add("unit_c_lk", est.get("c_lk"), u, unit)
        f.add("unit_c_lk_sigma", est.get("c_lk_sigma"), u, unit)
        f.add("unit_nis_in_band_ratio", a.get("nis_in_band"), u, unit)
        pooled = a.get("c_lk_pooled") or {}
        f.add("unit_c_lk_pooled", pooled.get("value"), u, unit)
        f.add("unit_c_lk_pooled_sigma", pooled.get("sigma"), u, unit)
        active = {str(x.get("kind")) for x in a.get("alarms") or () if isinstance(x, dict)}
        for kind in _ALARM_KINDS:
            f.add("unit_alarm", kind in active, [*u, kind], [*unit, "kind"])
        f.add("unit_silent", bool(a.get("silent")), u, unit)
        if "commissioned" in a:
            f.add("unit_commissioned", bool(a.get("commissioned")), u, unit)
            f.add("unit_baseline_version", a.get("baseline_version"), u, unit)
        f.add("unit_samples", a.get("samples"), u, unit)
        f.add("unit_bad", a.get("bad_total"), u, unit)
        f.add("unit_gaps", a.get("gaps"), u, unit)
        f.add("unit_dropped", a.get("dropped"), u, unit)
        rul = a.get("rul") if isinstance(a.get("rul"), dict) else {}
        f.add("unit_rul_median_flights", rul.get("median_flights"), u, unit)
        f.add("unit_rul_median_days", rul.get("median_days"), u, unit)
        f.add("unit_rul_median_hours", rul.get("median_h"), u, unit)
        if "periods" in a or "rul" in a:  # the store's view of the unit (a daemon with one)
            f.add("unit_failed", condition_of(a)[0] == "failed", u, unit)
    return list(f.f.values())


class StatusCollector(Collector):
    """A Prometheus collector over ``status()`` (a daemon's ``status``), read per scrape."""

    def __init__(self, status: Callable[[], dict[str, Any]]) -> None:
        self.status = status

    def collect(self) -> Iterator[Metric]:
        yield from collect_status(self.status())

    def describe(self) -> list[Metric]:  # no scrape at registration
        return []


class _Exposition:
    """The exposition of ``registry`` per content type, built at most once per
    ``max_age_s`` by one thread at a time; the others wait for it and take the same body."""

    def __init__(self, registry: CollectorRegistry, max_age_s: float) -> None:
        self.registry = registry
        self.max_age_s = float(max_age_s)
        self._lock = threading.Lock()
        self._bodies: dict[str, tuple[float, bytes]] = {}  # ctype -> (built at, body)
        self.builds = 0

    def body(self, encoder: Callable[[CollectorRegistry], bytes], ctype: str) -> bytes:
        with self._lock:
            got = self._bodies.get(ctype)
            now = time.monotonic()
            if got is not None and now - got[0] < self.max_age_s:
                return got[1]
            body = encoder(self.registry)
            self.builds += 1
            self._bodies[ctype] = (time.monotonic(), body)
            return body


class _Handler(GuardedHandler):
    server_version = "servowatch-metrics"
    sys_version = ""
    protocol_version = "HTTP/1.1"
    registry: CollectorRegistry
    exposition: _Exposition

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (the base's name)
        log.debug("%s " + format, self.address_string(), *args)

    def _send(self, code: int, body: bytes, ctype: str, head: bool = False) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        if code == HTTPStatus.METHOD_NOT_ALLOWED:
            self.send_header("Allow", "GET, HEAD")
        # one request per connection: the rate of requests is the rate of connections,
        # which the server limits before a thread is made (a body is never read either)
        self.close_connection = True
        self.send_header("Connection", "close")
        self.end_headers()
        if not head:
            self.wfile.write(body)

    def _answer(self, head: bool) -> None:
        text = "text/plain; charset=utf-8"
        if len(self.headers.get_all("Host") or ()) > 1:
            return self._send(400, b"more than one Host header\n", text, head)
        if not self._host_ok():
            return self._send(421, b"Host: not this server's name\n", text, head)
        path = urlsplit(self.path).path
        if path not in ("/metrics", "/"):
            return self._send(404, b"not found: the metrics are at /metrics\n", text, head)
        encoder, ctype = choose_encoder(self.headers.get("Accept") or "")
        try:
            body = self.exposition.body(encoder, ctype)
        except Exception as e:  # a status that cannot be read: an error, never a dead server
            log.warning("metrics scrape failed: %s", e)
            return self._send(503, f"status unavailable: {e}\n".encode(), text, head)
        self._send(200, body, ctype, head)

    def do_GET(self) -> None:  # noqa: N802 (BaseHTTPRequestHandler's name)
        self._answer(head=False)

    def do_HEAD(self) -> None:  # noqa: N802
        self._answer(head=True)

    def _refuse(self) -> None:
        self.close_connection = True
        self._send(405, b"GET and HEAD only\n", "text/plain; charset=utf-8")

    do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _refuse  # noqa: N815


_BUSY_BODY = b"too many connections\n"
_BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\n"
    b"Content-Length: %d\r\nRetry-After: 1\r\nConnection: close\r\n\r\n%s"
    % (len(_BUSY_BODY), _BUSY_BODY)
)


_REFUSE_S = 0.01  # the listening thread's pause after a refusal [s]


class _Server(ThreadingHTTPServer):
    """A thread per connection (one request each), at most ``max_connections`` at once and
    ``max_per_s`` a second (a token bucket of as many): one more is answered 503 and closed
    on the listening thread, without a thread of its own; then that thread pauses
    ``_REFUSE_S``, so refusals cost the daemon at most 100 a second."""

    daemon_threads = True
    request_queue_size = 128  # the listen backlog (docs/security.md, "HTTP")
    max_connections = 8
    max_per_s = 10.0

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self._count_lock = threading.Lock()
        self.active = 0
        self.refused = 0
        self._tokens = float(self.max_per_s)
        self._t_tokens = time.monotonic()

    def process_request(self, request: Any, client_address: Any) -> None:
        with self._count_lock:
            now = time.monotonic()
            self._tokens = min(
                self.max_per_s, self._tokens + (now - self._t_tokens) * self.max_per_s
            )
            self._t_tokens = now
            full = self.active >= self.max_connections or self._tokens < 1.0
            if not full:
                self.active += 1
                self._tokens -= 1.0
            else:
                self.refused += 1
        if full:
            with contextlib.suppress(OSError):
                request.setblocking(False)
                request.send(_BUSY)
            self.shutdown_request(request)
            # a refusal costs the daemon too: at most 1/_REFUSE_S a second, the others wait
            # in the kernel's listen queue meanwhile (no thread, no GIL)
            time.sleep(_REFUSE_S)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._done()
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._done()

    def _done(self) -> None:
        with self._count_lock:
            self.active -= 1

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client gone mid-answer (reset, timeout) is logged, not printed to stderr."""
        log.debug("metrics request from %s failed", client_address, exc_info=True)


class MetricsServer:
    """The endpoint on ``host:port`` (port 0: a free one, ``address`` tells which) over
    ``status()``; bound at construction (an address in use raises OSError), served by
    :meth:`start` on a daemon thread until :meth:`close`. ``max_age_s``: a built exposition
    is served this long [s]; ``max_connections`` served at once and ``max_per_s`` a second
    (one request each); ``idle_s``: a connection without a request is closed after this
    long [s]."""

    def __init__(
        self,
        status: Callable[[], dict[str, Any]],
        host: str = "127.0.0.1",
        port: int = 9464,
        *,
        allow_remote: bool = False,
        max_age_s: float = 1.0,
        max_connections: int = 8,
        idle_s: float = 5.0,
        max_per_s: float = 10.0,
    ) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(StatusCollector(status))
        self.exposition = _Exposition(self.registry, max_age_s)
        handler = type(
            "MetricsHandler",
            (_Handler,),
            {
                "registry": self.registry,
                "exposition": self.exposition,
                "allowed_hosts": None if allow_remote else loopback_names(host),
                "timeout": float(idle_s),
            },
        )
        cls: type[ThreadingHTTPServer] = type(
            "_Server", (_Server,),
            {"max_connections": int(max_connections), "max_per_s": float(max_per_s)},
        )  # fmt: skip
        if ":" in host:
            import socket

            cls = type("_V6", (cls,), {"address_family": socket.AF_INET6})
        try:
            self._srv = cls((host, port), handler)
        except OSError as e:  # an address in use, a host not on this machine
            raise OSError(e.errno, f"metrics endpoint {host}:{port}: {e.strerror}") from None
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the server listens on."""
        a = self._srv.server_address
        return str(a[0]), int(a[1])

    def stats(self) -> dict[str, Any]:
        """Connections served now, the cap, those refused, expositions built."""
        srv = self._srv
        return {"connections": srv.active, "max_connections": srv.max_connections,
                "refused": srv.refused, "builds": self.exposition.builds}  # fmt: skip

    def start(self) -> MetricsServer:
        """Serve on a daemon thread."""
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._srv.serve_forever, name="servowatch-metrics", daemon=True
            )
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop serving and close the socket (idempotent)."""
        if self._thread is not None:
            self._srv.shutdown()
            self._thread.join(5)
            self._thread = None
        self._srv.server_close()
