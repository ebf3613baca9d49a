"""The daemon's monitor stage: one monitor bank for all actuators (``MonitorFleet``: each on its
latest baseline from the store, or the default), the latency figures, auto-commissioning.

:meth:`MonitorStage.run` takes a tick's :class:`~service.daemon.block.Block` from the intake,
feeds its samples to the bank in one ``update_arrays`` call and puts the output rows in the
block for the outputs stage.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from typing import Any

import numpy as np

from service.daemon.block import Block
from service.daemon.commission import Commissioner
from service.daemon.status import percentiles
from service.monitor import Baseline, MonitorBank, MonitorConfig, MonitorFleet
from service.wire import messages as m

__all__ = ["LATENCY_BUCKETS_S", "MonitorStage"]

#: upper bounds of the latency histogram's buckets [s] (receipt -> health output)
LATENCY_BUCKETS_S = np.array([0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5])

log = logging.getLogger("servowatch.daemon")


class MonitorStage:
    """The monitors of every actuator (see the module docstring). ``bank`` replaces the
    ``MonitorFleet`` built from ``config`` and ``baseline`` (benchmarks: a bank that does
    nothing); ``store_url`` (None: no store) gives each actuator its stored baseline."""

    def __init__(
        self,
        config: MonitorConfig,
        baseline: Baseline | None = None,
        *,
        store_url: str | None = None,
        bank: Any = None,
    ) -> None:
        self.store_url = store_url
        if bank is None:
            resolve = self._resolve if store_url is not None else None
            bank = MonitorFleet(config, baseline, resolve)
        self.bank = bank
        self._rows: dict[int, Any] = {}  # bank row -> ActuatorState
        self._row_key: dict[int, str] = {}  # bank row -> meas key
        self.latency: deque = deque(maxlen=50000)  # receipt -> health output [s]
        self.age: deque = deque(maxlen=50000)  # sample time t -> health output [s] (Unix t)
        # every output's latency since the start, as cumulative counts (the metrics' histogram)
        self.latency_counts = np.zeros(len(LATENCY_BUCKETS_S) + 1, np.int64)  # last: +Inf
        self.latency_sum_s = 0.0
        self.commissioner: Commissioner | None = None
        self.errors = 0

    def commission(self, retrack: Any, duration_s: float, min_in_band: float) -> None:
        """Auto-commission uncommissioned actuators (``Commissioner``); ``retrack(row, c_lk0=,
        info=)`` tells the outputs of a new baseline."""
        self.commissioner = Commissioner(
            self.bank, self.store_url, retrack, duration_s, min_in_band
        )

    def warm_up(self) -> float:
        """Run a throwaway bank of the same configuration on a few synthetic samples, so that
        JIT compilation happens before the first real sample (and before READY). Seconds."""
        if not isinstance(self.bank, MonitorBank | MonitorFleet):
            return 0.0
        t0 = time.perf_counter()
        try:
            b = MonitorBank(self.bank.config, self.bank.baseline)
            k = b.index_of("_warm")
            ch = np.tile([0.0, 0.0, 0.0, 0.0, 10e6, 10e6, 20e6], (5, 1))
            b.update_arrays(np.full(5, k, np.int64), np.arange(5) * 1e-3, ch)
        except Exception as e:  # warming up is an optimisation only
            log.warning("monitor warm-up failed: %s", e)
        return time.perf_counter() - t0

    # -- the worker ---------------------------------------------------------------------
    def run(self, blk: Block) -> None:
        """The block's samples through the bank; the output rows into the block. A monitor
        failure is counted and logged, never raised (the block then has no rows)."""
        b = self.bank
        if isinstance(b, MonitorBank):  # a clock that went back: the filter restarts
            for key in blk.restarts:
                b.t_last[b.index_of(key)] = -np.inf
        parts = blk.parts
        if not parts:
            return
        try:
            sizes = [len(p.a.t) - p.j0 for p in parts]
            rows_of = []
            for p in parts:
                row = b.index_of(p.key)  # in the worker: it may grow the bank's arrays
                if self._rows.get(row) is not p.st:  # new, or back after it expired
                    self._rows[row] = p.st
                    self._row_key[row] = p.key
                    blk.new_rows.append((row, p.st, self._track_info(p.key)))
                blk.states[row] = p.st
                rows_of.append(row)
            ks = np.repeat(np.array(rows_of, np.int64), sizes)
            _, t, ch = blk.arrays()
            recv = np.repeat(np.array([p.t_recv for p in parts]), sizes)
            rows = b.update_arrays(ks, t, ch)
            blk.ks = ks
            idx = rows.index
            if len(idx) == 0:
                return
            blk.rows = rows
            now_m, now_w = time.monotonic(), time.time()
            lat = now_m - recv[idx]
            self.latency.extend(lat.tolist())
            self.latency_counts += np.bincount(
                np.searchsorted(LATENCY_BUCKETS_S, lat), minlength=len(self.latency_counts)
            )
            self.latency_sum_s += float(lat.sum())
            old = rows.t > 1e9  # Unix-time sample clock: end-to-end age is meaningful
            if old.any():
                self.age.extend((now_w - rows.t[old]).tolist())
            if self.commissioner is not None:
                self.commissioner.feed(parts, rows, ks)
        except Exception as e:  # a monitor failure must not kill the daemon
            self.errors += 1
            log.exception("monitor update failed: %s", e)

    def row_of(self, key: str) -> int | None:
        """The bank row of meas key ``key`` once it had samples, else None."""
        row = self.bank.ids.get(key) if hasattr(self.bank, "ids") else None
        return row if row in self._rows else None

    def counters_of_row(self, row: int) -> dict[str, int]:
        """The monitor's sample counters of bank row ``row``."""
        return self.bank.counters_of(self._row_key[row])

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
        """``FanOut.track`` arguments of a meas key: its baseline's C_Lk and commissioning."""
        b = self.bank
        if not isinstance(b, MonitorFleet):
            return {}
        v = b.versions.get(key)
        info = {"commissioned": v is not None, "baseline_version": v}
        return {"c_lk0": b.bank.baseline_of(key).c_lk, "info": info}

    # -- status -------------------------------------------------------------------------
    def unit_status(self, key: str) -> dict[str, Any]:
        """Status fields of meas key ``key``: the monitor's counters and the C_Lk changes its
        detector read (None before its first sample), commissioning."""
        try:
            mon = {**self.bank.counters_of(key), "c_lk_changes": self.bank.c_lk_changes_of(key)}
        except KeyError:
            mon = None
        out: dict[str, Any] = {"monitor": mon}
        b = self.bank
        if isinstance(b, MonitorFleet):
            v = b.versions.get(key)
            out.update({"commissioned": v is not None, "baseline_version": v})
        return out

    def status(self) -> dict[str, Any]:
        """The monitors' process model, latency and age percentiles [ms]."""
        lat, age = list(self.latency), list(self.age)
        p50, p99 = percentiles(lat)
        a50, a99 = percentiles(age)
        return {
            "model": self.bank.config.model,  # the model the monitors actually run
            "latency_ms": {
                "p50": None if p50 is None else 1e3 * p50,
                "p99": None if p99 is None else 1e3 * p99,
                "n": len(lat),
            },
            "age_ms": {
                "p50": None if a50 is None else 1e3 * a50,
                "p99": None if a99 is None else 1e3 * a99,
            },
            "latency_hist": {  # cumulative since the start: counts per bucket (le), sum
                "le_s": LATENCY_BUCKETS_S.tolist(),
                "counts": self.latency_counts.tolist(),
                "sum_s": self.latency_sum_s,
            },
            "errors": self.errors,
        }
