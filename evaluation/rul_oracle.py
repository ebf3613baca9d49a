"""How far the RUL targets are reachable: an oracle predictor on the same fleets (issue 31).

The oracle knows each unit's true wear law and its parameters, the damage done so far
(operating hours, load-weighted hours, actuator cycles: the truth's own increments) and the
distribution of the per-flight factors ahead (hours per flight, load, cycles), but not their
values. Its RUL after flight k is the Monte-Carlo distribution of the first crossing of the
threshold over draws of the flights ahead, on the life axis of ``fleet-sim --evaluate``
(flight k at k + 1, the crossing interpolated between two flights). Its median and 90 %
interval are scored like the RUL (``metrics.score_unit``; coverage from mid-life), at the same
flights (from the ``min_history``-th on, before the end of life).

What the oracle misses is unpredictable by construction: no predictor that sees only the past
can do better on average. It knows a knee ahead (it knows the law), which the RUL, seeing only
the indicator, cannot; ``--knee-unforeseen`` gives it only the first rate until the knee.

    .venv/bin/python -m evaluation.rul_oracle --truth t33.json --json
    .venv/bin/python -m evaluation.rul_oracle --acceptance 101 --units 10 --flights 30
    .venv/bin/python -m evaluation.rul_oracle --acceptance 101 --knee-unforeseen
    .venv/bin/python -m evaluation.rul_oracle --drawn 1-30      # fleet-sim truths, no logs

The future factors: ``fleet-sim`` hours per flight = the unit's mean x U(0.8, 1.2) (the mean
of ``draw_units``, drawn again from the truth's seed), load = the operator's mean load x
U(0.65, 1.35) (``load`` law: wear per flight hours x load^2), amplitude = the operator's mean
x U(0.75, 1.25) (``usage`` law: wear per flight hours x load x amplitude, the load-weighted
travel); the ``knee`` law is known with its knee. The acceptance fleet's hours = the unit's
base x U(0.7, 1.3), cycles U(0.3, 2.0), load and amplitude about the unit's profile
(``tests.acceptance_fleet.draw``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from service.prognostics.metrics import LAMBDAS, score_unit

__all__ = [
    "OracleUnit",
    "oracle_rul",
    "score_oracle",
    "fleetsim_units",
    "acceptance_units",
    "drawn_fleet_truth",
]

Sampler = Callable[[np.random.Generator, tuple[int, int]], np.ndarray]


@dataclass(frozen=True)
class OracleUnit:
    """One unit as the oracle sees it: the true damage increment of each flight of the
    schedule ``inc`` (flight i adds inc[i] after its reading), the true ratio at a damage
    ``ratio(d)`` (vectorised), draws of future increments ``future(rng, shape)``, the true end
    of life on the flights axis and the flights flown."""

    actuator: str
    law: str
    inc: np.ndarray
    ratio: Callable[[np.ndarray], np.ndarray]
    future: Sampler
    eol_flight: float
    flown: int
    law_at: Callable[[float], Callable[[np.ndarray], np.ndarray]] | None = None
    """The law as the predictor may know it at a damage (None: ``ratio`` throughout); a law
    that changes ahead without a precursor (a knee) is known only once passed."""


def oracle_rul(
    u: OracleUnit,
    k: int,
    thr: float,
    n: int = 2000,
    ahead: int = 200,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Draws of the RUL [flights] after flight ``k`` (life axis: flight k at k + 1; inf: no
    crossing within ``ahead`` flights)."""
    rng = rng or np.random.default_rng(0)
    d_now = float(np.sum(u.inc[:k]))  # damage at flight k's reading (x = k + 1)
    d_next = d_now + float(u.inc[k])  # flight k flown: its increment is known
    steps = u.future(rng, (n, ahead - 1))
    d = np.concatenate(
        [np.full((n, 1), d_now), np.full((n, 1), d_next), d_next + np.cumsum(steps, axis=1)],
        axis=1,
    )  # column j at x = k + 1 + j
    r = (u.law_at(d_now) if u.law_at is not None else u.ratio)(d)
    r[:, 0] = u.ratio(np.array([d_now]))[0]  # the reading now is seen, not predicted
    above = r >= thr
    hit = above.any(axis=1)
    c = np.argmax(above, axis=1)
    rul = np.full(n, np.inf)
    at0 = hit & (c == 0)
    rul[at0] = 0.0
    m = hit & (c > 0)
    rows = np.flatnonzero(m)
    r0, r1 = r[rows, c[m] - 1], r[rows, c[m]]
    f = np.where(r1 > r0, (thr - r0) / np.where(r1 > r0, r1 - r0, 1.0), 1.0)
    rul[m] = (c[m] - 1) + f
    return rul


