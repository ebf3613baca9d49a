"""``servowatch fleet-sim``: a simulated fleet with hidden wear laws as MCAP logs (HF bench),
ingested by the replay's code into the health store; ``--evaluate`` scores the RUL
predictions against the truth with Saxena et al.'s PHM metrics, interval coverage, Kendall's
tau and the healthy units' crossing probability (``service.replay.fleetsim``,
docs/prognostics.md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from service.cli.util import check_outputs, emit_json, fail, finite_float, to_jsonable, writing
from service.monitor.model_choice import DEFAULT_MODEL, MONITOR_MODELS
from service.progress import Progress
from service.store import StoreError
from service.store.cli import add_store_argument, open_store_arg, store_path_arg

NAME = "fleet-sim"
HELP = "simulated fleet with hidden wear laws into the store; --evaluate scores the RUL"

__all__ = ["NAME", "HELP", "add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--actuators", type=int, default=6, help="units (default 6)")
    p.add_argument("--flights", type=int, default=20, help="flights per unit (default 20)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    add_store_argument(p)
    p.add_argument("--truth", default="fleet-sim-truth.json", help="truth JSON file")
    p.add_argument("--evaluate", action="store_true", help="score the RUL predictions")
    p.add_argument(
        "--score-only", action="store_true",
        help="score the RUL on the existing --store against the existing --truth file "
        "(no simulation, no ingest; the fleet's seed and threshold from the truth)",
    )  # fmt: skip
    p.add_argument("--eval-every", type=int, default=1, help="predict every k-th flight")
    p.add_argument("--segment-s", type=finite_float, default=2.0, help="bench seconds per flight")
    p.add_argument("--horizon-h", type=finite_float, default=50.0, help="planning horizon [h]")
    p.add_argument(
        "--horizon-flights", type=finite_float, default=20.0,
        help="planning horizon [flights] (default 20)",
    )  # fmt: skip
    p.add_argument("--logs", default=None, metavar="DIR", help="keep the logs in DIR")
    p.add_argument(
        "--model", default=DEFAULT_MODEL, choices=MONITOR_MODELS,
        help=f"the monitor's process model (default {DEFAULT_MODEL})",
    )  # fmt: skip
    p.add_argument("--threshold", type=finite_float, default=None, help="C_Lk ratio at failure")
    p.add_argument("--workers", type=int, default=0, help="processes (default min(2, cores))")
    p.add_argument(
        "--robust-trend", action="store_true",
        help="the RUL with the opt-in Student-t readings and trend model (as rul --robust-trend)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def run(args: argparse.Namespace) -> int:
    from service.cli.warmup import ensure
    from service.prognostics.rul import RulConfig, compute_rul
    from service.replay.fleetsim import FleetSimConfig, evaluate, run_fleet_sim

    if args.score_only:
        return _score_only(args)
    check_outputs(
        [("--truth", args.truth), ("--store", store_path_arg(args))],
        directories=[("--logs", args.logs)],
    )
    ensure("models", "monitor", *(("trend",) if args.robust_trend else ()))

    if args.actuators < 1 or args.flights < 2:
        return fail("need --actuators >= 1 and --flights >= 2")
    if args.eval_every < 1 or args.workers < 0 or args.segment_s < 1.0 or args.horizon_h <= 0:
        return fail("need --eval-every >= 1, --workers >= 0, --segment-s >= 1, --horizon-h > 0")
    if args.threshold is not None and args.threshold <= 1.0:
        return fail("--threshold must be > 1 (a C_Lk ratio)")
    cfg = FleetSimConfig(
        actuators=args.actuators, flights=args.flights, seed=args.seed,
        segment_s=args.segment_s, threshold_ratio=args.threshold, eval_every=args.eval_every,
        horizon_h=args.horizon_h, horizon_flights=args.horizon_flights, workers=args.workers,
        model=args.model, log_dir=args.logs, robust_trend=args.robust_trend,
    )  # fmt: skip
    t0 = time.perf_counter()
    try:
        store = open_store_arg(args, create=True)
    except StoreError as e:
        return fail(str(e))
    with store:
        prog = Progress("fleet-sim")
        sim = run_fleet_sim(cfg, store, progress=prog)
        prog.done()
        compute_rul(
            store, None,
            RulConfig(threshold_ratio=cfg.threshold(), horizon_h=cfg.horizon_h,
                      horizon_flights=cfg.horizon_flights, robust_trend=cfg.robust_trend),
        )  # fmt: skip
        url = store.url
    units = sim["units"]
    truth = {
        "seed": cfg.seed,
        "threshold_ratio": cfg.threshold(),
        "units": [u["truth"] for u in units],
    }
    with writing("--truth", args.truth, so_far=f"the fleet's periods and RUL are in {url}"):
        Path(args.truth).write_text(json.dumps(to_jsonable(truth), indent=1) + "\n")
    out = {
        "actuators": cfg.actuators,
        "flights": cfg.flights,
        "segments": sum(u["segments"] for u in units),
        "sim_wall_s": sim["wall_s"],
        "logs": sim["logs"],
        "ingest_wall_s": sim["ingest_wall_s"],
        "threshold_ratio": cfg.threshold(),
        "store": url,
        "truth": args.truth,
        "false_alarms": sum(u["false_alarms"] for u in units),
        "healthy_units": sum(1 for u in units if u["truth"]["law"] == "none"),
        "alpha_lambda_pct": None,
        "relative_accuracy_pct": None,
        "prognostic_horizon_pct": None,
        "interval_coverage_pct": None,
        "kendall_tau": None,
        "healthy_max_p_horizon": None,
        "false_rul_warnings": None,
    }
    if args.evaluate:
        prog = Progress("evaluate")
        ev = evaluate(units, cfg, progress=prog)
        prog.done()
        out.update({k: v for k, v in ev.items() if k != "units"})
        out["eval_wall_s"] = time.perf_counter() - t0 - sim["wall_s"]
    out["wall_s"] = time.perf_counter() - t0
    return _print(out, args.json)


def _score_only(args: argparse.Namespace) -> int:
    """``--score-only``: ``fleetsim.evaluate_store`` on the stored histories and the truth."""
    from service.replay.fleetsim import FleetSimConfig, evaluate_store

    if args.eval_every < 1 or args.horizon_h <= 0:
        return fail("need --eval-every >= 1, --horizon-h > 0")
    try:
        truth = json.loads(Path(args.truth).read_text())
    except (OSError, ValueError) as e:
        return fail(f"--truth: {e}")
    if not isinstance(truth, dict):
        return fail("--truth: not a fleet-sim truth object")
    thr = args.threshold if args.threshold is not None else truth.get("threshold_ratio")
    if args.robust_trend:
        from service.cli.warmup import ensure

        ensure("trend")
    t0 = time.perf_counter()
    try:  # scoring reads the store only
        store = open_store_arg(args, create=False, read_only=True)
    except StoreError as e:
        return fail(str(e))
    with store:
        units = truth.get("units") or []
        cfg = FleetSimConfig(
            actuators=len(units), seed=int(truth.get("seed", 0)), threshold_ratio=thr,
            eval_every=args.eval_every, horizon_h=args.horizon_h,
            horizon_flights=args.horizon_flights, robust_trend=args.robust_trend,
        )  # fmt: skip
        prog = Progress("evaluate")
        try:
            ev = evaluate_store(store, truth, cfg, progress=prog)
        except ValueError as e:
            return fail(str(e))
        prog.done()
        url = store.url
    out = {"store": url, "truth": args.truth, "seed": cfg.seed,
           "threshold_ratio": cfg.threshold(), "healthy_units": ev["healthy_units"]}  # fmt: skip
    out.update({k: v for k, v in ev.items() if k != "units"})
    out["eval_wall_s"] = time.perf_counter() - t0
    return _print(out, args.json)


def _print(out: dict, as_json: bool) -> int:
    if as_json:
        emit_json(out)
        return 0
    for k, v in out.items():
        if k in ("by_law", "lambdas"):
            continue
        print(f"{k:<24} {v if not isinstance(v, float) else f'{v:.3g}'}")
    if "by_law" in out:
        for law, v in out["by_law"].items():
            print(
                f"  {law:<12} "
                + ", ".join(
                    f"{k} {x if not isinstance(x, float) else f'{x:.3g}'}" for k, x in v.items()
                )
            )
    return 0
