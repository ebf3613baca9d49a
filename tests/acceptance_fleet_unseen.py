"""A second acceptance fleet for the RUL (issue 55), with wear laws that neither the RUL's
parametric family nor ``fleet-sim`` nor ``tests.acceptance_fleet`` has. Built before any
tuning of issue 55's trend and noise models and kept apart from them: nothing in the RUL is
tuned on it. It goes the user's path (``servowatch calibrate --log <flight 0>``, then
``servowatch replay <folder> --store S``, the logs written by
``tests.acceptance_fleet.write_logs``) and is scored with ``fleet-sim --evaluate``'s metrics.

Wear laws (true C_Lk ratio r against the unit's damage d, x = d / life, 1 at the end of life;
d is operating hours unless said otherwise):

- ``none``: 1 (healthy);
- ``transient``: healthy, but one flight (the 8th to the 24th) reads a leak of 1.4-2.5 times
  the baseline that clears at the next flight (a healthy unit's one-flight transient);
- ``wear_in``: a rate that falls, r = 1 + (thr - 1) (1 - exp(-c x)) / (1 - exp(-c)),
  c in [1.5, 3] (the rate falls 4.5-20 times over the life);
- ``two_knees``: three linear rates, each 2-4 times the one before, knees at x in
  [0.2, 0.4] and [0.55, 0.8];
- ``random_rate``: linear in a damage whose rate per operating hour is random per flight and
  persistent (log-rate an AR(1), coefficient 0.8, sd 0.5), seen by no usage figure;
- ``runin_doubling``: a running-in (1 + a (1 - exp(-x / 0.06)), a in [0.2, 0.6]), flat, then
  from x0 in [0.3, 0.5] a rate that doubles every 0.1-0.2 of the life.

Schedule: 0.5-3.5 h per flight (each flight x lognormal(0, 0.2)), 1 to 3 flights a day with a
quarter of the days missed, 1.5-3 s of log per flight, sensor noise x[0.7, 1.5], an operator's
load x[0.75, 1.25] and amplitude x[0.85, 1.15], each flight's x[0.75, 1.25] about them; the
end of life at 0.45-0.95 of the damage of the flights flown, so most units are scored.

    .venv/bin/python -m tests.acceptance_fleet_unseen --seed 501 --units 12 --flights 30 --work u501
    .venv/bin/python -m tests.acceptance_fleet_unseen --seed 501 --work u501 --score-only --json
    .venv/bin/python -m tests.acceptance_fleet_unseen --seed 501 --oracle --json   # the oracle

``--build-only`` writes the logs, the store and the truth without scoring.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

LAWS = ("none", "transient", "wear_in", "two_knees", "random_rate", "runin_doubling")
HEALTHY_LAWS = ("none", "transient")
AR_PHI, AR_SD = 0.8, 0.5


def _ar_rates(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-flight rate factors exp(s z_k - s^2 / 2), z an AR(1) of unit variance; and z."""
    z = np.empty(n)
    z[0] = rng.standard_normal()
    e = rng.standard_normal(n) * math.sqrt(1 - AR_PHI**2)
    for k in range(1, n):
        z[k] = AR_PHI * z[k - 1] + e[k]
    return np.exp(AR_SD * z - 0.5 * AR_SD**2), z


def ratio_of(u: dict, d: float | np.ndarray, thr: float) -> np.ndarray:
    """True ratio of unit ``u`` at damage ``d`` (the law of the module docstring)."""
    p, law = u["params"], u["law"]
    x = np.asarray(d, float) / p["life"]
    if law in ("none", "transient"):
        return np.ones_like(x)
    if law == "wear_in":
        c = p["c"]
        return 1 + (thr - 1) * -np.expm1(-c * x) / -math.expm1(-c)
    if law == "two_knees":
        k1, k2, m1, m2 = p["k1"], p["k2"], p["m1"], p["m2"]
        tot = k1 + m1 * (k2 - k1) + m1 * m2 * (1 - k2)
        s = (np.minimum(x, k1) + m1 * np.clip(x - k1, 0, k2 - k1)
             + m1 * m2 * np.maximum(x - k2, 0))  # fmt: skip
        return 1 + (thr - 1) * s / tot
    if law == "random_rate":
        return 1 + (thr - 1) * x
    # runin_doubling
    a, x0, g = p["a"], p["x0"], p["g"]
    c = (thr - 1 - a * -math.expm1(-1 / 0.06)) / math.expm1(g * (1 - x0))
    return 1 + a * -np.expm1(-x / 0.06) + c * np.expm1(g * np.maximum(x - x0, 0.0))


