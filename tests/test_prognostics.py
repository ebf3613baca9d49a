"""Prognostics: failure threshold, PHM metrics on hand-computed cases, degradation fits on
synthetic histories, the period accumulator, and RUL through the real (SQLite) store."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from models.params import EHAParams
from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS
from service.prognostics.degradation import (
    FleetPrior,
    fit_history,
    learn_fleet_prior,
    noise_sigma,
    sample_crossing,
)
from service.prognostics.indicators import PeriodAccumulator, PeriodConfig
from service.prognostics.metrics import score_unit
from service.prognostics.rul import RulConfig, compute_rul, history_of, rul_of_history
from service.prognostics.threshold import leak_threshold, static_error
from service.store import Period, open_store

C0 = 2e-13


# -- threshold ---------------------------------------------------------------------------
def test_threshold_holds_rated_load_exactly_at_tolerance():
    thr = leak_threshold()
    p = EHAParams()
    assert thr.load_n == pytest.approx(2.0 / 3.0 * p.area * p.p_sr)
    # at the threshold the static error equals the tolerance; below it, it is smaller
    assert static_error(thr.c_lk_fail, thr.load_n) == pytest.approx(thr.tolerance_m, rel=1e-6)
    assert static_error(0.5 * thr.c_lk_fail, thr.load_n) < thr.tolerance_m
    assert thr.e_ss_nominal_m < thr.tolerance_m
    assert thr.ratio == pytest.approx(thr.c_lk_fail / p.c_lk)
    # a looser tolerance tolerates more leakage
    assert (
        leak_threshold(tolerance_m=2e-3).ratio
        > thr.ratio
        > leak_threshold(tolerance_m=0.75e-3).ratio
    )
    with pytest.raises(ValueError):
        leak_threshold(tolerance_m=0.1e-3)  # the healthy unit already misses it


def test_static_error_matches_the_linear_null_law_at_light_load():
    # near null the HF valve obeys P12 (1/G_PQ,t + C_Lk) = K_q x_S with the tangent gains;
    # doubling the leak from nominal raises e_ss by C_Lk P12 / (K_q K_sv k_p)
    p = EHAParams()
    f = 500.0
    e1, e2 = static_error(p.c_lk, f), static_error(2 * p.c_lk, f)
    x1, x2 = e1 * p.k_sv * p.k_p, e2 * p.k_sv * p.k_p
    k_q = (f / p.area) * p.c_lk / (x2 - x1)  # flow gain implied by the increase
    p12 = f / p.area
    inv_g = x1 * k_q / p12 - p.c_lk  # implied flow-pressure coefficient without the leak
    g_lam = p.w_eff * p.c_r**3 / (12 * p.mu * p.l_min)  # laminar land clearance flow
    assert inv_g == pytest.approx(1.0 / p.g_pq + g_lam, rel=0.03)  # docs/estimation.md
    assert k_q == pytest.approx(2 * p.g_q, rel=0.05)  # K_q = 2 G_Q (docs/estimation.md)


# -- metrics -----------------------------------------------------------------------------
def test_metrics_hand_computed():
    # EOL at 100 h, predictions every 10 h from t_s = 0
    t = np.arange(0.0, 100.0, 10.0)
    true = 100.0 - t
    rul = true.copy()
    rul[5] = true[5] * 1.25  # t = 50 (lambda 0.5): 25 % off -> not accurate, RA 0.75
    rul[7] = true[7] * 0.85  # t = 70 (lambda 0.7): 15 % off -> accurate, RA 0.85
    rul[2] = true[2] + 30.0  # t = 20: outside the +-20 h band (alpha * life)
    s = score_unit(t, rul, 100.0, alpha=0.2)
    assert s.accurate == (False, True, True, True, True)
    assert s.relative_accuracy[0] == pytest.approx(0.75)
    assert s.relative_accuracy[2] == pytest.approx(0.85)
    # band +-20 h: t=20 (+30) is out, t=50 (+12.5) and t=70 (-4.5) in -> PH from t = 30
    assert s.horizon == pytest.approx(70.0)
    assert s.horizon_frac == pytest.approx(0.7)


def test_metrics_lambda_uses_latest_prediction_and_inf_is_inaccurate():
    t = np.array([10.0, 30.0, 60.0, 80.0])
    rul = np.array([math.inf, 70.0, 40.0, 20.0])  # EOL 100, t_s = 10, life 90
    s = score_unit(t, rul, 100.0)
    # lambda 0.5 -> t 55 -> prediction at 30 (true 70): exact
    assert s.accurate[0] and s.relative_accuracy[0] == pytest.approx(1.0)
    s2 = score_unit(t[:1], rul[:1], 100.0)
    assert not any(s2.accurate) and s2.relative_accuracy[0] == -math.inf and s2.horizon == 0.0


# -- degradation fits --------------------------------------------------------------------
def _hist(law: str, n: int = 40, sigma: float = 0.02, seed: int = 3):
    rng = np.random.default_rng(seed)
    t = np.arange(1, n + 1) * 2.0
    y = {
        "none": np.ones_like(t),
        "linear": 1.0 + 0.05 * t,
        "exponential": 1.0 + 0.02 * np.expm1(0.025 * t) / 0.025,
        "step": np.where(t > 40.0, 1.8 + 0.05 * (t - 40.0), 1.0),
    }[law]
    return t, y + sigma * rng.standard_normal(n)


@pytest.mark.parametrize("law", ["none", "linear", "exponential", "step"])
def test_fit_selects_the_generating_model(law):
    t, y = _hist(law)
    fit = fit_history(t, y)
    assert fit.best() == law
    assert fit.p_model[law] > 0.8


def test_fit_recovers_parameters():
    # weights and rates are per unit of u = t / t_scale (the history's span by default)
    t, y = _hist("linear")
    f = fit_history(t, y)
    assert f.t_scale == pytest.approx(t[-1])
    g = int(np.argmax(f.post["linear"]))
    a, b = f.means["linear"][g]
    b = b / f.t_scale
    assert a == pytest.approx(1.0, abs=0.03) and b == pytest.approx(0.05, rel=0.03)
    assert f.sigma == pytest.approx(0.02, rel=0.35)
    t, y = _hist("exponential")
    f = fit_history(t, y)
    beta = f.grids["exponential"][int(np.argmax(f.post["exponential"]))] / f.t_scale
    assert beta == pytest.approx(0.025, rel=0.3)
    t, y = _hist("step")
    f = fit_history(t, y)
    g = int(np.argmax(f.post["step"]))
    tau = f.grids["step"][g] * f.t_scale
    assert 38.0 <= tau <= 42.0
    assert f.means["step"][g][1] == pytest.approx(0.8, abs=0.08)
    assert f.means["step"][g][2] / f.t_scale == pytest.approx(0.05, rel=0.1)


def test_rul_median_matches_the_analytic_crossing():
    thr = 11.0
    t, y = _hist("linear", sigma=0.01)
    cross = sample_crossing(fit_history(t, y), thr, 4000, np.random.default_rng(1))
    true = (thr - 1.0) / 0.05
    assert np.median(cross) == pytest.approx(true, rel=0.03)
    lo, hi = np.quantile(cross, [0.05, 0.95])
    assert lo < true < hi
    t, y = _hist("exponential", sigma=0.01)
    cross = sample_crossing(fit_history(t, y), thr, 4000, np.random.default_rng(1))
    true = math.log1p(0.025 * (thr - 1.0) / 0.02) / 0.025
    assert np.median(cross) == pytest.approx(true, rel=0.05)
    # no wear: almost every draw never crosses
    t, y = _hist("none")
    assert np.mean(np.isinf(sample_crossing(fit_history(t, y), thr, 2000))) > 0.95


def test_noise_sigma_ignores_trend_and_single_step():
    rng = np.random.default_rng(0)
    t = np.arange(200.0)
    y = 1 + 0.05 * t + np.where(t > 100, 2.0, 0.0) + 0.03 * rng.standard_normal(200)
    assert noise_sigma(y) == pytest.approx(0.03, rel=0.15)


def test_fleet_prior_learns_model_mix_and_rates():
    hist = []
    for i in range(6):
        rng = np.random.default_rng(i)
        t = np.arange(1, 31) * 2.0
        rate = 0.04 + 0.01 * i
        hist.append((t, 1 + rate * t + 0.02 * rng.standard_normal(30)))
    for i in range(3):
        t = np.arange(1, 31) * 2.0
        hist.append((t, 1 + 0.02 * np.random.default_rng(10 + i).standard_normal(30)))
    pr = learn_fleet_prior(hist)
    assert pr.units == 9
    # expected counts: each unit's posterior over the models, + 1 (Dirichlet) of 9 + 7; the
    # linear units share some of theirs with the curved models that also fit a straight path
    assert max(pr.p_model, key=pr.p_model.__getitem__) == "linear"
    assert 4.5 / 16 < pr.p_model["linear"] <= 7 / 16
    assert pr.p_model["none"] == pytest.approx(4 / 16, abs=0.01)
    assert sum(pr.p_model.values()) == pytest.approx(1.0)
    assert pr.t_scale == pytest.approx(60.0)  # the median span; weights per unit of t / t_scale
    assert pr.weights["linear"].mean[1] / pr.t_scale == pytest.approx(0.065, rel=0.1)
    assert pr.sigma == pytest.approx(0.02, rel=0.35)


# -- period accumulator ------------------------------------------------------------------
def _rows(t, c_lk, c_sig=0.1 * C0, alarm=None, p_sr=20e6):
    n = len(t)
    est = np.zeros((n, len(EST_KEYS)))
    est[:, EST_KEYS.index("c_lk")] = c_lk
    est[:, EST_KEYS.index("c_lk_sigma")] = c_sig
    est[:, EST_KEYS.index("p_sr")] = p_sr
    est[:, EST_KEYS.index("i_b")] = 1e-6
    health = np.zeros((n, len(HEALTH_KEYS)))
    health[:, HEALTH_KEYS.index("leak_ratio")] = np.asarray(c_lk) / C0
    if alarm is not None:
        health[:, HEALTH_KEYS.index("alarm_leak")] = alarm
    res = np.zeros((n, len(RES_KEYS)))
    res[:, RES_KEYS.index("nis")] = 4.0
    res[:, RES_KEYS.index("nis_dof")] = 4.0
    return est, health, res


def _acc(cfg=None):
    return PeriodAccumulator("AC1/elev_L", C0, "test", EST_KEYS, HEALTH_KEYS, RES_KEYS, cfg)


def test_accumulator_cuts_on_silence_and_window():
    cfg = PeriodConfig(silence_s=5.0, window_s=10.0, settle_s=0.0)
    t = np.concatenate([np.arange(0, 25, 0.01), np.arange(40, 43, 0.01)])
    est, health, res = _rows(t, 3 * C0)
    acc = _acc(cfg)
    # fed in uneven blocks: the result does not depend on the blocking
    out = []
    for a, b in [(0, 777), (777, 1800), (1800, len(t))]:
        out += acc.add_rows(t[a:b], est[a:b], health[a:b], res[a:b])
    out += acc.poll(50.0)
    assert acc.flush() == []
    assert [round(p.start_t, 2) for p in out] == [0.0, 10.0, 20.0, 40.0]
    assert [p.samples for p in out] == [1000, 1000, 500, 300]
    assert out[0].op_time_s == pytest.approx(9.99, abs=1e-6)
    assert all(p.c_lk_ratio == pytest.approx(3.0) for p in out)
    ref = _acc(cfg)
    again = ref.add_rows(t, est, health, res) + ref.flush()
    assert again == out  # same rows, same periods (idempotent replay)


def test_accumulator_observability_robust_mean_alarms_and_quality():
    cfg = PeriodConfig(obs_sigma_ratio=0.25, settle_s=0.5, c_lk_rate_hz=1000.0)
    t = np.arange(0, 10, 0.01)
    c = np.full(len(t), 2.0 * C0)
    sig = np.full(len(t), 0.1 * C0)
    c[300:400] = 20 * C0  # unobservable burst (large sigma): excluded
    sig[300:400] = 0.5 * C0
    c[600:620] = 9 * C0  # outliers with small sigma: the median ignores them
    alarm = np.zeros(len(t))
    alarm[600:650] = 1
    alarm[800:820] = 1
    est, health, res = _rows(t, c, sig, alarm)
    est[:, EST_KEYS.index("c_lk_sigma")] = sig
    res[::2, RES_KEYS.index("nis")] = 40.0  # half the samples outside the chi2(4) band
    acc = _acc(cfg)
    acc.add_rows(t[:500], est[:500], health[:500], res[:500], counters={"skipped_nan": 2})
    acc.add_rows(t[500:], est[500:], health[500:], res[500:], counters={"skipped_nan": 5, "bad_channel": 1}, dropped=3)  # fmt: skip
    (p,) = acc.flush()
    assert p.observable_samples == 1000 - 50 - 100  # settle 0.5 s and the burst
    assert p.c_lk_ratio == pytest.approx(2.0)
    assert p.c_lk_sigma == pytest.approx(0.0)
    assert p.alarms == 2
    assert [e.t for e in acc.alarm_events()] == pytest.approx([6.0, 8.0])
    assert p.bad_samples == 6 and p.dropped == 3
    assert p.nis_in_band == pytest.approx(0.5)
    assert p.nis_mean == pytest.approx((40.0 + 4.0) / 2 / 4.0)
    assert p.p_sr_mean == pytest.approx(20e6) and p.i_b_mean == pytest.approx(1e-6)


def test_accumulator_without_observable_samples_gives_nan_ratio():
    t = np.arange(0, 3, 0.01)
    est, health, res = _rows(t, 2 * C0, c_sig=C0)
    acc = _acc()
    (p,) = acc.add_rows(t, est, health, res) + acc.flush()
    assert p.observable_samples == 0 and math.isnan(p.c_lk_ratio)


# -- RUL through the real store -----------------------------------------------------------
def _period(act, k, ratio, hours=2.0):
    return Period(
        actuator=act, start_t=100.0 * k, end_t=100.0 * k + 3.0, op_time_s=hours * 3600.0,
        samples=3000, flight=k, c_lk_mean=ratio * C0, c_lk_sigma=0.01 * C0, c_lk_ratio=ratio,
        observable_samples=2500, p_sr_mean=20e6, p_sr_min=19.9e6, i_b_mean=0.0, nis_mean=1.0,
        nis_in_band=0.93, alarms=0, bad_samples=0, dropped=0, source="test",
    )  # fmt: skip


def test_rul_through_sqlite_store(tmp_path):
    rng = np.random.default_rng(0)
    with open_store(tmp_path / "h.sqlite") as st:
        for u in range(4):
            rate = 0.04 + 0.01 * u  # per hour
            st.add_periods(
                [_period(f"AC{u}/eha", k, 1 + rate * 2.0 * (k + 1) + 0.02 * rng.standard_normal()) for k in range(30)]
            )  # fmt: skip
        st.add_periods([_period("AC9/eha", k, 1 + 0.02 * rng.standard_normal()) for k in range(30)])
        res, prior = compute_rul(st, cfg=RulConfig(threshold_ratio=11.0, horizon_h=50.0))
        assert prior.units == 5
        by = {r["actuator"]: r for r in res}
        # AC0: 1 + 0.04 t reaches 11 at 250 h; 60 h flown -> 190 h, 95 flights of 2 h
        assert by["AC0/eha"]["median_h"] == pytest.approx(190.0, rel=0.05)
        assert by["AC0/eha"]["median_flights"] == pytest.approx(95.0, rel=0.05)
        assert by["AC0/eha"]["lo_h"] < by["AC0/eha"]["median_h"] < by["AC0/eha"]["hi_h"]
        assert by["AC9/eha"]["median_h"] is None and by["AC9/eha"]["p_horizon"] < 0.05
        assert not by["AC9/eha"]["warning"]
        stored = st.rul("AC0/eha")
        assert stored["median_h"] == by["AC0/eha"]["median_h"]
        h = history_of("AC3/eha", st.periods("AC3/eha"))
        assert h.hours_per_flight == pytest.approx(2.0)
        # AC3: 1 + 0.07 t crosses 11 at 142.9 h; 60 h flown (41.4 flights of 2 h remain);
        # the history counts flights, so the horizon is in flights
        assert h.axis == "flights" and by["AC3/eha"]["axis"] == "flights"
        r = rul_of_history(h, prior, RulConfig(threshold_ratio=11.0, horizon_flights=25.0))
        assert r["median_h"] == pytest.approx(82.9, rel=0.05)
        assert r["median_flights"] == pytest.approx(41.4, rel=0.05)
        assert r["p_horizon"] < 0.05
        r = rul_of_history(h, prior, RulConfig(threshold_ratio=11.0, horizon_flights=50.0))
        assert r["p_horizon"] > 0.95 and r["warning"]


def test_default_prior_is_usable_without_a_fleet():
    t, y = _hist("linear", n=6)
    f = fit_history(t, y, FleetPrior())
    assert f.best() in ("linear", "exponential")


def test_rul_cli_json_png_and_errors(tmp_path, capsys):
    from service.cli import main

    db = tmp_path / "h.sqlite"
    rng = np.random.default_rng(1)
    with open_store(db) as st:
        st.add_periods([_period("AC1/eha", k, 1 + 0.1 * (k + 1) + 0.02 * rng.standard_normal()) for k in range(20)])  # fmt: skip
        st.add_periods([_period("AC2/eha", k, 1 + 0.02 * rng.standard_normal()) for k in range(20)])
    png = tmp_path / "fan.png"
    rc = main(["rul", "--store", str(db), "--threshold", "6", "--json", "--png", str(png)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    by = {r["actuator"]: r for r in out["actuators"]}
    # AC1: 1 + 0.05 t (t in h, 2 h per flight) reaches 6 at 100 h; 40 h flown
    assert by["AC1/eha"]["median_h"] == pytest.approx(60.0, rel=0.1)
    assert by["AC1/eha"]["median_flights"] == pytest.approx(30.0, rel=0.1)
    assert by["AC2/eha"]["median_h"] is None
    assert png.stat().st_size > 10_000
    assert main(["rul", "--store", str(db), "--actuator", "AC9/eha"]) == 2
    assert main(["rul", "--store", str(db), "--threshold", "0.5"]) == 2
    assert main(["rul", "--store", str(tmp_path / "missing.sqlite")]) == 2
