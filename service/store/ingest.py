"""``HealthStore.ingest_log``: one replayed log into the store in one transaction
(docs/store.md, "What identifies a log" and "What a re-run does"; decision records 0033 and
0034, which replace 0010's first-sample identity and name order)."""

from __future__ import annotations

import copy
import json
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from service.store.lifeorder import LogUnit, SourceRule
from service.store.records import PERIOD_FIELDS, AlarmEvent, Period
from service.store.renumber import Added, renumber_append, renumber_full

__all__ = ["ingest_log", "ingest_logs"]

# column order of the periods table as written (as ``health._PERIOD_COLS``)
_PERIOD_COLS: tuple[str, ...] = ("actuator", "start_t", "source") + tuple(
    f for f in PERIOD_FIELDS if f not in ("actuator", "start_t", "source")
)
_ALARM_COLS: tuple[str, ...] = ("actuator", "t", "kind", "source", "value")
_LOG_COLS: tuple[str, ...] = (
    "actuator", "source", "samples", "name", "flights", "identity", "sample_order")  # fmt: skip


def ingest_log(
    hs: Any,
    units: Sequence[LogUnit],
    periods: Iterable[Period],
    alarms: Iterable[AlarmEvent],
    gap_s: float,
) -> dict[str, dict[str, Any]]:
    """Store one replayed log in one transaction (docs/store.md, "What identifies a log").

    Per unit of ``units``, against the unit's stored logs (their stream identities): the
    same stream (a copy under any name) or one that holds every sample of it (a longer or
    repaired version, its rotation set) stores nothing (``stored``; a ``--flight`` or
    ``--start-unix`` given for it is applied to the stored periods, with a ``note``); else
    its periods and alarms are added and every stored log whose samples it holds all (a
    shorter ingest, the members of a rotation set, a damaged copy) is replaced by it
    (``superseded``, else ``new``), as is the same log stored by an older servowatch under
    its ``legacy`` ids. A stored log it shares samples with otherwise (a common prefix, then
    different samples) is kept beside it, with a ``note``. Then every changed unit's
    gap-rule flights are renumbered along its life order and its summary row rebuilt.
    Returns per unit ``status``, ``periods_new``, ``flights`` (the final flight numbers of
    this log's periods of the unit) and ``notes``."""
    return ingest_logs(hs, [(units, periods, alarms)], gap_s)[0]


def ingest_logs(
    hs: Any,
    logs: Sequence[tuple[Sequence[LogUnit], Iterable[Period], Iterable[AlarmEvent]]],
    gap_s: float,
    incremental: bool = True,
) -> list[dict[str, dict[str, Any]]]:
    """Several replayed logs, each ``(units, periods, alarms)`` as ``ingest_log`` takes
    them, in one transaction: each log as ``ingest_log`` stores it, in the given order,
    then each changed unit renumbered and its summary updated once. The store is the one
    the logs give one by one (the flights are a function of the stored periods); the
    ``flights`` returned are the final ones. Returns ``ingest_log``'s dict per log.

    A unit to which the logs only add periods after its stored ones in life order is
    numbered and summarised from its stored last period (``renumber.renumber_append``: no
    read of its history); any other changed unit, or every one with ``incremental``
    False, is renumbered and summarised over its whole history (``renumber_full``). Both
    give the same store (``tests/test_renumber.py``)."""
    b = hs._b
    acts = sorted({u.actuator for units, _, _ in logs for u in units})
    stored_as: list[dict[str, dict[str, Any]]] = []
    changed: set[str] = set()
    added: dict[str, Added] = defaultdict(Added)
    with b.transaction():
        for a in acts:
            hs._ensure(a)
        summaries = hs._lock_summaries(acts)
        tx = _Tx(b, logs)
        for units, periods, alarms in logs:
            res = _store_units(hs, units, periods, alarms, added, summaries, tx)
            changed.update(a for a, r in res.items() if r["changed"])
            stored_as.append(res)
        tx.flush()
        for a in sorted(changed):
            if not (incremental and renumber_append(hs, a, summaries[a], added[a], gap_s)):
                renumber_full(hs, a, summaries[a], gap_s)
        flights = _flights(b, {(a, r["source"]) for res in stored_as for a, r in res.items()})
        out: list[dict[str, dict[str, Any]]] = []
        for res in stored_as:
            one = {}
            for a, r in res.items():
                one[a] = {
                    "status": r["status"],
                    "periods_new": 0 if r["status"] == "stored" else r["periods_new"],
                    "flights": sorted(flights.get((a, r["source"]), ())),
                    "notes": r["notes"],
                }
            out.append(one)
    hs._known.update(acts)
    return out


