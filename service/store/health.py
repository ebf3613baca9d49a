"""The health store: one class over SQLite (embedded, WAL) or PostgreSQL (psycopg 3).

All SQL is written once with ``?`` placeholders; ``_Backend`` is the one place that knows
the dialects (placeholder style, transaction start, row locks, bulk insert). Every public
write is one transaction, so a writer killed at any point leaves either the whole write or
none of it; the per-actuator ``summary`` row is updated in the same transaction as the
periods, alarms and baselines it summarises.
"""

from __future__ import annotations

import json
import math
import os
import re
import sqlite3
import time
from collections import defaultdict
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from service.store.access import StoreError, engine_error, first_line
from service.store.backends import _Backend, _Postgres, _SQLite, describe_url
from service.store.lifeorder import LogUnit, SourceRule, life_keys, life_order
from service.store.records import (
    PERIOD_FIELDS,
    PERIOD_FLOAT_FIELDS,
    AlarmEvent,
    BaselineRecord,
    Period,
    check_actuator,
)
from service.store.renumber import EVERYTHING
from service.store.schema import LATEST_VERSION, MIGRATIONS, REBUILD_SUMMARIES, RECOMPUTE_TRENDS
from service.store.summary import reset, summarise, trend_of
from service.store.usage import USAGE_TOTALS, usage_totals

__all__ = ["HealthStore", "StoreError", "open_store", "trend_of", "describe_url", "READ_TIMEOUT_S"]

# column order of the periods table as written (the key first)
_PERIOD_COLS: tuple[str, ...] = ("actuator", "start_t", "source") + tuple(
    f for f in PERIOD_FIELDS if f not in ("actuator", "start_t", "source")
)
_SUMMARY_COLS: tuple[str, ...] = (
    "n_periods",
    "op_time_s",
    "samples",
    "alarms",
    "bad_samples",
    "dropped",
    "first_start_t",
    "last_start_t",
    "last_period",
    "recent",
    "alarm_events",
    "last_alarm_t",
    "last_alarm_kind",
    "baseline_version",
    "trend_n",
    "trend_slope_per_h",
    "trend_change",
    "trend_label",
    *USAGE_TOTALS,
    "last_key",
    "life_axis",
    "first_flight",
    "n_flights",
    "last_ratio",
    "renumber_from",
    "flight_gap_s",
    "live_periods",
)
_FLEET_COLS: tuple[str, ...] = tuple(
    c
    for c in _SUMMARY_COLS
    if c not in ("recent", "last_key", "renumber_from", "flight_gap_s", "live_periods")
)
_CHUNK = 500  # parameters per IN (...) list
#: a read-only command waits at most this long for a writer's lock [s] (docs/cli.md)
READ_TIMEOUT_S = 5.0


def _dumps(obj: Any) -> str:
    return json.dumps(obj, separators=(",", ":"), sort_keys=True)


def _opt(v: Any, kind: type) -> Any:
    return None if v is None else kind(v)


def _float(v: Any) -> float:
    return math.nan if v is None else float(v)


