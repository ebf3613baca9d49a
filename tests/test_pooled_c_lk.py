"""The pooled C_Lk (issue 51; docs/estimation.md, "The pooled C_Lk"): the pool of the walk
filter's updates equals a filter without the walk, restarts on a change, reads a leak step
with a sigma under the walk's; the period records its last pooled reading within the
observability limit beside the indicator, which stays the median reading (decisions/0025:
the pool does not drive the indicator or the RUL yet); the store's migration 6 keeps old
stores and the page shows the pooled reading (SQLite and PostgreSQL)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS
from service.monitor.kernels import (
    C_POOL_D_MIN,
    C_POOL_H,
    C_POOL_TOL,
    CARRY_PI,
    CARRY_PN,
    CARRY_PS,
    CST_FIELDS,
    N_CARRY,
    pool_add,
)
from service.prognostics.indicators import PeriodAccumulator, PeriodConfig, pooled_limit
from service.store import Period, open_store
from service.store.records import POOLED_FIELDS
from service.store.schema import LATEST_VERSION, MIGRATIONS
from tests._store_versions import summary_columns_after


def _cst(h=6.9, tol=0.1, d_min=0.5):
    c = np.zeros(len(CST_FIELDS))
    c[C_POOL_H], c[C_POOL_TOL], c[C_POOL_D_MIN] = h, tol, d_min
    return c


def _walk_updates(z, r, q, p0=1.0, m0=1.0):
    """A scalar random-walk Kalman filter on measurements z (variance r, walk q per step):
    per step (m-, P-, m+, P+)."""
    m, p = m0, p0
    out = []
    for zj in z:
        pm = p + q
        k = pm / (pm + r)
        mp, pp = m + k * (zj - m), (1 - k) * pm
        out.append((m, pm, mp, pp))
        m, p = mp, pp
    return out


def _feed(z, r=25.0, q=1e-3, cst=None, walk=None):
    cr = np.zeros(N_CARRY)
    cst = _cst() if cst is None else cst
    for mm, pm, mp, pp in _walk_updates(z, r, q):
        pool_add(cr, 1 / pp - 1 / pm, mp / pp - mm / pm, mm if walk is None else walk, 1.0, cst)
    return cr


def test_the_pool_of_a_walk_filter_is_the_filter_without_the_walk():
    """Pooled mean and sigma = the mean of the measurements and sqrt(r / N) (and the prior's
    information): what the walk forgets, the pool keeps."""
    rng = np.random.default_rng(3)
    z = 1.3 + 5.0 * rng.standard_normal(4000)
    cr = _feed(z, cst=_cst(h=0.0))
    info = cr[CARRY_PI]
    assert info == pytest.approx(4000 / 25.0, rel=1e-6)  # the prior's 1/p0 is not counted
    assert cr[CARRY_PS] / info == pytest.approx(float(np.mean(z)), abs=1e-9)
    assert 1 / math.sqrt(info) == pytest.approx(0.079, abs=0.001)  # the walk's sigma: ~0.4


def test_the_pool_restarts_at_a_shift_and_not_without_one():
    rng = np.random.default_rng(4)
    noise = 5.0 * rng.standard_normal(40000)
    still = _feed(1.0 + noise)
    assert still[CARRY_PN] == 0  # 40 000 samples, 1600 information units: no restart
    z = np.where(np.arange(40000) < 20000, 1.0, 2.0) + noise
    cr = _feed(z)
    assert cr[CARRY_PN] >= 1
    assert cr[CARRY_PS] / cr[CARRY_PI] == pytest.approx(2.0, abs=0.08)
    kept = _feed(z, cst=_cst(h=0.0))  # without the test: the mean of both levels
    assert kept[CARRY_PS] / kept[CARRY_PI] == pytest.approx(1.5, abs=0.05)


def test_the_pool_reads_a_leak_step_with_a_sigma_under_the_walk():
    from evaluation.pooled import run

    r = run("leak_step")
    assert r["changes"] >= 1  # the walk's detector restarted the pool at the step
    assert abs(r["pool%"]) < 5.0
    assert r["pool_sd"] < 0.5 * r["walk_sd"]
    assert r["pool_sd"] <= r["limit"] and r["period%"] == pytest.approx(r["pool%"], abs=2.0)


def test_the_incipient_leak_pools_within_10_percent():
    """A slow ramp to 1.6x over 16 s of a 20 s run, under every alarm level
    (scenarios/incipient_leak.toml): the pool, restarted along the ramp by its own test,
    reads the increase within 10 % where the walk's last second reads it 11 % low; its
    sigma (0.030x) is at the observability limit (0.029x), so the indicator abstains (issue
    51: a miss, docs/evaluation.md)."""
    from evaluation.pooled import run

    r = run("incipient_leak")
    assert abs(r["pool%"]) <= 10.0 < abs(r["walk%"])
    assert r["pool_sd"] == pytest.approx(r["limit"], rel=0.1)


def _rows(n, ratio, sd, c0=2e-13, walk=1.0, walk_sd=0.5):
    """n rows whose walk reads ``walk`` x c0 with sigma ``walk_sd`` x c0 (0.5: never under
    the indicator's 0.25x) and whose pool reads ``ratio`` x c0 with sigma ``sd`` x c0."""
    est = np.zeros((n, len(EST_KEYS)))
    est[:, EST_KEYS.index("c_lk")] = walk * c0
    est[:, EST_KEYS.index("c_lk_sigma")] = walk_sd * c0
    pooled = np.column_stack([np.full(n, ratio * c0), np.asarray(sd, float) * c0])
    return est, np.zeros((n, len(HEALTH_KEYS))), np.zeros((n, len(RES_KEYS))), pooled


def _periods(t, est, health, res, pooled, c0=2e-13):
    acc = PeriodAccumulator("AC1/ail_L", c0, "test", EST_KEYS, HEALTH_KEYS, RES_KEYS,
                            PeriodConfig(settle_s=0.0))  # fmt: skip
    return acc.add_rows(t, est, health, res, pooled=pooled) + acc.flush()


def test_pooled_limit_is_relative_to_the_increase_with_a_floor():
    cfg = PeriodConfig()
    assert pooled_limit(3.0, cfg) == pytest.approx(0.1 * 2.0 / 1.96)
    assert pooled_limit(1.0, cfg) == pytest.approx(0.1 * 0.5 / 1.96)
    assert pooled_limit(1.2, cfg) == pytest.approx(0.1 * 0.5 / 1.96)


def test_the_period_records_the_last_pooled_reading_within_the_limit_beside_the_indicator():
    n = 100
    t = np.arange(n) * 1e-3
    sd = np.where(np.arange(n) < 60, 0.05, 0.02)  # 3x: the limit is 0.102 -> every row
    est, health, res, pooled = _rows(n, 3.0, sd, walk=2.0, walk_sd=0.1)
    pooled[:, 0] *= 1.0 + 1e-3 * np.arange(n)  # the pool moves: the last row's is recorded
    (p,) = _periods(t, est, health, res, pooled)
    assert p.c_lk_pooled == pytest.approx(3.0 * (1 + 0.099) * 2e-13)
    assert p.c_lk_pooled_sigma == pytest.approx(0.02 * 2e-13)
    # the indicator is the median of the observable walk estimates, as without a pool
    assert p.c_lk_ratio == pytest.approx(2.0) and p.observable_samples == n
    assert p.c_lk_ratio_sigma() == pytest.approx(0.0)
    # the walk never under 0.25x: the indicator abstains though the pool is within its limit
    est, health, res, pooled = _rows(n, 3.0, np.full(n, 0.02))
    (p,) = _periods(t, est, health, res, pooled)
    assert math.isnan(p.c_lk_ratio) and p.observable_samples == 0
    assert math.isnan(p.c_lk_ratio_sigma())
    assert p.c_lk_pooled == pytest.approx(3.0 * 2e-13)
    # 1.2x with sigma 0.03: over the floor's limit 0.0255 -> no pooled reading; the
    # indicator reads the walk
    est, health, res, pooled = _rows(n, 1.2, np.full(n, 0.03), walk=1.1, walk_sd=0.1)
    (p,) = _periods(t, est, health, res, pooled)
    assert math.isnan(p.c_lk_pooled) and math.isnan(p.c_lk_pooled_sigma)
    assert p.c_lk_ratio == pytest.approx(1.1) and p.observable_samples == n


def test_the_pool_changes_no_field_of_main_s_period():
    """Rows with and without a pool fold into the same period but for the two pooled fields:
    the indicator, its observable rows and everything the RUL reads stay main's."""
    rng = np.random.default_rng(5)
    n = 3000
    t = np.arange(n) * 1e-3
    walk_sd = np.where(np.arange(n) % 500 < 250, 0.1, 0.4)  # observable half the time
    est, health, res, pooled = _rows(n, 2.0, np.linspace(0.2, 0.01, n), walk=2.0)
    est[:, EST_KEYS.index("c_lk")] *= 1.0 + 0.05 * rng.standard_normal(n)
    est[:, EST_KEYS.index("c_lk_sigma")] = walk_sd * 2e-13
    with_pool = _periods(t, est, health, res, pooled)
    without = _periods(t, est, health, res, None)
    assert len(with_pool) == len(without) >= 1
    for a, b in zip(with_pool, without, strict=True):
        assert math.isfinite(a.c_lk_pooled) and math.isnan(b.c_lk_pooled)
        assert a == Period(**{**b.to_dict(), "c_lk_pooled": a.c_lk_pooled,
                              "c_lk_pooled_sigma": a.c_lk_pooled_sigma})  # fmt: skip
        assert 0 < a.observable_samples < a.samples and math.isfinite(a.c_lk_ratio)


def _old_period(k: int) -> Period:
    return Period(actuator="AC1/ail_L", start_t=100.0 * k, end_t=100.0 * k + 90, op_time_s=90.0,
                  samples=900, flight=k, c_lk_mean=2e-13, c_lk_sigma=2e-14, c_lk_ratio=1.0,
                  observable_samples=800, p_sr_mean=2.1e7, p_sr_min=2e7, i_b_mean=0.0,
                  nis_mean=1.0, nis_in_band=0.95, alarms=0, bad_samples=0, dropped=0,
                  source="log-a")  # fmt: skip


def test_migration_6_keeps_an_old_store_and_reads_null_pooled(store_url, monkeypatch):
    import service.store.health as health

    v5 = [m for m in MIGRATIONS if m[0] <= 5]
    with monkeypatch.context() as m:  # a store as servowatch wrote it before migration 6
        m.setattr(health, "MIGRATIONS", tuple(v5))
        m.setattr(health, "LATEST_VERSION", 5)
        m.setattr(health, "_PERIOD_COLS", tuple(c for c in health._PERIOD_COLS
                                                if c not in POOLED_FIELDS))  # fmt: skip
        v7 = summary_columns_after(5)
        for name in ("_SUMMARY_COLS", "_FLEET_COLS"):  # the summary columns of migrations 7 on
            m.setattr(health, name, tuple(c for c in getattr(health, name)
                                          if c not in v7))  # fmt: skip
        with open_store(store_url) as s:
            assert s.schema_version() == 5
            assert s.add_periods([_old_period(k) for k in range(3)]) == 3
    with open_store(store_url) as s:
        assert s.schema_version() == LATEST_VERSION  # 6, then the later ones
        old = s.periods("AC1/ail_L")
        assert len(old) == 3 and old[0] == _old_period(0)
        assert all(math.isnan(getattr(p, f)) for p in old for f in POOLED_FIELDS)
        assert old[0].c_lk_ratio_sigma() == pytest.approx(0.1)  # the median's scatter
        new = Period(**{**_old_period(3).to_dict(), "c_lk_ratio": 1.5, "c_lk_pooled": 3e-13,
                        "c_lk_pooled_sigma": 4e-15})  # fmt: skip
        assert s.add_periods([new]) == 1
        back = s.periods("AC1/ail_L")[-1]
        assert back == new
        assert back.c_lk_ratio_sigma() == pytest.approx(0.15)  # the median's, not the pool's
        assert s.check() == []
        # the page shows the pooled reading beside the indicator (null where none)
        from service.edge.web.view import unit_view

        rows = unit_view(s, "AC1/ail_L")["periods"]
        assert [r["c_lk_pooled"] for r in rows] == [None, None, None, 3e-13]
        assert rows[-1]["c_lk_pooled_sigma"] == 4e-15
        assert rows[-1]["c_lk_ratio"] == 1.5