class _Tx:
    """What a transaction's logs are weighed against and what they write, per unit: the
    stored logs that any of them relates to, its own source or its legacy ids (read once
    for all of them, then kept as the logs are added and removed), and the new period,
    alarm and log rows, written in one bulk insert per table (``flush``) before anything
    else reads or changes them."""

    def __init__(self, b: Any, logs: Sequence[tuple[Sequence[LogUnit], Any, Any]]) -> None:
        self.b = b
        self.rows: dict[str, dict[tuple[str, str], list[list[Any]]]] = {
            "periods": {}, "alarms": {}, "log_sources": {}}  # fmt: skip
        want: dict[str, set[str]] = defaultdict(set)
        legacy: dict[str, set[str]] = defaultdict(set)
        every: set[str] = set()  # units with a log related by a plain function: all rows
        for units, _, _ in logs:
            for u in units:
                want[u.actuator] |= _candidates(u)
                legacy[u.actuator].update(u.legacy)
                if u.relate is not None and not isinstance(u.relate, Mapping):
                    every.add(u.actuator)
        sql = ("SELECT source, samples, name, identity IS NOT NULL FROM log_sources "
               "WHERE actuator = ?")  # fmt: skip
        #: per unit ``{source: (samples, name, True if it has a stream identity else None)}``
        self.known: dict[str, dict[str, tuple]] = {}
        #: per unit the legacy ids with periods and no log row (a store before schema v4)
        self.legacy: dict[str, set[str]] = {}
        for a, srcs in want.items():
            rows = (b.execute(sql, (a,)).fetchall() if a in every
                    else _in(b, sql, a, sorted(srcs)))  # fmt: skip
            self.known[a] = {r[0]: (int(r[1]), r[2], r[3] or None) for r in rows}
            old = sorted(legacy[a] - set(self.known[a]))
            self.legacy[a] = {r[0] for r in _in(b, "SELECT DISTINCT source FROM periods "
                                                   "WHERE actuator = ?", a, old)}  # fmt: skip

    def stored(self, u: LogUnit) -> dict[str, tuple]:
        """The stored logs of ``u``'s unit that its ingest weighs (``_candidates``)."""
        known = self.known[u.actuator]
        if u.relate is not None and not isinstance(u.relate, Mapping):
            return dict(known)
        return {s: known[s] for s in _candidates(u) if s in known}

    def add(self, a: str, source: str, row: tuple, rows: dict[str, list[list[Any]]]) -> None:
        """A new log of unit ``a`` (its ``log_sources`` row fields and its table rows)."""
        self.known[a][source] = row
        for t, r in rows.items():
            self.rows[t][(a, source)] = r

    def remove(self, a: str, source: str) -> None:
        """A stored log of unit ``a`` replaced: its rows deleted, written or pending."""
        self.known[a].pop(source, None)
        self.legacy[a].discard(source)
        for t, part in self.rows.items():
            part.pop((a, source), None)
            self.b.execute(f"DELETE FROM {t} WHERE actuator = ? AND source = ?", (a, source))

    def flush(self) -> None:
        for t, cols in (("periods", _PERIOD_COLS), ("alarms", _ALARM_COLS),
                        ("log_sources", _LOG_COLS)):  # fmt: skip
            part = self.rows[t]
            if part:
                self.b.bulk_insert(t, cols, [r for rows in part.values() for r in rows])
            part.clear()


def _in(b: Any, sql: str, a: str, srcs: list[str]) -> list:
    """``sql`` (``... WHERE actuator = ?``) for unit ``a`` and the sources ``srcs``."""
    out: list = []
    for i in range(0, len(srcs), 500):
        part = srcs[i : i + 500]
        out += b.execute(f"{sql} AND source IN ({','.join('?' * len(part))})",
                         (a, *part)).fetchall()  # fmt: skip
    return out


def _candidates(u: LogUnit) -> set[str]:
    """The stored logs the ingest of ``u`` must weigh: its own source, its ``legacy`` ids
    and those ``u.relate`` (a ``Relations``) relates it to; the others are unrelated."""
    want = {u.source, *u.legacy}
    if isinstance(u.relate, Mapping):
        want.update(s for s, r in u.relate.items() if r is not None and (
            r.inside or r.holds or r.shared))  # fmt: skip
    return want