def score_oracle(
    units: Sequence[OracleUnit],
    thr: float,
    min_history: int = 8,
    n: int = 2000,
    seed: int = 0,
) -> dict:
    """The oracle's alpha-lambda (+-20 %), relative accuracy at lambda 0.5 and 90 % interval
    coverage from mid-life, over the units that reach their end of life within the flights
    flown (``fleet-sim --evaluate``'s selection), overall and per law."""
    rng = np.random.default_rng(seed)
    by_law: dict[str, dict[str, list]] = {}
    rows = []
    ckpt: dict[float, list[tuple]] = {}  # per checkpoint: (unit, t_now, median, true RUL)
    t_first: dict[str, float] = {}
    eol_of: dict[str, float] = {}
    for u in units:
        if u.law == "none" or not (u.eol_flight <= u.flown + 1):
            continue
        t, med, lo, hi = [], [], [], []
        for k in range(min_history - 1, u.flown):
            if k + 1 >= u.eol_flight:
                break
            d = oracle_rul(u, k, thr, n, rng=rng)
            q = np.quantile(d, [0.05, 0.5, 0.95])
            t.append(k + 1.0)
            lo.append(float(q[0]))
            med.append(float(q[1]))
            hi.append(float(q[2]))
        if not t:
            continue
        eol = u.eol_flight
        for i in range(len(t)):
            ckpt.setdefault(t[i], []).append((u.actuator, t[i], med[i], eol - t[i]))
        t_first[u.actuator], eol_of[u.actuator] = t[0], eol
        s = score_unit(t, med, eol)
        t_s = t[0]
        tol = 1e-9 * eol  # a crossing between two known readings is exact: no rounding miss
        mid = [i for i in range(len(t)) if t[i] >= t_s + 0.5 * (eol - t_s)]
        cov = [lo[i] - tol <= eol - t[i] <= hi[i] + tol for i in mid]
        b = by_law.setdefault(u.law, {"acc": [], "ra": [], "cov": [], "width": []})
        b["width"].extend(hi[i] - lo[i] for i in mid)
        b["acc"].extend(s.accurate)
        b["ra"].append(max(s.relative_accuracy[0], 0.0))
        b["cov"].extend(cov)
        rows.append({"actuator": u.actuator, "law": u.law, "eol_flight": eol,
                     "accurate": list(s.accurate)})  # fmt: skip

    def pct(v: list) -> float | None:
        return 100.0 * float(np.mean(v)) if v else None

    every = {k: [x for b in by_law.values() for x in b[k]]
             for k in ("acc", "ra", "cov", "width")}  # fmt: skip

    def med(v: list) -> float | None:
        return float(np.median(v)) if v else None

    # Kendall's tau of the scored units' order at each checkpoint (``fleet-sim``'s, over the
    # units that reach their end of life), and from mid-life (the coverage's checkpoints)
    from service.replay.fleetsim import kendall_tau, mid_life_taus

    cks = [ckpt[k] for k in sorted(ckpt)]
    taus = [x for row in cks
            if (x := kendall_tau([r[2] for r in row], [r[3] for r in row])) is not None]  # fmt: skip
    taus_mid = mid_life_taus(cks, t_first, eol_of)

    return {
        "alpha_lambda_pct": pct(every["acc"]),
        "relative_accuracy_pct": pct(every["ra"]),
        "interval_coverage_pct": pct(every["cov"]),
        "interval_width_median_flights": med(every["width"]),
        "scored_units": len(rows),
        "kendall_tau": float(np.mean(taus)) if taus else None,
        "kendall_tau_mid": float(np.mean(taus_mid)) if taus_mid else None,
        "by_law": {
            law: {
                "units": len(b["ra"]),
                "alpha_lambda_pct": pct(b["acc"]),
                "interval_coverage_pct": pct(b["cov"]),
                "interval_width_median_flights": med(b["width"]),
            }  # fmt: skip
            for law, b in by_law.items()
        },
        "lambdas": list(LAMBDAS),
        "units": rows,
    }


