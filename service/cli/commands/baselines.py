"""``servowatch baselines``: list the baseline versions recorded in the health store."""

from __future__ import annotations

import argparse
import datetime as dt

from service.cli.util import emit_json, fail
from service.store import StoreError, check_actuator
from service.store.cli import add_store_argument, open_store_arg

NAME = "baselines"
HELP = "list the per-actuator baseline versions in the health store"

__all__ = ["NAME", "HELP", "add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_store_argument(p)
    p.add_argument("--actuator", default=None, metavar="AC/ACT", help="only this actuator")
    p.add_argument("--all", action="store_true", help="every version (default: latest only)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _utc(t: float) -> str:
    return dt.datetime.fromtimestamp(t, dt.UTC).strftime("%Y-%m-%d %H:%M:%SZ")


def run(args: argparse.Namespace) -> int:
    if args.actuator is not None:
        try:
            check_actuator(args.actuator, "--actuator")
        except ValueError as e:
            return fail(str(e))
    try:
        store = open_store_arg(args, create=False, read_only=True)
    except StoreError as e:
        return fail(str(e))
    with store:
        if args.actuator is not None and not store.has_actuator(args.actuator):
            return fail(f"--actuator: unknown actuator {args.actuator!r} in {store.where}")
        recs = store.baselines(args.actuator)
        uncommissioned = [a for a in store.actuators() if args.actuator in (None, a)]
    latest = {r.actuator: r.version for r in recs}
    uncommissioned = [a for a in uncommissioned if a not in latest]
    if not args.all:
        recs = [r for r in recs if r.version == latest[r.actuator]]
    if args.json:
        emit_json(
            {
                "store": store.where,
                "baselines": [
                    {
                        "actuator": r.actuator,
                        "version": r.version,
                        "latest": r.version == latest[r.actuator],
                        "source": r.source,
                        "created_s": r.created_s,
                        "baseline": r.baseline,
                        "figures": r.figures,
                    }
                    for r in recs
                ],
                "uncommissioned": uncommissioned,
            }
        )
        return 0
    if not recs and not uncommissioned:
        print(f"no actuators in {store.where}")
        return 0
    head = f"{'actuator':<24} {'ver':>3}  {'recorded (UTC)':<20} {'law':<4} {'C_Lk':>9} "
    print(head + f"{'x_SS um':>8} {'G_PQ':>9}  source")
    for r in recs:
        b = r.baseline
        mark = "" if r.version == latest[r.actuator] else " (superseded)"
        print(
            f"{r.actuator:<24} {r.version:>3}  {_utc(r.created_s):<20} {b.get('law', '?'):<4} "
            f"{b.get('c_lk', float('nan')):>9.3g} {b.get('x_ss', float('nan')) * 1e6:>8.2f} "
            f"{b.get('g_pq', float('nan')):>9.3g}  {r.source}{mark}"
        )
    for a in uncommissioned:
        print(f"{a:<24}   -  not commissioned (runs on the default baseline)")
    return 0
