"""The daemon's outputs stage: the MCAP log, the fan-out (est/res/health logged and published,
alarm events), the live Foxglove feed, operating periods to the health store, and the
daemon-side events (silent, resumed, restart, released, group events).

:meth:`Outputs.write` takes a tick's :class:`~service.daemon.block.Block` after the monitor
stage: it logs the block's events and accepted measurements in arrival order, then hands the
output rows to ``service.daemon.fanout.FanOut`` (the replay's fan-out too) and commits the log.

A failure of the MCAP log (disk full, the log process gone) is kept as ``log_failure``: the
status shows it and reports the service ``degraded``, systemd gets a STATUS line, and
``servowatch run`` exits with ``EXIT_LOG_FAILURE``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from service.config import ServiceConfig
from service.daemon.block import Block, Part
from service.daemon.fanout import FanOut
from service.daemon.intake import MAX_ACTUATORS, ActuatorState
from service.daemon.ratelimit import RateLimitedLog
from service.daemon.systemd import sd_notify
from service.jsonutil import flat
from service.log.proclog import MEAS_LOG_FIELDS, ProcessLogger
from service.prognostics import PeriodConfig
from service.wire import messages as m

__all__ = ["Outputs", "default_log_path", "open_logger", "open_retention", "store_target"]

log = logging.getLogger("servowatch.daemon")


def default_log_path(log_dir: Path, station: str, shard: str, prefix: str = "servowatch") -> Path:
    """``{log_dir}/{prefix}-{station}-{shard}-{UTC time}.mcap``."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    return Path(log_dir) / f"{default_log_prefix(station, shard, prefix)}{stamp}.mcap"


def default_log_prefix(station: str, shard: str, prefix: str = "servowatch") -> str:
    """The name every default log file of daemon ``station``/``shard`` starts with."""
    return f"{prefix}-{station}-{shard}-"


def open_retention(config: ServiceConfig, log_path: str | Path | None):
    """The retention of the daemon's logs (``[log] keep_bytes``, ``keep_days``;
    ``service.log.retention``): every run's files on the default path, else the rotation set
    of ``log_path`` (an explicit ``--log``)."""
    from service.log.retention import Retention, pattern_of

    lc = config.log
    if log_path is None:
        folder = Path(config.log_dir)
        pattern = pattern_of("", default_log_prefix(config.station, config.shard, config.log_name))
    else:
        folder = Path(log_path).parent
        pattern = pattern_of(log_path)
    return Retention(folder, pattern, keep_bytes=lc.keep_bytes, keep_days=lc.keep_days)


def store_target(store: str | None) -> str | None:
    """The store a daemon writes to: None for None/"off"/"none", else the path or URL."""
    return None if store is None or store.strip().lower() in ("off", "none") else store


def open_logger(
    config: ServiceConfig, log_path: str | Path | None, metadata: dict[str, str], process: bool
) -> tuple[Any, Path]:
    """The daemon's MCAP logger (a ``ProcessLogger``, or an in-process ``McapLogger`` when
    ``process`` is False) at ``log_path`` (None: ``default_log_path``), and that path."""
    from service.log import McapLogger

    if log_path is None:
        log_path = default_log_path(config.log_dir, config.station, config.shard, config.log_name)
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    kw = {
        "rotate_bytes": config.rotate_bytes,
        "rotate_s": config.rotate_s,
        "flush_s": config.flush_s,
        "metadata": metadata,
    }
    logger = ProcessLogger(log_path, **kw) if process else McapLogger(log_path, **kw)
    return logger, Path(log_path)


