"""The fleet ranked by urgency, the one view of it that ``servowatch fleet`` and the fleet
page share: RUL median ascending (actuators without a RUL after those with one), then more
alarms first, then the higher last C_Lk ratio first, over ``HealthStore.fleet_summary`` rows.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["finite_or_none", "rul_interval", "alarm_count", "life_and_trend", "rank_fleet"]


def finite_or_none(v: Any) -> float | None:
    """``v`` as a float if it is a finite number (not a bool), else None."""
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        return None
    return float(v)


def rul_interval(rul: dict[str, Any] | None) -> dict[str, float | None] | None:
    """From a stored RUL summary (``put_rul``; None without one): ``median``/``lo``/``hi`` in
    ``unit``, the unit the history supports (``flights`` when it counts flights, else ``h``
    operating hours), the same as ``*_flights``, ``*_h`` and ``*_days`` (calendar) where
    known, and ``p_horizon``."""
    if not rul:
        return None
    keys = [f"{q}_{u}" for u in ("h", "flights", "days") for q in ("median", "lo", "hi")]
    out: dict[str, Any] = {k: finite_or_none(rul.get(k)) for k in [*keys, "p_horizon"]}
    unit = "flights" if rul.get("axis") == "flights" else "h"
    out["unit"] = unit
    for q in ("median", "lo", "hi"):
        out[q] = out[f"{q}_{unit}"]
    return out


def alarm_count(row: dict[str, Any]) -> int:
    return max(int(row.get("alarms") or 0), int(row.get("alarm_events") or 0))


def _ratio(row: dict[str, Any]) -> float | None:
    last = row.get("last") or {}
    return finite_or_none(last.get("c_lk_ratio"))


def life_and_trend(row: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """Where a unit stands on the life axis its history supports, and its C_Lk-ratio trend
    on that axis: ``({"value", "unit"}, {"value", "unit"} or None)``. A history that counts
    flights (its RUL's ``axis``) gives the flights so far and the trend per 10 flights (the
    stored slope per operating hour times the hours per flight); another gives operating
    hours and the trend per 100 h."""
    rul = row.get("rul") or {}
    slope = finite_or_none((row.get("trend") or {}).get("slope_per_h"))
    if rul.get("axis") == "flights":
        hpf = finite_or_none(rul.get("hours_per_flight"))
        life = {"value": finite_or_none(rul.get("t_now")), "unit": "flights"}
        rate = None if slope is None or hpf is None else {"value": slope * hpf * 10.0,
                                                          "unit": "per 10 flights"}  # fmt: skip
        return life, rate
    life = {"value": float(row.get("op_time_s") or 0.0) / 3600.0, "unit": "h"}
    return life, None if slope is None else {"value": slope * 100.0, "unit": "per 100 h"}


def rank_fleet(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` (``fleet_summary()``) sorted by urgency, each with ``rank``, ``rul_interval``,
    ``life`` and ``trend_rate`` (:func:`life_and_trend`)."""

    def key(r: dict[str, Any]) -> tuple[float, int, float, str]:
        iv = rul_interval(r.get("rul"))
        med = iv["median"] if iv and iv["median"] is not None else math.inf
        ratio = _ratio(r)
        return (med, -alarm_count(r), -(ratio if ratio is not None else -math.inf), r["actuator"])

    out = []
    for i, r in enumerate(sorted(rows, key=key), 1):
        life, rate = life_and_trend(r)
        out.append({"rank": i, **r, "rul_interval": rul_interval(r.get("rul")), "life": life,
                    "trend_rate": rate})  # fmt: skip
    return out