def _flights(b: Any, keys: set[tuple[str, str]]) -> dict[tuple[str, str], set[int]]:
    """The stored flights of each ``(actuator, source)`` of ``keys``."""
    out: dict[tuple[str, str], set[int]] = defaultdict(set)
    by_act: dict[str, list[str]] = defaultdict(list)
    for a, src in sorted(keys):
        by_act[a].append(src)
    for a, srcs in by_act.items():
        for src, fl in _in(b, "SELECT DISTINCT source, flight FROM periods WHERE actuator = ?",
                           a, srcs):  # fmt: skip
            if fl is not None:
                out[(a, src)].add(int(fl))
    return out


def _with_source(p: Period, source: str) -> Period:
    """``p`` under ``source`` (a copy; ``p`` was checked when it was made)."""
    q = copy.copy(p)
    object.__setattr__(q, "source", source)
    return q


def _store_units(
    hs: Any,
    units: Sequence[LogUnit],
    periods: Iterable[Period],
    alarms: Iterable[AlarmEvent],
    added: dict[str, Added],
    summaries: dict[str, dict[str, Any]],
    tx: _Tx,
) -> dict[str, dict[str, Any]]:
    """One log's units written (inside the caller's transaction, summaries locked): per
    unit its ``status``, whether its rows ``changed`` (it must be renumbered), the
    ``source`` that holds its samples, ``periods_new`` and ``notes``; what each unit's rows
    got goes in ``added`` (``renumber.Added``), its new rows in ``tx``."""
    by_act: dict[str, list[Period]] = defaultdict(list)
    for p in periods:
        by_act[p.actuator].append(p)
    al_by: dict[str, list[AlarmEvent]] = defaultdict(list)
    for e in alarms:
        al_by[e.actuator].append(e)
    out: dict[str, dict[str, Any]] = {}
    for u in units:
        a = u.actuator
        stored = tx.stored(u)
        notes: list[str] = []
        keep = _stored_as(u, stored, notes)
        mine = [_with_source(p, u.source) for p in by_act.get(a, [])]
        changed = False
        add = added[a]
        if keep is not None:
            status = "stored"
            if keep == u.source and _gives_flights(u):
                tx.flush()  # its rows may be this transaction's
                changed = _apply_given(hs, u, mine, notes)
            add.clean = add.clean and not changed
        else:
            gone = _superseded(u, stored, tx.legacy[a], notes)
            mine, n_live = _replace_live(hs, u, mine, notes, summaries[a])
            _calendar_overlaps(hs, u, mine, gone, notes)
            _undated_after_dated(u, mine, summaries.get(a), add.periods, notes)
            status = "superseded" if gone or n_live else "new"
            changed = True
            for src in gone:  # (its own source is not stored: it has no log row)
                tx.remove(a, src)
            add.clean = add.clean and status == "new"
            order = [float(t) for t in u.order] or sorted(float(p.start_t) for p in mine)
            add.rules[u.source] = SourceRule(u.gap, tuple(order))
            uniq = {float(p.start_t): p for p in mine}
            add.periods.extend(uniq.values())
            ev = {(float(e.t), e.kind): e for e in al_by.get(a, [])}
            add.alarms.extend(ev)
            ident = u.identity if u.identity is None or isinstance(u.identity, str) else (
                u.identity.dumps())  # fmt: skip
            tx.add(a, u.source, (int(u.samples), u.name, True if ident else None), {
                "log_sources": [[a, u.source, int(u.samples), u.name, "gap" if u.gap else "log",
                                 ident, json.dumps(order)]],
                "periods": [[getattr(p, c) for c in _PERIOD_COLS] for p in uniq.values()],
                "alarms": [[e.actuator, e.t, e.kind, u.source, e.value] for e in ev.values()],
            })  # fmt: skip
        prev = out.get(a)
        out[a] = {
            "status": status,
            "changed": changed or bool(prev and prev["changed"]),
            "source": keep if keep is not None else u.source,
            "periods_new": len(mine),
            "notes": notes,
        }
    return out


