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

from service.edge.fleet import alarm_count, finite_or_none, rank_fleet
from service.store import StoreError
from service.store.cli import add_store_argument, open_store_arg

NAME = "fleet"
HELP = "every actuator in the health store ranked by urgency (RUL, alarms, C_Lk ratio)"

__all__ = ["NAME", "HELP", "add_arguments", "run", "format_fleet"]


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
            f"{_f(iv and iv['p_horizon'], '.2f'):>6} {alarm_count(r):>6} "
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
