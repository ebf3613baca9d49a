"""The JSON the fleet page reads, from the health store: the ranked fleet with a status per
unit, and one unit's indicator history. No HTTP here (``service.edge.web.server`` serves it)."""

from __future__ import annotations

import math
import time
from typing import Any

from service.edge.fleet import finite_or_none as _finite
from service.edge.fleet import has_rul, rank_fleet, rul_interval
from service.jsonutil import jsonable
from service.prognostics.rul import history_of
from service.store import HealthStore
from service.store.records import Period, check_actuator

__all__ = [
    "STATUSES",
    "unit_status",
    "fleet_view",
    "unit_view",
    "usage_per_flight",
    "rul_on_axis",
    "UnknownActuatorError",
]

#: page status of a unit, most urgent first
STATUSES: tuple[str, ...] = ("critical", "watch", "ok", "uncommissioned")


class UnknownActuatorError(KeyError):
    """The store has no actuator of that name."""


def unit_status(row: dict[str, Any]) -> tuple[str, str]:
    """(status, reason) of one ranked fleet row (``rank_fleet``).

    - ``uncommissioned``: no baseline yet, so no indicator means anything;
    - ``critical``: the stored RUL warns (probability of crossing the failure threshold within
      the planning horizon at least ``RulConfig.warn_p``);
    - ``watch``: alarms recorded, or the C_Lk-ratio trend is rising;
    - ``ok``: none of these.
    """
    if not row.get("commissioned") and not row.get("condition"):
        return "uncommissioned", "no baseline: run `servowatch calibrate --actuator`"
    if row.get("condition") == "failed":
        return "critical", row.get("condition_reason") or "past the failure threshold"
    rul = row.get("rul") or {}
    if rul.get("warning"):
        p = _finite(rul.get("p_horizon"))
        flights = rul.get("axis") == "flights"
        hor = _finite(rul.get("horizon") if flights else rul.get("horizon_h"))
        if p is not None and hor is not None:
            unit = "flights" if flights else "h"
            return "critical", f"P(threshold within {hor:.0f} {unit}) = {p:.2f}"
        return "critical", "RUL warning"
    alarms = max(int(row.get("alarms") or 0), int(row.get("alarm_events") or 0))
    if alarms:
        return "watch", f"{alarms} alarm{'s' if alarms != 1 else ''} recorded"
    trend = row.get("trend") or {}
    if trend.get("label") == "rising":
        return "watch", "C_Lk ratio rising"
    return "ok", ""


def fleet_view(store: HealthStore, now_s: float | None = None) -> dict[str, Any]:
    """The page's fleet JSON: every unit ranked by urgency (``rank_fleet``, the order of
    ``servowatch fleet``), each with ``status``/``status_reason``, and counts per status."""
    ranked = rank_fleet(store.fleet_summary())
    counts = dict.fromkeys(STATUSES, 0)
    for r in ranked:
        r["status"], r["status_reason"] = unit_status(r)
        counts[r["status"]] += 1
    horizons = [_finite((r.get("rul") or {}).get("horizon_h")) for r in ranked]
    horizons = [h for h in horizons if h is not None]
    # the bars' axis: the unit most RULs are in (flights when the histories count them)
    units = [(r.get("rul_interval") or {}).get("unit") for r in ranked if r.get("rul")]
    unit = "flights" if units and units.count("flights") * 2 >= len(units) else "h"
    hz = [_finite((r.get("rul") or {}).get("horizon" if unit == "flights" else "horizon_h"))
          for r in ranked]  # fmt: skip
    hz = [h for h in hz if h is not None]
    return jsonable(
        {
            "store": store.where,
            "generated_s": time.time() if now_s is None else now_s,
            "actuators": len(ranked),
            "counts": counts,
            "with_rul": sum(1 for r in ranked if has_rul(r.get("rul"))),
            "horizon_h": max(horizons) if horizons else None,
            "horizon": max(hz) if hz else None,
            "horizon_unit": unit,
            "fleet": ranked,
        }
    )


