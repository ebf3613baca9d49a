"""``servowatch fleet``: every actuator in the health store ranked by urgency.

Urgency: RUL median ascending (actuators without a RUL after those with one), then more
alarms first, then the higher last C_Lk ratio first. Reads only the per-actuator summary
rows (``HealthStore.fleet_summary``), so it answers in well under a second on a store of
1000 actuators x 5 years of periods.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from service.store import StoreError
from service.store.cli import add_store_argument, open_store_arg

NAME = "fleet"
HELP = "every actuator in the health store ranked by urgency (RUL, alarms, C_Lk ratio)"

__all__ = [
    "NAME", "HELP", "add_arguments", "run", "rank_fleet", "rul_interval", "format_fleet",
    "finite_or_none",
]  # fmt: skip


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_store_argument(p)
    p.add_argument("--top", type=int, default=None, metavar="N", help="only the N most urgent")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _plain(v: Any) -> Any:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    return v


def emit_json(obj: Any) -> None:
    """One JSON object on stdout (non-finite floats as null); no numpy import, to keep the
    command's start-up short."""
    sys.stdout.write(json.dumps(_plain(obj)) + "\n")
    sys.stdout.flush()


def fail(message: str, code: int = 2) -> int:
    """Print an error on stderr and return the exit code."""
    print(f"servowatch: error: {message}", file=sys.stderr)
    return code


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


def _alarm_count(row: dict[str, Any]) -> int:
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
        return (med, -_alarm_count(r), -(ratio if ratio is not None else -math.inf), r["actuator"])

    out = []
    for i, r in enumerate(sorted(rows, key=key), 1):
        life, rate = life_and_trend(r)
        out.append({"rank": i, **r, "rul_interval": rul_interval(r.get("rul")), "life": life,
                    "trend_rate": rate})  # fmt: skip
    return out


def _f(v: Any, spec: str, scale: float = 1.0) -> str:
    n = finite_or_none(v)
    return "-" if n is None else format(n * scale, spec)


def format_fleet(ranked: list[dict[str, Any]]) -> str:
    """A fixed-width table of the ranked fleet: life and trend on each unit's life axis
    (flights, or operating hours: ``fl``, ``h``), and its usage per operating hour over the
    periods that carry it (jack travel, load-weighted travel; docs/prognostics.md, "Usage")."""
    head = (
        f"{'#':>4} {'actuator':<22} {'comm':<4} {'periods':>7} {'life':>8} {'C_Lk/base':>9} "
        f"{'trend':>20} {'P_SR min MPa':>12} {'RUL median [90%] unit':>30} "
        f"{'P(hor)':>6} {'alarms':>6} {'travel m/h':>10} {'|F|trav kJ/h':>12}"
    )
    lines = [head, "-" * len(head)]
    short = {"flights": "fl", "h": "h", "per 10 flights": "/10 fl", "per 100 h": "/100 h"}
    for r in ranked:
        last = r.get("last") or {}
        use = r.get("usage") or {}
        life, rate = r["life"], r["trend_rate"]
        life_s = (
            "-"
            if life["value"] is None
            else f"{life['value']:.{0 if life['unit'] == 'flights' else 1}f} {short[life['unit']]}"
        )
        trend = "-"
        if rate is not None:
            trend = f"{(r.get('trend') or {}).get('label', '')} {rate['value']:+.2f}{short[rate['unit']]}"
        iv = r.get("rul_interval")
        if iv and iv["median"] is not None:
            rul = f"{iv['median']:.0f} [{_f(iv['lo'], '.0f')}-{_f(iv['hi'], '.0f')}] {iv['unit']}"
            if iv["median_days"] is not None:
                rul += f" ~{iv['median_days']:.0f} d"
        else:
            rul = "-"
        lines.append(
            f"{r['rank']:>4} {r['actuator']:<22} {'yes' if r['commissioned'] else 'NO':<4} "
            f"{r['periods']:>7} {life_s:>8} {_f(last.get('c_lk_ratio'), '.3f'):>9} "
            f"{trend:>20} {_f(last.get('p_sr_min'), '.2f', 1e-6):>12} {rul:>30} "
            f"{_f(iv and iv['p_horizon'], '.2f'):>6} {_alarm_count(r):>6} "
            f"{_f(use.get('travel_m_per_h'), '.2f'):>10} "
            f"{_f(use.get('load_travel_j_per_h'), '.1f', 1e-3):>12}"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.top is not None and args.top < 1:
        return fail("--top must be >= 1")
    try:
        store = open_store_arg(args, create=False, read_only=True)
    except StoreError as e:
        return fail(str(e))
    with store:
        rows = store.fleet_summary()
    ranked = rank_fleet(rows)
    if args.top is not None:
        ranked = ranked[: args.top]
    if args.json:
        emit_json({"store": store.where, "actuators": len(rows), "fleet": ranked})
        return 0
    if not rows:
        print(f"no actuators in {store.where}")
        return 0
    uncomm = sum(1 for r in rows if not r["commissioned"])
    with_rul = sum(1 for r in rows if r.get("rul"))
    print(
        f"{len(rows)} actuators in {store.where}: {uncomm} not commissioned, "
        f"{with_rul} with a RUL (run `servowatch rul` to update)"
    )
    print(format_fleet(ranked))
    return 0