def draw(seed: int, units: int, flights: int, thr: float) -> list[dict]:
    """The hidden truth (the format of ``tests.acceptance_fleet.draw``: what its
    ``write_logs`` reads, and ``eol_flight`` on the flights axis, flight k at k + 1)."""
    rng = np.random.default_rng([seed, 55])
    out = []
    n = 5 * flights
    for i in range(units):
        law = LAWS[i % len(LAWS)]
        base_h = rng.uniform(0.5, 3.5)
        hours = base_h * rng.lognormal(0.0, 0.2, n)
        p_load, p_amp = rng.uniform(0.75, 1.25), rng.uniform(0.85, 1.15)
        load = p_load * rng.uniform(0.75, 1.25, n)
        amp = p_amp * rng.uniform(0.75, 1.25, n)
        load[0] = amp[0] = 1.0  # flight 0: the calibration run
        rate, z = _ar_rates(rng, n)
        inc = hours * rate if law == "random_rate" else hours
        d = np.concatenate(([0.0], np.cumsum(inc)[:-1]))  # damage at each flight's reading
        par: dict[str, float] = {"life": rng.uniform(0.45, 0.95) * float(np.sum(inc[:flights]))}
        if law == "transient":
            par.update(at=float(rng.integers(8, 25)), size=rng.uniform(1.4, 2.5))
        elif law == "wear_in":
            par["c"] = rng.uniform(1.5, 3.0)
        elif law == "two_knees":
            par.update(k1=rng.uniform(0.2, 0.4), k2=rng.uniform(0.55, 0.8),
                       m1=rng.uniform(2.0, 4.0), m2=rng.uniform(2.0, 4.0))  # fmt: skip
        elif law == "runin_doubling":
            par.update(a=rng.uniform(0.2, 0.6), x0=rng.uniform(0.3, 0.5),
                       g=math.log(2.0) / rng.uniform(0.1, 0.2))  # fmt: skip
        u = {"law": law, "params": {k: float(v) for k, v in par.items()}}
        r = ratio_of(u, d, thr)
        if law == "transient":
            r = r.copy()
            r[int(par["at"])] = par["size"]
        per_day = int(rng.integers(1, 4))
        starts, day = [], 0
        while len(starts) < n:
            if rng.uniform() >= 0.25:
                starts += [1.76e9 + 86400.0 * day + 7200.0 * j for j in range(per_day)]
            day += 1
        above = np.flatnonzero(r >= thr)
        eol = math.inf
        if law not in HEALTHY_LAWS and len(above) and above[0] > 0:
            j = int(above[0])
            eol = j + (thr - r[j - 1]) / (r[j] - r[j - 1])
        out.append({
            "actuator": f"UNS{seed % 1000:03d}{i:02d}/flap", "index": i, "law": law,
            "ratio_schedule": r.tolist(), "start_unix": starts[:n], "eol_flight": eol,
            "noise": float(rng.uniform(0.7, 1.5)), "load": float(p_load), "amp": float(p_amp),
            "flight_load": load.tolist(), "flight_amp": amp.tolist(),
            "log_s": float(rng.uniform(1.5, 3.0)), "base_h": float(base_h),
            "hours": hours.tolist(), "rate": rate.tolist(), "z": z.tolist(),
            "increments": inc.tolist(), "params": u["params"],
        })  # fmt: skip
    return out


def build(seed: int, units: int, flights: int, work: Path) -> None:
    """Logs, commissioning and ingest through the CLI; the truth to ``work/truth.json``."""
    from service.cli import main
    from service.prognostics.rul import default_threshold_ratio
    from tests.acceptance_fleet import write_logs

    thr = default_threshold_ratio()
    truth = draw(seed, units, flights, thr)
    logs = work / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    write_logs(truth, flights, thr, logs, seed + 55_000)
    store = work / "acceptance.sqlite"
    for u in truth:
        ac, act = u["actuator"].split("/")
        f0 = logs / f"{ac}_{act}_000.mcap"
        if main(["calibrate", "--log", str(f0), "--store", str(store), "--json"]) != 0:
            raise RuntimeError(f"calibrate failed on {f0}")
    if main(["replay", str(logs), "--store", str(store), "--json"]) != 0:
        raise RuntimeError("replay failed")
    tr = {"seed": seed, "threshold_ratio": thr, "flights": flights, "generator": "unseen",
          "units": [{k: v for k, v in u.items() if k != "ratio_schedule"} for u in truth]}  # fmt: skip
    (work / "truth.json").write_text(json.dumps(tr, default=float) + "\n")


