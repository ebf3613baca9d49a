"""Monitor outputs -> log blocks, alarm events and published messages: the one fan-out that
both the daemon and the replay use, so a replay logs and publishes what the daemon did.

Per actuator, counting its outputs 1, 2, ...:

* est, residual and health are logged together for every ``log_every``-th output and for
  every output that carries an alarm event (one ``log_block`` per topic and block);
* every alarm event is logged on ``.../events``;
* est, res and health are published every ``publish_every``-th output, one put each (in
  that order per output), as the protobuf rows of ``service.wire.messages.output_layout`` (the
  log row's fields, then ``t``; health also the commissioning of ``info``), made for all the
  published outputs of an update in one array operation (decision record 0018).

With ``live`` (a ``service.edge.foxglove_feed.FoxgloveFeed``), the logged est, residual, health
and events also go to the live Foxglove channels (the feed encodes only what a viewer
subscribed to).

With ``on_periods``, each tracked actuator's rows also go into a
``service.prognostics.PeriodAccumulator`` (docs/prognostics.md section 1); the periods it
closes and its alarm raises are handed to ``on_periods(periods, alarms)``, so the daemon and
the replay cut the same periods from the same rows.

Health follows ``log_every`` (as est and residual), not ``publish_every``: the log is the
record of the monitor, decimated by one setting, and each logged est row then has the health
row of the same sample; what is published is a transport choice of its own.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from service.jsonutil import event_dict, flat
from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS, BankRows
from service.prognostics import PeriodAccumulator, PeriodConfig
from service.store import AlarmEvent, Period
from service.wire import messages as m

__all__ = ["FanOut", "Emitted"]

log = logging.getLogger("servowatch.fanout")


@dataclass
class Emitted:
    """What :meth:`FanOut.emit` did for one actuator in one block of outputs."""

    row: int  # the actuator's bank row
    name: str  # "{aircraft}/{actuator}"
    outputs: int  # outputs of this actuator in the block
    last: int  # index in the BankRows of its latest output
    published: int = 0
    events: list[dict[str, Any]] = field(default_factory=list)  # event dicts, in order


@dataclass
class _Target:
    aircraft: str
    actuator: str
    prefix: str  # "/fleet/{aircraft}/{actuator}/"
    name: str  # "{aircraft}/{actuator}"
    outputs: int = 0
    publishers: dict[str, Any] = field(default_factory=dict)
    # the published health's (commissioned, baseline_version), from ``track``'s ``info``
    info_row: tuple[int, int] = (m.COMMISSIONED_UNKNOWN, 0)
    acc: PeriodAccumulator | None = None
    nis_in_band: float | None = None  # of its last closed period
    pooled: tuple[float, float] | None = None  # the pooled C_Lk of its last closed period


def _LEAVES(rows: BankRows) -> tuple[tuple[str, tuple[str, ...], np.ndarray], ...]:
    """(topic leaf, field names, output array) of the logged outputs."""
    return (
        ("est", EST_KEYS, rows.est),
        ("residual", RES_KEYS, rows.res),
        ("health", HEALTH_KEYS, rows.health),
    )


def _info_row(info: Mapping[str, Any]) -> tuple[int, int]:
    """(commissioned, baseline_version) of the published health (``service.wire.messages.
    output_layout``): -1 / 0 without a ``commissioned`` in ``info`` (no store)."""
    if "commissioned" not in info:
        return (m.COMMISSIONED_UNKNOWN, 0)
    c = m.COMMISSIONED_YES if info["commissioned"] else m.COMMISSIONED_NO
    return (c, int(info.get("baseline_version") or 0))


class FanOut:
    """Turns ``BankRows`` into log blocks (``logger.log_blocks``: one call per output topic
    leaf for every actuator of the update, or ``logger.log_block`` per topic), events
    (``logger.log``) and
    Zenoh puts on ``fleet/{ac}/{act}/{est,res,health}`` (``session``; None: no publishing),
    each publisher declared with the encoding of its message (``output_encoding``).

    ``live`` receives what is logged (``log_block``/``log``, as a ``McapLogger``; None: no
    live view). ``on_publish_error(exc)`` is called when a put fails (None: the error
    propagates).
    ``on_periods(periods, alarms)`` receives closed operating periods and alarm raises
    (None: no periods); ``source`` names them in the store (a log's identity, or
    ``live:{station}``); ``counters(row)`` gives the monitor's counters of a bank row.
    """

    def __init__(
        self,
        logger: Any | None,
        *,
        log_every: int = 1,
        publish_every: int = 10,
        session: Any | None = None,
        on_publish_error: Callable[[Exception], None] | None = None,
        on_periods: Callable[[list[Period], list[AlarmEvent]], None] | None = None,
        source: str = "live",
        period_config: PeriodConfig | None = None,
        counters: Callable[[int], Mapping[str, int]] | None = None,
        live: Any | None = None,
    ) -> None:
        if int(log_every) < 1 or int(publish_every) < 1:
            raise ValueError("log_every and publish_every must be >= 1")
        self.logger = logger
        self.log_every = int(log_every)
        self.publish_every = int(publish_every)
        self.session = session
        self.on_publish_error = on_publish_error
        self._targets: dict[int, _Target] = {}
        self.on_periods = on_periods
        self.source = source
        self.period_config = period_config or PeriodConfig()
        self.counters = counters
        self.live = live

    def track(
        self,
        row: int,
        aircraft: str,
        actuator: str,
        *,
        c_lk0: float | None = None,
        info: Mapping[str, Any] | None = None,
    ) -> None:
        """Name the actuator of bank row ``row`` (before its first output); ``c_lk0`` is the
        C_Lk of its baseline (for its periods), ``info`` goes into its published health."""
        if row not in self._targets:
            tg = _Target(
                aircraft, actuator, f"/fleet/{aircraft}/{actuator}/", f"{aircraft}/{actuator}"
            )
            self._targets[row] = tg
            self._set(tg, c_lk0, info)
            if self.live is not None:
                self.live.add_actuator(aircraft, actuator)

    def retrack(
        self, row: int, *, c_lk0: float | None, info: Mapping[str, Any] | None = None
    ) -> None:
        """A new baseline for bank row ``row``: its open period is closed, the next opens
        against ``c_lk0``."""
        tg = self._targets[row]
        self._deliver(self._flush(tg))
        self._set(tg, c_lk0, info)

    def _set(self, tg: _Target, c_lk0: float | None, info: Mapping[str, Any] | None) -> None:
        tg.info_row = _info_row(info or {})
        if self.on_periods is not None and c_lk0 is not None and c_lk0 > 0:
            tg.acc = PeriodAccumulator(
                tg.name, c_lk0, self.source, EST_KEYS, HEALTH_KEYS,
                RES_KEYS, self.period_config,
            )  # fmt: skip

    def _flush(self, tg: _Target) -> list[Period]:
        return [] if tg.acc is None else tg.acc.flush()

    def _deliver(self, periods: list[Period], accs: list[PeriodAccumulator] = ()) -> None:
        alarms = [e for a in accs for e in a.alarm_events()]
        if (periods or alarms) and self.on_periods is not None:
            self.on_periods(periods, alarms)

    def flush(self, row: int | None = None) -> int:
        """Close the open period of bank row ``row`` (None: of every actuator: end of a log,
        shutdown) and hand it over; returns the number of periods closed."""
        tgs = list(self._targets.values()) if row is None else [self._targets[row]]
        closed = [p for tg in tgs for p in self._flush(tg)]
        self._deliver(closed, [tg.acc for tg in tgs if tg.acc is not None])
        return len(closed)

    def nis_in_band_of(self, row: int | None) -> float | None:
        """Fraction of bank row ``row``'s outputs whose NIS lies in its 95 % band, over its
        open operating period (over its last closed one while the open one has none yet);
        None without periods (no store) or before any."""
        tg = self._targets.get(row) if row is not None else None
        if tg is None or tg.acc is None:
            return None
        v = tg.acc.nis_in_band()
        return v if v is not None else tg.nis_in_band

    def pooled_of(self, row: int | None) -> dict[str, float] | None:
        """The pooled C_Lk of bank row ``row`` (shown beside the indicator, decisions/0025):
        the last within its observability limit and its sigma [m^3/s/Pa]
        (``PeriodAccumulator.pooled_reading``) over its open period, else its last closed
        one's; None without periods or while it abstains."""
        tg = self._targets.get(row) if row is not None else None
        if tg is None or tg.acc is None:
            return None
        v = tg.acc.pooled_reading() or tg.pooled
        return None if v is None else {"value": v[0], "sigma": v[1]}

    def outputs_of(self, row: int) -> int:
        """Outputs of bank row ``row`` so far."""
        return self._targets[row].outputs

    def emit(self, rows: BankRows, ks: NDArray[np.int64]) -> list[Emitted]:
        """Log, publish and collect the events of ``rows`` (outputs of a bank update whose
        inputs belonged to bank rows ``ks``); one :class:`Emitted` per actuator, in the order
        of the bank rows."""
        idx = rows.index
        n = len(idx)
        if n == 0:
            return []
        owner = ks[idx]
        order = np.argsort(owner, kind="stable")
        so = owner[order]
        cut = np.flatnonzero(so[1:] != so[:-1]) + 1
        starts = np.concatenate(([0], cut))
        lens = np.diff(np.concatenate((starts, [n])))
        tgs = [self._targets[r] for r in so[starts].tolist()]
        base = np.fromiter((tg.outputs for tg in tgs), np.int64, len(tgs))
        # each row's output number (1, 2, ... per actuator), in ``order``
        num = np.arange(1, n + 1) - np.repeat(starts - base, lens)
        ev_rows = rows.events.rows()
        ev = rows.events.flags()[order] if ev_rows else None
        lg, lv = self.logger, self.live
        many = getattr(lg, "log_blocks", None)  # one record per leaf and call, not per topic
        logged = None  # in ``order``: the rows logged
        if lg is not None or lv is not None:
            logged = num % self.log_every == 0 if self.log_every > 1 else np.ones(n, bool)
            if ev is not None:
                logged |= ev
        pub = (num % self.publish_every == 0) if self.session is not None else None
        # per actuator: first row in ``order``, rows, bank row, latest output, rows logged
        # and published (plain ints: the loop below does no numpy per actuator unless it
        # must select rows for the periods, a logger without ``log_blocks`` or the live view)
        a_l, k_l = starts.tolist(), lens.tolist()
        row_l, last_l = so[starts].tolist(), order[starts + lens - 1].tolist()
        full = self.log_every == 1 and ev is None  # every row logged
        n_log = None
        if logged is not None:
            n_log = k_l if full else np.add.reduceat(logged, starts, dtype=np.int64).tolist()
        n_pub = None if pub is None else np.add.reduceat(pub, starts, dtype=np.int64).tolist()
        each = lv is not None or (lg is not None and many is None)  # rows selected per actuator
        out = []
        who: list[_Target] = []  # the target of each published row, in ``order``
        logged_at: list[str] = []  # topic prefixes of the actuators with logged rows
        ev_at = iter(np.flatnonzero(ev).tolist()) if ev is not None else iter(())
        ev_next = next(ev_at, n)
        for gi, tg in enumerate(tgs):
            a, k = a_l[gi], k_l[gi]
            b = a + k
            tg.outputs += k
            row = row_l[gi]
            em = Emitted(row, tg.name, k, last_l[gi])
            if tg.acc is not None:
                g = order[a:b]
                cnt = self.counters(row) if self.counters is not None else None
                u = None if rows.usage is None else rows.usage[g]
                pl = None if rows.pooled is None else rows.pooled[g]
                closed = tg.acc.add_rows(
                    rows.t[g], rows.est[g], rows.health[g], rows.res[g], counters=cnt, usage=u,
                    pooled=pl,
                )  # fmt: skip
                self._deliver(closed, [tg.acc])
                if closed:
                    v = closed[-1].nis_in_band
                    tg.nis_in_band = v if math.isfinite(v) else None
                    c = closed[-1]
                    if math.isfinite(c.c_lk_pooled):
                        tg.pooled = (c.c_lk_pooled, c.c_lk_pooled_sigma)
            if n_log is not None and n_log[gi]:
                if many is not None:
                    logged_at.append(tg.prefix)
                if each:
                    sel = order[a:b] if full else order[a:b][logged[a:b]]
                    self._log_rows(rows, tg.prefix, sel, lg is not None and many is None)
            while ev_next < b:  # the events of this actuator's rows
                r = int(order[ev_next])
                self._events(tg, em, float(rows.t[r]), rows.events[r])
                ev_next = next(ev_at, n)
            if n_pub is not None and n_pub[gi]:
                em.published = n_pub[gi]
                who += [tg] * em.published
            out.append(em)
        if logged_at:
            sel = order if full else order[logged]
            counts = [c for c in n_log if c]
            ts = rows.t[sel]
            for leaf, keys, arr in _LEAVES(rows):
                many([p + leaf for p in logged_at], counts, ts, keys, arr[sel])
        if who:
            self._publish(rows, order[pub], who)
        return out

    def _log_rows(self, rows: BankRows, prefix: str, sel: np.ndarray, log: bool) -> None:
        """Rows ``sel`` of an actuator to the logger (``log``: one ``log_block`` per leaf)
        and to the live view."""
        lg, lv = self.logger, self.live
        ts = rows.t[sel]
        for leaf, keys, arr in _LEAVES(rows):
            topic = prefix + leaf
            blk = None
            if log:
                blk = arr[sel]
                lg.log_block(topic, ts, keys, blk)
            if lv is not None and lv.wants(topic):  # else nothing is made
                lv.log_block(topic, ts, keys, arr[sel] if blk is None else blk)

    def _events(self, tg: _Target, em: Emitted, t_r: float, events: list) -> None:
        lg, lv = self.logger, self.live
        for e in events:
            d = event_dict(e)
            te, fd = float(d.get("t") or t_r), flat(d)
            if lg is not None:  # a servowatch.Event protobuf row (JSON: a logger without it)
                ev = getattr(lg, "log_event", None)
                if ev is not None:
                    ev(tg.prefix + "events", te, d)
                else:
                    lg.log(tg.prefix + "events", te, fd)
            if lv is not None:  # the live feed: the log's bytes
                lev = getattr(lv, "log_event", None)
                if lev is not None:
                    lev(tg.prefix + "events", te, d)
                else:
                    lv.log(tg.prefix + "events", te, fd)
            em.events.append(d)

    def _publish(
        self,
        rows: BankRows,
        sel: np.ndarray,
        who: list[_Target],
    ) -> None:
        """Put est, res and health of rows ``sel`` (of the actuators ``who``) in their
        protobuf form (``service.wire.messages.encode_output_rows``: all the messages in a few
        array operations), one put per message."""
        info = np.array([tg.info_row for tg in who], np.int64).reshape(len(who), 2)
        buf, sizes = m.encode_output_rows(
            rows.est[sel], rows.res[sel], rows.health[sel], rows.t[sel], info
        )
        leaves = tuple(zip(m.OUTPUT_LEAVES, sizes, strict=True))
        off = 0
        for tg in who:  # per row est, res, health: the order of the JSON era
            for leaf, size in leaves:
                p = tg.publishers.get(leaf)
                try:
                    if p is None:
                        p = self._declare(tg, leaf)
                    p.put(buf[off : off + size])
                except Exception as e:
                    if self.on_publish_error is None:
                        raise
                    self.on_publish_error(e)
                off += size

    def _declare(self, tg: _Target, leaf: str) -> Any:
        tmpl = {"est": m.KEY_EST, "res": m.KEY_RES, "health": m.KEY_HEALTH}[leaf]
        p = tg.publishers[leaf] = self.session.declare_publisher(
            tmpl.format(aircraft=tg.aircraft, actuator=tg.actuator),
            encoding=m.output_encoding(leaf),
        )
        return p

    def warm_up(self) -> None:
        """Make what the first outputs would make lazily: the NIS band (scipy.stats, about a
        second of import under the GIL) and the published rows' protobuf layouts. The
        daemon calls it before its Zenoh entities exist, so a unit does not look silent
        while the first period is folded."""
        from service.prognostics.indicators import nis_band

        nis_band(np.array([1]))
        for leaf in m.OUTPUT_LEAVES:
            m.output_layout(leaf)

    def close(self) -> None:
        """Undeclare the publishers."""
        for tg in self._targets.values():
            for pub in tg.publishers.values():
                try:
                    pub.undeclare()
                except Exception as e:  # the session may be closed already
                    log.debug("undeclare: %s", e)
            tg.publishers.clear()