def _stored_as(u: LogUnit, stored: dict[str, tuple], notes: list[str]) -> str | None:
    """The stored log that already holds every sample of ``u`` (None: none does)."""
    if u.source in stored:
        return u.source
    for src, (_n, name, ident) in sorted(stored.items()):
        if ident is None or u.relate is None:
            continue
        rel = u.relate(src)
        if rel is not None and rel.inside:
            how = "" if rel.exact else " (its first and last block by sample count)"
            notes.append(f"every sample of it is stored already, from {name}{how}: "
                         "nothing stored")  # fmt: skip
            return src
    return None


def _superseded(
    u: LogUnit, stored: dict[str, tuple], legacy: set[str], notes: list[str]
) -> set[str]:
    """The stored logs of ``u``'s unit it replaces: those whose samples it holds all, and
    the same log under an older servowatch's id; notes on the logs it overlaps."""
    gone: set[str] = set()
    for src, (n, name, ident) in sorted(stored.items()):
        if ident is None:  # stored before schema v7: identified by its first sample
            if src in u.legacy:
                if n <= u.samples:
                    gone.add(src)
                else:
                    notes.append(
                        f"{name}, stored by an older servowatch, starts with the same sample "
                        f"and holds more ({n} against {u.samples}): both kept; if this log is a "
                        "shorter copy of it, rebuild the store from the logs"
                    )
            continue
        rel = u.relate(src) if u.relate is not None else None
        if rel is None:
            continue
        if rel.holds:
            gone.add(src)
        elif rel.shared:
            notes.append(f"shares {rel.shared} samples with {name} and differs in others: "
                         "two logs, both kept")  # fmt: skip
    gone.update(legacy.intersection(u.legacy))  # a store before schema v4: no log row
    return gone


def _replace_live(
    hs: Any, u: LogUnit, mine: list[Period], notes: list[str], s: dict[str, Any]
) -> tuple[list[Period], int]:
    """The daemon's live periods written beside this log (source ``live:...@{log_id}``)
    that lie within its samples are replaced by the log's (with their alarms); a log period
    that overlaps a live one kept (it straddles the log's first or last sample) is left
    out. Returns the log's periods to store and how many live periods went (``s``: the
    unit's summary row, which counts its live periods)."""
    if not u.live or not mine or not int(s.get("live_periods") or 0):  # none stored
        return mine, 0
    b = hs._b
    lo = min(p.start_t for p in mine)
    hi = max(p.end_t for p in mine)
    rows = b.execute("SELECT source, start_t, end_t FROM periods WHERE actuator = ? AND "
                     "source LIKE ?", (u.actuator, "live:%")).fetchall()  # fmt: skip
    rows = [(s, float(a), float(e)) for s, a, e in rows if s.endswith(u.live)]
    gone = [(s, a) for s, a, e in rows if a >= lo and e <= hi]
    kept = [(a, e) for s, a, e in rows if not (a >= lo and e <= hi)]
    for s, a in gone:
        b.execute("DELETE FROM periods WHERE actuator = ? AND source = ? AND start_t = ?",
                  (u.actuator, s, a))  # fmt: skip
    for s in {s for s, _ in gone}:
        b.execute("DELETE FROM alarms WHERE actuator = ? AND source = ? AND t >= ? AND t <= ?",
                  (u.actuator, s, lo, hi))  # fmt: skip
    out = [p for p in mine if not any(p.start_t < e and p.end_t > a for a, e in kept)]
    if gone:
        notes.append(f"replaces {len(gone)} live period(s) the daemon stored beside this log")
    return out, len(gone)


def _calendar_overlaps(
    hs: Any, u: LogUnit, mine: list[Period], gone: set[str], notes: list[str]
) -> None:
    """A note per stored log (or live periods) of the unit whose periods overlap this log's
    in calendar time while sharing no sample with it: the same flight recorded or imported
    twice in different samples (another rate, map or acquisition). Both are kept, as two
    flights (``lifeorder.next_flight``); the note is the sign of it."""
    spans = [(float(p.start_unix), float(p.start_unix) + float(p.end_t - p.start_t))
             for p in mine if p.start_unix is not None]  # fmt: skip
    if not spans:
        return
    lo, hi = min(a for a, _ in spans), max(e for _, e in spans)
    rows = hs._b.execute(
        "SELECT p.source, l.name, p.start_unix, p.start_unix + (p.end_t - p.start_t) "
        "FROM periods p LEFT JOIN log_sources l ON l.actuator = p.actuator "
        "AND l.source = p.source WHERE p.actuator = ? AND p.source <> ? "
        "AND p.start_unix IS NOT NULL AND p.start_unix < ? "
        "AND p.start_unix + (p.end_t - p.start_t) > ?",
        (u.actuator, u.source, hi, lo),
    ).fetchall()
    over: dict[str, list] = {}
    for src, name, a, e in rows:
        if src in gone or (u.live and src.endswith(u.live)):
            continue
        rel = u.relate(src) if u.relate is not None and name is not None else None
        if rel is not None and (rel.shared or rel.inside or rel.holds):
            continue  # noted as sharing samples (``_superseded``)
        ov = sum(max(0.0, min(e, y) - max(a, x)) for x, y in spans)
        if ov > 0:
            o = over.setdefault(src, [name or src, 0.0])
            o[1] += ov
    for _src, (name, ov) in sorted(over.items()):
        notes.append(f"overlaps {name} by {ov:.1f} s of calendar time with other samples: "
                     "both kept, as two flights (the same flight recorded or imported "
                     "twice differently?)")  # fmt: skip


