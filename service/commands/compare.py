"""``servowatch compare``: HF against every simplified model on one scenario (seed Figs. 13-18)."""

from __future__ import annotations

import argparse

import numpy as np

from service.cliutil import emit_json, fail
from service.progress import Progress
from service.scenarios import ScenarioError, load_scenario

NAME = "compare"
HELP = "run HF and every simplified model on a scenario: NRMSE table, wall times, plot"

SIMPLIFIED = ("A", "B", "C1", "C3", "C5")
NRMSE_SIGNALS = ("x_j", "v_j", "p12", "x_s")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", required=True, help="scenario TOML file (or a bundled name)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--png", default=None, help="plot the time histories side by side (PNG)")


def compare(scenario, progress=None) -> tuple[dict, dict]:
    """Run HF and each simplified valve; return (summary dict, results by model)."""
    from models.eha import simulate
    from models.metrics import nrmse_pct
    from service.commands.simulate import warm_up

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
    models = {}
    for name in SIMPLIFIED:
        r = results[name]
        nrmse = {}
        for sig in NRMSE_SIGNALS:
            y = np.interp(ref.t, r.t, getattr(r, sig))  # common time grid (the HF one)
            nrmse[sig] = float(nrmse_pct(y, getattr(ref, sig)))
        models[name] = {"nrmse_pct": nrmse, "wall_s": float(r.wall_s)}
    out = {
        "scenario": scenario.name,
        "reference": "HF",
        "hf_wall_s": float(ref.wall_s),
        "models": models,
    }
    return out, results


def run(args: argparse.Namespace) -> int:
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as e:
        return fail(str(e))
    prog = Progress("compare")
    out, results = compare(scenario, progress=prog)
    prog.done()
    if args.png:
        from service.plots import plot_comparison

        plot_comparison(results, args.png, title=f"{scenario.name}: HF against A, B, C1, C3, C5")
    if args.json:
        emit_json(out)
        return 0
    print(f"scenario {scenario.name}: NRMSE % against HF (HF wall {out['hf_wall_s']:.3f} s)")
    print(f"{'model':6}" + "".join(f"{s:>9}" for s in NRMSE_SIGNALS) + f"{'wall [s]':>11}")
    for name, m in out["models"].items():
        row = "".join(f"{m['nrmse_pct'][s]:9.2f}" for s in NRMSE_SIGNALS)
        print(f"{name:6}{row}{m['wall_s']:11.4f}")
    if args.png:
        print(f"plot written to {args.png}")
    return 0