class HealthStore:
    """Actuators, versioned baselines, operating periods, alarm events and RUL summaries.

    Open with ``open_store``; a context manager (``close()`` on exit).
    """

    def __init__(self, backend: _Backend, url: str, read_only: bool = False) -> None:
        self._b = backend
        self.url = url
        self.backend = backend.name
        self.read_only = read_only
        self._known: set[str] = set()
        if read_only:
            self._check_schema()
        else:
            self._migrate()

    # -- lifecycle ------------------------------------------------------------------------
    def __enter__(self) -> HealthStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def where(self) -> str:
        """The store's path or URL with any password hidden (for messages)."""
        return describe_url(self.url)

    def close(self) -> None:
        """Close the connection (idempotent)."""
        self._b.close()

    def _migrate(self) -> None:
        b = self._b
        with b.transaction():
            b.lock_migrations()
            b.execute(
                "CREATE TABLE IF NOT EXISTS schema_migrations ("
                "version INTEGER PRIMARY KEY, description TEXT NOT NULL, "
                "applied_s DOUBLE PRECISION NOT NULL)"
            )
        current = self.schema_version()
        if current > LATEST_VERSION:
            raise StoreError(
                f"store {describe_url(self.url)}: schema version {current} is newer than this "
                f"servowatch understands ({LATEST_VERSION}); upgrade servowatch"
            )
        todo = [m for m in MIGRATIONS if m[0] > current]
        # the summary rows are rebuilt (with every column) by the last migration to apply
        # that rebuilds them: an earlier one's rebuild would write columns not yet added
        rebuild_at = max((v for v, _, st in todo if REBUILD_SUMMARIES in st), default=None)
        for version, desc, stmts in MIGRATIONS:
            if version <= current:
                continue
            with b.transaction():
                b.lock_migrations()
                # another process may have applied it meanwhile
                row = b.execute(
                    "SELECT 1 FROM schema_migrations WHERE version = ?", (version,)
                ).fetchone()
                if row:
                    continue
                for s in stmts:
                    if s == RECOMPUTE_TRENDS:
                        self._recompute_trends()
                    elif s == REBUILD_SUMMARIES:  # the units that have periods to order
                        if version != rebuild_at:
                            continue
                        for (a,) in b.execute("SELECT DISTINCT actuator FROM periods").fetchall():
                            self.rebuild_summary(a, self._lock_summaries([a])[a])
                    else:
                        b.execute(s)
                b.execute(
                    "INSERT INTO schema_migrations (version, description, applied_s) "
                    "VALUES (?, ?, ?)",
                    (version, desc, time.time()),
                )

    def _check_schema(self) -> None:
        """A reader's check in place of the migrations: the schema is this servowatch's."""
        try:
            current = self.schema_version()
        except Exception as e:  # no schema_migrations table: not a health store (yet)
            raise StoreError(
                f"store {describe_url(self.url)}: not a health store yet (no schema): {e}"
            ) from e
        if current != LATEST_VERSION:
            hint = (
                "upgrade servowatch"
                if current > LATEST_VERSION
                else "any servowatch command that writes the store (e.g. `servowatch rul`) migrates it"
            )
            raise StoreError(
                f"store {describe_url(self.url)}: schema version {current}, this servowatch "
                f"reads {LATEST_VERSION}; {hint}"
            )

    def _recompute_trends(self) -> None:
        rows = self._b.execute("SELECT actuator, recent FROM summary").fetchall()
        for a, recent in rows:
            tr = trend_of(json.loads(recent or "[]"))
            self._b.execute(
                "UPDATE summary SET trend_n = ?, trend_slope_per_h = ?, trend_change = ?, "
                "trend_label = ? WHERE actuator = ?",
                (tr["periods"], tr["slope_per_h"], tr["change"], tr["label"], a),
            )

    def schema_version(self) -> int:
        """The highest migration applied (0 for an empty store)."""
        row = self._b.execute("SELECT MAX(version) FROM schema_migrations").fetchone()
        return int(row[0] or 0)

    def check_writable(self) -> None:
        """Raise ``StoreError`` when this store cannot be written (a read-only file, folder
        or database, no write privilege): a write that changes nothing, rolled back.
        ``open_store`` checks it for a writer, before the writer's work."""
        try:
            with self._b.transaction():
                self._b.execute("DELETE FROM schema_migrations WHERE version < 0")
        except Exception as e:
            if isinstance(e, StoreError) or not engine_error(e):
                raise
            raise StoreError(f"store {self.where}: cannot be written: {first_line(e)}") from e

    # -- actuators ------------------------------------------------------------------------
    def _ensure(self, actuator: str) -> None:
        if actuator in self._known:
            return
        b = self._b
        b.execute(
            "INSERT INTO actuators (name, created_s) VALUES (?, ?) ON CONFLICT (name) DO NOTHING",
            (actuator, time.time()),
        )
        b.execute(
            "INSERT INTO summary (actuator) VALUES (?) ON CONFLICT (actuator) DO NOTHING",
            (actuator,),
        )

    def ensure_actuator(self, actuator: str) -> None:
        """Register ``actuator`` (``AIRCRAFT/ACTUATOR``) if it is not in the store yet."""
        check_actuator(actuator)
        with self._b.transaction():
            self._ensure(actuator)
        self._known.add(actuator)

    def actuators(self) -> list[str]:
        """Every actuator in the store, sorted."""
        rows = self._b.execute("SELECT name FROM actuators ORDER BY name").fetchall()
        return [r[0] for r in rows]

    def has_actuator(self, actuator: str) -> bool:
        """Whether ``actuator`` is in the store."""
        row = self._b.execute("SELECT 1 FROM actuators WHERE name = ?", (actuator,)).fetchone()
        return row is not None

    def _lock_summaries(self, actuators: Sequence[str]) -> dict[str, dict[str, Any]]:
        """The summary rows of ``actuators``, locked for this transaction."""
        out: dict[str, dict[str, Any]] = {}
        acts = list(actuators)
        for i in range(0, len(acts), _CHUNK):
            part = acts[i : i + _CHUNK]
            ph = ",".join("?" * len(part))
            rows = self._b.execute(
                f"SELECT actuator, {','.join(_SUMMARY_COLS)} FROM summary "
                f"WHERE actuator IN ({ph}){self._b.for_update}",
                part,
            ).fetchall()
            for r in rows:
                out[r[0]] = dict(zip(_SUMMARY_COLS, r[1:], strict=True))
        return out

    def _write_summary(self, actuator: str, s: dict[str, Any]) -> None:
        cols = [c for c in _SUMMARY_COLS]
        self._b.execute(
            f"UPDATE summary SET {','.join(f'{c} = ?' for c in cols)} WHERE actuator = ?",
            [s[c] for c in cols] + [actuator],
        )

    # -- baselines ------------------------------------------------------------------------
    def add_baseline(
        self,
        actuator: str,
        baseline: dict[str, Any],
        source: str,
        figures: dict[str, Any] | None = None,
    ) -> BaselineRecord:
        """Record ``baseline`` (``Baseline.model_dump()``) as the actuator's next version."""
        check_actuator(actuator)
        if not isinstance(baseline, dict) or not baseline:
            raise ValueError("baseline: expected a non-empty dict (Baseline.model_dump())")
        if not isinstance(source, str) or not source:
            raise ValueError(f"source: expected a non-empty string, got {source!r}")
        figures = dict(figures or {})
        b = self._b
        with b.transaction():
            self._ensure(actuator)
            s = self._lock_summaries([actuator])[actuator]
            row = b.execute(
                "SELECT MAX(version) FROM baselines WHERE actuator = ?", (actuator,)
            ).fetchone()
            version = int(row[0] or 0) + 1
            rec = BaselineRecord(actuator, version, source, time.time(), dict(baseline), figures)
            b.execute(
                "INSERT INTO baselines (actuator, version, source, created_s, baseline, figures) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (actuator, version, source, rec.created_s, _dumps(baseline), _dumps(figures)),
            )
            s["baseline_version"] = version
            self._write_summary(actuator, s)
        self._known.add(actuator)
        return rec

    @staticmethod
    def _baseline_row(r: Sequence[Any]) -> BaselineRecord:
        return BaselineRecord(
            r[0], int(r[1]), r[2], float(r[3]), json.loads(r[4]), json.loads(r[5])
        )

    def latest_baseline(self, actuator: str) -> BaselineRecord | None:
        """The actuator's highest baseline version, or None (not commissioned)."""
        r = self._b.execute(
            "SELECT actuator, version, source, created_s, baseline, figures FROM baselines "
            "WHERE actuator = ? ORDER BY version DESC LIMIT 1",
            (actuator,),
        ).fetchone()
        return None if r is None else self._baseline_row(r)

    def baselines(self, actuator: str | None = None) -> list[BaselineRecord]:
        """Every baseline version (of one actuator), by actuator then version."""
        sql = "SELECT actuator, version, source, created_s, baseline, figures FROM baselines"
        params: tuple[Any, ...] = ()
        if actuator is not None:
            sql += " WHERE actuator = ?"
            params = (actuator,)
        rows = self._b.execute(sql + " ORDER BY actuator, version", params).fetchall()
        return [self._baseline_row(r) for r in rows]

    # -- periods --------------------------------------------------------------------------
    def add_period(self, p: Period) -> bool:
        """Store one period; False (and nothing written) if ``(actuator, source, start_t)``
        is already stored."""
        return self.add_periods([p]) == 1

    def add_periods(self, ps: Iterable[Period]) -> int:
        """Store periods in one transaction, skipping those already stored; returns how many
        were new."""
        batch: dict[tuple[str, str, float], Period] = {}
        for p in ps:
            if not isinstance(p, Period):
                raise TypeError(f"add_periods: expected Period records, got {type(p).__name__}")
            batch.setdefault((p.actuator, p.source, float(p.start_t)), p)
        if not batch:
            return 0
        by_act: dict[str, list[Period]] = defaultdict(list)
        for p in batch.values():
            by_act[p.actuator].append(p)
        b = self._b
        new: list[Period] = []
        with b.transaction():
            for a in by_act:
                self._ensure(a)
            summaries = self._lock_summaries(sorted(by_act))
            rebuild: list[str] = []
            for a, plist in by_act.items():
                lo = min(p.start_t for p in plist)
                hi = max(p.start_t for p in plist)
                have = {
                    (r[0], float(r[1]))
                    for r in b.execute(
                        "SELECT source, start_t FROM periods "
                        "WHERE actuator = ? AND start_t >= ? AND start_t <= ?",
                        (a, lo, hi),
                    ).fetchall()
                }
                fresh = [p for p in plist if (p.source, float(p.start_t)) not in have]
                if not fresh:
                    continue
                new.extend(fresh)
                rules = self.rules(a) if summaries[a]["n_periods"] else {}
                keys = life_keys(fresh, rules)
                last = summaries[a].get("last_key")
                after = last is None or min(keys) > tuple(json.loads(last))
                if after and not any(p.source in rules for p in fresh):
                    order = sorted(range(len(fresh)), key=keys.__getitem__)
                    summarise(summaries[a], [fresh[i] for i in order],
                              [keys[i] for i in order])  # fmt: skip
                else:  # before the unit's latest period: the row made again in life order
                    rebuild.append(a)
                if a in rebuild or any(p.flight is None for p in fresh):
                    # the walk over the history would number these or the ones after them
                    summaries[a]["renumber_from"] = EVERYTHING
            if new:
                b.bulk_insert(
                    "periods", _PERIOD_COLS, [[getattr(p, c) for c in _PERIOD_COLS] for p in new]
                )
                for a in {p.actuator for p in new}:
                    if a in rebuild:
                        self.rebuild_summary(a, summaries[a])
                    else:
                        self._write_summary(a, summaries[a])
        self._known.update(by_act)
        return len(new)

    def ingest_log(
        self,
        units: Sequence[LogUnit],
        periods: Iterable[Period],
        alarms: Iterable[AlarmEvent],
        gap_s: float,
    ) -> dict[str, dict[str, Any]]:
        """Store one replayed log in one transaction: ``service.store.ingest.ingest_log``
        (docs/store.md, "What identifies a log")."""
        from service.store.ingest import ingest_log

        return ingest_log(self, units, periods, alarms, gap_s)

    def rules(self, actuator: str) -> dict[str, SourceRule]:
        """The life-order rule of each replayed log of ``actuator`` (``lifeorder``)."""
        out = {}
        for src, flights, order in self._b.execute(
            "SELECT source, flights, sample_order FROM log_sources WHERE actuator = ?",
            (actuator,),
        ).fetchall():
            out[src] = SourceRule(flights == "gap",
                                  tuple(json.loads(order)) if order else None)  # fmt: skip
        return out

    def stream_ids(self, actuator: str) -> dict[str, Any]:
        """``{source: StreamId}`` of the replayed logs of ``actuator`` stored with a stream
        identity (``service.store.identity``; schema v7)."""
        from service.store.identity import StreamId

        rows = self._b.execute("SELECT source, identity FROM log_sources WHERE actuator = ? "
                               "AND identity IS NOT NULL", (actuator,)).fetchall()  # fmt: skip
        return {src: StreamId.loads(text) for src, text in rows}

    def life(self, actuator: str) -> list[Period]:
        """The actuator's periods in its **life order** (``lifeorder.life_order``: calendar
        time, then given flights, then the logs' content identity; a log's periods in its
        sample order): the one order every view reads."""
        return life_order(self.periods(actuator), self.rules(actuator))

    def rebuild_summary(
        self,
        actuator: str,
        s: dict[str, Any],
        periods: Sequence[Period] | None = None,
        rules: dict[str, SourceRule] | None = None,
    ) -> None:
        """Make ``actuator``'s summary row ``s`` (locked by the caller's transaction) afresh
        from its whole history in life order, and write it (``periods`` and ``rules``: the
        unit's, as stored, when the caller has read them)."""
        rules = self.rules(actuator) if rules is None else rules
        periods = self.periods(actuator) if periods is None else list(periods)
        keys = life_keys(periods, rules)
        order = sorted(range(len(periods)), key=keys.__getitem__)
        reset(s)
        summarise(s, [periods[i] for i in order], [keys[i] for i in order])
        n, last_t = self._b.execute(
            "SELECT COUNT(*), MAX(t) FROM alarms WHERE actuator = ?", (actuator,)
        ).fetchone()
        s["alarm_events"] = int(n)
        s["last_alarm_t"] = s["last_alarm_kind"] = None
        if last_t is not None:
            r = self._b.execute(
                "SELECT t, kind FROM alarms WHERE actuator = ? AND t = ? ORDER BY kind DESC",
                (actuator, last_t),
            ).fetchone()
            s["last_alarm_t"], s["last_alarm_kind"] = float(r[0]), r[1]
        self._write_summary(actuator, s)

    def ingest_logs(
        self,
        logs: Sequence[tuple[Sequence[LogUnit], Iterable[Period], Iterable[AlarmEvent]]],
        gap_s: float,
        incremental: bool = True,
    ) -> list[dict[str, dict[str, Any]]]:
        """Several replayed logs in one transaction, each unit renumbered once:
        ``service.store.ingest.ingest_logs`` (the store ``ingest_log`` one by one gives;
        ``incremental`` False: every changed unit renumbered over its whole history)."""
        from service.store.ingest import ingest_logs

        return ingest_logs(self, logs, gap_s, incremental)

    def periods(self, actuator: str) -> list[Period]:
        """The actuator's periods, by start_t."""
        rows = self._b.execute(
            f"SELECT {','.join(_PERIOD_COLS)} FROM periods WHERE actuator = ? "
            "ORDER BY start_t, source",
            (actuator,),
        ).fetchall()
        return [Period.from_dict(dict(zip(_PERIOD_COLS, r, strict=True))) for r in rows]

    def count_periods(self, actuator: str | None = None) -> int:
        """Number of stored periods (of one actuator)."""
        if actuator is None:
            row = self._b.execute("SELECT COUNT(*) FROM periods").fetchone()
        else:
            row = self._b.execute(
                "SELECT COUNT(*) FROM periods WHERE actuator = ?", (actuator,)
            ).fetchone()
        return int(row[0])

    # -- alarms ---------------------------------------------------------------------------
    def add_alarms(self, events: Iterable[AlarmEvent]) -> int:
        """Store alarm events in one transaction, skipping those already stored
        (same actuator, t, kind and source); returns how many were new."""
        batch: dict[tuple[str, float, str, str], AlarmEvent] = {}
        for e in events:
            if not isinstance(e, AlarmEvent):
                raise TypeError(f"add_alarms: expected AlarmEvent records, got {type(e).__name__}")
            batch.setdefault((e.actuator, float(e.t), e.kind, e.source), e)
        if not batch:
            return 0
        by_act: dict[str, list[AlarmEvent]] = defaultdict(list)
        for e in batch.values():
            by_act[e.actuator].append(e)
        b = self._b
        n = 0
        with b.transaction():
            for a in by_act:
                self._ensure(a)
            summaries = self._lock_summaries(sorted(by_act))
            for a, elist in by_act.items():
                lo, hi = min(e.t for e in elist), max(e.t for e in elist)
                have = {
                    (float(r[0]), r[1], r[2])
                    for r in b.execute(
                        "SELECT t, kind, source FROM alarms WHERE actuator = ? AND t >= ? AND t <= ?",
                        (a, lo, hi),
                    ).fetchall()
                }
                fresh = [e for e in elist if (float(e.t), e.kind, e.source) not in have]
                if not fresh:
                    continue
                b.bulk_insert(
                    "alarms",
                    ("actuator", "t", "kind", "source", "value"),
                    [[e.actuator, e.t, e.kind, e.source, e.value] for e in fresh],
                )
                s = summaries[a]
                s["alarm_events"] = int(s["alarm_events"]) + len(fresh)
                last = max(fresh, key=lambda e: e.t)
                if s["last_alarm_t"] is None or last.t >= s["last_alarm_t"]:
                    s["last_alarm_t"], s["last_alarm_kind"] = last.t, last.kind
                self._write_summary(a, s)
                n += len(fresh)
        self._known.update(by_act)
        return n

    def alarms(self, actuator: str) -> list[AlarmEvent]:
        """The actuator's alarm events, by t."""
        rows = self._b.execute(
            "SELECT actuator, t, kind, value, source FROM alarms WHERE actuator = ? ORDER BY t, kind",
            (actuator,),
        ).fetchall()
        return [AlarmEvent(r[0], float(r[1]), r[2], _float(r[3]), r[4]) for r in rows]

    # -- RUL ------------------------------------------------------------------------------
    def put_rul(self, actuator: str, rul: dict[str, Any]) -> None:
        """Replace the actuator's latest RUL summary (a JSON-able dict).

        The fleet view reads ``median_h``, ``lo_h``, ``hi_h`` (90 % interval, operating
        hours), ``median_flights``/``lo_flights``/``hi_flights`` and ``p_horizon`` from it
        when present; any other keys are kept as they are.
        """
        check_actuator(actuator)
        if not isinstance(rul, dict):
            raise ValueError(f"rul: expected a dict, got {type(rul).__name__}")
        text = json.dumps(rul, separators=(",", ":"), sort_keys=True, default=float)
        with self._b.transaction():
            self._ensure(actuator)
            self._b.execute(
                "INSERT INTO rul (actuator, updated_s, rul) VALUES (?, ?, ?) "
                "ON CONFLICT (actuator) DO UPDATE SET updated_s = excluded.updated_s, "
                "rul = excluded.rul",
                (actuator, time.time(), text),
            )
        self._known.add(actuator)

    def rul(self, actuator: str) -> dict[str, Any] | None:
        """The actuator's latest RUL summary, or None."""
        r = self._b.execute("SELECT rul FROM rul WHERE actuator = ?", (actuator,)).fetchone()
        return None if r is None else json.loads(r[0])

    # -- fleet ----------------------------------------------------------------------------
    def fleet_summary(self, actuator: str | None = None) -> list[dict[str, Any]]:
        """One dict per actuator (sorted by name; only ``actuator``'s when given) from the
        summary rows only: the last period's indicators, the C_Lk-ratio trend, the last RUL
        dict, alarm counts, the life axis and whether it is commissioned (has a baseline).
        Reads O(actuators) rows."""
        where, args = ("WHERE a.name = ? ", (actuator,)) if actuator is not None else ("", ())
        rows = self._b.execute(
            f"SELECT a.name, {','.join('s.' + c for c in _FLEET_COLS)}, r.rul, r.updated_s "
            "FROM actuators a LEFT JOIN summary s ON s.actuator = a.name "
            f"LEFT JOIN rul r ON r.actuator = a.name {where}ORDER BY a.name",
            args,
        ).fetchall()
        out: list[dict[str, Any]] = []
        for r in rows:
            s = dict(zip(_FLEET_COLS, r[1:-2], strict=True))
            last = json.loads(s["last_period"]) if s["last_period"] else None
            if last is not None:
                for k in PERIOD_FLOAT_FIELDS:
                    last[k] = _float(last.get(k))
            bv = int(s["baseline_version"] or 0)
            out.append(
                {
                    "actuator": r[0],
                    "commissioned": bv > 0,
                    "baseline_version": bv or None,
                    "periods": int(s["n_periods"] or 0),
                    "op_time_s": float(s["op_time_s"] or 0.0),
                    "samples": int(s["samples"] or 0),
                    "first_t": s["first_start_t"],
                    "last_t": None if last is None else last["end_t"],
                    "last": last,
                    "trend": {
                        "periods": int(s["trend_n"] or 0),
                        "slope_per_h": s["trend_slope_per_h"],
                        "change": s["trend_change"],
                        "label": s["trend_label"] or "unknown",
                    },
                    "alarms": int(s["alarms"] or 0),
                    "alarm_events": int(s["alarm_events"] or 0),
                    "last_alarm": None
                    if s["last_alarm_t"] is None
                    else {"t": float(s["last_alarm_t"]), "kind": s["last_alarm_kind"]},
                    "bad_samples": int(s["bad_samples"] or 0),
                    "dropped": int(s["dropped"] or 0),
                    "rul": None if r[-2] is None else json.loads(r[-2]),
                    "rul_updated_s": None if r[-1] is None else float(r[-1]),
                    "usage": usage_totals(s),
                    "last_ratio": _opt(s.get("last_ratio"), float),
                    "life_axis": s.get("life_axis") or "hours",
                    "first_flight": _opt(s.get("first_flight"), int),
                    "flights": int(s.get("n_flights") or 0),
                }
            )
        return out

    # -- checks ---------------------------------------------------------------------------
    def check(self) -> list[str]:
        """Consistency problems (empty when consistent): each summary row against the
        periods and alarms it summarises, and SQLite's own integrity check."""
        problems: list[str] = []
        b = self._b
        if b.name == "sqlite":
            res = b.execute("PRAGMA integrity_check").fetchall()
            if [tuple(x) for x in res] != [("ok",)]:
                problems.append(f"integrity_check: {res}")
        counts = {
            r[0]: (int(r[1]), int(r[2] or 0))
            for r in b.execute(
                "SELECT actuator, COUNT(*), SUM(samples) FROM periods GROUP BY actuator"
            ).fetchall()
        }
        nal = {
            r[0]: int(r[1])
            for r in b.execute("SELECT actuator, COUNT(*) FROM alarms GROUP BY actuator").fetchall()
        }
        nus = {  # periods that carry usage (the summary's usage totals, migration 5)
            r[0]: int(r[1])
            for r in b.execute(
                "SELECT actuator, COUNT(*) FROM periods WHERE usage_travel_m IS NOT NULL "
                "AND usage_travel_m <> 'NaN' GROUP BY actuator"
            ).fetchall()
        }
        for a, n, smp, ae, nu in b.execute(
            "SELECT actuator, n_periods, samples, alarm_events, usage_periods FROM summary"
        ).fetchall():
            if nus.get(a, 0) != int(nu):
                problems.append(f"{a}: summary says {nu} periods with usage, "
                                f"periods table has {nus.get(a, 0)}")  # fmt: skip
            if counts.get(a, (0, 0)) != (int(n), int(smp)):
                problems.append(f"{a}: summary says {n} periods/{smp} samples, "
                                f"periods table has {counts.get(a, (0, 0))}")  # fmt: skip
            if nal.get(a, 0) != int(ae):
                problems.append(f"{a}: summary says {ae} alarms, alarms table has {nal.get(a, 0)}")
        return problems