def _fleetsim_ratio(law: str, w: dict) -> Callable[[np.ndarray], np.ndarray]:
    def ratio(d: np.ndarray) -> np.ndarray:
        if law in ("linear", "load", "usage"):
            return 1.0 + w["k"] * d
        if law == "knee":
            dk = w["d_k"]
            return 1.0 + w["k"] * np.minimum(d, dk) + w["m"] * w["k"] * np.maximum(d - dk, 0.0)
        if law == "exponential":
            return 1.0 + w["a"] * np.expm1(w["b"] * d)
        if law == "power":
            return 1.0 + w["k"] * d ** w["p"]
        if law == "step":
            return np.where(d < w["t_s"], 1.0, 1.0 + w["s"] + w["k"] * (d - w["t_s"]))
        return np.ones_like(d)

    return ratio


def fleetsim_units(truth: dict) -> list[OracleUnit]:
    """The oracle's view of a ``fleet-sim --truth`` file's units."""
    from service.replay.fleetsim import FleetSimConfig, draw_units

    units = truth["units"]
    n_sched = len(units[0]["flight_hours"])
    again = draw_units(FleetSimConfig(actuators=len(units), flights=n_sched // 4,
                                      seed=int(truth["seed"]),
                                      threshold_ratio=float(truth["threshold_ratio"])))  # fmt: skip
    out = []
    for u, a in zip(units, again, strict=True):
        law = u["law"]
        h = np.asarray(u["flight_hours"], float)
        if a.actuator != u["actuator"] or not np.array_equal(a.flight_hours, h):
            raise ValueError(f"truth of {u['actuator']} is not fleet-sim's draw of its seed")
        inc = a.increments()
        hpf = a.usage_h
        prof = a.profile

        def future(rng, shape, hpf=hpf, law=law, prof=prof):
            x = hpf * rng.uniform(0.8, 1.2, shape)
            if law == "load":
                return x * (prof["load"] * rng.uniform(0.65, 1.35, shape)) ** 2
            if law == "usage":
                return (x * prof["load"] * rng.uniform(0.65, 1.35, shape)
                        * prof["amp"] * rng.uniform(0.75, 1.25, shape))  # fmt: skip
            return x

        eol = u["eol_flight"]
        out.append(OracleUnit(u["actuator"], law, inc, _fleetsim_ratio(law, u["wear"]), future,
                              math.inf if eol is None else float(eol), int(u["flown"])))  # fmt: skip
    return out


def drawn_fleet_truth(
    seed: int, actuators: int = 12, flights: int = 30, thr: float | None = None
) -> dict:
    """A ``fleet-sim --truth`` object of ``draw_units`` alone (no logs, no ingest): each unit
    flown up to the flight that reaches the threshold, as ``simulate_unit`` does."""
    from dataclasses import asdict

    from service.replay.fleetsim import FleetSimConfig, draw_units

    cfg = FleetSimConfig(actuators=actuators, flights=flights, seed=seed, threshold_ratio=thr)
    units = []
    for u in draw_units(cfg):
        r = u.ratios()[:flights]
        above = np.flatnonzero(r >= cfg.threshold())
        units.append({**asdict(u), "flown": int(above[0]) + 1 if len(above) else flights})
    return {"seed": seed, "threshold_ratio": cfg.threshold(), "units": units}


