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
        pending = _Pending()
        for units, periods, alarms in logs:
            res = _store_units(hs, units, periods, alarms, added, summaries, pending)
            changed.update(a for a, r in res.items() if r["changed"])
            stored_as.append(res)
        pending.flush(b)
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


class _Pending:
    """The period and alarm rows of a transaction's logs, per ``(actuator, source)``,
    written in one bulk insert per table (``flush``) before anything reads or changes
    them."""

    def __init__(self) -> None:
        self.periods: dict[tuple[str, str], list[list[Any]]] = {}
        self.alarms: dict[tuple[str, str], list[list[Any]]] = {}

    def drop(self, actuator: str, source: str) -> None:
        self.periods.pop((actuator, source), None)
        self.alarms.pop((actuator, source), None)

    def flush(self, b: Any) -> None:
        for table, cols, rows in (("periods", _PERIOD_COLS, self.periods),
                                  ("alarms", _ALARM_COLS, self.alarms)):  # fmt: skip
            if rows:
                b.bulk_insert(table, cols, [r for part in rows.values() for r in part])
            rows.clear()


def _flights(b: Any, keys: set[tuple[str, str]]) -> dict[tuple[str, str], set[int]]:
    """The stored flights of each ``(actuator, source)`` of ``keys``."""
    out: dict[tuple[str, str], set[int]] = defaultdict(set)
    by_act: dict[str, list[str]] = defaultdict(list)
    for a, src in sorted(keys):
        by_act[a].append(src)
    for a, srcs in by_act.items():
        for i in range(0, len(srcs), 500):
            part = srcs[i : i + 500]
            for src, fl in b.execute(
                "SELECT DISTINCT source, flight FROM periods WHERE actuator = ? AND source "
                f"IN ({','.join('?' * len(part))})", (a, *part)).fetchall():  # fmt: skip
                if fl is not None:
                    out[(a, src)].add(int(fl))
    return out


def _with_source(p: Period, source: str) -> Period:
    """``p`` under ``source`` (a copy; ``p`` was checked when it was made)."""
    q = copy.copy(p)
    object.__setattr__(q, "source", source)
    return q


def _stored_rows(hs: Any, u: LogUnit) -> dict[str, tuple]:
    """``{source: (samples, name, has identity)}`` of the stored logs of ``u``'s unit that
    its ingest must weigh: its own source, its ``legacy`` ids and those ``u.relate`` relates
    it to (``Relations``: the others are unrelated); every stored log when ``relate`` is a
    plain function."""
    b = hs._b
    sql = ("SELECT source, samples, name, identity IS NOT NULL FROM log_sources "
           "WHERE actuator = ?")  # fmt: skip
    rel = u.relate
    if rel is not None and not isinstance(rel, Mapping):
        rows = b.execute(sql, (u.actuator,)).fetchall()
    else:
        want = {u.source, *u.legacy}
        if rel is not None:
            want.update(s for s, r in rel.items() if r is not None and (
                r.inside or r.holds or r.shared))  # fmt: skip
        rows = []
        ws = sorted(want)
        for i in range(0, len(ws), 500):
            part = ws[i : i + 500]
            rows += b.execute(f"{sql} AND source IN ({','.join('?' * len(part))})",
                              (u.actuator, *part)).fetchall()  # fmt: skip
    return {r[0]: (int(r[1]), r[2], r[3] or None) for r in rows}