def open_store(
    url_or_path: str | os.PathLike[str],
    *,
    create: bool = True,
    timeout_s: float = 30.0,
    read_only: bool = False,
) -> HealthStore:
    """Open (migrating as needed) the store at a ``postgresql://`` URL or a SQLite file
    path; a missing SQLite file (and its directory) is created unless ``create`` is False.
    ``read_only``: never create, never migrate, and a connection that cannot write (SQLite
    ``mode=ro``, PostgreSQL ``default_transaction_read_only``), waiting for a writer's lock
    at most ``timeout_s`` (``READ_TIMEOUT_S`` for the commands); a store whose schema is
    not this servowatch's is a ``StoreError``. A writer's store is checked writable
    (``HealthStore.check_writable``) before it is returned."""
    if read_only:
        create = False
    if isinstance(url_or_path, os.PathLike):
        url_or_path = os.fspath(url_or_path)
    if not isinstance(url_or_path, str) or not url_or_path.strip():
        raise StoreError(f"store: expected a file path or a postgresql:// URL, got {url_or_path!r}")
    text = url_or_path.strip()
    if text.startswith(("postgresql://", "postgres://")):
        backend: _Backend = _Postgres(text, timeout_s, read_only)
    elif re.match(r"^[A-Za-z][A-Za-z0-9+.\-]*://", text) and not text.startswith("sqlite:///"):
        scheme = text.split("://", 1)[0]
        raise StoreError(
            f"store: unsupported URL scheme {scheme!r} in {describe_url(text)}; "
            "expected a file path or postgresql://user@host:port/db"
        )
    else:
        path = Path(text.removeprefix("sqlite:///") if text.startswith("sqlite:///") else text)
        if path.is_dir():
            raise StoreError(f"store: {path} is a directory; expected a SQLite file path")
        if not create and not path.exists():
            raise StoreError(f"store: {path} does not exist (no health store there yet)")
        if not create and path.is_file() and path.stat().st_size == 0:
            raise StoreError(f"store: {path} is an empty file (0 bytes): not a health store yet")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            backend = _SQLite(path, timeout_s, read_only)
        except (OSError, sqlite3.Error) as e:
            ro = "" if os.access(path.parent, os.W_OK) else " (its folder is read only)"
            raise StoreError(f"store: cannot open SQLite file {path}: {e}{ro}") from e
    try:
        store = HealthStore(backend, text, read_only)
        if not read_only:
            store.check_writable()
        return store
    except Exception as e:
        backend.close()
        if isinstance(e, StoreError) or not engine_error(e):
            raise
        if "lock" in str(e).lower():
            raise StoreError(
                f"store: {describe_url(text)} is busy: a writer held its lock longer than "
                f"{timeout_s:g} s ({first_line(e)})"
            ) from e
        raise StoreError(
            f"store: {describe_url(text)} is not a usable health store: {first_line(e)}"
        ) from e
    except BaseException:
        backend.close()
        raise
