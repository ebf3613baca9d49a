"""A unit's flights and summary row after a write, along its life order (docs/store.md,
"What a re-run does"; decision records 0034 and 0044).

The flights are the gap rule walked over the unit's whole history in life order
(``lifeorder.number_flights``); the summary row is the history summarised in that order.
``renumber_full`` does exactly that: it reads the unit's periods. ``renumber_append`` gives
the same store without reading them when the write only **appends**: every period it adds
comes after every stored one in life order (``summary.last_key``), and it removes and
changes no stored row. Then the walk over the whole history is the stored walk followed by
the walk of the new periods from the stored last period (``summary.last_period``, with its
flight), and the summary is the stored row with the new periods added (``summarise``).

That holds when the stored flights are what a walk over the stored history gives, which the
summary row records (``renumber_from``, schema v8): NULL when they are; ``'[]'`` when the
next write must walk the whole history (a store migrated from v7, a unit whose walk moved a
period in the order: one without a flight and without a calendar time, once numbered, goes
by its flight; live periods added out of order or without a flight, ``add_periods``), as
must a write with another flight gap than the stored flights were numbered with
(``flight_gap_s``). Any other write takes ``renumber_full``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from service.store.lifeorder import SourceRule, life_keys, number_flights
from service.store.records import Period
from service.store.summary import summarise

__all__ = ["Added", "renumber_full", "renumber_append", "EVERYTHING"]

#: ``summary.renumber_from`` when the next write must walk the unit's whole history
EVERYTHING = "[]"


@dataclass
class Added:
    """What a transaction wrote of one unit: the periods and alarms it inserted under new
    sources (and the sources' rules), and whether it did nothing else to the unit's rows
    (``clean``: no row removed, no stored period changed)."""

    periods: list[Period] = field(default_factory=list)
    rules: dict[str, SourceRule] = field(default_factory=dict)
    alarms: list[tuple[float, str]] = field(default_factory=list)  # (t, kind)
    clean: bool = True


def _update_flights(hs: Any, actuator: str, was: dict, now: list[Period]) -> None:
    upd = [(p.flight, actuator, p.start_t, p.source) for p in now
           if was[(float(p.start_t), p.source)] != p.flight]  # fmt: skip
    if upd:
        hs._b.executemany(
            "UPDATE periods SET flight = ? WHERE actuator = ? AND start_t = ? AND source = ?", upd
        )


def _settled(before: list[tuple], now: list[Period], rules: dict[str, SourceRule]) -> bool:
    """The walk moved no period in the life order (``before``: the keys it walked, sorted):
    a walk over the result gives the result again."""
    return life_keys(now, rules) == before


def renumber_full(hs: Any, actuator: str, s: dict[str, Any], gap_s: float) -> None:
    """Renumber the unit's gap-rule flights over its whole history in life order and make its
    summary row ``s`` afresh (inside the caller's transaction, ``s`` locked by it)."""
    old = hs.periods(actuator)
    rules = hs.rules(actuator)
    now = number_flights(old, rules, gap_s)
    _update_flights(hs, actuator, {(float(p.start_t), p.source): p.flight for p in old}, now)
    s["renumber_from"] = None if _settled(sorted(life_keys(old, rules)), now, rules) else EVERYTHING
    s["flight_gap_s"] = float(gap_s)
    hs.rebuild_summary(actuator, s, now, rules)


def renumber_append(hs: Any, actuator: str, s: dict[str, Any], add: Added, gap_s: float) -> bool:
    """Number the periods ``add`` inserted and add them to summary row ``s`` without reading
    the unit's history, when the write only appended (module docstring); False (nothing
    done) otherwise."""
    if not add.clean or s.get("renumber_from") is not None or s.get("flight_gap_s") != gap_s:
        return False
    if add.alarms:  # a tie at the latest alarm time is left to the store's order of kinds
        t, _ = max(add.alarms)
        lt = s.get("last_alarm_t")
        if (lt is not None and t == float(lt)) or sum(a[0] == t for a in add.alarms) > 1:
            return False
    keys = sorted(life_keys(add.periods, add.rules))
    last = s.get("last_key")
    if last is None:
        if int(s.get("n_periods") or 0):
            return False
        prev = None
    else:
        if keys and keys[0] <= tuple(json.loads(last)):
            return False
        prev = Period.from_dict(json.loads(s["last_period"]))
    now = number_flights(add.periods, add.rules, gap_s, prev)
    if not _settled(keys, now, add.rules):
        return False
    _update_flights(hs, actuator, {(float(p.start_t), p.source): p.flight
                                   for p in add.periods}, now)  # fmt: skip
    summarise(s, now, keys)
    if add.alarms:  # the alarm fields as ``rebuild_summary`` counts them
        s["alarm_events"] = int(s["alarm_events"] or 0) + len(add.alarms)
        t, kind = max(add.alarms)
        lt = s.get("last_alarm_t")
        if lt is None or t > float(lt):
            s["last_alarm_t"], s["last_alarm_kind"] = float(t), kind
    hs._write_summary(actuator, s)
    return True
