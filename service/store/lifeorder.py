"""A unit's **life order** and its flight numbers, as pure functions of its stored periods
(docs/store.md, "What a re-run does"; decision record 0034, which replaces the life order of
decision 0010).

``life_order`` is the one order of a unit's periods that every view reads (the summary's
latest period, trend and recent window, ``fleet``, the page and its API, ``status``, the
metrics, ``rul``) and that the flights are numbered along. Periods are taken by **stretch**:
a replayed log of a unit is one stretch, its periods in the log's own sample order (a clock
that steps back inside a log does not reorder it); any other period (the daemon's live
periods, periods stored before schema v4) is a stretch of its own. Stretches go

1. with a calendar time (the stretch's first period's ``start_unix``), by it;
2. else with a flight given by the log (a flight record, ``replay --flight``), by that flight;
3. else by the log's content identity (its source, ``service.store.identity.stream_source``):
   an order that neither a copy under another name nor a re-run in any split can change.

Nothing is read from a file name or compared across logs by log-relative time. Walking that
order, a period whose flight follows the **gap rule** (``next_flight``) gets its number from
the period before it; any other keeps its own. ``number_flights`` does the walk; the store
runs it on a unit after every ingest that changed the unit, in the same transaction.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any, NamedTuple

from service.store.records import Period

__all__ = [
    "LogUnit",
    "SourceRule",
    "next_flight",
    "life_keys",
    "life_order",
    "number_flights",
]


class SourceRule(NamedTuple):
    """What the store keeps of a replayed log of a unit for its life order: whether its
    flights follow the gap rule, and its periods' ``start_t`` in the log's sample order
    (None for a log stored before schema v7: then by ``start_t``)."""

    gap: bool
    order: tuple[float, ...] | None = None


class LogUnit(NamedTuple):
    """What one replayed log holds of one unit, for ``HealthStore.ingest_log``."""

    actuator: str
    source: str  # the unit's stream identity (``service.store.identity.stream_source``)
    samples: int  # samples of the unit accepted from the log
    name: str  # the log's file name (for messages only)
    gap: bool  # its flights follow the gap rule (no flight record, no ``--flight``)
    legacy: tuple[str, ...] = ()  # the ids older stores gave the same log (adopted)
    identity: Any = None  # its ``StreamId`` or its text (stored for later logs to compare)
    relate: Callable[[str], Any] | None = None  # source -> ``Relation`` (or None: unknown)
    order: tuple[float, ...] = ()  # its periods' start_t in sample order
    flight: int | None = None  # ``--flight`` given for this log
    start_unix: float | None = None  # ``--start-unix`` given for this log
    first_t: float | None = None  # its first accepted sample time
    live: str | None = None  # ``@{log_id}``: the daemon's live periods written beside it


def _end_unix(p: Period) -> float | None:
    return None if p.start_unix is None else p.start_unix + (p.end_t - p.start_t)


def next_flight(
    prev: Period | None,
    p: Period,
    start_unix: float | None,
    gap_s: float,
    same_log: bool = False,
) -> int:
    """The gap rule: the flight of ``p`` (calendar start ``start_unix``) after ``prev``, the
    unit's period before it in life order (None: ``p`` is its first, flight 0). A gap from
    ``prev``'s end to ``p``'s start above ``gap_s`` (calendar time when both have it, else
    sample time) opens the next flight, as does one below zero between two logs (another
    log's clock); inside one log (``same_log``) a clock that stepped back does not: its
    samples follow each other."""
    if prev is None:
        return 0
    base = prev.flight if prev.flight is not None else 0
    pe = _end_unix(prev)
    gap = start_unix - pe if start_unix is not None and pe is not None else p.start_t - prev.end_t
    return base + 1 if (gap > gap_s or (gap < 0 and not same_log)) else base


def life_keys(periods: Sequence[Period], rules: Mapping[str, SourceRule]) -> list[tuple]:
    """The life-order key of each of ``periods`` (module docstring); ``rules[source]`` for
    the sources that are replayed logs."""
    first: dict[str, tuple[float, float | None]] = {}  # a log's first period: (pos, start_unix)
    pos: list[float] = []
    ats: dict[str, dict[float, int]] = {}  # a log's sample order: start_t -> position
    for p in periods:
        r = rules.get(p.source)
        if r is None:
            pos.append(float(p.start_t))
            continue
        at = ats.get(p.source)
        if at is None:
            at = ats[p.source] = {t: i for i, t in enumerate(r.order)} if r.order else {}
        x = float(at.get(float(p.start_t), p.start_t)) if at else float(p.start_t)
        pos.append(x)
        f = first.get(p.source)
        if f is None or x < f[0] or (x == f[0] and f[1] is None):
            first[p.source] = (x, p.start_unix)
    keys = []
    for p, x in zip(periods, pos, strict=True):
        r = rules.get(p.source)
        cal = p.start_unix if r is None else first[p.source][1]
        if cal is not None:
            keys.append((0, float(cal), p.source, x))
        elif (r is None or not r.gap) and p.flight is not None:
            keys.append((1, float(p.flight), p.source, x))
        else:
            keys.append((2, 0.0, p.source, x))
    return keys


def life_order(periods: Sequence[Period], rules: Mapping[str, SourceRule]) -> list[Period]:
    """``periods`` of one unit in its life order (module docstring)."""
    keys = life_keys(periods, rules)
    return [p for _, p in sorted(zip(keys, periods, strict=True), key=lambda kp: kp[0])]


def number_flights(
    periods: Sequence[Period],
    rules: Mapping[str, SourceRule],
    gap_s: float,
    prev: Period | None = None,
) -> list[Period]:
    """One unit's ``periods`` in life order with their flights: a period of a log whose
    flights follow the gap rule (``rules[source].gap``), or one without a flight, is
    numbered from the period before it; any other keeps its flight. ``prev``: the unit's
    period just before the first of ``periods`` in life order, numbered (None: they are its
    first), so that periods which all follow the stored ones are numbered on their own
    (the store's incremental renumbering, ``service.store.renumber``)."""
    if not gap_s > 0:
        raise ValueError("gap_s must be > 0")
    out: list[Period] = []
    for p in life_order(periods, rules):
        r = rules.get(p.source)
        if (r is not None and r.gap) or p.flight is None:
            same = prev is not None and r is not None and prev.source == p.source
            fl = next_flight(prev, p, p.start_unix, gap_s, same)
            if fl != p.flight:
                p = replace(p, flight=fl)
        out.append(p)
        prev = p
    return out


def natural_key(text: str) -> tuple:
    """``text`` with its digit runs compared as numbers (``f2`` before ``f10``): the order a
    batch reads its logs in (``replay.log_order``), never a life order."""
    import re

    return tuple(
        (0, int(s), "") if s.isdigit() else (1, 0, s) for s in re.split(r"(\d+)", text) if s
    )
