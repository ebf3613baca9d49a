"""Prognostics benchmark: the PHM metrics of the fleet simulator on several seeds, the RUL
computation time per actuator, and a baseline to beat on the same histories: MATLAB's
documented exponential degradation model (Predictive Maintenance Toolbox,
``exponentialDegradationModel``) reimplemented.

The baseline: S(t) = phi + theta exp(beta t + eps - sigma^2 / 2), eps ~ N(0, sigma^2), so
ln(S - phi) = ln theta + beta t + eps with a Gaussian prior on (ln theta, beta) learned from
the fleet (``fit``: per-unit least squares, mean and covariance across units, pooled noise
variance), updated per unit by Bayesian linear regression (``update``) and the RUL from
posterior draws of the noise-free path's threshold crossing (``predictRUL``). phi = 0 (the
indicator's healthy value is 1, so ln S starts at 0). The prior is learned, like ours, from
every unit's history up to the flight of the prediction.

    .venv/bin/python bench/prognostics.py                       # 16 units x 60 flights, seeds 1 2
    .venv/bin/python bench/prognostics.py --actuators 40 --flights 100 --seeds 1,2,3
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from service.prognostics.rul import RulConfig, fleet_prior, history_of, rul_of_history  # noqa: E402
from service.replay.fleetsim import FleetSimConfig, evaluate, run_fleet_sim  # noqa: E402
from service.store.records import Period  # noqa: E402

PHI = 0.0


def matlab_exp_learn(histories) -> dict:
    """``fit``: prior of (ln theta, beta) and noise variance from the fleet's histories of
    degrading units (C_Lk ratio above 1.5 at some point: MATLAB fits the prior on an
    ensemble of degradation profiles, not on healthy units)."""
    params, res = [], []
    for t, y in histories:
        ok = np.asarray(y) > PHI
        t, z = np.asarray(t)[ok], np.log(np.asarray(y)[ok] - PHI)
        if len(t) < 5 or np.max(z) < math.log(1.5):
            continue
        A = np.stack([np.ones_like(t), t], axis=1)
        w, *_ = np.linalg.lstsq(A, z, rcond=None)
        params.append(w)
        res.append(np.var(z - A @ w, ddof=2))
    if len(params) < 3:
        return {"mean": np.array([0.0, 0.0]), "cov": np.diag([1.0, 1.0]), "s2": 1e-3}
    p = np.array(params)
    return {
        "mean": p.mean(axis=0),
        "cov": np.cov(p.T) + np.diag([1e-6, 1e-8]),
        "s2": float(np.median(res)),
    }


def matlab_exp_predict(h, prior: dict, rc: RulConfig, n: int = 2000):
    """``update`` + ``predictRUL``: (median RUL on the history's axis or inf, warning) or
    None."""
    t, y = h.observed()
    if len(t) < rc.min_periods:
        return None
    ok = y > PHI
    t, z = t[ok], np.log(y[ok] - PHI)
    s2 = prior["s2"]
    A = np.stack([np.ones_like(t), t], axis=1)
    P0 = np.linalg.inv(prior["cov"])
    Pn = P0 + A.T @ A / s2
    cov = np.linalg.inv(Pn)
    mean = cov @ (P0 @ prior["mean"] + A.T @ z / s2)
    w = np.random.default_rng(rc.seed).multivariate_normal(mean, cov, size=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        tc = (math.log(rc.threshold() - PHI) - w[:, 0] + 0.5 * s2) / w[:, 1]
    tc = np.where((w[:, 1] > 0) & np.isfinite(tc), tc, np.inf)
    rul = np.maximum(tc - h.t_now(), 0.0)
    med = float(np.quantile(rul, 0.5, method="inverted_cdf"))
    return med, bool(np.mean(rul <= rc.horizon(h.axis)) >= rc.warn_p)


def _row(name: str, ev: dict) -> str:
    f = lambda v: "     -" if v is None else f"{v:6.1f}"  # noqa: E731
    bl = {law: ev["by_law"].get(law, {"alpha_lambda_pct": None})
          for law in ("linear", "exponential", "step")}  # fmt: skip
    return (
        f"{name:<22}{f(ev['alpha_lambda_pct'])}{f(ev['relative_accuracy_pct'])}"
        f"{f(ev['prognostic_horizon_pct'])}{ev['scored_units']:>6}"
        f"{f(bl['linear']['alpha_lambda_pct'])}{f(bl['exponential']['alpha_lambda_pct'])}"
        f"{f(bl['step']['alpha_lambda_pct'])}{ev['false_rul_warnings']:>5}/{ev['healthy_units']}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--actuators", type=int, default=16)
    ap.add_argument("--flights", type=int, default=60)
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--json", metavar="F", help="also write the figures as JSON here")
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    out = {"seeds": {}}
    head = (
        f"{'method':<22}{'a-l %':>6}{'RA %':>6}{'PH %':>6}{'units':>6}"
        f"{'lin':>6}{'exp':>6}{'step':>6}{'false':>7}"
    )
    for seed in seeds:
        cfg = FleetSimConfig(actuators=a.actuators, flights=a.flights, seed=seed)
        sim = run_fleet_sim(cfg)
        units = sim["units"]
        t0 = time.perf_counter()
        ours = evaluate(units, cfg)
        t1 = time.perf_counter()
        base = evaluate(units, cfg, learn=matlab_exp_learn, predict=matlab_exp_predict)
        t2 = time.perf_counter()
        # RUL time per actuator on the full histories (fleet prior learned once)
        hist = [
            history_of(u["truth"]["actuator"], [Period.from_dict(p) for p in u["periods"]])
            for u in units
        ]
        tp0 = time.perf_counter()
        prior = fleet_prior(hist)
        tp1 = time.perf_counter()
        rc = RulConfig(threshold_ratio=cfg.threshold())
        times = []
        for h in hist:
            s = time.perf_counter()
            rul_of_history(h, prior, rc)
            times.append(time.perf_counter() - s)
        mtimes = []
        bprior = matlab_exp_learn([h.observed() for h in hist])
        for h in hist:
            s = time.perf_counter()
            matlab_exp_predict(h, bprior, rc)
            mtimes.append(time.perf_counter() - s)
        print(f"seed {seed}: {a.actuators} units x {a.flights} flights, "
              f"{sum(u['segments'] for u in units)} segments, sim {sim['wall_s']:.0f} s, "
              f"false leak alarms {sum(u['false_alarms'] for u in units)}")  # fmt: skip
        print(head)
        print(_row("servowatch (BMA)", ours))
        print(_row("MATLAB exp. model", base))
        print(
            f"RUL per actuator: servowatch {1e3 * np.median(times):.1f} ms (median, "
            f"{min(len(h.t_h) for h in hist)}-{max(len(h.t_h) for h in hist)} periods; fleet prior "
            f"{1e3 * (tp1 - tp0):.0f} ms for {len(hist)} units), MATLAB exp. "
            f"{1e3 * np.median(mtimes):.2f} ms; evaluation {t1 - t0:.1f} s vs {t2 - t1:.1f} s\n"
        )
        out["seeds"][seed] = {
            "ours": {k: v for k, v in ours.items() if k != "units"},
            "matlab_exp": {k: v for k, v in base.items() if k != "units"},
            "rul_ms_per_actuator": 1e3 * float(np.median(times)),
            "matlab_ms_per_actuator": 1e3 * float(np.median(mtimes)),
            "fleet_prior_ms": 1e3 * (tp1 - tp0),
            "sim_wall_s": sim["wall_s"],
        }
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
