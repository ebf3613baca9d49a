"""``servowatch calibrate``: identify the monitor's baseline from a healthy run.

The healthy run is a scenario (HF bench + its sensor noise) or a recorded MCAP log whose
topic ending in ``/meas`` carries t, x_cmd, i, x_s, x_j, p1, p2 (as written by
``servowatch estimate --out``). The method is in ``service.monitor.calibration``.

``--out`` writes the baseline JSON; ``--actuator AC/ACT`` records it as that actuator's next
baseline version in the health store (``--store``, default servowatch-data/health.sqlite).
A log's topics ``/fleet/{aircraft}/{actuator}/meas`` name its actuators: ``--actuator`` must be
one of them (else exit 2), and without ``--actuator`` a log of one actuator names it.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from service.cli.util import check_outputs, emit_json, fail, writing
from service.monitor.model_choice import DEFAULT_MODEL, MONITOR_MODELS
from service.progress import Progress
from service.sim.scenarios import ScenarioError, load_scenario, resolve_scenario
from service.store import StoreError, check_actuator
from service.store.cli import add_store_argument, open_store_arg, store_path_arg

NAME = "calibrate"
HELP = "identify the monitor's nominal (baseline) parameters from a healthy run"

__all__ = ["NAME", "HELP", "add_arguments", "run", "meas_from_log", "log_actuators"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--scenario", help="healthy scenario TOML (or a bundled name)")
    src.add_argument("--log", help="recorded MCAP log with a .../meas topic")
    p.add_argument(
        "--model",
        default=DEFAULT_MODEL,
        help=f"process model of the monitor ({', '.join(MONITOR_MODELS)}; default {DEFAULT_MODEL})",
    )
    p.add_argument("--out", default=None, help="write the baseline JSON here")
    p.add_argument(
        "--actuator",
        default=None,
        metavar="AC/ACT",
        help="record the baseline as this actuator's next version in the health store",
    )
    add_store_argument(p)
    p.add_argument("--passes", type=int, default=2, help="bias-correction passes (default 2)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def log_actuators(path: str) -> list[str]:
    """``{aircraft}/{actuator}`` of each ``/fleet/{aircraft}/{actuator}/meas`` topic of a log."""
    from service.log.flightrec import log_units

    return log_units(path)


MIN_SAMPLES = 200  # a healthy run shorter than this cannot be calibrated on


def meas_from_log(path: str, actuator: str | None = None) -> dict[str, np.ndarray]:
    """Measured arrays from the ``.../meas`` topic of ``actuator`` (``AC/ACT``; None: the
    first ``.../meas`` topic) of an MCAP log.

    Checked, not trusted (a foreign log): a message that is not a JSON object, or whose
    channel is not a number, is a ``ValueError`` naming the message; samples whose time
    repeats or steps back are dropped, as the daemon's intake drops them, and fewer than
    ``MIN_SAMPLES`` left (constant timestamps) is a ``ValueError`` that counts them."""
    from service.log import read_log

    rows: list[dict] = []
    topic0 = None if actuator is None else f"/fleet/{actuator}/meas"
    for topic, t, msg in read_log(path):
        if not topic.endswith("/meas"):
            continue
        if topic0 is None:
            topic0 = topic
        if topic != topic0:
            continue
        if not isinstance(msg, dict):
            raise ValueError(
                f"{topic} message {len(rows)} at t = {t:.6g} s is a JSON "
                f"{type(msg).__name__}, not an object of channels"
            )
        rows.append({"t": t, **msg})
    if not rows:
        raise ValueError("no .../meas topic")
    keys = [k for k in ("t", "x_cmd", "i", "x_s", "x_j", "p1", "p2") if k in rows[0]]
    out: dict[str, np.ndarray] = {}
    for k in keys:
        col = np.empty(len(rows))
        for j, r in enumerate(rows):
            v = r.get(k)
            if v is None:  # null: a non-finite value as the logger writes it
                col[j] = np.nan
            elif isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"{topic0} message {j}: {k} = {v!r} is not a number")
            else:
                col[j] = v
        out[k] = col
    t = out["t"]
    finite = np.all(np.isfinite(np.column_stack(list(out.values()))), axis=1)
    keep = finite.copy()
    last = -np.inf
    for j in np.flatnonzero(finite):  # the intake's rule: a sample must move the time on
        if t[j] > last:
            last = t[j]
        else:
            keep[j] = False
    n, n_keep = len(t), int(keep.sum())
    dropped_t = int(finite.sum()) - n_keep
    if n_keep < MIN_SAMPLES:
        raise ValueError(
            f"{topic0}: {n_keep} usable samples of {n} ({dropped_t} repeat or step back the "
            f"time, {n - int(finite.sum())} hold a non-finite value); calibration needs at "
            f"least {MIN_SAMPLES} with increasing time"
        )
    if n_keep < n:
        print(
            f"servowatch calibrate: {path}: dropped {n - n_keep} of {n} samples "
            f"({dropped_t} repeat or step back the time, {n - int(finite.sum())} non-finite)",
            file=sys.stderr,
        )
    return {k: v[keep] for k, v in out.items()}


def run(args: argparse.Namespace) -> int:
    from service.cli.warmup import ensure, monitor_group

    if args.model not in MONITOR_MODELS:
        return fail(f"unknown model {args.model!r}; expected one of {', '.join(MONITOR_MODELS)}")
    ensure("models", monitor_group(args.model))
    if args.passes < 0:
        return fail("--passes must be >= 0")
    if args.log is not None:
        try:
            named = log_actuators(args.log)
        except (OSError, ValueError) as e:
            return fail(f"{args.log}: cannot read a healthy run: {e}")
        if args.actuator is not None and named and args.actuator not in named:
            return fail(
                f"--actuator {args.actuator}: the log {args.log} holds "
                f"{', '.join(named)}, not {args.actuator} (a baseline of another actuator)"
            )
        if args.actuator is None and len(named) == 1:
            args.actuator = named[0]
        elif args.actuator is None and len(named) > 1 and args.store is not None:
            return fail(f"--actuator: the log holds {', '.join(named)}; name one")
    if args.store is not None and args.actuator is None:
        return fail("--store needs --actuator AC/ACT (the actuator the baseline belongs to)")
    if args.out is None and args.actuator is None:
        return fail("give --out FILE.json and/or --actuator AC/ACT (to record it in --store)")
    try:
        scenario_path = None if args.scenario is None else resolve_scenario(args.scenario)
    except ScenarioError as e:
        return fail(str(e))
    check_outputs(
        [("--out", args.out), ("--store", store_path_arg(args) if args.actuator else None)],
        [("--scenario", scenario_path), ("--log", args.log)],
        makes_folders=("--store",),  # --out: a JSON file in an existing folder
    )
    store = None
    if args.actuator is not None:
        try:
            check_actuator(args.actuator, "--actuator")
            store = open_store_arg(args, create=True)  # fail fast, before the long run
        except (ValueError, StoreError) as e:
            return fail(str(e))
    try:
        return _run(args, store)
    finally:
        if store is not None:
            store.close()


def _run(args: argparse.Namespace, store) -> int:
    from service.monitor.calibration import calibrate, measured_run

    prog = Progress("calibrate")
    t0 = time.perf_counter()
    if args.scenario:
        try:
            scenario = load_scenario(args.scenario)
        except ScenarioError as e:
            return fail(str(e))
        _, meas = measured_run(scenario, progress=prog)
        source = f"scenario {scenario.name}"
    else:
        try:
            meas = meas_from_log(args.log, args.actuator if _named(args.log) else None)
        except (OSError, ValueError) as e:
            return fail(f"{args.log}: cannot read a healthy run: {e}")
        source = f"log {args.log}"
    need = {"t", "x_s", "x_j", "p1", "p2"}
    if not need <= set(meas):
        return fail(f"calibration needs the full channel set {sorted(need)}")
    try:
        base = calibrate(meas, args.model, passes=args.passes)
    except ValueError as e:
        return fail(str(e))
    prog.done()
    base = base.model_copy(update={"source": f"calibrated on {source}"})
    if args.out is not None:
        with writing("--out", args.out, so_far="nothing was stored"):
            base.save(args.out)
    wall_s = time.perf_counter() - t0
    out = {
        "source": source,
        "model": args.model,
        "out": args.out,
        "wall_s": wall_s,
        "baseline": base.model_dump(),
    }
    if store is not None:
        t = np.asarray(meas["t"], float)
        figures = {
            "model": args.model,
            "passes": args.passes,
            "samples": int(len(t)),
            "duration_s": float(t[-1] - t[0]) if len(t) else 0.0,
            "wall_s": wall_s,
        }
        rec = store.add_baseline(args.actuator, base.model_dump(), source, figures)
        out.update(actuator=rec.actuator, version=rec.version, store=store.where)
    if args.json:
        emit_json(out)
        return 0
    if args.out is not None:
        print(f"baseline for {args.model} from {source} written to {args.out}")
    if store is not None:
        print(f"baseline version {out['version']} of {args.actuator} recorded in {store.where}")
    print(f"  effective x_SS {base.x_ss * 1e6:.2f} um (nominal 100), G_PQ {base.g_pq:.3e} Pa s/m^3")
    print(f"  C_Lk (fixed, nominal) {base.c_lk:.2e}, P_R {base.p_r / 1e6:.3f} MPa")
    if base.law == "WH":
        stick = f"breakaway F_s {base.f_s:.0f} N" if base.f_s > 0 else "no stiction (F_s 0)"
        print(f"  friction (datasheet): Coulomb F_d {base.f_d:.0f} N, {stick}")
    return 0


def _named(path: str) -> bool:
    return bool(log_actuators(path))
