"""The fleet ranked by urgency, the one view of it that ``servowatch fleet`` and the fleet
page share: RUL median ascending (actuators without a RUL after those with one), then more
alarms first, then the higher last C_Lk ratio first, over ``HealthStore.fleet_summary`` rows.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = [
    "finite_or_none", "rul_interval", "has_rul", "alarm_count", "life_and_trend", "rank_fleet",
    "condition_of", "threshold_of",
]  # fmt: skip


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


def has_rul(rul: dict[str, Any] | None) -> bool:
    """Whether a stored RUL gives a median on its own axis (the count every view shows)."""
    iv = rul_interval(rul)
    return iv is not None and iv["median"] is not None


def threshold_of(rul: dict[str, Any] | None) -> float:
    """The failure threshold (C_Lk ratio) a unit is judged by: its stored RUL's, else the
    derived default (``RulConfig.threshold``)."""
    thr = finite_or_none((rul or {}).get("threshold_ratio"))
    if thr is not None:
        return thr
    from service.prognostics.rul import default_threshold_ratio

    return default_threshold_ratio()


def condition_of(row: dict[str, Any]) -> tuple[str, str]:
    """``("failed", reason)`` when a unit's latest observable C_Lk ratio (``last_ratio``, in
    life order) is at or above its failure threshold (``threshold_of``), else ``("", "")``:
    the one rule of ``fleet``, the page, ``status`` and the metrics (``rul`` says
    ``failed`` by the same threshold)."""
    r = finite_or_none(row.get("last_ratio"))
    if r is None:
        return "", ""
    thr = threshold_of(row.get("rul") if isinstance(row.get("rul"), dict) else None)
    if r >= thr:
        return "failed", f"C_Lk ratio {r:.2f} past the failure threshold {thr:.2f}"
    return "", ""


def alarm_count(row: dict[str, Any]) -> int:
    return max(int(row.get("alarms") or 0), int(row.get("alarm_events") or 0))


def _ratio(row: dict[str, Any]) -> float | None:
    return finite_or_none(row.get("last_ratio"))


def life_and_trend(row: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """Where a unit stands on the life axis its history supports, and its C_Lk-ratio trend
    on that axis: ``({"value", "unit"}, {"value", "unit"} or None)``. A history that counts
    flights (the summary's ``life_axis``: every period has a flight, as ``rul``'s
    ``History.axis``) gives the flights so far in life order and the trend per 10 flights
    (the stored slope per operating hour times the hours per flight); another gives
    operating hours and the trend per 100 h."""
    slope = finite_or_none((row.get("trend") or {}).get("slope_per_h"))
    last = row.get("last") or {}
    if row.get("life_axis") == "flights" and last.get("flight") is not None:
        n = int(row.get("flights") or 0)
        hpf = float(row.get("op_time_s") or 0.0) / 3600.0 / n if n else None
        first = row.get("first_flight")
        now = None if first is None else float(last["flight"] - first + 1)
        life = {"value": now, "unit": "flights"}
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
        cond, why = condition_of(r)
        out.append({"rank": i, **r, "rul_interval": rul_interval(r.get("rul")), "life": life,
                    "trend_rate": rate, "condition": cond or None,
                    "condition_reason": why or None})  # fmt: skip
    return out
