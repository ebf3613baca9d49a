"""The monitoring daemon: Zenoh samples in, one monitor bank for all actuators, estimates out,
MCAP log.

The daemon is a pipeline of stages, each owning its state and its ``status()``, with one
block type (``service.daemon.block.Block``, one worker tick) passing between them
(docs/design.md, "Data flow" and "Backpressure"):

* ``intake.Intake``: the Zenoh subscriber callback only appends ``(key, payload, t_recv)``
  to its bounded queue (a full queue drops the new message and counts it against its
  actuator); each tick the worker drains the queue, decodes and validates each message into
  arrays and checks sequence numbers and sample times per actuator;
* ``monitoring.MonitorStage``: the whole tick's samples to the monitors in one
  ``MonitorBank.update_arrays`` call (each actuator on its latest baseline from the store,
  or the default), auto-commissioning;
* ``outputs.Outputs``: every accepted sample logged, the output rows through
  ``service.daemon.fanout.FanOut`` (the replay's fan-out too): est, residual and health logged
  every ``log_every``-th output and at every alarm event, events logged, est/res/health
  published every ``publish_every``-th output per actuator; closed operating periods to the
  health store (``service.store.StoreWriter``, a thread of its own); with ``[foxglove]`` the
  live feed (docs/dashboard.md);
* ``member.GroupMember`` (with ``[group]``): ownership of the units among the members.

:class:`Daemon` holds the Zenoh session's entities, the worker thread and start/stop, and
wires the stages. The status queryable ``monitor/{station}/{shard}/status`` answers a JSON
snapshot made of the stages' status (``service.daemon.status.snapshot``).

Bad input (malformed payload, wrong schema, NaN/inf, duplicate or out-of-order samples,
oversize messages, unparseable keys) is counted per actuator and logged at a limited rate;
it never stops the worker and never discards a good sample of the same message stream. A
failure of the MCAP log degrades the service (``service.daemon.outputs``) and ``servowatch
run`` exits with ``EXIT_LOG_FAILURE``.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from service.config import ServiceConfig
from service.daemon.intake import ClockCheck, Intake
from service.daemon.member import GroupMember
from service.daemon.monitoring import MonitorStage
from service.daemon.outputs import (
    Outputs,
    default_log_path,
    open_logger,
    open_retention,
    store_target,
)
from service.daemon.ratelimit import RateLimitedLog
from service.daemon.status import snapshot
from service.daemon.systemd import extending_start, notify_ready, sd_notify, watchdog_interval
from service.monitor import Baseline
from service.wire import messages as m

__all__ = ["Daemon", "default_log_path", "EXIT_LOG_FAILURE", "store_target"]

log = logging.getLogger("servowatch.daemon")

#: exit code of ``servowatch run`` when the MCAP log failed (docs/cli.md, "Commands")
EXIT_LOG_FAILURE = 5  # 3 and 4 are the Zenoh session's (service.config)


class Daemon:
    """The monitoring daemon (see the module docstring): ``intake``, ``monitor``,
    ``outputs`` and, with ``[group]``, ``member``.

    Usable without Zenoh: ``submit(key, payload)`` then ``process_pending()`` (tests). With
    Zenoh: ``start(session)`` declares the subscriber, queryable and liveliness token and
    starts the worker; ``stop()`` stops the inflow, drains the queue, finishes the log.

    ``logger`` (default: a ``ProcessLogger``, or an in-process ``McapLogger`` when
    ``log_process`` is False) needs ``log``, ``log_block``, ``commit``, ``close``, ``paths``
    and ``failure``. ``bank`` replaces the ``MonitorBank`` built from the config
    (benchmarks: a bank that does nothing).
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
        self.station, self.shard, self.key_expr = config.station, config.shard, config.key_expr
        self.tick_s = tick_s
        self.gather_s = gather_s
        bad_log = RateLimitedLog(log, bad_log_interval_s)
        self.intake = Intake(
            queue_size=config.queue_size, max_bytes=config.max_bytes,
            clock=ClockCheck(**config.clock.model_dump()), max_batch=max_batch, bad_log=bad_log,
            max_per_aircraft=config.max_units_per_aircraft, expire_s=config.unit_expire_s,
        )  # fmt: skip
        self.member = None
        if config.group is not None:
            self.member = GroupMember(
                config.group, self.station, self.shard, self.intake.submit, config.max_bytes
            )
        self.metrics = None  # the OpenMetrics endpoint, bound first: a port in use fails here
        if config.metrics is not None:
            from service.edge.metrics import MetricsServer

            host, port = config.metrics.host_port()
            m = config.metrics
            self.metrics = MetricsServer(
                self.status, host, port, allow_remote=m.allow_remote,
                max_connections=m.max_connections, idle_s=m.idle_s, max_per_s=m.max_per_s,
            )  # fmt: skip
        store_url = store_target(config.store)
        baseline = Baseline.load(config.baseline) if config.baseline and bank is None else None
        self.monitor = MonitorStage(config.monitor, baseline, store_url=store_url, bank=bank)
        log_id = None  # the id of the log the live periods are written beside
        retention = None if logger is not None else open_retention(config, log_path)
        if logger is None:
            b = self.monitor.bank
            log_id = uuid.uuid4().hex[:16]
            meta = {"source": "daemon", "station": self.station, "shard": self.shard,
                    "monitor_config": b.config.model_dump_json(),
                    "baseline": b.baseline.model_dump_json(), "log_id": log_id}  # fmt: skip
            logger, log_path = open_logger(config, log_path, meta, log_process)
        self.log_path = Path(log_path) if log_path is not None else None
        self.outputs = Outputs(
            config, logger, counters=self.monitor.counters_of_row, store_url=store_url,
            bad_log=bad_log, log_id=log_id, retention=retention,
        )  # fmt: skip
        pc = config.prognostics
        if self.outputs.store is not None and pc.auto_commission_s is not None:
            self.monitor.commission(
                self.outputs.fanout.retrack, pc.auto_commission_s, pc.auto_commission_min_in_band
            )
        self.started = time.time()
        self.ticks = 0
        self.busy_s = 0.0
        self.errors = 0  # the worker's and the Zenoh callbacks'
        self._stop = threading.Event()
        self._notify_lock = threading.Lock()
        self._worker: threading.Thread | None = None
        self._session = None
        self._decl: list[Any] = []
        self._closed = False
        self._last_silence_check = 0.0
        self._wd_interval = watchdog_interval()
        self._wd_last = 0.0
        self.sweep_s = config.log.sweep_s
        self._last_sweep = -math.inf
        self._swept_paths = 0
        self._sweep_lock = threading.Lock()

    # -- the pipeline ---------------------------------------------------------------------
    def submit(self, key: str, payload: bytes, t_recv: float | None = None) -> bool:
        """Queue one message (never blocks); False if the queue was full (drop counted)."""
        return self.intake.submit(key, payload, t_recv)

    @property
    def queued(self) -> int:
        """Messages waiting in the receive queue."""
        return self.intake.queued

    def process_pending(self) -> int:
        """One tick: intake (drain, validate), monitor, outputs (log, publish, store).
        Returns the number of samples fed to the monitors."""
        t0 = time.perf_counter()
        blk = self.intake.take()
        if blk is None:
            return 0
        self.monitor.run(blk)
        self.outputs.write(blk)
        self.ticks += 1
        self.busy_s += time.perf_counter() - t0
        return blk.samples

    def check_silence(self, now: float | None = None) -> list[str]:
        """Mark actuators silent after ``silence_s`` without a message; return new ones."""
        now = time.monotonic() if now is None else now
        out = []
        for key, st, gap in self.intake.silent(now, self.config.silence_s):
            out.append(st.name)
            self.outputs.end_period(self.monitor.row_of(key))
            self.outputs.service_event(st, "silent", st.last_t, value=gap)
        return out

    def expire_units(self, now: float | None = None) -> list[str]:
        """Units silent for ``unit_expire_s`` leave the table (``Intake.expire``)."""
        now = time.monotonic() if now is None else now
        out = []
        for key, st in self.intake.expire(now):
            if st is not None:
                self.outputs.end_period(self.monitor.row_of(key))
                out.append(st.name)
        if out:
            log.info("%d silent units left the table: %s", len(out), ", ".join(out[:10]))
        return out

    def release_units(self) -> list[str]:
        """Group units another member took over (``GroupMember.release_units``)."""
        return self.member.release_units(self.intake, self.monitor, self.outputs)

    def check_unmonitored(self, now: float) -> list[str]:
        """Group units no member monitors (``GroupMember.check_unmonitored``)."""
        return self.member.check_unmonitored(now, self.config.silence_s, self.intake, self.outputs)

    def maybe_sweep(self, now: float) -> list:
        """A retention sweep of the logs every ``[log] sweep_s`` and after each rotation
        (``Outputs.sweep_logs``); returns what it deleted."""
        with self._sweep_lock:  # the worker's, and a caller's (tests)
            n = len(self.outputs.logger.paths)
            if now - self._last_sweep < self.sweep_s and n == self._swept_paths:
                return []
            self._last_sweep, self._swept_paths = now, n
            return self.outputs.sweep_logs()

    def _run_worker(self) -> None:
        while True:
            stopping = self._stop.is_set()
            self.intake.wake.wait(self.tick_s)
            self.intake.wake.clear()
            try:
                self.process_pending()
                now = time.monotonic()
                if now - self._last_silence_check > 0.2:
                    self._last_silence_check = now
                    changed = []
                    if self.member is not None:
                        changed = self.release_units() + self.check_unmonitored(now)
                        self.member.publish_outputs(now, self.intake)
                    self.expire_units(now)
                    if self.check_silence(now) or changed:
                        self.outputs.logger.commit()
                    self.outputs.check_feed()
                    self.maybe_sweep(now)
                if self._wd_interval is not None and now - self._wd_last > self._wd_interval:
                    self._wd_last = now
                    with self._notify_lock:  # never a WATCHDOG after STOPPING
                        if not self._stop.is_set():
                            sd_notify("WATCHDOG=1")
            except Exception:
                self.errors += 1
                log.exception("worker tick failed")
            if stopping and not self.intake.queued:
                return
            if self.gather_s > 0:
                time.sleep(self.gather_s)  # let the next tick's samples gather into one batch

    def status(self) -> dict[str, Any]:
        """A JSON-ready snapshot: actuators, counters, latency, alarms, silent actuators, the
        log's failure and the service state (``service.daemon.status.snapshot``)."""
        info = {"station": self.station, "shard": self.shard, "key_expr": self.key_expr,
                "started": self.started}  # fmt: skip
        return snapshot(
            info, self.intake, self.monitor, self.outputs, self.member,
            busy_s=self.busy_s, errors=self.errors,
        )  # fmt: skip

    # -- Zenoh ----------------------------------------------------------------------------
    def _on_zenoh_sample(self, sample) -> None:
        try:
            key = str(sample.key_expr)
            if not self.intake.admit_key(key):  # the key grammar, the per-aircraft cap
                return
            if self.member is not None:  # a unit of another member is held, not queued
                self.member.group.admit(key, sample.payload.to_bytes(), time.monotonic())
            else:
                self.intake.submit(key, sample.payload.to_bytes())
            si = sample.source_info
            if si is not None and si.source_id is not None:
                self.intake.source(str(si.source_id), key)
        except Exception:  # never let a callback raise into zenoh
            self.errors += 1

    def _on_miss(self, miss) -> None:
        """Samples that the advanced subscriber could not recover, counted per actuator."""
        try:
            key = self.intake.key_of_source(str(miss.source))
            if self.member is not None and key and not self.member.group.owns_key(key):
                return  # another member's unit: its misses are that member's to count
            st = self.intake.missed(key, int(miss.nb))
            log.warning("missed %d messages from %s", miss.nb, st.name if st else miss.source)
        except Exception:
            self.errors += 1

    def _on_alive(self, sample) -> None:
        """Liveliness token of an actuator appeared (PUT) or vanished (DELETE)."""
        try:
            import zenoh

            self.intake.alive(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
        except Exception:
            self.errors += 1

    def _on_status_query(self, query) -> None:
        try:
            key = m.KEY_STATUS.format(station=self.station, shard=self.shard)
            query.reply(key, m.encode_json(self.status()))
        except Exception as e:
            self.errors += 1
            log.warning("status query failed: %s", e)

    # -- lifecycle ----------------------------------------------------------------------
    def start(self, session=None) -> None:
        """Load the monitor's kernels and what the first outputs import, then declare Zenoh
        entities on ``session`` (if given) and start the worker thread. Loading comes first:
        it holds the GIL for seconds, during which Zenoh's callbacks could not queue samples
        (a unit would look silent) nor answer status (a daemon answers once it can
        monitor)."""
        with extending_start("starting: loading the kernels"):  # systemd: the start goes on
            warm = self.monitor.warm_up()
            self.intake.warm_up()
            self.outputs.fanout.warm_up()
        if warm > 0.05:
            log.info("monitor warm-up (JIT) took %.2f s", warm)
        if session is not None:
            self._session = session
            self.outputs.fanout.session = session
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
            if self.member is not None:  # before the status answers: a member is one at once
                self._decl.extend(self.member.declare(session))
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
        if self.metrics is not None:
            self.metrics.start()
            log.info("metrics on http://%s:%d/metrics", *self.metrics.address)
        self._worker = threading.Thread(
            target=self._run_worker, name="servowatch-worker", daemon=True
        )
        self._worker.start()
        self.maybe_sweep(time.monotonic())  # the files of earlier runs, before READY
        notify_ready()  # once compiled, loaded, subscribed and serving status
        log.info("daemon %s/%s started on %s", self.station, self.shard, self.key_expr)
        self.outputs.announce_log()  # the file written, by its own name (rotated or not)

    def stop(self, timeout: float = 30.0) -> dict[str, Any]:
        """Stop the inflow, process what is queued, finish the log. Idempotent.

        Returns the final status."""
        if self._closed:
            return self.status()
        with self._notify_lock:
            self._stop.set()
            sd_notify("STOPPING=1")
        if self.member is not None:  # the others take its units over while it drains
            self.member.leave()
        # stop the inflow first: the subscriber goes, queued messages are still processed
        for d in self._decl[:1]:
            with contextlib.suppress(Exception):
                d.undeclare()
        self.intake.wake.set()
        if self._worker is not None:
            self._worker.join(timeout)
        while self.intake.queued:  # no worker (tests) or it gave up: drain here
            self.process_pending()
        for d in self._decl[1:]:
            with contextlib.suppress(Exception):
                d.undeclare()
        self.outputs.close()
        self._closed = True
        final = self.status()
        if self.metrics is not None:
            self.metrics.close()
        log.info(
            "daemon stopped: %s samples, %s dropped, %s bad",
            final["samples"],
            final["dropped"],
            final["bad"],
            extra={"fields": {k: final[k] for k in ("samples", "dropped", "bad")}},
        )
        return final

    def __enter__(self) -> Daemon:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
