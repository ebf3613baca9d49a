"""``HealthStore.ingest_log``: one replayed log into the store in one transaction
(docs/store.md, "What identifies a log" and "What a re-run does"; decision record 0010)."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import replace
from typing import Any

from service.store.lifeorder import LogUnit, natural_key, number_flights
from service.store.records import PERIOD_FIELDS, AlarmEvent, Period
from service.store.usage import USAGE_TOTALS

__all__ = ["ingest_log", "ingest_logs"]

# column order of the periods table as written (as ``health._PERIOD_COLS``)
_PERIOD_COLS: tuple[str, ...] = ("actuator", "start_t", "source") + tuple(
    f for f in PERIOD_FIELDS if f not in ("actuator", "start_t", "source")
)


def ingest_log(
    hs: Any,
    units: Sequence[LogUnit],
    periods: Iterable[Period],
    alarms: Iterable[AlarmEvent],
    gap_s: float,
) -> dict[str, dict[str, Any]]:
    """Store one replayed log in one transaction (docs/store.md, "What identifies a log").

    Per unit of ``units``: a source not stored yet is added; one stored with at least as
    many samples is kept as it is (``stored``); one stored with fewer samples (a log
    ingested while it was written, a damaged copy) is replaced by this log's periods and
    alarms (``superseded``), as are the periods a store before schema v4 holds under
    ``legacy``. Then every changed unit's gap-rule flights are renumbered over its whole
    history (``lifeorder.number_flights``) and its summary row rebuilt. Returns per unit
    ``status`` (``new``, ``superseded``, ``stored``), ``periods_new`` and ``flights``
    (the final flight numbers of this log's periods of the unit)."""
    return ingest_logs(hs, [(units, periods, alarms)], gap_s)[0]


def ingest_logs(
    hs: Any,
    logs: Sequence[tuple[Sequence[LogUnit], Iterable[Period], Iterable[AlarmEvent]]],
    gap_s: float,
) -> list[dict[str, dict[str, Any]]]:
    """Several replayed logs, each ``(units, periods, alarms)`` as ``ingest_log`` takes
    them, in one transaction: each log as ``ingest_log`` stores it, in the given order,
    then each changed unit renumbered and its summary rebuilt once (the renumbering reads
    the unit's whole history: once per batch, not once per log). The store is the one
    the logs give one by one (the flights are a function of the stored periods); the
    ``flights`` returned are the final ones. Returns ``ingest_log``'s dict per log."""
    b = hs._b
    acts = sorted({u.actuator for units, _, _ in logs for u in units})
    out: list[dict[str, dict[str, Any]]] = []
    changed: set[str] = set()
    with b.transaction():
        for a in acts:
            hs._ensure(a)
        summaries = hs._lock_summaries(acts)
        for units, periods, alarms in logs:
            res = _store_units(hs, units, periods, alarms)
            changed.update(a for a, (_, ch) in res.items() if ch)
            out.append({a: {"status": st} for a, (st, _) in res.items()})
        final: dict[str, dict[str, list]] = {}
        for a in sorted(changed):
            final[a] = defaultdict(list)
            for (_, src), f in _renumber(hs, a, summaries[a], gap_s).items():
                final[a][src].append(f)
        for (units, periods, _), res in zip(logs, out, strict=True):
            mine = defaultdict(int)
            for p in periods:
                mine[p.actuator] += 1
            for u in units:
                a = u.actuator
                if a in final:
                    fl = final[a].get(u.source, [])
                else:
                    fl = [r[0] for r in b.execute(
                        "SELECT flight FROM periods WHERE actuator = ? AND source = ?",
                        (a, u.source),
                    ).fetchall()]  # fmt: skip
                st = res[a]["status"]
                res[a] = {
                    "status": st,
                    "periods_new": 0 if st == "stored" else mine[a],
                    "flights": sorted({int(f) for f in fl if f is not None}),
                }
    hs._known.update(acts)
    return out


def _store_units(
    hs: Any, units: Sequence[LogUnit], periods: Iterable[Period], alarms: Iterable[AlarmEvent]
) -> dict[str, tuple[str, bool]]:
    """One log's units written (inside the caller's transaction, summaries locked): per
    unit its status and whether its rows changed (it must be renumbered)."""
    by_act: dict[str, list[Period]] = defaultdict(list)
    for p in periods:
        by_act[p.actuator].append(p)
    al_by: dict[str, list[AlarmEvent]] = defaultdict(list)
    for e in alarms:
        al_by[e.actuator].append(e)
    b = hs._b
    out: dict[str, tuple[str, bool]] = {}
    for u in units:
        a = u.actuator
        row = b.execute(
            "SELECT samples, name FROM log_sources WHERE actuator = ? AND source = ?",
            (a, u.source),
        ).fetchone()
        legacy = 0
        if u.legacy:
            legacy = int(b.execute(
                "SELECT COUNT(*) FROM periods WHERE actuator = ? AND source = ?",
                (a, u.legacy),
            ).fetchone()[0])  # fmt: skip
        mine = [replace(p, source=u.source) for p in by_act.get(a, [])]
        if row is not None and int(row[0]) >= u.samples and not legacy:
            status, changed = "stored", False
            if natural_key(u.name) < natural_key(row[1]):  # life order of the names
                b.execute(
                    "UPDATE log_sources SET name = ? WHERE actuator = ? AND source = ?",
                    (u.name, a, u.source),
                )
                changed = True
        else:
            status = "new" if row is None and not legacy else "superseded"
            changed = True
            name = u.name if row is None else min(u.name, row[1], key=natural_key)
            for src in {u.source, u.legacy} - {None}:
                b.execute("DELETE FROM periods WHERE actuator = ? AND source = ?",
                          (a, src))  # fmt: skip
                b.execute("DELETE FROM alarms WHERE actuator = ? AND source = ?",
                          (a, src))  # fmt: skip
            b.execute("DELETE FROM log_sources WHERE actuator = ? AND source = ?",
                      (a, u.source))  # fmt: skip
            b.execute(
                "INSERT INTO log_sources (actuator, source, samples, name, flights) "
                "VALUES (?, ?, ?, ?, ?)",
                (a, u.source, int(u.samples), name, "gap" if u.gap else "log"),
            )
            uniq = {float(p.start_t): p for p in mine}
            if uniq:
                b.bulk_insert("periods", _PERIOD_COLS,
                              [[getattr(p, c) for c in _PERIOD_COLS]
                               for p in uniq.values()])  # fmt: skip
            ev = {(float(e.t), e.kind): replace(e, source=u.source)
                  for e in al_by.get(a, [])}  # fmt: skip
            if ev:
                b.bulk_insert(
                    "alarms",
                    ("actuator", "t", "kind", "source", "value"),
                    [[e.actuator, e.t, e.kind, e.source, e.value] for e in ev.values()],
                )
        out[a] = (status, changed)
    return out


def _renumber(
    hs: Any, actuator: str, s: dict[str, Any], gap_s: float
) -> dict[tuple[float, str], int | None]:
    """Renumber the unit's gap-rule flights over its whole history and rebuild its
    summary row (inside the caller's transaction); returns every period's flight by
    ``(start_t, source)``."""
    b = hs._b
    rules = {
        r[0]: (r[1], r[2] == "gap")
        for r in b.execute(
            "SELECT source, name, flights FROM log_sources WHERE actuator = ?", (actuator,)
        ).fetchall()
    }
    old = hs.periods(actuator)
    now = number_flights(old, rules, gap_s)
    was = {(float(p.start_t), p.source): p.flight for p in old}
    upd = [
        (p.flight, actuator, p.start_t, p.source)
        for p in now
        if was[(float(p.start_t), p.source)] != p.flight
    ]
    if upd:
        b.executemany(
            "UPDATE periods SET flight = ? WHERE actuator = ? AND start_t = ? AND source = ?",
            upd,
        )
    by_t = sorted(now, key=lambda p: (p.start_t, p.source))
    for k in ("n_periods", "samples", "alarms", "bad_samples", "dropped"):
        s[k] = 0
    s["op_time_s"] = 0.0
    for k in USAGE_TOTALS:  # rebuilt with the rest from every period (migration 5)
        s[k] = 0
    s["first_start_t"] = s["last_start_t"] = s["last_period"] = None
    s["recent"] = "[]"
    if by_t:
        hs._summarise(s, by_t)
    n, last_t, last_kind = b.execute(
        "SELECT COUNT(*), MAX(t), NULL FROM alarms WHERE actuator = ?", (actuator,)
    ).fetchone()
    s["alarm_events"] = int(n)
    s["last_alarm_t"] = s["last_alarm_kind"] = None
    if last_t is not None:
        r = b.execute(
            "SELECT t, kind FROM alarms WHERE actuator = ? AND t = ? ORDER BY kind DESC",
            (actuator, last_t),
        ).fetchone()
        s["last_alarm_t"], s["last_alarm_kind"] = float(r[0]), r[1]
    hs._write_summary(actuator, s)
    return {(float(p.start_t), p.source): p.flight for p in now}
