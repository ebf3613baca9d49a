"""``servowatch compare``: HF against every simplified model on one scenario (seed Figs. 13-18),
or on the whole scenario suite (``--suite``: per-scenario NRMSE tables, worst and median per
model, cost per step; docs/models.md section 5)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from service.cli.util import check_outputs, emit_json, fail, writing
from service.progress import Progress
from service.sim.scenarios import SCENARIO_DIR, ScenarioError, load_scenario, resolve_scenario

NAME = "compare"
HELP = "run HF and every simplified model on a scenario or a suite: NRMSE tables, costs, plot"

SIMPLIFIED = ("A", "B", "C1", "C3", "C5", "WH")
NRMSE_SIGNALS = ("x_j", "v_j", "p12", "x_s")
SUITE_DIR = SCENARIO_DIR / "suite"


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--scenario", help="scenario TOML file (or a bundled name)")
    src.add_argument(
        "--suite",
        nargs="?",
        const=str(SUITE_DIR),
        default=None,
        metavar="DIR",
        help="every *.toml in DIR (default: the bundled suite, scenarios/suite)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--png", default=None, help="plot the time histories side by side (PNG)")
    p.add_argument(
        "--plot-models",
        type=lambda t: [m.strip() for m in t.split(",") if m.strip()],
        default=None,
        metavar="M1,M2",
        help="--png: plot HF and only these models (default: all)",
    )
    p.add_argument("--quiet", action="store_true", help="--suite: no progress lines on stderr")


def compare(scenario, progress=None) -> tuple[dict, dict]:
    """Run HF and each simplified valve; return (summary dict, results by model).

    The summary holds, per model, the NRMSE % of x_J, v_J, P12, x_S against HF on the HF
    time grid (physics.md section 5), the loop wall time and the wall time per step.
    """
    from models.eha import simulate
    from models.metrics import nrmse_pct
    from service.cli.commands.simulate import warm_up

    names = ("HF", *SIMPLIFIED)
    for name in names:
        warm_up(scenario, name)
    results = {}
    for k, name in enumerate(names):
        sub = None
        if progress is not None:

            def sub(f, k=k):  # noqa: E306
                progress((k + f) / len(names))

        results[name] = simulate(scenario, name, progress=sub)
    ref = results["HF"]
    n_steps = scenario.n_steps()
    models = {}
    for name in SIMPLIFIED:
        r = results[name]
        nrmse = {}
        for sig in NRMSE_SIGNALS:
            y = np.interp(ref.t, r.t, getattr(r, sig))  # common time grid (the HF one)
            nrmse[sig] = float(nrmse_pct(y, getattr(ref, sig)))
        models[name] = {
            "nrmse_pct": nrmse,
            "wall_s": float(r.wall_s),
            "wall_per_step_s": float(r.wall_s) / n_steps,
        }
    out = {
        "scenario": scenario.name,
        "reference": "HF",
        "hf_wall_s": float(ref.wall_s),
        "n_steps": n_steps,
        "models": models,
    }
    return out, results


def suite_files(directory: str | Path) -> list[Path]:
    """The suite's scenario files, sorted by name."""
    return sorted(Path(directory).glob("*.toml"))


def summarise_suite(rows: list[dict]) -> dict:
    """Worst and median NRMSE per model and signal over ``rows`` (``compare`` summaries),
    and the cost per step: total loop wall time over total steps, HF included."""
    n_total = sum(r["n_steps"] for r in rows)
    hf_wall = sum(r["hf_wall_s"] for r in rows)
    out: dict[str, dict] = {
        "HF": {"wall_s": hf_wall, "wall_per_step_s": hf_wall / n_total},
    }
    for name in SIMPLIFIED:
        vals = {
            s: np.array([r["models"][name]["nrmse_pct"][s] for r in rows]) for s in NRMSE_SIGNALS
        }
        wall = sum(r["models"][name]["wall_s"] for r in rows)
        worst_idx = {s: int(np.argmax(v)) for s, v in vals.items()}
        out[name] = {
            "worst_pct": {s: float(v.max()) for s, v in vals.items()},
            "worst_scenario": {s: rows[i]["scenario"] for s, i in worst_idx.items()},
            "median_pct": {s: float(np.median(v)) for s, v in vals.items()},
            "wall_s": wall,
            "wall_per_step_s": wall / n_total,
        }
    c5 = out["C5"]["wall_per_step_s"]
    for d in out.values():
        d["cost_vs_c5"] = d["wall_per_step_s"] / c5
    return out


