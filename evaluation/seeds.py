"""Two process models of the monitor compared over sensor-noise seeds, paired (issue 11:
"no worse than C5 on every scenario").

One run of ``bench/estimation.py`` is one draw of the sensor noise: a C_Lk RMS of 9.2 % against
8.8 % on a 4 s run says nothing until the seed-to-seed scatter is known. This runs the
full-channel scenarios of ``bench/estimation.py`` on N noise seeds (``sensors.seed`` = 1..N;
the HF truth is the same for every seed), both models on the same measured signals, and prints
for each scenario and figure the mean of each model, the mean paired difference B - A with its
95 % interval (Student t over the N pairs) and a verdict: "B worse" or "B better" when the
interval lies wholly on one side of zero, else "-" (no difference seen at this N).

    .venv/bin/python -m evaluation.seeds --models C5,WH --seeds 8 --workers 2
    .venv/bin/python -m evaluation.seeds --seeds 4 --only leak_step,est_overload --json s.json
    .venv/bin/python -m evaluation.seeds --seeds 8 --only combined --plant c_r=2.5e-7

``--plant FIELD=VALUE`` changes the HF plant of every scenario (an ``EHAParams`` field); each
model's baseline is then calibrated on healthy_noise with that plant (``calibrate``) instead
of its default baseline (``Baseline.default``: the C-types' bundled calibration, WH's
datasheet values).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy import stats

from evaluation.scenarios import SCENARIOS, SCENARIOS_WH, bundled_scenario
from evaluation.suite import numeric_items, parse_overrides

# the full-channel rows of bench/estimation.py: (row name, scenario, leak step to [m^3/s/Pa])
RUNS: tuple[tuple[str, str, float | None], ...] = (
    *((n, n, None) for n in SCENARIOS[:3]),
    ("leak_step_2x", "leak_step", 4e-13),  # the smallest target: +1x nominal
    *((n, n, None) for n in SCENARIOS[3:]),
    *((n, n, None) for n in SCENARIOS_WH),
)
# figure: (label, True if lower is better)
FIGURES: dict[str, tuple[str, bool]] = {
    "c_lk_rms": ("C_Lk rms%", True),
    "c_lk_1s_abs": ("|C_Lk 1s|%", True),
    "p_sr_rms": ("P_SR rms%", True),
    "p_sr_settle": ("P_SR 5% s", True),
    "delay": ("delay s", True),
    "false": ("false", True),
    "nis_in": ("NIS in%", False),
    "reinit": ("reinit", True),
}


def _figures(r: dict) -> dict[str, float | None]:
    """The compared figures of one ``evaluate`` summary (None: not defined on this run)."""
    s1 = r.get("c_lk_error_settled_pct")
    return {
        "c_lk_rms": r.get("c_lk_rms_pct"),
        "c_lk_1s_abs": None if s1 is None else abs(s1),
        "p_sr_rms": r.get("p_sr_rms_pct"),
        "p_sr_settle": r.get("p_sr_settle_s"),
        "delay": r.get("detection_delay_s"),
        "false": float(r["false_alarms"]),
        "nis_in": r.get("nis_in_band_pct"),
        "reinit": float(r["counters"]["reinit"]),
    }


def plant_scenario(name: str, plant: dict[str, float], leak: float | None = None):
    """Bundled scenario ``name`` (``bundled_scenario``) with the EHAParams overrides ``plant``
    added to its own."""
    sc = bundled_scenario(name, leak=leak)
    return sc.model_copy(update={"params": {**sc.params, **plant}}) if plant else sc


def plant_baselines(models, overrides: dict, plant: dict[str, float]) -> dict:
    """Each model's baseline for the plant: the bundled default without ``plant``, else
    ``calibrate`` on healthy_noise with it."""
    from service.monitor import Baseline, MonitorConfig
    from service.monitor.calibration import calibrate, measured_run

    if not plant:
        return {m: Baseline.default(m) for m in models}
    _, meas = measured_run(plant_scenario("healthy_noise", plant))
    return {
        m: calibrate(meas, config=MonitorConfig(model=m, **overrides.get(m, {}))) for m in models
    }


def run_pair(args) -> dict:
    """Scenario ``name`` (leak step to ``leak`` at 1.5 s if given; EHAParams overrides
    ``plant``) with sensor seed ``seed``, through the monitor on each of ``models`` with its
    baseline: {model: figures}."""
    models, overrides, plant, baselines, row, name, leak, seed = args
    from service.cli.commands.estimate import evaluate
    from service.monitor import MonitorConfig

    sc = plant_scenario(name, plant, leak)
    sc = sc.model_copy(update={"sensors": sc.sensors.model_copy(update={"seed": seed})})
    out = {"row": row, "seed": seed}
    for m in models:
        cfg = MonitorConfig(model=m, **overrides.get(m, {}))
        out[m] = _figures(evaluate(sc, cfg, baselines[m]))
    return out


def paired(a: list[float | None], b: list[float | None], lower_better: bool) -> dict:
    """Mean of each, mean of the pairs' b - a with its 95 % Student-t interval (pairs where
    both are defined), the verdict on b, and how many seeds define the figure for one only."""
    pairs = [(x, y) for x, y in zip(a, b, strict=True) if x is not None and y is not None]
    one_only = sum((x is None) != (y is None) for x, y in zip(a, b, strict=True))
    res = {"n": len(pairs), "one_only": one_only, "mean_a": None, "mean_b": None}
    res.update(diff=None, lo=None, hi=None, verdict="-")
    if not pairs:
        return res
    xa, xb = np.array(pairs).T
    d = xb - xa
    res.update(mean_a=float(xa.mean()), mean_b=float(xb.mean()), diff=float(d.mean()))
    if len(d) > 1:
        half = float(stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / math.sqrt(len(d)))
        res.update(lo=res["diff"] - half, hi=res["diff"] + half)
        if res["lo"] > 0 or res["hi"] < 0:
            worse = res["lo"] > 0 if lower_better else res["hi"] < 0
            res["verdict"] = "B worse" if worse else "B better"
    return res


def compare(rows: list[dict], a: str, b: str) -> list[dict]:
    """One entry per (row name, figure) defined on at least one seed."""
    out = []
    for name in dict.fromkeys(r["row"] for r in rows):
        runs = [r for r in rows if r["row"] == name]
        for key, (label, lower) in FIGURES.items():
            res = paired([r[a][key] for r in runs], [r[b][key] for r in runs], lower)
            if res["n"] or res["one_only"]:
                out.append({"row": name, "figure": label, **res})
    return out


def _f(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def print_compare(cmp: list[dict], a: str, b: str, seeds: int) -> None:
    print(
        f"\n{a} (A) against {b} (B), {seeds} sensor-noise seeds, paired; d = B - A, 95 % interval"
    )
    hdr = f"{'scenario':<20}{'figure':<12}{'n':>3}{'mean A':>10}{'mean B':>10}{'d':>10}"
    hdr += f"{'interval':>22}  verdict"
    print(hdr)
    print("-" * len(hdr))
    for c in cmp:
        iv = f"[{_f(c['lo'], '+.3g')}, {_f(c['hi'], '+.3g')}]" if c["lo"] is not None else "-"
        extra = f" ({c['one_only']} seed(s) defined for one model only)" if c["one_only"] else ""
        print(
            f"{c['row']:<20}{c['figure']:<12}{c['n']:>3}{_f(c['mean_a'], '10.3f')}"
            f"{_f(c['mean_b'], '10.3f')}{_f(c['diff'], '+10.3f')}{iv:>22}  {c['verdict']}{extra}"
        )
    worse = [c for c in cmp if c["verdict"] == "B worse"]
    better = [c for c in cmp if c["verdict"] == "B better"]
    print(f"\n{b} worse than {a} (interval above zero): {len(worse)}; better: {len(better)}")
    for c in worse:
        print(f"  {c['row']}: {c['figure']} {c['mean_a']:.3f} -> {c['mean_b']:.3f}")


def parse_plant(ap: argparse.ArgumentParser, items: list[str]) -> dict[str, float]:
    """``--plant FIELD=VALUE`` items as EHAParams overrides, checked; ``ap.error`` names a bad
    item."""
    from models.params import EHAParams

    plant = dict(numeric_items(ap, "--plant", items))
    try:
        EHAParams(**plant)
    except ValueError as e:
        ap.error(f"--plant: {e}")
    return plant


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default="C5,WH", help="A,B: the two process models")
    ap.add_argument("--seeds", type=int, default=8, help="sensor-noise seeds 1..N (N >= 2)")
    ap.add_argument("--only", default=None, help="comma-separated row names (default: all)")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--json", default=None, help="write every run and the comparison here")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="MODEL:FIELD=VALUE",
        help="override a MonitorConfig field of one model, e.g. --set WH:process.c_lk=1.2e-13",
    )
    ap.add_argument(
        "--plant",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="change the HF plant of every scenario (an EHAParams field, e.g. c_r=2.5e-7); "
        "each model is then calibrated on healthy_noise with that plant",
    )
    args = ap.parse_args(argv)
    models = tuple(m.strip() for m in args.models.split(",") if m.strip())
    if len(models) != 2 or models[0] == models[1]:
        ap.error("--models: expected two different models, e.g. C5,WH")
    if args.seeds < 2:
        ap.error("--seeds: at least 2 (the interval needs a spread)")
    names = [r[0] for r in RUNS]
    only = names if args.only is None else [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = [s for s in only if s not in names]
    if unknown:
        ap.error(f"--only: unknown {', '.join(unknown)}; expected some of {', '.join(names)}")
    overrides: dict[str, dict] = {}
    for m in models:
        items = []
        for kv in args.set:
            mod, sep, rest = kv.partition(":")
            if not sep or mod not in models:
                ap.error(f"--set {kv!r}: expected MODEL:FIELD=VALUE with MODEL one of {models}")
            if mod == m:
                items.append(rest)
        overrides[m] = parse_overrides(ap, m, items)
    plant = parse_plant(ap, args.plant)
    baselines = plant_baselines(models, overrides, plant)
    if plant:
        print(f"plant: {plant}; baselines calibrated on healthy_noise with it", file=sys.stderr)
    jobs = [
        (models, overrides, plant, baselines, *r, s)
        for r in RUNS
        if r[0] in only
        for s in range(1, args.seeds + 1)
    ]
    t0 = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as ex:
        for i, r in enumerate(ex.map(run_pair, jobs), 1):
            rows.append(r)
            print(
                f"\r{i}/{len(jobs)} runs ({time.perf_counter() - t0:.0f} s)",
                end="",
                file=sys.stderr,
            )
    print(file=sys.stderr)
    cmp = compare(rows, *models)
    print_compare(cmp, *models, args.seeds)
    print(
        f"({len(jobs)} scenario runs x {len(models)} models: {time.perf_counter() - t0:.0f} s wall)"
    )
    if args.json:
        Path(args.json).write_text(
            json.dumps(
                {"models": models, "seeds": args.seeds, "runs": rows, "compare": cmp}, indent=1
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
