"""The monitoring daemon: Zenoh samples in, one monitor bank for all actuators, estimates out,
MCAP log.

Data path (docs/design.md, "Data flow" and "Backpressure"):

* the Zenoh subscriber callback only appends ``(key, payload, t_recv)`` to a bounded queue
  (a full queue drops the new message and counts it against its actuator);
* one worker thread drains the queue every tick, decodes and validates each message into
  arrays (``service.messages.decode_meas_arrays``), checks sequence numbers and sample times
  per actuator (``service.daemon.intake``), logs every accepted sample, feeds the whole tick's
  samples to the monitors in one ``MonitorBank.update_arrays`` call, and hands the output rows
  to ``service.fanout.FanOut`` (the replay's fan-out too): est, residual and health logged
  every ``log_every``-th output and at every alarm event, events logged, est/res/health
  published every ``publish_every``-th output per actuator;
* with ``[foxglove]`` (docs/dashboard.md): the logged meas, est, residual, health and events
  also go live to a Foxglove WebSocket server (``service.foxglove_feed``) through a bounded
  queue and a thread of its own; only subscribed topics are encoded, and what does not fit
  is dropped and counted in the status (``foxglove.dropped``);
* the status queryable ``monitor/{station}/{shard}/status`` answers a JSON snapshot;
* with a health store (``store`` in the TOML, docs/store.md): each actuator runs on its
  latest baseline from the store (``service.monitor.MonitorFleet``; none: the default,
  ``commissioned: false``), the fan-out cuts operating periods, and a background thread
  (``service.store.StoreWriter``) writes each closed period in its own transaction; open
  periods are flushed when an actuator goes silent and at ``stop()`` (SIGTERM).

Bad input (malformed payload, wrong schema, NaN/inf, duplicate or out-of-order samples,
oversize messages, unparseable keys) is counted per actuator and logged at a limited rate;
it never stops the worker and never discards a good sample of the same message stream.

A failure of the MCAP log (disk full, the log process gone) is kept as ``log_failure``: the
status shows it and reports the service ``degraded``, systemd gets a STATUS line, and
``servowatch run`` exits with ``EXIT_LOG_FAILURE``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from service import messages as m
from service.config import ServiceConfig
from service.daemon.commission import Commissioner
from service.daemon.intake import MAX_ACTUATORS, ActuatorState, ClockCheck, accept, reason_of
from service.daemon.ratelimit import RateLimitedLog
from service.daemon.status import snapshot
from service.daemon.systemd import sd_notify, watchdog_interval
from service.fanout import FanOut
from service.jsonutil import flat
from service.monitor import Baseline, MonitorBank, MonitorFleet
from service.proclog import MEAS_LOG_FIELDS, ProcessLogger, meas_log_values
from service.prognostics import PeriodConfig

__all__ = ["Daemon", "default_log_path", "EXIT_LOG_FAILURE"]

log = logging.getLogger("servowatch.daemon")

#: exit code of ``servowatch run`` when the MCAP log failed (docs/cli.md, "Commands")
EXIT_LOG_FAILURE = 5  # 3 and 4 are the Zenoh session's (service.config)


def default_log_path(log_dir: Path, station: str, shard: str, prefix: str = "servowatch") -> Path:
    """``{log_dir}/{prefix}-{station}-{shard}-{UTC time}.mcap``."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    return Path(log_dir) / f"{prefix}-{station}-{shard}-{stamp}.mcap"


def store_target(store: str | None) -> str | None:
    """The store a daemon writes to: None for None/"off"/"none", else the path or URL."""
    return None if store is None or store.strip().lower() in ("off", "none") else store


def _warm_up(bank: MonitorBank | MonitorFleet) -> float:
    """Run a throwaway bank of the same configuration on a few synthetic samples, so that JIT
    compilation happens before the first real sample (and before READY). Seconds taken."""
    t0 = time.perf_counter()
    try:
        b = MonitorBank(bank.config, bank.baseline)
        k = b.index_of("_warm")
        ch = np.tile([0.0, 0.0, 0.0, 0.0, 10e6, 10e6, 20e6], (5, 1))
        b.update_arrays(np.full(5, k, np.int64), np.arange(5) * 1e-3, ch)
    except Exception as e:  # warming up is an optimisation only
        log.warning("monitor warm-up failed: %s", e)
    return time.perf_counter() - t0


