"""A unit's flight numbers as a pure function of its stored periods (docs/store.md, "What a
re-run does"; docs/decisions/0010-log-identity-and-flight-numbers.md).

Every period of a unit is put in **life order** (``life_key``): periods with a calendar time
by ``start_unix``; then those without one whose flight the log gave, by that flight; then
the rest by the name of the log they came from (digits compared as numbers); ties by sample
time and source. Walking that order, a period whose flight follows the **gap rule**
(``next_flight``: the flight of the period before it, plus one when the gap between them
exceeds ``gap_s`` or is negative; the first period is flight 0) gets its number from the
period before it; any other period (a flight record, ``replay --flight``, the daemon's live
periods, a log stored before schema v4) keeps the one it has. ``number_flights`` does the
walk; the store runs it on a unit after every ingest that changed the unit, in the same
transaction, so the numbers never depend on what was stored before or in which split the
logs came.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import NamedTuple

from service.store.records import Period

__all__ = ["LogUnit", "next_flight", "life_key", "natural_key", "number_flights"]


class LogUnit(NamedTuple):
    """What one replayed log holds of one unit, for ``HealthStore.ingest_log``."""

    actuator: str
    source: str  # the log's identity for this unit (``service.replay.unit_source``)
    samples: int  # samples of the unit accepted from the log
    name: str  # the log's file name
    gap: bool  # its flights follow the gap rule (no flight record, no ``--flight``)
    legacy: str | None = None  # the id a store before schema v4 gave the same log


def _end_unix(p: Period) -> float | None:
    return None if p.start_unix is None else p.start_unix + (p.end_t - p.start_t)


def next_flight(prev: Period | None, p: Period, start_unix: float | None, gap_s: float) -> int:
    """The gap rule: the flight of ``p`` (calendar start ``start_unix``) after ``prev``, the
    unit's period before it in life order (None: ``p`` is its first, flight 0). A gap from
    ``prev``'s end to ``p``'s start above ``gap_s`` (calendar time when both have it, else
    sample time) or below zero (the log's clock restarted: another log) opens the next
    flight."""
    if prev is None:
        return 0
    base = prev.flight if prev.flight is not None else 0
    pe = _end_unix(prev)
    gap = start_unix - pe if start_unix is not None and pe is not None else p.start_t - prev.end_t
    return base + 1 if (gap > gap_s or gap < 0) else base


def natural_key(text: str) -> tuple:
    """``text`` with its digit runs compared as numbers (``f2`` before ``f10``)."""
    return tuple(
        (0, int(s), "") if s.isdigit() else (1, 0, s) for s in re.split(r"(\d+)", text) if s
    )


def life_key(p: Period, gap: bool, name: str) -> tuple:
    """Where ``p`` sits in its unit's life (module docstring); ``gap``: its flight follows
    the gap rule; ``name``: the name of the log it came from (its source when none)."""
    if p.start_unix is not None:
        return (0, p.start_unix, 0, (), p.start_t, p.source)
    if not gap and p.flight is not None:
        return (1, 0.0, p.flight, natural_key(name), p.start_t, p.source)
    return (2, 0.0, 0, natural_key(name), p.start_t, p.source)


def number_flights(
    periods: Sequence[Period], rules: Mapping[str, tuple[str, bool]], gap_s: float
) -> list[Period]:
    """One unit's ``periods`` in life order with their flights: ``rules[source] = (name,
    gap)`` for the periods of a replayed log (``gap``: its flights follow the gap rule); a
    source without a rule keeps its flights."""
    if not gap_s > 0:
        raise ValueError("gap_s must be > 0")

    def rule(p: Period) -> tuple[str, bool]:
        return rules.get(p.source, (p.source, False))

    order = sorted(periods, key=lambda p: life_key(p, rule(p)[1], rule(p)[0]))
    out: list[Period] = []
    prev: Period | None = None
    for p in order:
        if rule(p)[1] or p.flight is None:
            fl = next_flight(prev, p, p.start_unix, gap_s)
            if fl != p.flight:
                p = replace(p, flight=fl)
        out.append(p)
        prev = p
    return out
