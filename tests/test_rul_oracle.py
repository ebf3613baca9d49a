"""The RUL oracle (evaluation.rul_oracle): calibrated where it knows the law, and it
reproduces the truth it is built from."""

from __future__ import annotations

import json
import math

import numpy as np

from evaluation.rul_oracle import (
    OracleUnit,
    acceptance_units,
    drawn_fleet_truth,
    fleetsim_units,
    oracle_rul,
    score_oracle,
)

THR = 10.0


def _linear_unit(rng: np.random.Generator, i: int, cv: float) -> OracleUnit:
    """Linear wear in damage; damage per flight 1 x U(1 - a, 1 + a) with sd cv."""
    a = cv * math.sqrt(3.0)
    inc = rng.uniform(1 - a, 1 + a, 200)
    k = (THR - 1.0) / rng.uniform(15.0, 25.0)
    d = np.concatenate(([0.0], np.cumsum(inc)[:-1]))
    r = 1.0 + k * d
    j = int(np.flatnonzero(r >= THR)[0])
    eol = j + (THR - r[j - 1]) / (r[j] - r[j - 1])
    return OracleUnit(f"U{i}/a", "linear", inc, lambda x, k=k: 1.0 + k * x,
                      lambda g, s, a=a: g.uniform(1 - a, 1 + a, s), eol, j + 1)  # fmt: skip


def test_oracle_interval_holds_the_truth_at_its_nominal_rate():
    rng = np.random.default_rng(5)
    hits, n = 0, 0
    for i in range(300):
        u = _linear_unit(rng, i, cv=0.4)
        k = int(rng.integers(7, int(u.eol_flight) - 2))  # one prediction per unit: independent
        d = oracle_rul(u, k, THR, n=800, rng=rng)
        lo, hi = np.quantile(d, [0.05, 0.95])
        hits += lo <= u.eol_flight - (k + 1) <= hi
        n += 1
    assert 0.85 <= hits / n <= 0.95


def test_oracle_is_exact_when_the_future_is_known():
    rng = np.random.default_rng(1)
    u = _linear_unit(rng, 0, cv=0.0)  # every flight the same damage: nothing to guess
    for k in (7, 12, int(u.eol_flight) - 1):
        d = oracle_rul(u, k, THR, n=50)
        assert np.ptp(d) < 1e-9 and abs(d[0] - (u.eol_flight - k - 1)) < 1e-9
    ev = score_oracle([u], THR, n=50)
    assert ev["alpha_lambda_pct"] == 100.0 and ev["interval_coverage_pct"] == 100.0


def test_oracle_on_fleet_sim_truth_misses_only_load_wear():
    """Hours per flight vary +-20 %: the laws in hours are foretold, the knee too (the oracle
    knows it); the load and usage of the flights ahead are not."""
    thr = 11.0
    acc: dict[str, list[float]] = {}
    for seed in (1, 2, 3):
        truth = json.loads(json.dumps(drawn_fleet_truth(seed, thr=thr)))  # as a truth file
        assert truth["units"][0]["flown"] <= 30
        for law, v in score_oracle(fleetsim_units(truth), thr, n=500)["by_law"].items():
            acc.setdefault(law, []).append(v["alpha_lambda_pct"])
    for law in ("linear", "exponential", "power", "knee"):
        assert min(acc[law]) >= 90.0, (law, acc[law])
    assert np.mean(acc["load"] + acc["usage"]) < 95.0, acc


def test_acceptance_oracle_reproduces_the_truth_schedule():
    from tests.acceptance_fleet import LAWS, draw, increments, ratio_of

    for u in draw(7, 6, 14, THR):
        d = np.concatenate(([0.0], np.cumsum(increments(u))[:-1]))
        assert np.allclose(ratio_of(u, d, THR), u["ratio_schedule"], rtol=0, atol=1e-12)
    us = acceptance_units(7, 6, 14, THR)
    assert [u.law for u in us] == list(LAWS)
    assert "usage" in LAWS and "two_rate" in LAWS


def test_knee_unforeseen_oracle_predicts_the_first_rate_before_the_knee():
    thr = 11.0
    seen = {u.actuator: u for u in acceptance_units(101, 10, 30, thr)}
    blind = {u.actuator: u for u in acceptance_units(101, 10, 30, thr, knee_foreseen=False)}
    u = next(v for v in seen.values() if v.law == "two_rate")
    b = blind[u.actuator]
    assert b.law_at is not None and u.law_at is None
    # before the knee the blind oracle expects the slow rate to last: a longer RUL
    m_seen = np.median(oracle_rul(u, 7, thr, n=400))
    m_blind = np.median(oracle_rul(b, 7, thr, n=400))
    assert m_blind > 1.5 * m_seen
    # once past the knee both know it
    k = int(u.eol_flight) - 2
    assert np.median(oracle_rul(b, k, thr, n=400)) == np.median(oracle_rul(u, k, thr, n=400))