def _store_units(
    hs: Any,
    units: Sequence[LogUnit],
    periods: Iterable[Period],
    alarms: Iterable[AlarmEvent],
    added: dict[str, Added],
    summaries: dict[str, dict[str, Any]],
    pending: _Pending,
) -> dict[str, dict[str, Any]]:
    """One log's units written (inside the caller's transaction, summaries locked): per
    unit its ``status``, whether its rows ``changed`` (it must be renumbered), the
    ``source`` that holds its samples, ``periods_new`` and ``notes``; what each unit's rows
    got goes in ``added`` (``renumber.Added``), its new rows in ``pending``."""
    by_act: dict[str, list[Period]] = defaultdict(list)
    for p in periods:
        by_act[p.actuator].append(p)
    al_by: dict[str, list[AlarmEvent]] = defaultdict(list)
    for e in alarms:
        al_by[e.actuator].append(e)
    b = hs._b
    out: dict[str, dict[str, Any]] = {}
    for u in units:
        a = u.actuator
        stored = _stored_rows(hs, u)
        notes: list[str] = []
        keep = _stored_as(u, stored, notes)
        mine = [_with_source(p, u.source) for p in by_act.get(a, [])]
        changed = False
        add = added[a]
        if keep is not None:
            status = "stored"
            if keep == u.source and (u.flight is not None or u.start_unix is not None):
                pending.flush(b)  # its periods may be this transaction's
                changed = _apply_given(hs, u, notes)
            add.clean = add.clean and not changed
        else:
            gone = _superseded(hs, u, stored, notes)
            mine, n_live = _replace_live(hs, u, mine, notes, summaries[a])
            status = "superseded" if gone or n_live else "new"
            changed = True
            for src in gone:  # (its own source is not stored: no log_sources row)
                pending.drop(a, src)
                for t in ("periods", "alarms", "log_sources"):
                    cur = b.execute(f"DELETE FROM {t} WHERE actuator = ? AND source = ?",
                                    (a, src))  # fmt: skip
                    add.clean = add.clean and not cur.rowcount
            add.clean = add.clean and status == "new"
            order = [float(t) for t in u.order] or sorted(float(p.start_t) for p in mine)
            add.rules[u.source] = SourceRule(u.gap, tuple(order))
            b.execute(
                "INSERT INTO log_sources (actuator, source, samples, name, flights, identity, "
                "sample_order) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (a, u.source, int(u.samples), u.name, "gap" if u.gap else "log",
                 None if u.identity is None else u.identity.dumps(),
                 json.dumps(order)),
            )  # fmt: skip
            uniq = {float(p.start_t): p for p in mine}
            add.periods.extend(uniq.values())
            pending.periods[(a, u.source)] = [[getattr(p, c) for c in _PERIOD_COLS]
                                              for p in uniq.values()]  # fmt: skip
            ev = {(float(e.t), e.kind): e for e in al_by.get(a, [])}
            add.alarms.extend(ev)
            pending.alarms[(a, u.source)] = [[e.actuator, e.t, e.kind, u.source, e.value]
                                             for e in ev.values()]  # fmt: skip
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


def _superseded(hs: Any, u: LogUnit, stored: dict[str, tuple], notes: list[str]) -> set[str]:
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
    old = sorted(set(u.legacy) - set(stored))  # a store before schema v4: no log_sources row
    if old:
        gone.update(r[0] for r in hs._b.execute(
            f"SELECT DISTINCT source FROM periods WHERE actuator = ? AND source IN "
            f"({','.join('?' * len(old))})", (u.actuator, *old)).fetchall())  # fmt: skip
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


def _apply_given(hs: Any, u: LogUnit, notes: list[str]) -> bool:
    """A ``--flight``/``--start-unix`` given for a log stored already: applied to its
    stored periods (then no longer renumbered by the gap rule). True if anything changed."""
    if u.flight is None and u.start_unix is None:
        return False
    b = hs._b
    rows = b.execute("SELECT start_t, flight, start_unix FROM periods WHERE actuator = ? "
                     "AND source = ?", (u.actuator, u.source)).fetchall()  # fmt: skip
    t0 = u.first_t if u.first_t is not None else min((float(r[0]) for r in rows), default=0.0)
    upd = []
    for t, fl, su in rows:
        nfl = int(u.flight) if u.flight is not None else fl
        nsu = u.start_unix + (float(t) - t0) if u.start_unix is not None else su
        if nfl != fl or nsu != su:
            upd.append((nfl, nsu, u.actuator, t, u.source))
    if not upd:
        return False
    b.executemany("UPDATE periods SET flight = ?, start_unix = ? WHERE actuator = ? "
                  "AND start_t = ? AND source = ?", upd)  # fmt: skip
    if u.flight is not None:
        b.execute("UPDATE log_sources SET flights = 'log' WHERE actuator = ? AND source = ?",
                  (u.actuator, u.source))  # fmt: skip
    given = " and ".join(x for x in (
        f"flight {u.flight}" if u.flight is not None else "",
        f"start {u.start_unix:.0f} (Unix s)" if u.start_unix is not None else "") if x)  # fmt: skip
    notes.append(f"stored already: {given} applied to its {len(rows)} stored period(s)")
    return True