def unit_view(store: HealthStore, actuator: str) -> dict[str, Any]:
    """One unit's history for the page, on the unit's life axis ``life_axis`` (the store
    summary's, decisions/0035: ``flights`` when its history counts flights, else ``hours``):
    per period (in life order) its position ``life`` on that axis (flights: the flights flown
    since the history's first flight, counting that one, flight - first + 1, as ``rul``'s
    ``History.life`` and ``fleet``'s life column; hours: ``t_h``), the cumulative operating
    hours at its end ``t_h`` (``history_of``), the C_Lk ratio and its
    1-sigma (NaN -> null where unobservable), the pooled C_Lk and its sigma [m^3/(s Pa)]
    (recorded beside the indicator, decisions/0025; null where it abstains), the lowest
    supply pressure [Pa] and the alarm count, the usage (travel, load-weighted travel, reversals; null where unknown); its alarm
    events, baseline versions, stored RUL (and ``rul_on_axis``) and mean usage per flight
    (``usage_per_flight``)."""
    check_actuator(actuator)
    if not store.has_actuator(actuator):
        raise UnknownActuatorError(actuator)
    periods = store.life(actuator)  # the unit's life order, as every view
    hist = history_of(actuator, periods)
    (row,) = store.fleet_summary(actuator)
    first = row.get("first_flight")
    axis = "flights" if row.get("life_axis") == "flights" and first is not None else "hours"
    rows = []
    for p, t_h, y in zip(periods, hist.t_h, hist.y, strict=True):
        sig = p.c_lk_ratio_sigma()
        if axis == "hours":
            life: float | None = float(t_h)
        else:  # a period without a flight has no place on it (the summary says none has)
            life = None if p.flight is None else float(p.flight - first + 1)
        rows.append(
            {
                "start_t": p.start_t,
                "end_t": p.end_t,
                "t_h": float(t_h),
                "life": life,
                "flight": p.flight,
                "c_lk_ratio": _finite(float(y)),
                "c_lk_ratio_sigma": _finite(sig) if math.isfinite(float(y)) else None,
                "c_lk_pooled": _finite(p.c_lk_pooled),
                "c_lk_pooled_sigma": _finite(p.c_lk_pooled_sigma),
                "p_sr_min": _finite(p.p_sr_min),
                "alarms": p.alarms,
                "source": p.source,
                "usage_travel_m": _finite(p.usage_travel_m),
                "usage_load_travel_j": _finite(p.usage_load_travel_j),
                "usage_reversals": _finite(p.usage_reversals),
            }
        )
    rul = store.rul(actuator)
    return jsonable(
        {
            "actuator": actuator,
            "life_axis": axis,
            "periods": rows,
            "alarms": [
                {"t": e.t, "kind": e.kind, "value": e.value, "source": e.source}
                for e in store.alarms(actuator)
            ],
            "baselines": [
                {"version": b.version, "created_s": b.created_s, "source": b.source}
                for b in store.baselines(actuator)
            ],
            "rul": rul,
            "rul_on_axis": rul_on_axis(rul, axis),
            "usage": usage_per_flight(periods),
        }
    )


def rul_on_axis(rul: dict[str, Any] | None, axis: str) -> dict[str, float] | None:
    """Where a stored RUL's 90 % interval lies on life axis ``axis`` (``flights`` or
    ``hours``): ``now`` (where the history ended when the RUL was computed, ``t_now``; newer
    periods may have passed it) and ``median``/``lo``/``hi`` counted from it
    (``rul_interval``, the RUL's own axis). None without a median, or when the RUL was
    computed on the other axis (a RUL older than the history's last change of axis)."""
    iv = rul_interval(rul)
    if rul is None or iv is None or iv["median"] is None:
        return None
    if iv["unit"] != ("flights" if axis == "flights" else "h"):
        return None
    # a RUL stored before ``t_now`` was: on hours its operating hours say the same
    now = _finite(rul.get("t_now"))
    if now is None and axis == "hours":
        now = _finite(rul.get("t_now_h"))
    if now is None:
        return None
    med = iv["median"]
    lo = med if iv["lo"] is None else iv["lo"]
    hi = med if iv["hi"] is None else iv["hi"]
    return {"now": now, "median": med, "lo": lo, "hi": hi}


def usage_per_flight(periods: list[Period]) -> dict[str, Any]:
    """Mean usage per flight over the flights whose every period carries usage (periods
    without a flight number are left out): ``flights`` counted, ``travel_m``,
    ``load_travel_j`` (over the flights with a load figure) and ``reversals`` per flight,
    None where no flight counts."""
    by: dict[int, list[Period]] = {}
    for p in periods:
        if p.flight is not None:
            by.setdefault(p.flight, []).append(p)
    ok = [ps for ps in by.values() if all(math.isfinite(p.usage_travel_m) for p in ps)]
    load = [ps for ps in ok if all(math.isfinite(p.usage_load_travel_j) for p in ps)]

    def mean(groups: list[list[Period]], field: str) -> float | None:
        if not groups:
            return None
        return sum(getattr(p, field) for ps in groups for p in ps) / len(groups)

    return {
        "flights": len(ok),
        "travel_m": mean(ok, "usage_travel_m"),
        "reversals": mean(ok, "usage_reversals"),
        "load_flights": len(load),
        "load_travel_j": mean(load, "usage_load_travel_j"),
    }
