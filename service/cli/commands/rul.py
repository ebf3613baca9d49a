"""``servowatch rul``: remaining useful life of each actuator in the health store.

Fits each actuator's C_Lk-ratio history against its life axis (flights when the history
counts them, else operating hours) under a fleet prior learned from the store
(``service.prognostics.degradation``), gives the RUL to the failure threshold (median and
90 % interval in flights, calendar days and operating hours as far as the history has them) and the probability of crossing
within the planning horizon, and writes each summary back with ``put_rul`` (read by
``servowatch fleet``). docs/prognostics.md has the models and the threshold.
"""

from __future__ import annotations

import argparse
import time

from service.cli.util import check_outputs, emit_json, fail, finite_float, plural, writing
from service.store import StoreError
from service.store.cli import add_store_argument, open_store_arg, store_path_arg

NAME = "rul"
HELP = "remaining useful life of each actuator (median, 90 % interval, horizon probability)"

__all__ = ["NAME", "HELP", "add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_store_argument(p)
    p.add_argument("--actuator", metavar="AC/ACT", help="only this actuator (default: all)")
    p.add_argument(
        "--threshold",
        type=finite_float,
        default=None,
        metavar="RATIO",
        help="failure threshold as C_Lk / C_Lk,baseline (default: derived, docs/prognostics.md)",
    )
    p.add_argument(
        "--tolerance-m",
        type=finite_float,
        default=None,
        help="derive the threshold from this static position tolerance at rated load [m]",
    )
    p.add_argument(
        "--horizon-h",
        type=finite_float,
        default=50.0,
        help="planning horizon [operating hours] for histories without flights (default 50)",
    )
    p.add_argument(
        "--horizon-flights",
        type=finite_float,
        default=20.0,
        help="planning horizon [flights] for histories that count flights (default 20)",
    )
    p.add_argument(
        "--no-save", action="store_true",
        help="do not write the RUL to the store (the store is then opened read only)",
    )  # fmt: skip
    p.add_argument(
        "--robust-trend", action="store_true",
        help="opt in to the Student-t readings and the trend model (off by default: on fresh "
        "fleets they regressed the step, quadratic and linear laws; docs/prognostics.md)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--png", metavar="F", help="RUL fan plot of --actuator (or the most urgent)")


def _fmt(v, spec: str = ".1f") -> str:
    return "-" if v is None else format(v, spec)


def run(args: argparse.Namespace) -> int:
    from service.prognostics.rul import RulConfig, compute_rul, history_of
    from service.prognostics.threshold import leak_threshold

    if args.horizon_h <= 0 or args.horizon_flights <= 0:
        return fail("--horizon-h and --horizon-flights must be > 0")
    if args.threshold is not None and args.threshold <= 1.0:
        return fail("--threshold must be > 1 (a C_Lk ratio)")
    thr = args.threshold
    if thr is None and args.tolerance_m is not None:
        try:
            thr = leak_threshold(tolerance_m=args.tolerance_m).ratio
        except ValueError as e:
            return fail(f"--tolerance-m: {e}")
    cfg = RulConfig(threshold_ratio=thr, horizon_h=args.horizon_h,
                    horizon_flights=args.horizon_flights,
                    robust_trend=args.robust_trend)  # fmt: skip
    check_outputs([("--png", args.png)], [("--store", store_path_arg(args))])
    if args.robust_trend:
        from service.cli.warmup import ensure

        ensure("trend")  # its first use compiles the trend model's kernel (and says so)
    t0 = time.perf_counter()
    try:  # --no-save only reads: the store opened read only (never migrated, never written)
        store = open_store_arg(args, create=False, read_only=args.no_save)
    except StoreError as e:
        return fail(str(e))
    with store:
        if args.actuator is not None and args.actuator not in store.actuators():
            return fail(f"--actuator: {args.actuator!r} is not in the store")
        if not store.actuators():
            return fail("the store holds no actuator")
        results, prior = compute_rul(store, args.actuator, cfg, save=not args.no_save)
        png = None
        if args.png:
            from service.prognostics.plot import plot_rul_fan

            target = args.actuator or _most_urgent(results)
            saved = "the RUL was stored" if not args.no_save else "nothing was stored"
            with writing("--png", args.png, so_far=saved):
                png = str(
                    plot_rul_fan(history_of(target, store.life(target)), prior, cfg, args.png)
                )
    wall = time.perf_counter() - t0
    if args.json:
        emit_json(
            {
                "store": store.url,
                "threshold_ratio": cfg.threshold(),
                "horizon_h": cfg.horizon_h,
                "horizon_flights": cfg.horizon_flights,
                "prior": prior.as_dict(),
                "actuators": results,
                "png": png,
                "wall_s": wall,
            }
        )
        return 0
    print(f"threshold C_Lk ratio {cfg.threshold():.2f}, horizon "
          f"{plural(cfg.horizon_flights, 'flight')} (histories with flight numbers) or "
          f"{cfg.horizon_h:g} h")  # fmt: skip
    print(
        f"{'actuator':<24}{'ratio':>7}  {'model':<20}{'RUL median [90 %]':>28}{'days':>8}"
        f"{'P(H)':>7}"
    )
    for r in results:
        u = "flights" if r.get("axis") == "flights" else "h"
        iv = (
            f"{_fmt(r.get(f'median_{u}'))} [{_fmt(r.get(f'lo_{u}'))}, {_fmt(r.get(f'hi_{u}'))}] {u}"
        )
        print(
            f"{r['actuator']:<24}{_fmt(r['last_ratio'], '.2f'):>7}  "
            f"{r.get('model') or r.get('status', '-'):<20}"
            f"{iv:>28}{_fmt(r.get('median_days')):>8}{_fmt(r['p_horizon'], '.2f'):>7}"
        )
    if png:
        print(f"wrote {png}")
    return 0


def _most_urgent(results: list[dict]) -> str:
    def key(r: dict):
        m = r.get("median_flights" if r.get("axis") == "flights" else "median_h")
        return (m is None, m if m is not None else 0.0, -(r.get("last_ratio") or 0.0))

    return sorted(results, key=key)[0]["actuator"]
