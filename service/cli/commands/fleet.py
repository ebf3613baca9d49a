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

from service.edge.fleet import alarm_count, finite_or_none, has_rul, rank_fleet
from service.store import StoreError
from service.store.cli import add_store_argument, open_store_arg

NAME = "fleet"
HELP = "every actuator in the health store ranked by urgency (RUL, alarms, C_Lk ratio)"

__all__ = ["NAME", "HELP", "add_arguments", "run", "format_fleet"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_store_argument(p)
    p.add_argument("--top", type=int, default=None, metavar="N", help="only the N most urgent")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--wide", action="store_true",
                   help="every column (P_SR, P(horizon), usage per hour): about 160 columns; "
                   "the default fits 100")  # fmt: skip
    p.add_argument("--png", metavar="F.png", default=None,
                   help="also draw the most urgent units' C_Lk-ratio trends against the "
                   "threshold (--top N of them, default 6)")  # fmt: skip


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


_SHORT = {"flights": "fl", "h": "h", "per 10 flights": "/10 fl", "per 100 h": "/100 h"}


def _cells(r: dict[str, Any]) -> dict[str, str]:
    """The text of each column of one ranked unit."""
    last = r.get("last") or {}
    use = r.get("usage") or {}
    life, rate = r["life"], r["trend_rate"]
    life_s = (
        "-"
        if life["value"] is None
        else f"{life['value']:.{0 if life['unit'] == 'flights' else 1}f} {_SHORT[life['unit']]}"
    )
    trend = "-" if rate is None else f"{rate['value']:+.2f}{_SHORT[rate['unit']]}"
    label = (r.get("trend") or {}).get("label", "")
    iv = r.get("rul_interval")
    if iv and iv["median"] is not None:
        unit = iv["unit"]
        if unit == "flights" and round(iv["median"]) == 1:
            unit = "flight"
        rul = f"{iv['median']:.0f} [{_f(iv['lo'], '.0f')}-{_f(iv['hi'], '.0f')}] {unit}"
        if iv["median_days"] is not None:
            rul += f" ~{iv['median_days']:.0f} d"
    else:
        rul = "-"
    return {
        "rank": str(r["rank"]), "actuator": r["actuator"],
        "comm": "yes" if r["commissioned"] else "NO", "periods": str(r["periods"]),
        "cond": "FAILED" if r.get("condition") == "failed" else "-",
        "life": life_s, "ratio": _f(r.get("last_ratio"), ".3f"),
        "trend": trend, "trend_wide": f"{label} {trend}" if rate is not None else "-",
        "p_sr": _f(last.get("p_sr_min"), ".2f", 1e-6), "rul": rul,
        "p_hor": _f(iv and iv["p_horizon"], ".2f"), "alarms": str(alarm_count(r)),
        "travel": _f(use.get("travel_m_per_h"), ".2f"),
        "load_travel": _f(use.get("load_travel_j_per_h"), ".1f", 1e-3),
    }  # fmt: skip


#: (cell, header, width, align) of the default table (within 100 columns) and of --wide
NARROW = (("rank", "#", 3, ">"), ("actuator", "actuator", 18, "<"), ("comm", "comm", 4, "<"),
          ("cond", "cond", 6, "<"), ("life", "life", 8, ">"), ("ratio", "C_Lk/base", 9, ">"),
          ("trend", "trend", 11, ">"), ("rul", "RUL median [90%]", 26, ">"),
          ("alarms", "alarms", 6, ">"))  # fmt: skip
WIDE = (("rank", "#", 4, ">"), ("actuator", "actuator", 22, "<"), ("comm", "comm", 4, "<"),
        ("cond", "cond", 6, "<"), ("periods", "periods", 7, ">"), ("life", "life", 8, ">"),
        ("ratio", "C_Lk/base", 9, ">"), ("trend_wide", "trend", 20, ">"),
        ("p_sr", "P_SR min MPa", 12, ">"), ("rul", "RUL median [90%]", 30, ">"),
        ("p_hor", "P(horizon)", 10, ">"), ("alarms", "alarms", 6, ">"),
        ("travel", "travel m/h", 10, ">"), ("load_travel", "load x travel kJ/h", 18, ">"))  # fmt: skip


def format_fleet(ranked: list[dict[str, Any]], wide: bool = False) -> str:
    """A fixed-width table of the ranked fleet: life and trend on each unit's life axis
    (flights, or operating hours: ``fl``, ``h``), the C_Lk ratio, the RUL interval and the
    alarms, within 100 columns; ``wide`` adds the periods, the lowest P_SR, P(horizon) and
    the usage per operating hour over the periods that carry it (jack travel, load-weighted
    travel; docs/prognostics.md, "Usage")."""
    cols = WIDE if wide else NARROW
    head = " ".join(f"{h:{a}{w}}" for _, h, w, a in cols)
    lines = [head, "-" * len(head)]
    for r in ranked:
        c = _cells(r)
        lines.append(" ".join(f"{c[k]:{a}{w}}" for k, _, w, a in cols))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.top is not None and args.top < 1:
        return fail("--top must be >= 1")
    try:
        store = open_store_arg(args, create=False, read_only=True)
    except StoreError as e:
        return fail(str(e))
    if args.png:
        from service.cli.util import check_outputs

        check_outputs([("--png", args.png)], [])
    with store:
        rows = store.fleet_summary()
        ranked = rank_fleet(rows)
        if args.png:
            from service.edge.fleet_plot import plot_trends

            try:
                drawn = plot_trends(store, ranked[: args.top or 6], args.png)
            except OSError as e:
                return fail(f"--png {args.png}: {e.strerror or e}", 5)
            print(f"wrote {args.png} ({drawn} unit{'' if drawn == 1 else 's'})", file=sys.stderr)
    if args.top is not None:
        ranked = ranked[: args.top]
    if args.json:
        emit_json({"store": store.where, "actuators": len(rows), "fleet": ranked})
        return 0
    if not rows:
        print(f"no actuators in {store.where}")
        return 0
    uncomm = sum(1 for r in rows if not r["commissioned"])
    with_rul = sum(1 for r in rows if has_rul(r.get("rul")))
    print(
        f"{len(rows)} actuator{'' if len(rows) == 1 else 's'} in {store.where}: {uncomm} not "
        f"commissioned, {with_rul} with a RUL (run `servowatch rul` to update)"
    )
    print(format_fleet(ranked, wide=args.wide))
    return 0
