"""The pooled C_Lk against the walk filter's own reading on the bundled scenarios and the
paper bench (issue 51; docs/estimation.md, "The pooled C_Lk").

    .venv/bin/python -m evaluation.pooled                       # every scenario, WH
    .venv/bin/python -m evaluation.pooled --only incipient_leak --set c_lk_pool_h=0

Per scenario (the HF bench with the scenario's seeded sensor noise is the truth; the monitor
on the model's default baseline, full channel set): the C_Lk increase error [%] over the last
second of the walk filter's mean (``walk%``) and its last 1-sigma / baseline (``walk_sd``);
the pooled reading of the last row (``pool%``, ``pool_sd``) and the observability limit it
is judged on (``limit``, ``service.prognostics.indicators.pooled_limit``); ``period%`` the
pooled reading a period of the last 2 s records beside its indicator (``c_lk_pooled``;
"-": no row within the limit); without a true increase of at
least 0.25x (healthy, supply), the errors are against nominal C_Lk in % of it (``*``).
"""

from __future__ import annotations

import argparse
import math
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from evaluation.scenarios import SCENARIOS, SCENARIOS_WH

EXTRA = ("incipient_leak", "paper_bench")


def run(name: str, model: str = "WH", overrides: dict | None = None) -> dict:
    """One scenario through the monitor: the figures of the module docstring."""
    from service.monitor import EST_KEYS, Baseline, MonitorBank, MonitorConfig
    from service.monitor.calibration import meas_channels, measured_run
    from service.prognostics.indicators import PeriodConfig, periods_of_rows, pooled_limit
    from service.sim.scenarios import load_scenario

    sim, meas = measured_run(load_scenario(name))
    cfg = MonitorConfig(model=model, **(overrides or {}))
    base = Baseline.default(model)
    bank = MonitorBank(cfg, base)
    t = np.asarray(meas["t"])
    rows = bank.update_arrays(np.full(len(t), bank.index_of("a")), t, meas_channels(meas))
    c0 = base.c_lk
    c_true = float(np.interp(rows.t[-1], sim.t, sim.c_lk))
    inc = c_true - float(sim.c_lk[0])
    rel = inc >= 0.25 * c0
    den = inc if rel else c0

    def err(c: float) -> float:
        return 100.0 * ((c - c0) - (inc if rel else 0.0)) / den

    last = rows.t >= rows.t[-1] - 1.0
    c = rows.est[:, EST_KEYS.index("c_lk")]
    sd = rows.est[:, EST_KEYS.index("c_lk_sigma")]
    w = rows.t >= rows.t[-1] - 2.0
    pcfg = PeriodConfig(settle_s=0.0, window_s=math.inf)
    (p,) = periods_of_rows("a/b", c0, "pooled", rows.t[w], rows.est[w], rows.health[w],
                           config=pcfg, pooled=rows.pooled[w])  # fmt: skip
    pr, ps = rows.pooled[-1]
    return {
        "scenario": name,
        "rel": rel,
        "walk%": err(float(np.mean(c[last]))),
        "walk_sd": float(sd[-1] / c0),
        "pool%": err(float(pr)),
        "pool_sd": float(ps / c0),
        "limit": float(pooled_limit(pr / c0, pcfg)),
        "period%": err(p.c_lk_pooled) if math.isfinite(p.c_lk_pooled) else None,
        "changes": bank.c_lk_changes_of("a"),
    }


def main(argv: list[str] | None = None) -> int:
    from evaluation.suite import parse_overrides

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="WH")
    ap.add_argument("--only", default=None, help="comma-separated scenario names")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    a = ap.parse_args(argv)
    names = a.only.split(",") if a.only else [*SCENARIOS, *SCENARIOS_WH, *EXTRA]
    ov = parse_overrides(ap, a.model, a.set)
    with ProcessPoolExecutor(a.workers) as ex:
        rows = list(ex.map(run, names, [a.model] * len(names), [ov] * len(names)))
    print(f"{'scenario':<18}{'walk%':>8}{'walk_sd':>8}{'pool%':>8}{'pool_sd':>8}{'limit':>7}"
          f"{'period%':>8}{'changes':>8}")  # fmt: skip
    for r in rows:
        star = "" if r["rel"] else "*"
        ind = "-" if r["period%"] is None else f"{r['period%']:+.1f}{star}"
        print(f"{r['scenario']:<18}{r['walk%']:>+7.1f}{star or ' '}{r['walk_sd']:>8.3f}"
              f"{r['pool%']:>+7.1f}{star or ' '}{r['pool_sd']:>8.3f}{r['limit']:>7.3f}"
              f"{ind:>8}{r['changes']:>8}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
