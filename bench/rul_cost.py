"""Cost of ``servowatch rul`` (``rul.compute_rul``'s work: the fleet prior learned from every
unit's history, then each unit's RUL) on a large fleet with years of flights, contenders side
by side in one run: this tree with its default RUL, this tree with the opt-in trend model and
Student-t readings (``--robust-trend``) and another source tree (``--compare PATH``, e.g. a
worktree of main, its default RUL), each timed in its own process on the same histories,
alternately.

The histories (seeded, no store): per unit one period per flight, ``--flights-per-day``
flights a day for ``--years``, noise 0.03; a fifth of the units healthy, the others wearing
linearly, exponentially or with a knee to a random share of the threshold. The store's read
is left out (the same for both).

    .venv/bin/python bench/rul_cost.py --units 1000 --years 5 --compare /path/to/main
    .venv/bin/python bench/rul_cost.py --units 40 --years 5 --compare ../main --sample 40
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
import numpy as np
from service.prognostics.rul import History, RulConfig, fleet_prior, rul_of_history

units, years, fpd, sample, seed, robust = (int(sys.argv[1]), float(sys.argv[2]),
                                           float(sys.argv[3]), int(sys.argv[4]),
                                           int(sys.argv[5]), sys.argv[6] == "1")
opt = {"robust_trend": True} if robust else {}  # the switch: absent from an older tree
rng = np.random.default_rng(seed)
n = int(years * 365 * fpd)
hist = []
for i in range(units):
    t = np.arange(1.0, n + 1)
    x = t / n
    law = i % 5
    share = rng.uniform(0.3, 0.9) * 10.0
    if law == 0:
        r = np.ones(n)
    elif law in (1, 2):
        r = 1 + share * x
    elif law == 3:
        r = 1 + share * np.expm1(2 * x) / np.expm1(2)
    else:
        k = rng.uniform(0.3, 0.7)
        r = 1 + share * np.where(x < k, 0.2 * x / k, 0.2 + 0.8 * (x - k) / (1 - k))
    y = r + 0.03 * rng.standard_normal(n)
    hist.append(History(f"B{i:04d}/eha", t * 2.0, y, 2.0, t - 1.0, None))
t0 = time.perf_counter()
prior = fleet_prior(hist[:sample], **opt)  # linear in the units: each fitted on its own
t1 = time.perf_counter()
cfg = RulConfig(**opt)
for h in hist[:sample]:
    rul_of_history(h, prior, cfg)
t2 = time.perf_counter()
print(json.dumps({"prior_s": t1 - t0, "rul_s": t2 - t1, "rul_units": min(sample, units),
                  "readings_per_unit": n}))
"""


def _run(tree: Path, robust: bool, a) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(a.units), str(a.years), str(a.flights_per_day),
         str(a.sample or a.units), str(a.seed), "1" if robust else "0"],
        cwd=tree, env=env, capture_output=True, text=True, check=True,
    )  # fmt: skip
    r = json.loads(out.stdout.strip().splitlines()[-1])
    r["total_s"] = (r["prior_s"] + r["rul_s"]) / r["rul_units"] * a.units  # scaled to --units
    return r


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--units", type=int, default=1000)
    ap.add_argument("--years", type=float, default=5.0)
    ap.add_argument("--flights-per-day", type=float, default=1.0)
    ap.add_argument("--sample", type=int, default=0, help="time the fleet prior and the RUL "
                    "on this many units and scale to --units (0: all)")  # fmt: skip
    ap.add_argument("--compare", metavar="PATH", help="another source tree (e.g. main's)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-robust", action="store_true",
                    help="leave out this tree's --robust-trend contender")  # fmt: skip
    a = ap.parse_args()
    trees = [("this tree", HERE, False), ("robust", HERE, True)]
    if a.no_robust:
        trees = trees[:1]
    if a.compare:
        trees.append(("compare", Path(a.compare).resolve(), False))
    res: dict[str, list[dict]] = {name: [] for name, _, _ in trees}
    for _ in range(a.repeats):
        for name, tree, robust in trees:  # alternately, so load changes hit all of them
            res[name].append(_run(tree, robust, a))
    best = {name: min(v, key=lambda r: r["total_s"]) for name, v in res.items()}
    n = next(iter(best.values()))["readings_per_unit"]
    print(f"{a.units} units x {n} readings ({a.years:g} years at {a.flights_per_day:g} "
          f"flights a day); RUL timed on {a.sample or a.units} units, best of {a.repeats}")  # fmt: skip
    for name, r in best.items():
        print(f"  {name:<10} fleet prior {r['prior_s']:8.1f} s  RUL {r['rul_s']:8.1f} s "
              f"({r['rul_s'] / r['rul_units'] * 1e3:.1f} ms/unit)  total {r['total_s']:8.1f} s")  # fmt: skip
    ref = "compare" if "compare" in best else "this tree"
    for name in best:
        if name != ref:
            print(f"  ratio {name} / {ref}: {best[name]['total_s'] / best[ref]['total_s']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
