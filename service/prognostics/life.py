"""Where each operating period sits on a unit's life: its flight number and calendar time
(docs/prognostics.md, "From logs to a history"). Used by the replay and the daemon alike.

A period's calendar start ``start_unix`` [Unix s] is, in this order:

1. from the log's ``servowatch.flight`` record of the unit (``service.log.flightrec``):
   ``start_unix + (start_t - t0)``;
2. from the caller (``replay --start-unix``), the same way from the log's first sample;
3. the sample time itself when it is a Unix time (``start_t`` >= ``UNIX_MIN``, as live
   acquisition sends it);
4. else None.

Its flight number, in this order: the caller's (``replay --flight N``); the unit's flight
record; else the **gap rule**: a period belongs to the flight of the unit's previous period
unless the gap from that period's end to its start exceeds ``gap_s`` (calendar time when both
have it, else sample time) or is negative (the log's clock restarted: another log); then it
opens the next flight (the unit's first period: flight 0). The rule itself is
``service.store.lifeorder.next_flight``; for replayed logs the store applies it again over the
unit's whole history after each ingest (``HealthStore.ingest_log``), so the flights stored
never depend on the order or split of the ingests (docs/store.md, "What a re-run does").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

from service.log.flightrec import FlightRecord
from service.store.lifeorder import next_flight
from service.store.records import Period

__all__ = ["FlightStamper", "FLIGHT_GAP_S", "UNIX_MIN"]

FLIGHT_GAP_S = 1800.0
"""Default gap [s] between two periods that starts a new flight (gap rule)."""
UNIX_MIN = 1e9
"""Sample times at or above this [s] are Unix times (2001-09-09 on)."""


class FlightStamper:
    """Stamps periods with flight and calendar time (module docstring). ``last(name)`` gives
    the unit's latest stored period (or None) the first time a unit is seen; afterwards the
    stamper remembers the last period it stamped."""

    def __init__(
        self, last: Callable[[str], Period | None] | None = None, gap_s: float = FLIGHT_GAP_S
    ) -> None:
        if not gap_s > 0:
            raise ValueError("gap_s must be > 0")
        self.gap_s = float(gap_s)
        self._last_of = last
        self._last: dict[str, Period | None] = {}

    def _prev(self, name: str) -> Period | None:
        if name not in self._last:
            self._last[name] = self._last_of(name) if self._last_of is not None else None
        return self._last[name]

    def stamp(
        self,
        periods: Sequence[Period],
        *,
        records: Sequence[FlightRecord] = (),
        first_t: dict[str, float] | None = None,
        flight: int | None = None,
        start_unix: float | None = None,
    ) -> list[Period]:
        """The periods (any units, any order) stamped, in life order per unit. ``records``:
        the log's flight records; ``first_t``: each unit's first sample time in the log;
        ``flight``/``start_unix``: the caller's, for every unit of the log."""
        out = []
        for p in sorted(periods, key=lambda q: (q.actuator, q.start_t)):
            rec = _record_at([r for r in records if r.name == p.actuator], p.start_t)
            t0 = (first_t or {}).get(p.actuator, p.start_t)
            su = p.start_unix
            if su is None:
                if rec is not None and rec.start_unix is not None:
                    su = rec.start_unix + (p.start_t - (rec.t0 if rec.t0 is not None else t0))
                elif start_unix is not None:
                    su = start_unix + (p.start_t - t0)
                elif p.start_t >= UNIX_MIN:
                    su = p.start_t
            fl = flight if flight is not None else (rec.flight if rec is not None else None)
            if fl is None:
                fl = p.flight if p.flight is not None else self._gap_rule(p, su)
            q = replace(p, flight=int(fl), start_unix=su)
            self._last[p.actuator] = q
            out.append(q)
        return out

    def _gap_rule(self, p: Period, su: float | None) -> int:
        return next_flight(self._prev(p.actuator), p, su, self.gap_s)


def _record_at(recs: Sequence[FlightRecord], t: float) -> FlightRecord | None:
    """The unit's record in force at sample time ``t``: the last whose ``t0`` is <= t (one
    without ``t0`` holds from the log's start); before every ``t0``, the first."""
    held = [r for r in recs if r.t0 is None or r.t0 <= t + 1e-9]
    return held[-1] if held else (recs[0] if recs else None)