def acceptance_units(
    seed: int, units: int, flights: int, thr: float, knee_foreseen: bool = True
) -> list[OracleUnit]:
    """The oracle's view of the acceptance fleet (``tests.acceptance_fleet.draw``; the
    flights flown: up to the one reaching the threshold). ``knee_foreseen`` False: before a
    two-rate unit's knee the oracle knows only the first rate (the knee has no precursor)."""
    from tests.acceptance_fleet import draw, increments, ratio_of

    out = []
    for u in draw(seed, units, flights, thr):
        cyc = u["law"] == "cycles"
        inc = increments(u)
        r = np.asarray(u["ratio_schedule"][:flights])
        above = np.flatnonzero(r >= thr)
        flown = int(above[0]) + 1 if len(above) else flights

        def future(rng, shape, cyc=cyc, base=u["base_h"], u=u):
            if cyc:
                return rng.uniform(0.3, 2.0, shape)
            x = base * rng.uniform(0.7, 1.3, shape)
            if u["law"] == "usage":
                x = (x * u["load"] * rng.uniform(0.7, 1.3, shape)
                     * u["amp"] * rng.uniform(0.7, 1.3, shape))  # fmt: skip
            return x

        def ratio(d, u=u):
            return ratio_of(u, d, thr)

        law_at = None
        if u["law"] == "two_rate" and not knee_foreseen:
            p = u["params"]
            knee_d = p["knee"] * p["life"]
            at = p["knee"] / (p["knee"] + p["k"] * (1 - p["knee"]))

            def law_at(d_now, ratio=ratio, knee_d=knee_d, at=at, life=p["life"]):
                if d_now >= knee_d:
                    return ratio
                return lambda d: 1 + (thr - 1) * at * np.asarray(d, float) / knee_d

        out.append(OracleUnit(u["actuator"], u["law"], inc, ratio, future,
                              float(u["eol_flight"]), flown, law_at))  # fmt: skip
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--truth", help="a fleet-sim --truth file")
    g.add_argument("--acceptance", type=int, metavar="SEED", help="the acceptance fleet's seed")
    g.add_argument(
        "--drawn", metavar="A-B",
        help="fleet-sim seeds A..B drawn without logs (12 units, 30 flights): per seed and mean",
    )  # fmt: skip
    ap.add_argument("--units", type=int, default=10, help="acceptance fleet units (default 10)")
    ap.add_argument("--flights", type=int, default=30, help="acceptance fleet flights (30)")
    ap.add_argument("--draws", type=int, default=2000, help="Monte-Carlo draws per prediction")
    ap.add_argument(
        "--knee-unforeseen", action="store_true",
        help="acceptance fleet: the two-rate knee unknown to the oracle until passed",
    )  # fmt: skip
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    from service.prognostics.rul import default_threshold_ratio

    if a.drawn:
        lo, _, hi = a.drawn.partition("-")
        per = []
        for sd in range(int(lo), int(hi or lo) + 1):
            tr = drawn_fleet_truth(sd)
            ev = score_oracle(fleetsim_units(tr), tr["threshold_ratio"], n=a.draws)
            per.append((sd, ev["alpha_lambda_pct"], ev["interval_coverage_pct"]))
        al = [x[1] for x in per if x[1] is not None]
        cv = [x[2] for x in per if x[2] is not None]
        out = {"seeds": [x[0] for x in per], "alpha_lambda_pct": [x[1] for x in per],
               "interval_coverage_pct": [x[2] for x in per],
               "mean_alpha_lambda_pct": float(np.mean(al)), "min_alpha_lambda_pct": min(al),
               "mean_interval_coverage_pct": float(np.mean(cv)),
               "min_interval_coverage_pct": min(cv)}  # fmt: skip
        if a.json:
            print(json.dumps(out))
        else:
            for sd, x, c in per:
                print(f"seed {sd:<4} alpha-lambda {x:5.1f} %  coverage {c:5.1f} %")
            print(f"mean alpha-lambda {out['mean_alpha_lambda_pct']:.1f} % (min {min(al):.1f}), "
                  f"coverage {out['mean_interval_coverage_pct']:.1f} % (min {min(cv):.1f})")  # fmt: skip
        return 0
    if a.truth:
        with open(a.truth) as f:
            tr = json.load(f)
        thr = float(tr["threshold_ratio"])
        us = fleetsim_units(tr)
    else:
        thr = default_threshold_ratio()
        us = acceptance_units(a.acceptance, a.units, a.flights, thr, not a.knee_unforeseen)
    ev = score_oracle(us, thr, n=a.draws)
    if a.json:
        print(json.dumps({k: v for k, v in ev.items() if k != "units"}))
        return 0
    for k in (
        "alpha_lambda_pct",
        "relative_accuracy_pct",
        "interval_coverage_pct",
        "interval_width_median_flights",
    ):
        print(f"{k:<24} {ev[k]:.1f}" if ev[k] is not None else f"{k:<24} -")
    for law, v in ev["by_law"].items():
        al, cv = v["alpha_lambda_pct"], v["interval_coverage_pct"]
        print(f"  {law:<14} units {v['units']}, alpha-lambda {al:.0f} %, coverage "
              + (f"{cv:.0f} %" if cv is not None else "-"))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