def oracle_units(seed: int, units: int, flights: int, thr: float) -> list:
    """The oracle's view (``evaluation.rul_oracle.OracleUnit``): it knows the law, its
    parameters and the damage so far; the flights ahead are drawn from their distribution
    (hours: the unit's base x lognormal(0, 0.2); ``random_rate``: the AR(1) continued from
    the last flight's state). It knows a knee or the doubling's start ahead."""
    from evaluation.rul_oracle import OracleUnit

    out = []
    for u in draw(seed, units, flights, thr):
        r = np.asarray(u["ratio_schedule"][:flights])
        above = np.flatnonzero(r >= thr)
        flown = int(above[0]) + 1 if len(above) else flights
        inc = np.asarray(u["increments"], float)

        def future(rng, shape, u=u, flown=flown):
            h = u["base_h"] * rng.lognormal(0.0, 0.2, shape)
            if u["law"] != "random_rate":
                return h
            # the AR(1) from the state of the unit's latest flight (the oracle's knowledge)
            zs = np.asarray(u["z"], float)
            z = np.full(shape[0], zs[min(flown, len(zs)) - 1])
            out = np.empty(shape)
            for j in range(shape[1]):
                z = AR_PHI * z + math.sqrt(1 - AR_PHI**2) * rng.standard_normal(shape[0])
                out[:, j] = h[:, j] * np.exp(AR_SD * z - 0.5 * AR_SD**2)
            return out

        def ratio(d, u=u):
            return ratio_of(u, d, thr)

        out.append(OracleUnit(u["actuator"], u["law"], inc, ratio, future,
                              float(u["eol_flight"]), flown))  # fmt: skip
    return out


def score(work: Path, robust_trend: bool = False) -> dict:
    """``fleet-sim --evaluate``'s metrics on the store and truth in ``work``, with the healthy
    laws' (none, transient) largest crossing probability each (``robust_trend``: the RUL's
    opt-in trend model and Student-t readings)."""
    from tests.acceptance_fleet import score as acc_score

    ev = acc_score(work, robust_trend)
    tr = json.loads((work / "truth.json").read_text())
    law = {u["actuator"]: u["law"] for u in tr["units"]}
    ev["healthy_max_p_by_law"] = {
        lw: max((r.get("max_p_horizon") or 0.0 for r in ev["units"] if law[r["actuator"]] == lw),
                default=None)
        for lw in HEALTHY_LAWS
    }  # fmt: skip
    return ev


def main_cli() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=501)
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument("--flights", type=int, default=30)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--work", default=None, metavar="DIR", help="logs, store and truth")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--build-only", action="store_true", help="build, do not score")
    g.add_argument("--score-only", action="store_true", help="score the store kept in --work")
    g.add_argument("--oracle", action="store_true", help="the oracle's scores (no logs)")
    ap.add_argument("--robust-trend", action="store_true",
                    help="the RUL's opt-in trend model and Student-t readings")  # fmt: skip
    a = ap.parse_args()
    import contextlib
    import io

    if a.oracle:
        from evaluation.rul_oracle import score_oracle
        from service.prognostics.rul import default_threshold_ratio

        thr = default_threshold_ratio()
        ev = score_oracle(oracle_units(a.seed, a.units, a.flights, thr), thr)
        ev.pop("units", None)
        print(json.dumps(ev) if a.json else ev)
        return 0
    if a.work is None:
        ap.error("--work DIR is needed")
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    with contextlib.redirect_stdout(io.StringIO()):
        if not a.score_only:
            build(a.seed, a.units, a.flights, work)
        if a.build_only:
            return 0
        ev = score(work, a.robust_trend)
    keys = ("alpha_lambda_pct", "interval_coverage_pct", "interval_coverage_all_pct",
            "interval_width_median_flights", "kendall_tau", "kendall_tau_min",
            "kendall_tau_mid", "healthy_max_p_horizon", "healthy_max_p_by_law",
            "relative_accuracy_pct", "scored_units", "healthy_units")  # fmt: skip
    if a.json:
        print(json.dumps({k: ev.get(k) for k in (*keys, "by_law", "fleet")}, default=str))
    else:
        for k in keys:
            print(f"{k:<28} {ev.get(k)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main_cli())