def _undated_after_dated(
    u: LogUnit,
    mine: list[Period],
    s: dict[str, Any] | None,
    added: list[Period],
    notes: list[str],
) -> None:
    """A note when a log without calendar time (no dated samples, no ``--start-unix``) joins
    a unit whose history is dated: the life order (decision 0034) puts it after every dated
    stretch, so its periods become the unit's latest reading, whatever its real date."""
    if not mine or any(p.start_unix is not None for p in mine):
        return
    last = json.loads(s["last_period"]) if s and s.get("last_period") else None
    if (last is None or last.get("start_unix") is None) and not any(
        p.start_unix is not None for p in added
    ):
        return
    notes.append("has no calendar time (samples not in Unix time, no --start-unix): placed "
                 "after the unit's dated flights, so it is now the unit's latest reading; "
                 "give --start-unix if it is older")  # fmt: skip


def _gives_flights(u: LogUnit) -> bool:
    """``u`` names its flights or date: ``--flight``, ``--start-unix`` or its own flight
    records (not the gap rule), to be applied to its stored periods (decision 0048)."""
    return u.flight is not None or u.start_unix is not None or u.gap is False


def _apply_given(hs: Any, u: LogUnit, mine: list[Period], notes: list[str]) -> bool:
    """A ``--flight``/``--start-unix`` given for a log stored already, else the flights of
    its own flight records (``mine``: its periods as this replay stamped them): applied to
    its stored periods (then no longer renumbered by the gap rule), so the store does not
    depend on whether a copy with a record came first. True if anything changed."""
    if not _gives_flights(u):
        return False
    own = u.flight is None and u.start_unix is None  # then its own flight records
    b = hs._b
    rows = b.execute("SELECT start_t, flight, start_unix FROM periods WHERE actuator = ? "
                     "AND source = ?", (u.actuator, u.source)).fetchall()  # fmt: skip
    t0 = u.first_t if u.first_t is not None else min((float(r[0]) for r in rows), default=0.0)
    stamped = {float(p.start_t): p for p in mine}
    upd = []
    for t, fl, su in rows:
        if own:
            p = stamped.get(float(t))
            nfl = fl if p is None or p.flight is None else int(p.flight)
            nsu = su if p is None or p.start_unix is None else p.start_unix
        else:
            nfl = int(u.flight) if u.flight is not None else fl
            nsu = u.start_unix + (float(t) - t0) if u.start_unix is not None else su
        if nfl != fl or nsu != su:
            upd.append((nfl, nsu, u.actuator, t, u.source))
    if not upd:
        return False
    b.executemany("UPDATE periods SET flight = ?, start_unix = ? WHERE actuator = ? "
                  "AND start_t = ? AND source = ?", upd)  # fmt: skip
    if u.flight is not None or own:
        b.execute("UPDATE log_sources SET flights = 'log' WHERE actuator = ? AND source = ?",
                  (u.actuator, u.source))  # fmt: skip
    if own:
        fls = sorted({int(p.flight) for p in mine if p.flight is not None})
        given = "its flight record (flight " + ", ".join(map(str, fls)) + ")"
    else:
        given = " and ".join(x for x in (
            f"flight {u.flight}" if u.flight is not None else "",
            f"start {u.start_unix:.0f} (Unix s)" if u.start_unix is not None else "") if x)  # fmt: skip
    notes.append(f"stored already: {given} applied to its {len(rows)} stored period(s)")
    return True