def log_alarm(unit: str, d: dict[str, Any]) -> None:
    """An alarm event as one log line with its unit, kind, state, value and time as fields
    (``fields``: JSON keys, journald ``SERVOWATCH_*`` fields), the time in RFC 3339
    (``event_time``: the sample's; a record's own ``time`` is when it was logged)."""
    from service.log.retention import rfc3339

    kind, state, value, t = d.get("kind"), d.get("state"), d.get("value"), d.get("t")
    when = rfc3339(float(t)) if isinstance(t, int | float) and np.isfinite(t) else None
    shown = f"{value:.4g}" if isinstance(value, int | float) else str(value)
    log.log(
        logging.WARNING if _is_active(state) else logging.INFO,
        "alarm %s %s %s, value %s at %s", unit, kind, state, shown, when,
        extra={"fields": {"event": "alarm", "unit": unit, "kind": kind, "state": state,
                          "value": value, "event_time": when}},
    )  # fmt: skip


_OFF_STATES = {"off", "clear", "cleared", "ok", "normal", "none", "false", "0", "inactive"}


def _is_active(state: Any) -> bool:
    if isinstance(state, bool):
        return state
    return str(state).lower() not in _OFF_STATES


class Outputs:
    """Everything that leaves the daemon (see the module docstring).

    ``logger`` needs ``log``, ``log_block``, ``commit``, ``close``, ``paths`` and
    ``failure``. ``counters(row)`` gives the monitor's counters of a bank row (for the
    periods); ``store_url`` (None: no store) receives the closed periods."""

    def __init__(
        self,
        config: ServiceConfig,
        logger: Any,
        *,
        counters: Callable[[int], Any],
        store_url: str | None,
        bad_log: RateLimitedLog,
        log_id: str | None = None,
        retention: Any = None,
    ) -> None:
        self.logger = logger
        self.retention = retention  # service.log.retention.Retention, or None
        self._announced = 0  # log files announced so far
        self._meas_topics: dict[str, str] = {}  # meas key -> its MCAP topic
        self.log_failure: str | None = None
        self.bad_log = bad_log
        self.errors = 0
        self.store = None  # StoreWriter
        self.store_url = store_url
        self._life = None  # FlightStamper, on the first closed period
        self._flights_logged: dict[str, int] = {}
        self.flight_gap_s = config.prognostics.flight_gap_s
        if store_url is not None:
            from service.store.writer import StoreWriter

            self.store = StoreWriter(store_url)
        self.foxglove = None  # FoxgloveFeed
        self._feed_state = "ok"  # its guard's listener, as last reported
        if config.foxglove is not None:
            from service.edge.foxglove_feed import FoxgloveFeed

            fc = config.foxglove
            host, port = fc.host_port()
            self.foxglove = FoxgloveFeed(
                host, port, queue_size=fc.queue_size, backlog=fc.backlog, every=fc.every,
                name=f"servowatch {config.station}/{config.shard}", limits=fc.guard_limits(),
            )  # fmt: skip
        pc = config.prognostics
        self.fanout = FanOut(
            logger,
            log_every=config.log_every,
            publish_every=config.publish_every,
            on_publish_error=self._publish_failed,
            on_periods=None if self.store is None else self._on_periods,
            # the log's id: a replay of that log replaces these periods (docs/store.md)
            source=f"live:{config.station}/{config.shard}" + (f"@{log_id}" if log_id else ""),
            period_config=PeriodConfig(silence_s=pc.period_silence_s, window_s=pc.period_window_s),
            counters=counters,
            live=self.foxglove,
        )

    # -- the worker ---------------------------------------------------------------------
    def write(self, blk: Block) -> None:
        """A tick's block: its events and measurements in arrival order, then its output
        rows (log blocks, events, publishing, periods); the log committed."""
        run: list[Part] = []  # consecutive parts: their samples are a run of blk.arrays()
        off = 0
        for e in blk.log:
            if isinstance(e, Part):
                run.append(e)
            else:
                off = self._log_meas(blk, run, off)
                run = []
                self.service_event(*e)
        self._log_meas(blk, run, off)
        for row, st, info in blk.new_rows:
            self.fanout.track(row, st.aircraft, st.actuator, **info)
        rows = blk.rows
        if rows is not None:
            for em in self.fanout.emit(rows, blk.ks):
                st = blk.states[em.row]
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
                    log_alarm(st.name, d)
        self.commit()

    def _log_meas(self, blk: Block, run: list[Part], off: int) -> int:
        """The accepted samples of the messages ``run`` (samples ``off``.. of the block's
        arrays), each on its actuator's ``meas`` topic, as one record for a logger with
        ``log_blocks`` (the log process). Returns the offset after the run."""
        if not run:
            return off
        seq, t, ch = blk.arrays()
        cache = self._meas_topics
        topics = []
        for p in run:
            tp = cache.get(p.key)
            if tp is None:
                if len(cache) > 4 * MAX_ACTUATORS:
                    cache.clear()
                tp = cache[p.key] = m.mcap_topic(p.st.aircraft, p.st.actuator, "meas")
            topics.append(tp)
        counts = [len(p.a.t) - p.j0 for p in run]
        end = off + sum(counts)
        vals = np.column_stack([ch[off:end], seq[off:end], t[off:end]])  # MEAS_LOG_FIELDS
        ts = t[off:end]
        many = getattr(self.logger, "log_blocks", None)
        try:
            if many is not None:
                many(topics, counts, ts, MEAS_LOG_FIELDS, vals, int_fields=("seq",))
            else:
                k = 0
                for topic, n in zip(topics, counts, strict=True):
                    self.logger.log_block(
                        topic, ts[k : k + n], MEAS_LOG_FIELDS, vals[k : k + n], int_fields=("seq",)
                    )
                    k += n
        except Exception:  # kept in logger.failure and logged there; monitoring goes on
            self.errors += 1
        fx = self.foxglove
        if fx is not None:
            k = 0
            for topic, n in zip(topics, counts, strict=True):
                if fx.wants(topic):
                    fx.log_block(
                        topic, ts[k : k + n], MEAS_LOG_FIELDS, vals[k : k + n], int_fields=("seq",)
                    )
                k += n
        return end

    def service_event(
        self, st: ActuatorState, kind: str, t: float | None, value: Any = None
    ) -> None:
        """A daemon-side event (silent, resumed, restart, released) in the log and the
        actuator's status."""
        t = float(t) if t is not None else time.time()
        d = {"t": t, "kind": kind, "value": value, "wall": time.time()}
        st.events.append(d)
        self._log_event(f"/fleet/{st.aircraft}/{st.actuator}/service", t, d)
        log.info("%s %s", st.name, kind,
                 extra={"fields": {"event": kind, "unit": st.name}})  # fmt: skip

    def group_event(self, key: str, kind: str, value: Any, st: ActuatorState | None) -> None:
        """An event of a group unit (meas key ``key``), owned by this member or not: logged,
        and in the unit's status (``st``) when this member has monitored it."""
        parts = key.split("/")
        t = time.time()
        d = {"t": t, "kind": kind, "value": value, "wall": t}
        if st is not None:
            st.events.append(d)
        self._log_event(f"/fleet/{parts[1]}/{parts[2]}/service", t, d)

    def _log_event(self, topic: str, t: float, d: dict[str, Any]) -> None:
        """An event in the log: a ``servowatch.Event`` protobuf row (``log_event``), or JSON
        for a logger without it."""
        ev = getattr(self.logger, "log_event", None)
        if ev is not None:
            ev(topic, t, d)
        else:
            self.logger.log(topic, t, flat(d))

    def end_period(self, row: int | None) -> None:
        """The open operating period of bank row ``row`` ends (silent, released)."""
        if row is not None:
            self.fanout.flush(row)

    def commit(self) -> None:
        """Send what was logged to the log; take up its first failure."""
        self.logger.commit()
        self.check_log()
        if len(self.logger.paths) != self._announced:
            self.announce_log()

    def announce_log(self) -> Path | None:
        """Log the file now written (the name it has: a rotated file's own name), once per
        file; returns it."""
        paths = self.logger.paths
        self._announced = len(paths)
        if not paths:
            return None
        log.info("logging to %s", paths[-1], extra={"fields": {"log_file": str(paths[-1])}})
        return Path(paths[-1])

    def sweep_logs(self) -> list:
        """A retention sweep (``service.log.retention.Retention.sweep``): never the open
        file. Returns what it deleted."""
        if self.retention is None:
            return []
        closed = getattr(self.logger, "closed", False)
        open_paths = [] if closed or not self.logger.paths else [self.logger.paths[-1]]
        try:
            return self.retention.sweep(open_paths)
        except Exception as e:  # a directory gone, ...: counted, monitoring goes on
            self.errors += 1
            log.warning("retention sweep failed: %s", e)
            return []

    def check_log(self) -> None:
        """Take up the logger's first failure: status, health, systemd."""
        if self.log_failure is None and self.logger.failure is not None:
            self.log_failure = str(self.logger.failure)
            log.error("MCAP log failed, service degraded: %s", self.log_failure)
            sd_notify(f"STATUS=degraded: MCAP log failed: {self.log_failure[:200]}")

    def check_feed(self) -> None:
        """The live feed's listener went down or came back: logged, and a systemd STATUS
        line (the status shows it as ``feed_failure``, the service ``degraded``)."""
        if self.foxglove is None:
            return
        state = self.foxglove.guard.listener()
        if state == self._feed_state:
            return
        self._feed_state = state
        if state == "ok":
            log.info("the Foxglove feed's listener is back")
            sd_notify(
                "STATUS=ok" if self.log_failure is None else "STATUS=degraded: MCAP log failed"
            )
        else:
            log.error("the Foxglove feed's listener: %s; service degraded", state)
            sd_notify(f"STATUS=degraded: the Foxglove feed's listener: {state[:200]}")

    def _publish_failed(self, e: Exception) -> None:
        self.errors += 1
        self.bad_log.warning("publish", "publish failed: %s", e)

    # -- health store -------------------------------------------------------------------
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
        from service.log.flightrec import FLIGHT_RECORD, FlightRecord

        seen = self._flights_logged
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
        if self._life is None:
            from service.prognostics.life import FlightStamper
            from service.store import open_store

            url = self.store_url

            def last(name: str):
                try:
                    with open_store(url, read_only=True) as st:
                        if name not in st.actuators():
                            return None
                        ps = st.life(name)  # the unit's life order (every view's)
                except Exception as e:  # a store the writer cannot read: count from 0
                    log.warning("store: last period of %s: %s", name, e)
                    return None
                return ps[-1] if ps else None

            self._life = FlightStamper(last, self.flight_gap_s)
        return self._life

    # -- lifecycle and status -----------------------------------------------------------
    def close(self) -> None:
        """Open periods to the store, publishers undeclared, the live feed, the store writer
        and the log closed."""
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

    def unit_status(self, name: str, row: int | None = None) -> dict[str, Any]:
        """Stored periods and the last RUL of actuator ``name`` (none without a store) and
        the NIS in band and the pooled C_Lk of bank row ``row``
        (``FanOut.nis_in_band_of``, ``FanOut.pooled_of``)."""
        out = self.store.info(name) if self.store is not None else {}
        out["nis_in_band"] = self.fanout.nis_in_band_of(row)
        out["c_lk_pooled"] = self.fanout.pooled_of(row)
        return out

    def status(self) -> dict[str, Any]:
        """The log's paths and failure, the store writer's and the live feed's state."""
        self.check_log()
        w = self.store
        store = None
        if w is not None:
            from service.store import describe_url

            store = {"where": describe_url(w.url), "pending": w.pending, "written": w.written,
                     "errors": w.errors, "failure": w.failure}  # fmt: skip
        return {
            "log_failure": self.log_failure,
            "log": [str(p) for p in self.logger.paths],
            "log_retention": None if self.retention is None else self.retention.status(),
            "store": store,
            "foxglove": None if self.foxglove is None else self.foxglove.status(),
            "errors": self.errors,
        }