class Daemon:
    """The monitoring daemon (see the module docstring).

    Usable without Zenoh: ``submit(key, payload)`` then ``process_pending()`` (tests). With
    Zenoh: ``start(session)`` declares the subscriber, queryable and liveliness token and
    starts the worker; ``stop()`` stops the inflow, drains the queue, finishes the log.

    ``logger`` (default: a ``ProcessLogger``, or an in-process ``McapLogger`` when
    ``log_process`` is False) needs ``log``, ``log_block``, ``commit``, ``close``, ``paths``
    and ``failure``; a ``log_payload`` method, when it has one, takes the received
    measurement payloads instead of decoded blocks. ``bank`` replaces the ``MonitorBank``
    built from the config (benchmarks: a bank that does nothing).
    """

    def __init__(
        self,
        config: ServiceConfig | None = None,
        *,
        log_path: str | Path | None = None,
        logger: Any = None,
        bank: Any = None,
        tick_s: float = 0.05,
        gather_s: float = 0.005,
        max_batch: int = 500,
        bad_log_interval_s: float = 5.0,
        log_process: bool = True,
    ) -> None:
        config = config if config is not None else ServiceConfig()
        self.config = config
        self.station = config.station
        self.shard = config.shard
        self.key_expr = config.key_expr
        self.publish_every = config.publish_every
        self.log_every = config.log_every
        self.silence_s = config.silence_s
        self.group_config = config.group
        self.group = None
        if config.group is not None:
            from service.daemon.group import MonitorGroup

            self.group = MonitorGroup(
                config.group.name,
                f"{self.station}/{self.shard}",
                self.submit,
                takeover_s=config.group.takeover_s,
                unmonitored_s=config.group.unmonitored_s,
                max_units=MAX_ACTUATORS,
                max_bytes=config.max_bytes,
            )
        self._group_token = None
        self._join_timer: threading.Timer | None = None
        self.queue_size = config.queue_size
        self.max_bytes = config.max_bytes
        self.clock = ClockCheck(**config.clock.model_dump())
        self.tick_s = tick_s
        self.gather_s = gather_s
        self.max_batch = max_batch
        self.store_url = store_target(config.store)
        self.store = None  # StoreWriter
        self._life = None  # FlightStamper, on the first closed period
        self.config_flight_gap_s = config.prognostics.flight_gap_s
        if self.store_url is not None:
            from service.store.writer import StoreWriter

            self.store = StoreWriter(self.store_url)
        if bank is None:
            baseline = Baseline.load(config.baseline) if config.baseline else None
            resolve = self._resolve if self.store_url is not None else None
            bank = MonitorFleet(config.monitor, baseline, resolve)
        self.bank = bank
        self._row_key: dict[int, str] = {}
        pc = config.prognostics
        self.commissioner = (
            Commissioner(self, pc.auto_commission_s, pc.auto_commission_min_in_band)
            if self.store is not None and pc.auto_commission_s is not None
            else None
        )
        if logger is None:
            from service.log import McapLogger

            if log_path is None:
                log_path = default_log_path(
                    config.log_dir, self.station, self.shard, config.log_name
                )
            Path(log_path).parent.mkdir(parents=True, exist_ok=True)
            kw = {
                "rotate_bytes": config.rotate_bytes,
                "rotate_s": config.rotate_s,
                "flush_s": config.flush_s,
                "metadata": {
                    "source": "daemon",
                    "station": self.station,
                    "shard": self.shard,
                    "monitor_config": bank.config.model_dump_json(),
                    "baseline": bank.baseline.model_dump_json(),
                },
            }
            logger = ProcessLogger(log_path, **kw) if log_process else McapLogger(log_path, **kw)
        self.logger = logger
        self._log_payload = getattr(logger, "log_payload", None)
        self.log_path = Path(log_path) if log_path is not None else None
        self.log_failure: str | None = None
        self.actuators: dict[str, ActuatorState] = {}
        self._rows: dict[int, ActuatorState] = {}  # bank row -> actuator
        self.unknown: dict[str, int] = {}  # reason -> count, for keys that name no actuator
        self._queue: deque = deque()
        self._arrival: dict[str, float] = {}  # key -> time.monotonic() of the last message
        self.first_arrival: dict[str, float] = {}  # key -> time.monotonic() of the first one
        self.alive_tokens: dict[str, bool] = {}  # fleet/{ac}/{act}/alive -> token present
        self._wake = threading.Event()
        self._lock = threading.Lock()  # guards self.actuators structure + status snapshot
        self._stop = threading.Event()
        self._notify_lock = threading.Lock()
        self._worker: threading.Thread | None = None
        self._session = None
        self._decl: list[Any] = []
        self._sources: dict[str, str] = {}  # advanced publisher id -> key
        self.latency = deque(maxlen=50000)  # receipt -> health output [s]
        self.age = deque(maxlen=50000)  # sample time t -> health output [s] (Unix-time t)
        self.bad_log = RateLimitedLog(log, bad_log_interval_s)
        self.foxglove = None  # FoxgloveFeed
        if config.foxglove is not None:
            from service.foxglove_feed import FoxgloveFeed

            fc = config.foxglove
            host, port = fc.host_port()
            self.foxglove = FoxgloveFeed(
                host, port, queue_size=fc.queue_size, backlog=fc.backlog, every=fc.every,
                name=f"servowatch {self.station}/{self.shard}",
            )  # fmt: skip
        self.fanout = FanOut(
            logger,
            log_every=self.log_every,
            publish_every=self.publish_every,
            on_publish_error=self._publish_failed,
            on_periods=None if self.store is None else self._on_periods,
            source=f"live:{self.station}/{self.shard}",
            period_config=PeriodConfig(silence_s=pc.period_silence_s, window_s=pc.period_window_s),
            counters=lambda row: self.bank.counters_of(self._row_key[row]),
            live=self.foxglove,
        )
        self.started = time.time()
        self.ticks = 0
        self.busy_s = 0.0
        self.queue_high = 0
        self.errors = 0
        self._closed = False
        self._last_silence_check = 0.0
        self._wd_interval = watchdog_interval()
        self._wd_last = 0.0

    # -- inflow -------------------------------------------------------------------------
    def submit(self, key: str, payload: bytes, t_recv: float | None = None) -> bool:
        """Queue one message (never blocks); False if the queue was full (drop counted)."""
        if len(self._queue) >= self.queue_size:
            self._count_drop(key)
            return False
        t_recv = time.monotonic() if t_recv is None else t_recv
        self._arrival[key] = t_recv  # for silence detection, even while the worker lags
        if key not in self.first_arrival:
            self.first_arrival[key] = t_recv
        self._queue.append((key, payload, t_recv))
        n = len(self._queue)
        if n > self.queue_high:
            self.queue_high = n
        if n == 1 or n % 64 == 0:
            self._wake.set()
        return True

    def _on_zenoh_sample(self, sample) -> None:
        try:
            key = str(sample.key_expr)
            if self.group is not None:  # a unit of another member is held, not queued
                self.group.admit(key, sample.payload.to_bytes(), time.monotonic())
            else:
                self.submit(key, sample.payload.to_bytes())
            si = sample.source_info
            if si is not None and si.source_id is not None:
                self._sources[str(si.source_id)] = key
        except Exception:  # never let a callback raise into zenoh
            self.errors += 1

    def _on_miss(self, miss) -> None:
        """Samples that the advanced subscriber could not recover, counted per actuator."""
        try:
            key = self._sources.get(str(miss.source), "")
            if self.group is not None and key and not self.group.owns_key(key):
                return  # another member's unit: its misses are that member's to count
            st = self._state_for_key(key)
            if st is not None:
                st.missed += int(miss.nb)
            else:
                self.unknown["missed"] = self.unknown.get("missed", 0) + int(miss.nb)
            log.warning("missed %d messages from %s", miss.nb, st.name if st else miss.source)
        except Exception:
            self.errors += 1

    def _count_drop(self, key: str) -> None:
        st = self._state_for_key(key)
        if st is not None:
            st.dropped += 1
        else:
            self.unknown["dropped"] = self.unknown.get("dropped", 0) + 1

    # -- per-actuator state --------------------------------------------------------------
    def _state_for_key(self, key: str) -> ActuatorState | None:
        st = self.actuators.get(key)
        if st is not None:
            return st
        try:
            aircraft, actuator = m.parse_meas_key(key)
        except m.MessageError:
            return None
        with self._lock:
            st = self.actuators.get(key)
            if st is None:
                if len(self.actuators) >= MAX_ACTUATORS:
                    return None
                st = ActuatorState(aircraft, actuator)
                self.actuators[key] = st
                log.info("new actuator %s", st.name)
        return st

    # -- worker -------------------------------------------------------------------------
    def process_pending(self) -> int:
        """Drain the queue once: validate, log, update the monitors, publish. Returns the
        number of samples fed to the monitors."""
        q = self._queue
        if not q:
            return 0
        t0 = time.perf_counter()
        msgs = []
        while q and len(msgs) < self.max_batch:
            msgs.append(q.popleft())
        parts: list[tuple[ActuatorState, str, m.MeasArrays, int, float]] = []
        now = time.time()
        for key, payload, t_recv in msgs:
            st = self._state_for_key(key)
            if st is None:
                reason = "unknown_actuator" if key.endswith("/meas") else "invalid_key"
                try:
                    m.parse_meas_key(key)
                except m.MessageError:
                    reason = "invalid_key"
                self.unknown[reason] = self.unknown.get(reason, 0) + 1
                self.bad_log.warning("key:" + reason, "%s: %s", reason, key[:200])
                continue
            st.messages += 1
            st.last_recv = t_recv
            if st.silent:
                st.silent = False
                self._service_event(st, "resumed", st.last_t)
            try:
                a = m.decode_meas_arrays(payload, self.max_bytes)
            except m.MessageError as e:
                reason = reason_of(e)
                st.count_bad(reason)
                self.bad_log.warning(st.name, "bad message from %s: %s (%s)", st.name, e, reason)
                continue
            j0, j1 = accept(st, a, self.bad_log, self._on_restart, self.clock, now)
            if j0 >= j1:
                continue
            full = j0 == 0 and j1 == len(a.t)
            if j1 < len(a.t):
                a = m.MeasArrays(a.seq[:j1], a.t[:j1], a.values[:j1])
            self._log_meas(st, payload, a, j0, full)
            parts.append((st, key, a, j0, t_recv))
        n_fed = sum(len(p[2].t) - p[3] for p in parts)
        if parts:
            try:
                self._update(parts)
            except Exception as e:  # a monitor failure must not kill the daemon
                self.errors += 1
                log.exception("monitor update failed: %s", e)
        self.logger.commit()
        self._check_log()
        self.ticks += 1
        self.busy_s += time.perf_counter() - t0
        return n_fed

    def _log_meas(
        self, st: ActuatorState, payload: bytes, a: m.MeasArrays, j0: int, full: bool = True
    ) -> None:
        """The accepted samples j0.. of a message (``full``: all of the payload's) on the
        actuator's ``meas`` topic."""
        topic = m.mcap_topic(st.aircraft, st.actuator, "meas")
        n = len(a.t)
        try:
            if self._log_payload is not None:  # the log process decodes the payload again
                self._log_payload(topic, payload, None if full else list(range(j0, n)))
            else:
                self.logger.log_block(
                    topic, a.t[j0:], MEAS_LOG_FIELDS, meas_log_values(a, j0), int_fields=("seq",)
                )
        except Exception:  # kept in logger.failure and logged there; monitoring goes on
            self.errors += 1
        fx = self.foxglove
        if fx is not None and fx.wants(topic):
            fx.log_block(topic, a.t[j0:], MEAS_LOG_FIELDS, meas_log_values(a, j0),
                         int_fields=("seq",))  # fmt: skip

    def _update(self, parts: list) -> None:
        """The tick's samples in one ``MonitorBank.update_arrays`` call; the output rows
        through the fan-out (log blocks, events, publishing)."""
        sizes = [len(a.t) - j0 for _, _, a, j0, _ in parts]
        rows_of = []
        for st, key, _, _, _ in parts:
            row = self.bank.index_of(key)  # in the worker: it may grow the bank's arrays
            if row not in self._rows:
                self._rows[row] = st
                self._row_key[row] = key
                self.fanout.track(row, st.aircraft, st.actuator, **self._track_info(key))
            rows_of.append(row)
        ks = np.repeat(np.array(rows_of, np.int64), sizes)
        t = np.concatenate([a.t[j0:] for _, _, a, j0, _ in parts])
        ch = np.concatenate([a.values[j0:] for _, _, a, j0, _ in parts])
        recv = np.repeat(np.array([p[4] for p in parts]), sizes)
        rows = self.bank.update_arrays(ks, t, ch)
        idx = rows.index
        if len(idx) == 0:
            return
        now_m, now_w = time.monotonic(), time.time()
        self.latency.extend((now_m - recv[idx]).tolist())
        old = rows.t > 1e9  # Unix-time sample clock: end-to-end age is meaningful
        if old.any():
            self.age.extend((now_w - rows.t[old]).tolist())
        if self.commissioner is not None:
            self.commissioner.feed(parts, rows, ks)
        for em in self.fanout.emit(rows, ks):
            st = self._rows[em.row]
            st.outputs += em.outputs
            st.published += em.published
            st.latest = (rows, em.last)
            for d in em.events:
                kind = str(d.get("kind"))
                if _is_active(d.get("state")):
                    st.alarms[kind] = d
                else:
                    st.alarms.pop(kind, None)
                st.events.append(d)
                log.info("alarm %s %s: %s", st.name, kind, d)

    # -- health store -------------------------------------------------------------------
    def _resolve(self, key: str) -> tuple[Baseline, int | None]:
        """The latest baseline of the actuator of meas key ``key`` in the store."""
        from service.store import open_store

        name = "/".join(m.parse_meas_key(key))
        try:
            with open_store(self.store_url) as s:
                rec = s.latest_baseline(name)
        except Exception as e:  # the store is unreachable: monitor on the default
            log.error("baseline of %s from the store: %s", name, e)
            rec = None
        if rec is None:
            return self.bank.baseline, None
        return Baseline.model_validate(rec.baseline), rec.version

    def _track_info(self, key: str) -> dict[str, Any]:
        """``track`` arguments of a meas key: its baseline's C_Lk and commissioning."""
        b = self.bank
        if not isinstance(b, MonitorFleet):
            return {}
        v = b.versions.get(key)
        info = {"commissioned": v is not None, "baseline_version": v}
        return {"c_lk0": b.bank.baseline_of(key).c_lk, "info": info}

    def _on_periods(self, periods: list, alarms: list) -> None:
        if self.store is not None:
            if periods:
                periods = self._stamper().stamp(periods)
                self._record_flights(periods)
            self.store.submit(periods, alarms)

    def _record_flights(self, periods: list) -> None:
        """Each new flight of a unit as a ``servowatch.flight`` record in the daemon's log
        (a later replay of the log finds the same flights); a process logger has none."""
        add = getattr(self.logger, "add_metadata", None)
        if add is None:
            return
        from service.flightrec import FLIGHT_RECORD, FlightRecord

        seen = self.__dict__.setdefault("_flights_logged", {})
        for p in periods:
            if seen.get(p.actuator) == p.flight:
                continue
            seen[p.actuator] = p.flight
            ac, act = p.actuator.split("/", 1)
            rec = FlightRecord(ac, act, int(p.flight), p.start_unix, p.start_t)
            try:
                add(FLIGHT_RECORD, rec.to_metadata())
            except Exception as e:  # the log's failure is reported by its own path
                log.warning("log: flight record of %s: %s", p.actuator, e)

    def _stamper(self):
        """Flight and calendar time of each period (``service.prognostics.life``: the live
        sample times are Unix times; flights by the gap rule, continuing the stored ones)."""
        if getattr(self, "_life", None) is None:
            from service.prognostics.life import FlightStamper
            from service.store import open_store

            url = self.store_url

            def last(name: str):
                try:
                    with open_store(url, read_only=True) as st:
                        if name not in st.actuators():
                            return None
                        ps = st.periods(name)
                except Exception as e:  # a store the writer cannot read: count from 0
                    log.warning("store: last period of %s: %s", name, e)
                    return None
                key = lambda p: (p.flight if p.flight is not None else -1, p.start_t)  # noqa: E731
                return max(ps, key=key, default=None)

            self._life = FlightStamper(last, self.config_flight_gap_s)
        return self._life

    def prognostics_of(self, key: str) -> dict[str, Any]:
        """Status fields of meas key ``key``: commissioning, stored periods, last RUL."""
        b = self.bank
        if not isinstance(b, MonitorFleet):
            return {}
        v = b.versions.get(key)
        out: dict[str, Any] = {"commissioned": v is not None, "baseline_version": v}
        if self.store is not None:
            st = self.actuators.get(key)
            out.update(self.store.info(st.name) if st is not None else {})
        return out

    def store_status(self) -> dict[str, Any] | None:
        """The store writer's state for the status (None without a store)."""
        w = self.store
        if w is None:
            return None
        from service.store import describe_url

        return {"where": describe_url(w.url), "pending": w.pending, "written": w.written,
                "errors": w.errors, "failure": w.failure}  # fmt: skip

    def _publish_failed(self, e: Exception) -> None:
        self.errors += 1
        self.bad_log.warning("publish", "publish failed: %s", e)

    def _check_log(self) -> None:
        """Take up the logger's first failure: status, health, systemd."""
        if self.log_failure is None and self.logger.failure is not None:
            self.log_failure = str(self.logger.failure)
            log.error("MCAP log failed, service degraded: %s", self.log_failure)
            sd_notify(f"STATUS=degraded: MCAP log failed: {self.log_failure[:200]}")

    def _on_restart(self, st: ActuatorState, t: float, seq: int, back: bool = False) -> None:
        if back and isinstance(self.bank, MonitorBank):  # time went back: the filter restarts
            self.bank.t_last[
                self.bank.index_of(f"fleet/{st.aircraft}/{st.actuator}/meas")
            ] = -np.inf
        self._service_event(st, "restart", t, value=seq)

    def _service_event(
        self, st: ActuatorState, kind: str, t: float | None, value: Any = None
    ) -> None:
        """A daemon-side event (silent, resumed, restart) in the log and the status."""
        t = float(t) if t is not None else time.time()
        d = {"t": t, "kind": kind, "value": value, "wall": time.time()}
        st.events.append(d)
        self.logger.log(f"/fleet/{st.aircraft}/{st.actuator}/service", t, flat(d))
        log.info("%s %s", st.name, kind)

    def check_silence(self, now: float | None = None) -> list[str]:
        """Mark actuators silent after ``silence_s`` without a message; return new ones."""
        now = time.monotonic() if now is None else now
        out = []
        for key, st in list(self.actuators.items()):
            last = self._arrival.get(key, st.last_recv)
            if not st.silent and last is not None and now - last > self.silence_s:
                st.silent = True
                out.append(st.name)
                self._end_period(key)
                self._service_event(st, "silent", st.last_t, value=now - last)
        return out

    def _end_period(self, key: str) -> None:
        """The actuator's open operating period ends (silent, released)."""
        row = self.bank.ids.get(key) if hasattr(self.bank, "ids") else None
        if row in self._rows:
            self.fanout.flush(row)

    def release_units(self) -> list[str]:
        """Units another group member took over: their operating period ends and their
        stream state is forgotten, so one that comes back starts afresh (no false gaps, a new
        period); the monitor re-initialises itself on the time gap. Returns their names."""
        g = self.group
        g.sweep(time.monotonic())
        out = []
        for key in g.pop_released():
            st = self.actuators.get(key)
            if st is None:
                continue
            self._end_period(key)
            self._service_event(st, "released", st.last_t)  # at its last sample, as "silent"
            st.first_seq = st.last_seq = st.last_t = st.period = st.resync = None
            st.refused = 0
            st.silent = True
            out.append(st.name)
        return out

    def check_unmonitored(self, now: float) -> list[str]:
        """Group units with measurements but no member's output for ``unmonitored_s``: the
        ``unmonitored`` event (and ``monitored`` when outputs resume); returns the new ones."""
        new, back = self.group.check_unmonitored(now, self.silence_s)
        for key, owner, age in new:
            log.warning(
                "%s unmonitored: no health output for %.1f s (its owner in this member's view: "
                "%s)", key, age, owner,
            )  # fmt: skip
            self._group_event(key, "unmonitored", {"owner": owner, "for_s": round(age, 3)})
        for key in back:
            log.info("%s monitored again", key)
            self._group_event(key, "monitored", None)
        return [k for k, _, _ in new]

    def _group_event(self, key: str, kind: str, value: Any) -> None:
        """An event of a group unit, owned by this member or not: logged, and in the unit's
        status when this member has monitored it."""
        parts = key.split("/")
        t = time.time()
        d = {"t": t, "kind": kind, "value": value, "wall": t}
        st = self.actuators.get(key)
        if st is not None:
            st.events.append(d)
        self.logger.log(f"/fleet/{parts[1]}/{parts[2]}/service", t, flat(d))

    def _on_output(self, sample) -> None:
        """A member's health output (this member's own too): the unit is monitored."""
        try:
            k = str(sample.key_expr)
            self.group.output_seen(k[: -len("health")] + "meas", time.monotonic())
        except Exception:
            self.errors += 1

    def _run_worker(self) -> None:
        while True:
            stopping = self._stop.is_set()
            self._wake.wait(self.tick_s)
            self._wake.clear()
            try:
                self.process_pending()
                now = time.monotonic()
                if now - self._last_silence_check > 0.2:
                    self._last_silence_check = now
                    changed = self.release_units() if self.group is not None else []
                    if self.group is not None:
                        changed += self.check_unmonitored(now)
                    if self.check_silence(now) or changed:
                        self.logger.commit()
                if self._wd_interval is not None and now - self._wd_last > self._wd_interval:
                    self._wd_last = now
                    with self._notify_lock:  # never a WATCHDOG after STOPPING
                        if not self._stop.is_set():
                            sd_notify("WATCHDOG=1")
            except Exception:
                self.errors += 1
                log.exception("worker tick failed")
            if stopping and not self._queue:
                return
            if self.gather_s > 0:
                time.sleep(self.gather_s)  # let the next tick's samples gather into one batch

    # -- status -------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """A JSON-ready snapshot: actuators, counters, latency, alarms, silent actuators, the
        log's failure and the service state (``service.daemon.status.snapshot``)."""
        self._check_log()
        return snapshot(self)

    @property
    def queued(self) -> int:
        """Messages waiting in the receive queue."""
        return len(self._queue)

    def monitor_counters(self, key: str) -> dict[str, int] | None:
        """The monitor's own sample counters of ``key`` and the C_Lk changes its detector read
        (None before its first sample)."""
        try:
            return {
                **self.bank.counters_of(key),
                "c_lk_changes": self.bank.c_lk_changes_of(key),
            }
        except KeyError:
            return None

    def _on_alive(self, sample) -> None:
        """Liveliness token of an actuator appeared (PUT) or vanished (DELETE)."""
        try:
            import zenoh

            key = str(sample.key_expr)
            self.alive_tokens[key] = sample.kind == zenoh.SampleKind.PUT
        except Exception:
            self.errors += 1

    def _start_group(self, session) -> None:
        """Hold this member's group token, watch the others', own after ``join_s``."""
        import zenoh

        from service.daemon.group import GROUP_TOKENS, group_token

        g = self.group
        zid = str(session.info.zid())
        self._group_token = session.liveliness().declare_token(
            group_token(self.station, self.shard, g.name, zid)
        )
        self._decl.append(self._group_token)

        def on_member(sample) -> None:
            try:
                who = g.member_of_token(str(sample.key_expr))
                if who is not None:
                    g.member_event(who[0], sample.kind == zenoh.SampleKind.PUT, who[1])
            except Exception:
                self.errors += 1

        self._decl.append(
            session.liveliness().declare_subscriber(
                GROUP_TOKENS.format(group=g.name), on_member, history=True
            )
        )
        # every member's health outputs: a unit with meas but none is unmonitored
        self._decl.append(
            session.declare_subscriber(
                m.KEY_HEALTH.format(aircraft="*", actuator="*"),
                self._on_output,
            )
        )
        self._join_timer = threading.Timer(self.group_config.join_s, g.join)
        self._join_timer.daemon = True
        self._join_timer.start()
        log.info("member %s of monitor group %s, owning after %.1f s", g.me, g.name,
                 self.group_config.join_s)  # fmt: skip

    def _on_status_query(self, query) -> None:
        try:
            key = m.KEY_STATUS.format(station=self.station, shard=self.shard)
            query.reply(key, m.encode_json(self.status()))
        except Exception as e:
            self.errors += 1
            log.warning("status query failed: %s", e)

    # -- lifecycle ----------------------------------------------------------------------
    def start(self, session=None) -> None:
        """Declare Zenoh entities on ``session`` (if given) and start the worker thread."""
        if session is not None:
            self._session = session
            self.fanout.session = session
            from zenoh import ext as zx

            # advanced subscriber: recovers from the publishers' caches what a router restart
            # or a disconnect lost; what it cannot recover is counted as ``missed``
            sub = zx.declare_advanced_subscriber(
                session,
                self.key_expr,
                self._on_zenoh_sample,
                history=zx.HistoryConfig(detect_late_publishers=True),
                recovery=zx.RecoveryConfig(heartbeat=True),
                subscriber_detection=True,
            )
            self._decl.append(sub)
            self._decl.append(sub.sample_miss_listener(self._on_miss))
            if self.group is not None:  # before the status answers: a member is one at once
                self._start_group(session)
            skey = m.KEY_STATUS.format(station=self.station, shard=self.shard)
            self._decl.append(session.declare_queryable(skey, self._on_status_query))
            self._decl.append(
                session.liveliness().declare_token(f"monitor/{self.station}/{self.shard}/alive")
            )
            try:  # actuators' liveliness tokens (virtual actuators hold one)
                self._decl.append(
                    session.liveliness().declare_subscriber(
                        m.KEY_ALIVE.format(aircraft="*", actuator="*"), self._on_alive, history=True
                    )
                )
            except Exception as e:  # an older zenoh without history: data silence still works
                log.warning("no liveliness subscriber: %s", e)
        warm = _warm_up(self.bank) if isinstance(self.bank, MonitorBank | MonitorFleet) else 0.0
        if warm > 0.05:
            log.info("monitor warm-up (JIT) took %.2f s", warm)
        self._worker = threading.Thread(
            target=self._run_worker, name="servowatch-worker", daemon=True
        )
        self._worker.start()
        sd_notify("READY=1")
        log.info(
            "daemon %s/%s started on %s, logging to %s",
            self.station,
            self.shard,
            self.key_expr,
            self.log_path,
        )

    def stop(self, timeout: float = 30.0) -> dict[str, Any]:
        """Stop the inflow, process what is queued, finish the log. Idempotent.

        Returns the final status."""
        if self._closed:
            return self.status()
        with self._notify_lock:
            self._stop.set()
            sd_notify("STOPPING=1")
        # a group member leaves the group first: the others take its units over while it
        # drains what it has (overlap, not loss)
        if self._join_timer is not None:
            self._join_timer.cancel()
        if self._group_token is not None:
            with contextlib.suppress(Exception):
                self._group_token.undeclare()
        # stop the inflow first: the subscriber goes, queued messages are still processed
        for d in self._decl[:1]:
            with contextlib.suppress(Exception):
                d.undeclare()
        self._wake.set()
        if self._worker is not None:
            self._worker.join(timeout)
        while self._queue:  # no worker (tests) or it gave up: drain here
            self.process_pending()
        for d in self._decl[1:]:
            with contextlib.suppress(Exception):
                d.undeclare()
        self.fanout.flush()  # open periods of every actuator to the store
        self.fanout.close()
        if self.foxglove is not None:
            self.foxglove.close()
        if self.store is not None:
            self.store.close()
        try:
            self.logger.close()
        except Exception as e:  # kept in logger.failure
            log.error("closing the MCAP log failed: %s", e)
        self._closed = True
        final = self.status()
        log.info(
            "daemon stopped: %s samples, %s dropped, %s bad",
            final["samples"],
            final["dropped"],
            final["bad"],
        )
        return final

    def __enter__(self) -> Daemon:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


_OFF_STATES = {"off", "clear", "cleared", "ok", "normal", "none", "false", "0", "inactive"}


def _is_active(state: Any) -> bool:
    if isinstance(state, bool):
        return state
    return str(state).lower() not in _OFF_STATES
