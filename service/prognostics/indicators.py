"""Condition indicators: the monitor's output rows of one actuator folded into operating
periods (ISO 13374 "health assessment" input), one ``service.store.Period`` each.

A period closes when the actuator goes silent (no sample for ``silence_s``) or after
``window_s`` of sample time. Per period (docs/prognostics.md section 1):

- operating time: the sum of the sample intervals no longer than ``max_dt_s``; samples;
- C_Lk over the *observable* samples only: the filter's own 1-sigma of C_Lk below
  ``obs_sigma_ratio`` times the baseline C_Lk, at least ``settle_s`` after the period's first
  sample. The UKF's posterior sigma is small only where the data constrain C_Lk (a loaded
  hold with the full channel set, P12 != 0: the null relation of docs/estimation.md); with
  no load, a reduced channel set or just after a re-initialisation it stays near its prior.
  The observable estimates, decimated to ``c_lk_rate_hz`` (the estimate is correlated over
  much longer than that), give the robust mean (median) and sigma (1.4826 MAD);
  c_lk_ratio = median / C_Lk,baseline, the indicator the views and the RUL read;
- the pooled C_Lk, recorded beside the indicator and not driving it (``BankRows.pooled``:
  everything the filter learnt since the last detected change, with the sigma of that pooled
  information; docs/estimation.md, "The pooled C_Lk"; decisions/0025): ``c_lk_pooled`` and
  ``c_lk_pooled_sigma`` are the pool of the period's last row whose pooled sigma is within
  the observability limit ``pooled_limit`` (its +-z band inside ``pool_tol`` of the increase
  read, at least of ``pool_d_min``), NaN where no row passes or the rows came without a pool;
- P_SR mean and minimum, null bias i_b mean, NIS/dof mean and the share of samples whose NIS
  lies in the two-sided 95 % chi-square band of its degrees of freedom;
- alarms raised (rising edges of the health alarm flags, every kind) and data quality: the
  increase of the monitor's rejection counters (skipped_nan, skipped_time, bad_channel) and
  the transport's dropped messages, as given by the caller;
- usage (``BankRows.usage``, the rates of ``service.monitor.usage``): travel, load-weighted
  travel, time under load and at pressure, each the sum of its rate times the sample
  intervals that count as operating time (the same intervals as ``op_time_s``), and the
  reversals; NaN when any of the period's rows came without usage (the load figures also
  when none of its rows had both chamber pressures).

No I/O: the daemon and the replay feed rows (``MonitorBank.update_arrays`` / ``rows_of``)
and write the returned periods to the store. Given the same rows it returns the same
periods (same ``start_t``), so the store's (actuator, source, start_t) key makes a replay
idempotent.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from service.monitor.usage_config import (
    U_LOAD2_SPEED,
    U_LOAD_SPEED,
    U_LOADED,
    U_PRESSURISED,
    U_REVERSAL,
    U_SPEED,
)
from service.store.records import AlarmEvent, Period

__all__ = [
    "PeriodConfig",
    "PeriodAccumulator",
    "BAD_COUNTERS",
    "periods_of_rows",
    "nis_band",
    "pooled_limit",
]

BAD_COUNTERS: tuple[str, ...] = ("skipped_nan", "skipped_time", "bad_channel")
"""Monitor counters (``MonitorBank.counters_of``) that count a bad sample or channel."""

_MAX_DOF = 8


@functools.cache
def _band() -> NDArray:
    from scipy.stats import chi2  # here, not at import: seconds off every daemon's start

    return np.array(
        [(0.0, math.inf)]
        + [(chi2.ppf(0.025, d), chi2.ppf(0.975, d)) for d in range(1, _MAX_DOF + 1)]
    )


def nis_band(dof: NDArray) -> tuple[NDArray, NDArray]:
    """The NIS's 95 % band (chi-square quantiles 2.5 % and 97.5 %) for integer degrees of
    freedom ``dof`` in 1.._MAX_DOF (8)."""
    b = _band()
    return b[dof, 0], b[dof, 1]


@dataclass(frozen=True)
class PeriodConfig:
    """How periods are cut and which C_Lk estimates count as observable (SI)."""

    silence_s: float = 5.0
    window_s: float = 600.0
    max_dt_s: float = 0.1
    obs_sigma_ratio: float = 0.25
    settle_s: float = 0.5
    c_lk_rate_hz: float = 20.0
    pool_tol: float = 0.1
    pool_z: float = 1.96
    pool_d_min: float = 0.5


def pooled_limit(ratio: NDArray | float, cfg: PeriodConfig) -> NDArray | float:
    """The largest pooled C_Lk sigma (a share of baseline) at which a pooled reading of
    ``ratio`` (C_Lk / baseline) counts as observable: its +-``pool_z`` band (1.96, 95 %)
    within ``pool_tol`` (10 %) of the increase read, |ratio - 1|, and of at least
    ``pool_d_min`` (0.5, the leak alarm's band between its clear and raise levels):
    sigma <= pool_tol max(|ratio - 1|, pool_d_min) / pool_z (docs/estimation.md, "The pooled
    C_Lk")."""
    return cfg.pool_tol * np.maximum(np.abs(np.asarray(ratio) - 1.0), cfg.pool_d_min) / cfg.pool_z


class _Open:
    """Running sums of the open period."""

    def __init__(self, t0: float, flight: int | None) -> None:
        self.start_t = t0
        self.end_t = t0
        self.flight = flight
        self.op = 0.0
        self.n = 0
        self.c_lk: list[NDArray] = []
        self.n_obs = 0
        self.p_sum = 0.0
        self.p_min = math.inf
        self.ib_sum = 0.0
        self.nis_sum = 0.0
        self.nis_n = 0
        self.in_band = 0
        self.pooled = (math.nan, math.nan)  # the last observable pooled C_Lk and its sigma
        self.pool_rows = True  # every row came with a pool
        self.alarms = 0
        self.bad = 0
        self.dropped = 0
        # usage: travel, |F| travel, F^2 travel, loaded s, pressurised s, reversals
        self.usage = np.zeros(6)
        self.usage_all = True  # every row came with usage
        self.usage_load = False  # some row had a load figure


class PeriodAccumulator:
    """Operating periods of one actuator from its monitor output rows (module docstring).

    ``add_rows`` takes the rows of this actuator in time order, with the column names of the
    arrays (``EST_KEYS``, ``HEALTH_KEYS``, ``RES_KEYS`` of ``service.monitor``), and returns
    the periods it closed; ``poll(now_t)`` closes the open period if the actuator has been
    silent for ``silence_s``; ``flush()`` closes it at the end of a log or at shutdown.
    ``alarm_events()`` hands over the alarm raises seen since the last call.
    """

    def __init__(
        self,
        actuator: str,
        c_lk_baseline: float,
        source: str,
        est_keys: Sequence[str],
        health_keys: Sequence[str],
        res_keys: Sequence[str] | None = None,
        config: PeriodConfig | None = None,
    ) -> None:
        if not c_lk_baseline > 0:
            raise ValueError("c_lk_baseline must be > 0")
        self.actuator = actuator
        self.c_lk0 = float(c_lk_baseline)
        self.source = source
        self.cfg = config or PeriodConfig()
        ek = list(est_keys)
        self._i_c, self._i_cs = ek.index("c_lk"), ek.index("c_lk_sigma")
        self._i_p, self._i_ib = ek.index("p_sr"), ek.index("i_b")
        hk = list(health_keys)
        self._alarm_cols = [
            (j, k[len("alarm_") :]) for j, k in enumerate(hk) if k.startswith("alarm_")
        ]
        self._ratio_col = {"leak": hk.index("leak_ratio"), "supply": hk.index("supply_ratio")}
        if res_keys is not None:
            rk = list(res_keys)
            self._i_nis, self._i_dof = rk.index("nis"), rk.index("nis_dof")
        else:
            self._i_nis = self._i_dof = -1
        self._open: _Open | None = None
        self._last_t = -math.inf
        self._alarm_state = np.zeros(len(self._alarm_cols), bool)
        self._keep_bin = -math.inf
        self._counters: dict[str, int] | None = None
        self._events: list[AlarmEvent] = []

    # -- input ----------------------------------------------------------------------------
    def add_rows(
        self,
        t: NDArray,
        est: NDArray,
        health: NDArray,
        res: NDArray | None = None,
        *,
        counters: Mapping[str, int] | None = None,
        dropped: int = 0,
        flight: int | None = None,
        usage: NDArray | None = None,
        pooled: NDArray | None = None,
    ) -> list[Period]:
        """Fold rows (t (n,), est (n, len(est_keys)), health, res) into periods; returns the
        periods closed by them. ``counters``: the monitor's cumulative counters of this
        actuator after these rows (the increase of ``BAD_COUNTERS`` is charged to the open
        period); ``dropped``: messages lost in transport since the last call; ``flight``:
        flight number recorded on a period opened by these rows; ``usage``: the rows' usage
        rates (``BankRows.usage``; None: the periods these rows fall in get NaN usage);
        ``pooled``: the rows' pooled C_Lk and sigma (``BankRows.pooled``; recorded as
        ``c_lk_pooled``, not the indicator; None: no pooled reading)."""
        t = np.asarray(t, float)
        closed: list[Period] = []
        bad = self._bad_delta(counters)
        if len(t) == 0:
            if self._open is not None:
                self._open.bad += bad
                self._open.dropped += int(dropped)
            return closed
        if np.any(np.diff(t) < 0) or t[0] < self._last_t:
            raise ValueError("add_rows: rows must come in time order")
        cfg = self.cfg
        # cut points: silences (also against the previous call's last sample) and windows
        prev = np.concatenate(([self._last_t], t[:-1]))
        silent = np.flatnonzero(t - prev > cfg.silence_s)
        silent_set = set(silent.tolist())
        n = len(t)
        a = 0
        while a < n:
            o = self._open
            if o is not None and (a in silent_set or t[a] >= o.start_t + cfg.window_s):
                closed.append(self._close())
                o = None
            if o is None:
                o = self._open = _Open(float(t[a]), flight)
                self._keep_bin = -math.inf
            if a == 0:
                o.bad += bad
                o.dropped += int(dropped)
            later = silent[silent > a]
            stop = int(later[0]) if len(later) else n
            b_w = a + int(np.searchsorted(t[a:stop], o.start_t + cfg.window_s, side="left"))
            b = max(min(stop, b_w), a + 1)
            sl = slice(a, b)
            self._fold(o, t[sl], est[sl], health[sl], None if res is None else res[sl],
                       None if usage is None else usage[sl],
                       None if pooled is None else pooled[sl])  # fmt: skip
            self._last_t = float(t[b - 1])
            a = b
        return closed

    def poll(self, now_t: float) -> list[Period]:
        """Close the open period if no sample came for ``silence_s`` before ``now_t``."""
        if self._open is not None and now_t - self._last_t > self.cfg.silence_s:
            return [self._close()]
        return []

    def flush(self) -> list[Period]:
        """Close the open period (end of a log, shutdown)."""
        return [self._close()] if self._open is not None else []

    def alarm_events(self) -> list[AlarmEvent]:
        """Alarm raises seen since the last call (store records; value = the ratio)."""
        ev, self._events = self._events, []
        return ev

    def pooled_reading(self) -> tuple[float, float] | None:
        """The open period's pooled C_Lk so far (recorded beside the indicator, 0025): its
        last pooled C_Lk within the observability limit and that sigma [m^3/s/Pa] (None
        without an open period or before such a row)."""
        o = self._open
        if o is None or not math.isfinite(o.pooled[0]):
            return None
        return o.pooled

    def nis_in_band(self) -> float | None:
        """Fraction of the open period's rows whose NIS lies in its 95 % band (None without
        an open period or before its first row with a NIS)."""
        o = self._open
        return o.in_band / o.nis_n if o is not None and o.nis_n else None

    # -- internals ------------------------------------------------------------------------
    def _bad_delta(self, counters: Mapping[str, int] | None) -> int:
        if counters is None:
            return 0
        now = {k: int(counters.get(k, 0)) for k in BAD_COUNTERS}
        prev = self._counters or dict.fromkeys(BAD_COUNTERS, 0)
        self._counters = now
        return sum(max(now[k] - prev[k], 0) for k in BAD_COUNTERS)

    def _fold(
        self,
        o: _Open,
        t: NDArray,
        est: NDArray,
        health: NDArray,
        res: NDArray | None,
        usage: NDArray | None,
        pooled: NDArray | None,
    ) -> None:
        cfg = self.cfg
        dt = np.diff(np.concatenate(([o.end_t if o.n else t[0]], t)))
        o.op += float(dt[dt <= cfg.max_dt_s].sum())
        if usage is None:
            o.usage_all = False
        else:
            w = np.where(dt <= cfg.max_dt_s, dt, 0.0)  # the intervals of op_time_s
            o.usage[0] += float(w @ usage[:, U_SPEED])
            o.usage[4] += float(w @ usage[:, U_PRESSURISED])
            o.usage[5] += float(usage[:, U_REVERSAL].sum())
            fin = np.isfinite(usage[:, U_LOAD_SPEED])
            if fin.any():
                o.usage_load = True
                wf = w[fin]
                o.usage[1] += float(wf @ usage[fin, U_LOAD_SPEED])
                o.usage[2] += float(wf @ usage[fin, U_LOAD2_SPEED])
                o.usage[3] += float(wf @ usage[fin, U_LOADED])
        o.end_t = float(t[-1])
        o.n += len(t)
        c, cs = est[:, self._i_c], est[:, self._i_cs]
        obs = (cs < cfg.obs_sigma_ratio * self.c_lk0) & (t - o.start_t >= cfg.settle_s)
        obs &= np.isfinite(c)
        o.n_obs += int(obs.sum())
        if obs.any():
            tb = np.floor(t[obs] * cfg.c_lk_rate_hz)
            first = np.concatenate(([tb[0] != self._keep_bin], tb[1:] != tb[:-1]))
            o.c_lk.append(c[obs][first])
            self._keep_bin = float(tb[-1])
        if pooled is None:
            o.pool_rows = False
        else:
            r = pooled[:, 0] / self.c_lk0
            sd = pooled[:, 1] / self.c_lk0
            ok = np.flatnonzero((sd <= pooled_limit(r, cfg)) & np.isfinite(r))
            if len(ok):
                o.pooled = (float(pooled[ok[-1], 0]), float(pooled[ok[-1], 1]))
        p = est[:, self._i_p]
        o.p_sum += float(p.sum())
        o.p_min = min(o.p_min, float(p.min()))
        o.ib_sum += float(est[:, self._i_ib].sum())
        if res is not None and self._i_nis >= 0:
            nis, dof = res[:, self._i_nis], res[:, self._i_dof].astype(int)
            ok = (dof > 0) & (dof <= _MAX_DOF)
            if ok.any():
                nd = nis[ok] / dof[ok]
                o.nis_sum += float(nd.sum())
                o.nis_n += int(ok.sum())
                lo, hi = nis_band(dof[ok])
                o.in_band += int(((nis[ok] >= lo) & (nis[ok] <= hi)).sum())
        for j, (col, kind) in enumerate(self._alarm_cols):
            on = health[:, col] > 0.5
            edges = np.flatnonzero(on & ~np.concatenate(([self._alarm_state[j]], on[:-1])))
            o.alarms += len(edges)
            rc = self._ratio_col.get(kind)
            for e in edges:
                v = float(health[e, rc]) if rc is not None else 1.0
                self._events.append(AlarmEvent(self.actuator, float(t[e]), kind, v, self.source))
            self._alarm_state[j] = bool(on[-1])

    def _close(self) -> Period:
        o = self._open
        assert o is not None
        self._open = None
        if o.c_lk:
            c = np.concatenate(o.c_lk)
            med = float(np.median(c))
            sig = float(1.4826 * np.median(np.abs(c - med)))
        else:
            med = sig = math.nan
        u = o.usage if o.usage_all else np.full(6, math.nan)
        ul = u if o.usage_load else np.full(6, math.nan)
        return Period(
            actuator=self.actuator,
            start_t=o.start_t,
            end_t=o.end_t,
            op_time_s=o.op,
            samples=o.n,
            flight=o.flight,
            c_lk_mean=med,
            c_lk_sigma=sig,
            c_lk_ratio=med / self.c_lk0,
            c_lk_pooled=o.pooled[0] if o.pool_rows else math.nan,
            c_lk_pooled_sigma=o.pooled[1] if o.pool_rows else math.nan,
            observable_samples=o.n_obs,
            p_sr_mean=o.p_sum / o.n if o.n else math.nan,
            p_sr_min=o.p_min if o.n else math.nan,
            i_b_mean=o.ib_sum / o.n if o.n else math.nan,
            nis_mean=o.nis_sum / o.nis_n if o.nis_n else math.nan,
            nis_in_band=o.in_band / o.nis_n if o.nis_n else math.nan,
            alarms=o.alarms,
            bad_samples=o.bad,
            dropped=o.dropped,
            source=self.source,
            usage_travel_m=float(u[0]),
            usage_load_travel_j=float(ul[1]),
            usage_load2_travel_n2m=float(ul[2]),
            usage_reversals=float(u[5]),
            usage_loaded_s=float(ul[3]),
            usage_pressurised_s=float(u[4]),
        )


def periods_of_rows(
    actuator: str,
    c_lk_baseline: float,
    source: str,
    t: NDArray,
    est: NDArray,
    health: NDArray,
    res: NDArray | None = None,
    config: PeriodConfig | None = None,
    usage: NDArray | None = None,
    pooled: NDArray | None = None,
    **keys: Sequence[str],
) -> list[Period]:
    """All periods of one actuator's complete rows (``add_rows`` then ``flush``); ``keys``
    may override ``est_keys``, ``health_keys``, ``res_keys`` (default: the monitor's)."""
    from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS

    acc = PeriodAccumulator(
        actuator,
        c_lk_baseline,
        source,
        keys.get("est_keys", EST_KEYS),
        keys.get("health_keys", HEALTH_KEYS),
        keys.get("res_keys", RES_KEYS) if res is not None else None,
        config,
    )
    return acc.add_rows(t, est, health, res, usage=usage, pooled=pooled) + acc.flush()