def compare_suite(files: list[Path], log=None) -> dict:
    """``compare`` on every scenario file; one JSON-ready object (docs/models.md section 5)."""
    rows = []
    t0 = time.perf_counter()
    for k, f in enumerate(files):
        sc = load_scenario(f)
        row, _ = compare(sc)
        rows.append(row)
        if log is not None:
            m = row["models"]
            log(
                f"compare --suite: {k + 1}/{len(files)} {sc.name}  "
                f"WH P12 {m['WH']['nrmse_pct']['p12']:.2f} %  "
                f"C5 P12 {m['C5']['nrmse_pct']['p12']:.2f} %  "
                f"({time.perf_counter() - t0:.0f} s)"
            )
    return {"reference": "HF", "scenarios": rows, "summary": summarise_suite(rows)}


def _print_table(row: dict) -> None:
    print(f"{'model':6}" + "".join(f"{s:>9}" for s in NRMSE_SIGNALS) + f"{'wall [s]':>11}")
    for name, m in row["models"].items():
        vals = "".join(f"{m['nrmse_pct'][s]:9.2f}" for s in NRMSE_SIGNALS)
        print(f"{name:6}{vals}{m['wall_s']:11.4f}")


def _run_suite(args: argparse.Namespace) -> int:
    files = suite_files(args.suite)
    if not files:
        return fail(f"{args.suite}: no scenario files (*.toml)")
    from service.cli.warmup import ensure

    ensure("models", "valves")
    log = None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    try:
        out = compare_suite(files, log)
    except ScenarioError as e:
        return fail(str(e))
    out["suite"] = str(args.suite)
    if args.json:
        emit_json(out)
        return 0
    for row in out["scenarios"]:
        print(
            f"\nscenario {row['scenario']}: NRMSE % against HF (HF wall {row['hf_wall_s']:.3f} s)"
        )
        _print_table(row)
    print(f"\nsuite {args.suite}: {len(files)} scenarios, NRMSE % against HF")
    print(f"{'model':6} {'worst':>36}   {'median':>36} {'us/step':>8} {'x C5':>6}")
    print(f"{'':6} " + "".join(f"{s:>9}" for s in NRMSE_SIGNALS) + "   "
          + "".join(f"{s:>9}" for s in NRMSE_SIGNALS))  # fmt: skip
    for name, d in out["summary"].items():
        if name == "HF":
            continue
        worst = "".join(f"{d['worst_pct'][s]:9.2f}" for s in NRMSE_SIGNALS)
        med = "".join(f"{d['median_pct'][s]:9.2f}" for s in NRMSE_SIGNALS)
        print(f"{name:6} {worst}   {med} {d['wall_per_step_s'] * 1e6:8.3f} {d['cost_vs_c5']:6.2f}")
    hf = out["summary"]["HF"]
    print(f"{'HF':6} {'':36}   {'':36} {hf['wall_per_step_s'] * 1e6:8.3f} {hf['cost_vs_c5']:6.2f}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.suite is not None:
        if args.png:
            return fail("--png plots one scenario; use it with --scenario")
        return _run_suite(args)
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as e:
        return fail(str(e))
    check_outputs([("--png", args.png)], [("--scenario", resolve_scenario(args.scenario))])
    from service.cli.warmup import ensure

    ensure("models", "valves")
    prog = Progress("compare")
    out, results = compare(scenario, progress=prog)
    prog.done()
    if args.png:
        from service.plots import plot_comparison

        shown = args.plot_models or list(SIMPLIFIED)
        unknown = sorted(set(shown) - set(SIMPLIFIED))
        if unknown:
            return fail(f"--plot-models: unknown model(s) {unknown}; expected {SIMPLIFIED}")
        sel = {"HF": results["HF"], **{m: results[m] for m in shown}}
        with writing("--png", args.png):
            plot_comparison(sel, args.png, title=f"{scenario.name}: HF against {', '.join(shown)}")
    if args.json:
        emit_json(out)
        return 0
    print(f"scenario {scenario.name}: NRMSE % against HF (HF wall {out['hf_wall_s']:.3f} s)")
    _print_table(out)
    if args.png:
        print(f"plot written to {args.png}")
    return 0
