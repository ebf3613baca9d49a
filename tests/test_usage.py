"""Usage per period (issue 42 item 1): the monitor's usage rates (``service.monitor.usage``)
integrated per period (``PeriodAccumulator``) against hand-computed values, the block and
per-round paths, the HF bench's truth, the store's migration 5 on both engines, and the
replay into a store end to end."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.scenario import Periodic, Profile
from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS
from service.monitor.usage import usage_rows
from service.monitor.usage_config import N_USAGE, UsageConfig, new_state
from service.prognostics.indicators import PeriodAccumulator, PeriodConfig
from service.store import Period, open_store
from service.store.records import LATER_FIELDS, USAGE_FIELDS
from service.store.schema import LATEST_VERSION, MIGRATIONS
from tests._store_versions import summary_columns_after

AREA, P_RATED = 1e-3, 20e6
# columns of the filter state the kernel reads (C-type order: x_s, v_s, x_j, v_j, f_r, p_sr)
I_XJ, I_VJ, I_PSR = 2, 3, 5
I_P1, I_P2 = 2, 3  # measured channels x_s, x_j, p1, p2, p_sr


def _rates(t, x_j, v_j, p1, p2, p_sr, cfg=None, ust=None):
    """The kernel's usage rates of one actuator's rows (filter units = SI)."""
    n = len(t)
    X = np.zeros((n, 8))
    X[:, I_XJ], X[:, I_VJ], X[:, I_PSR] = x_j, v_j, p_sr
    z = np.zeros((n, 5))
    z[:, I_P1], z[:, I_P2] = p1, p2
    mask = np.ones((n, 5), np.bool_)
    mask[:, I_P1] = mask[:, I_P2] = np.isfinite(p1) & np.isfinite(p2)
    z[~mask] = 0.0
    out = np.zeros((n, N_USAGE))
    ust = new_state(1) if ust is None else ust
    usage_rows(np.zeros(n, np.int64), np.ones(n, np.bool_), True, X, np.ones((1, 8)),
               np.ones((1, 5)), I_VJ, I_XJ, I_PSR, z, mask, I_P1, I_P2,
               (cfg or UsageConfig()).row(AREA, P_RATED)[None, :], ust, out)  # fmt: skip
    return out


def _period(t, usage, cfg=None) -> list[Period]:
    """The periods of rows at ``t`` carrying ``usage`` (est/health: an idle monitor)."""
    n = len(t)
    est = np.zeros((n, len(EST_KEYS)))
    est[:, EST_KEYS.index("c_lk_sigma")] = 1.0  # never observable: no C_Lk (not tested here)
    acc = PeriodAccumulator("AC1/ail_L", 1e-12, "test", EST_KEYS, HEALTH_KEYS, RES_KEYS, cfg)
    res = np.zeros((n, len(RES_KEYS)))
    return acc.add_rows(t, est, np.zeros((n, len(HEALTH_KEYS))), res, usage=usage) + acc.flush()


def _sine(amp=5e-3, f=0.5, cycles=3, rate=1000.0):
    t = np.arange(int(round(cycles / f * rate)) + 1) / rate
    w = 2 * np.pi * f
    return t, amp * np.sin(w * t), amp * w * np.cos(w * t)


def test_sine_stroke_travel_is_4_amplitudes_and_2_reversals_per_cycle():
    t, x, v = _sine(amp=5e-3, f=0.5, cycles=3)
    p12 = 6e6  # constant load 6 kN on a 1e-3 m^2 jack: above 10 % of the 20 kN stall force
    one = np.ones_like(t)
    u = _rates(t, x, v, 10e6 + 0.5 * p12 * one, 10e6 - 0.5 * p12 * one, 21e6 * one)
    (p,) = _period(t, u)
    assert p.usage_travel_m == pytest.approx(4 * 5e-3 * 3, rel=2e-3)
    assert p.usage_reversals == 6.0
    # constant load: the load-weighted travel is the load times the travel, exactly
    assert p.usage_load_travel_j == pytest.approx(AREA * p12 * p.usage_travel_m, rel=1e-12)
    assert p.usage_load2_travel_n2m == pytest.approx(
        (AREA * p12) ** 2 * p.usage_travel_m, rel=1e-12
    )
    assert p.usage_loaded_s == pytest.approx(p.op_time_s) and p.op_time_s == pytest.approx(6.0)
    assert p.usage_pressurised_s == pytest.approx(6.0)


def test_thresholds_dither_below_the_hysteresis_and_missing_pressures():
    t, x, v = _sine(amp=5e-3, f=0.5, cycles=2)
    rng = np.random.default_rng(3)
    x = x + 0.05e-3 * np.sin(2 * np.pi * 23 * t) + 20e-6 * rng.standard_normal(len(t))
    one = np.ones_like(t)
    # load under 10 % of stall (1 kN < 2 kN) in the first half, pressures absent in the second
    p1 = np.where(t < 2.0, 10.5e6, np.nan) * one
    p2 = np.where(t < 2.0, 9.5e6, np.nan) * one
    p_sr = np.where(t < 1.0, 9e6, 21e6)  # under half of rated for the first second
    u = _rates(t, x, v, p1, p2, p_sr)
    (p,) = _period(t, u)
    assert p.usage_reversals == 4.0  # the dither (0.05 mm < 0.2 mm) and the noise count nothing
    assert p.usage_loaded_s == 0.0
    first = t < 2.0
    dt = np.diff(t, prepend=t[0])
    assert p.usage_load_travel_j == pytest.approx(1000.0 * np.sum(np.abs(v[first]) * dt[first]))
    assert p.usage_pressurised_s == pytest.approx(3.0, abs=2e-3)
    # no pressures at all: the load figures are unknown, not zero
    (q,) = _period(t, _rates(t, x, v, np.nan * one, np.nan * one, p_sr))
    for f in ("usage_load_travel_j", "usage_load2_travel_n2m", "usage_loaded_s"):
        assert math.isnan(getattr(q, f))
    assert q.usage_travel_m == pytest.approx(p.usage_travel_m)
    # without hysteresis the same noise reads as hundreds of reversals
    raw = _rates(t, x, v, p1, p2, p_sr, UsageConfig(reversal_m=0.0))
    assert raw[:, 5].sum() > 100


def test_periods_split_the_usage_and_rows_without_usage_read_nan():
    t, x, v = (a[:-1] for a in _sine(amp=5e-3, f=0.5, cycles=4))  # 0 <= t < 8 s
    one = np.ones_like(t)
    u = _rates(t, x, v, 11e6 * one, 9e6 * one, 21e6 * one)
    whole = _period(t, u)
    cut = _period(t, u, PeriodConfig(window_s=2.0))
    assert len(whole) == 1 and len(cut) == 4
    # the same intervals as op_time_s: the periods add up to the whole but for the interval
    # between two periods, which belongs to neither
    lost = sum(1e-3 * abs(v[np.searchsorted(t, p.start_t)]) for p in cut[1:])
    assert sum(p.usage_travel_m for p in cut) + lost == pytest.approx(whole[0].usage_travel_m)
    assert sum(p.usage_reversals for p in cut) == whole[0].usage_reversals == 8.0
    # blocks of any size give the same periods
    acc = PeriodAccumulator("AC1/ail_L", 1e-12, "test", EST_KEYS, HEALTH_KEYS, RES_KEYS,
                            PeriodConfig(window_s=2.0))  # fmt: skip
    n = len(t)
    est = np.zeros((n, len(EST_KEYS)))
    est[:, EST_KEYS.index("c_lk_sigma")] = 1.0
    h, r = np.zeros((n, len(HEALTH_KEYS))), np.zeros((n, len(RES_KEYS)))
    got = []
    for a in range(0, n, 777):
        s = slice(a, a + 777)
        got += acc.add_rows(t[s], est[s], h[s], r[s], usage=u[s])
    got += acc.flush()
    assert [p.start_t for p in got] == [p.start_t for p in cut]
    for a, b in zip(got, cut, strict=True):
        for f in USAGE_FIELDS:
            assert getattr(a, f) == pytest.approx(getattr(b, f), rel=1e-12)
    (none,) = _period(t, None)
    assert all(math.isnan(getattr(none, f)) for f in USAGE_FIELDS)


def _scenario_run(seed: int = 5, duration_s: float = 3.0):
    from service.monitor.calibration import measured_run
    from service.sim.scenarios import load_scenario

    base = load_scenario("healthy_noise")
    sc = base.model_copy(
        update={
            "duration_s": duration_s,
            "command": Profile(periodic=[Periodic(kind="sine", amplitude=0.008, freq_hz=0.7)]),
            "load": Profile(initial=5000.0),
            "sensors": base.sensors.model_copy(update={"seed": seed}),
        }
    )
    return measured_run(sc)


def test_block_and_round_paths_give_the_same_usage():
    from service.monitor import MonitorBank, MonitorConfig

    sim, meas = _scenario_run(duration_s=0.6)
    keys = [k for k in ("t", "x_cmd", "i", "x_s", "x_j", "p1", "p2") if k in meas]
    samples = [("AC1/a", {k: float(meas[k][j]) for k in keys}) for j in range(len(meas["t"]))]
    b1, b2 = MonitorBank(MonitorConfig()), MonitorBank(MonitorConfig())
    r1 = b1.update_rows(samples[:300])
    r1b = b1.update_rows(samples[300:])
    r2 = b2.update_rows_rounds(samples)
    u1 = np.concatenate([r1.usage, r1b.usage])
    assert u1.shape == (len(samples), N_USAGE)
    np.testing.assert_array_equal(u1, r2.usage)
    assert u1[:, 5].sum() >= 1  # the stroke reversed at least once in 0.6 s at 0.7 Hz


@pytest.mark.slow
def test_usage_against_the_hf_bench_truth():
    """Travel and load-weighted travel within 2 % of the HF bench's truth, reversals exact."""
    from service.monitor import Baseline, MonitorConfig
    from service.monitor.calibration import bank_rows
    from service.prognostics.indicators import periods_of_rows

    sim, meas = _scenario_run(duration_s=3.0)
    cfg = MonitorConfig()
    base = Baseline.default(cfg.model)
    rows = bank_rows(meas, cfg, base)
    (p,) = periods_of_rows("AC1/a", base.c_lk, "t", rows.t, rows.est, rows.health, rows.res,
                           usage=rows.usage)  # fmt: skip
    sel = rows.index
    dt = np.diff(rows.t, prepend=rows.t[0])
    v, f = sim.v_j[sel], base.area * (sim.p1 - sim.p2)[sel]
    assert p.usage_travel_m == pytest.approx(np.sum(np.abs(v) * dt), rel=0.02)
    assert p.usage_load_travel_j == pytest.approx(np.sum(np.abs(f * v) * dt), rel=0.02)
    assert p.usage_load2_travel_n2m == pytest.approx(np.sum(f**2 * np.abs(v) * dt), rel=0.03)
    truth = _rates(rows.t, sim.x_j[sel], v, sim.p1[sel], sim.p2[sel], sim.p_sr[sel])
    assert p.usage_reversals == truth[:, 5].sum() >= 4.0  # 2.1 cycles of 0.7 Hz


def _old_period(k: int) -> Period:
    return Period(actuator="AC1/ail_L", start_t=100.0 * k, end_t=100.0 * k + 90, op_time_s=90.0,
                  samples=900, flight=k, c_lk_mean=1e-12, c_lk_sigma=1e-14, c_lk_ratio=1.0,
                  observable_samples=800, p_sr_mean=2.1e7, p_sr_min=2e7, i_b_mean=0.0,
                  nis_mean=1.0, nis_in_band=0.95, alarms=0, bad_samples=0, dropped=0,
                  source="log-a")  # fmt: skip


def test_migration_5_keeps_an_old_store_and_reads_null_usage(store_url, monkeypatch):
    import service.store.health as health

    v3 = [m for m in MIGRATIONS if m[0] <= 3]
    with monkeypatch.context() as m:  # a store as servowatch wrote it before migration 5
        m.setattr(health, "MIGRATIONS", tuple(v3))
        m.setattr(health, "LATEST_VERSION", 3)
        m.setattr(health, "_PERIOD_COLS", tuple(c for c in health._PERIOD_COLS
                                                if c not in LATER_FIELDS))  # fmt: skip
        later = summary_columns_after(3)  # the summary columns of migrations 5 and later
        for name in ("_SUMMARY_COLS", "_FLEET_COLS"):
            m.setattr(health, name, tuple(c for c in getattr(health, name)
                                          if c not in later))  # fmt: skip
        with open_store(store_url) as s:
            assert s.schema_version() == 3
            assert s.add_periods([_old_period(k) for k in range(3)]) == 3
    with open_store(store_url) as s:
        assert s.schema_version() == LATEST_VERSION
        old = s.periods("AC1/ail_L")
        assert len(old) == 3
        assert all(math.isnan(getattr(p, f)) for p in old for f in USAGE_FIELDS)
        new = Period(**{**_old_period(3).to_dict(), "usage_travel_m": 1.5,
                        "usage_load_travel_j": 6000.0, "usage_load2_travel_n2m": 2.4e7,
                        "usage_reversals": 12.0, "usage_loaded_s": 80.0,
                        "usage_pressurised_s": 90.0})  # fmt: skip
        assert s.add_periods([new]) == 1
        assert s.periods("AC1/ail_L")[-1] == new
        (row,) = s.fleet_summary()
        assert row["periods"] == 4
        u = row["usage"]
        assert (u["periods"], u["op_time_s"], u["travel_m"]) == (1, 90.0, 1.5)
        assert u["travel_m_per_h"] == pytest.approx(1.5 / 0.025)
        assert u["load_travel_j_per_h"] == pytest.approx(6000.0 / 0.025)
        assert u["reversals_per_h"] == pytest.approx(12.0 / 0.025)
        assert row["last"]["usage_travel_m"] == 1.5
        assert s.check() == []


def test_fleet_usage_of_a_store_without_usage(store_url):
    with open_store(store_url) as s:
        s.add_periods([_old_period(k) for k in range(2)])
        (row,) = s.fleet_summary()
    assert row["usage"]["periods"] == 0 and row["usage"]["travel_m_per_h"] is None
    assert math.isnan(row["last"]["usage_travel_m"])


@pytest.mark.slow
def test_replay_store_writes_usage_end_to_end(tmp_path):
    """A log replayed with --store: every period carries usage, close to the bench's truth;
    a second replay adds nothing."""
    from service.cli import main
    from service.log import McapLogger
    from service.wire.messages import mcap_topic

    sim, meas = _scenario_run(duration_s=3.0, seed=8)
    log = tmp_path / "AC1-ail_L-f000.mcap"
    ch = ("x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr")
    with McapLogger(log, background_flush=False) as lg:  # one JSON message per sample
        topic = mcap_topic("AC1", "ail_L", "meas")
        for j in range(len(meas["t"])):
            lg.log(topic, float(meas["t"][j]),
                   {"seq": j, "t": float(meas["t"][j]),
                    **{c: float(meas[c][j]) for c in ch if c in meas}})  # fmt: skip
    store = tmp_path / "s.sqlite"
    assert main(["replay", str(log), "--store", str(store), "--json"]) == 0
    with open_store(store) as s:
        ps = s.periods("AC1/ail_L")
        assert len(ps) == 1
        (p,) = ps
        dt = np.diff(sim.t, prepend=0.0)
        true_travel = np.sum(np.abs(sim.v_j) * dt)
        assert p.usage_travel_m == pytest.approx(true_travel, rel=0.02)
        f = 1e-3 * (sim.p1 - sim.p2)
        assert p.usage_load_travel_j == pytest.approx(np.sum(np.abs(f * sim.v_j) * dt), rel=0.02)
        truth = _rates(sim.t, sim.x_j, sim.v_j, sim.p1, sim.p2, sim.p_sr)
        assert p.usage_reversals == truth[:, 5].sum() >= 4.0
        assert p.usage_pressurised_s == pytest.approx(p.op_time_s)
        (row,) = s.fleet_summary()
        assert row["usage"]["travel_m"] == p.usage_travel_m
    assert main(["replay", str(log), "--store", str(store), "--json"]) == 0
    with open_store(store) as s:
        assert s.count_periods() == 1


def _used_period(k: int, flight: int, travel: float, load: float | None) -> Period:
    return Period(**{**_old_period(k).to_dict(), "flight": flight, "usage_travel_m": travel,
                     "usage_load_travel_j": math.nan if load is None else load,
                     "usage_load2_travel_n2m": math.nan if load is None else 1e3 * load,
                     "usage_reversals": 10.0, "usage_loaded_s": 45.0 if load else math.nan,
                     "usage_pressurised_s": 90.0})  # fmt: skip


def test_fleet_text_json_and_the_unit_view_show_usage(store_url, capsys):
    import json

    from service.cli import main
    from service.edge.web.view import fleet_view, unit_view

    with open_store(store_url) as s:
        # two flights of two 90 s periods, one flight with usage but no pressures, one old
        s.add_periods([_used_period(0, 1, 2.0, 4000.0), _used_period(1, 1, 1.0, 2000.0),
                       _used_period(2, 2, 3.0, 6000.0), _used_period(3, 2, 3.0, 6000.0),
                       _used_period(4, 3, 0.5, None), _old_period(5)])  # fmt: skip
    assert main(["fleet", "--store", store_url, "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)["fleet"]
    u = row["usage"]
    hours = 5 * 90 / 3600  # the 5 periods with usage
    assert u["periods"] == 5 and u["travel_m"] == pytest.approx(9.5)
    assert u["travel_m_per_h"] == pytest.approx(9.5 / hours)
    assert u["load_travel_j_per_h"] == pytest.approx(18000.0 / (4 * 90 / 3600))
    assert main(["fleet", "--store", store_url, "--wide"]) == 0  # usage: the wide table's
    text = capsys.readouterr().out.splitlines()
    assert "travel m/h" in text[1] and "load x travel kJ/h" in text[1]
    assert text[3].split()[-2:] == [f"{9.5 / hours:.2f}", f"{18.0 / (4 * 90 / 3600):.1f}"]
    with open_store(store_url) as s:
        fv = fleet_view(s)
        assert fv["fleet"][0]["usage"]["travel_m"] == pytest.approx(9.5)
        uv = unit_view(s, "AC1/ail_L")
    # per flight: flights 1-3 carry usage (flight 5's one period does not), flights 1-2 load
    assert uv["usage"] == {"flights": 3, "travel_m": pytest.approx(9.5 / 3),
                           "reversals": pytest.approx(50 / 3), "load_flights": 2,
                           "load_travel_j": pytest.approx(9000.0)}  # fmt: skip
    assert [p["usage_travel_m"] for p in uv["periods"]] == [2.0, 1.0, 3.0, 3.0, 0.5, None]


@pytest.mark.slow
def test_the_daemon_writes_usage_with_its_periods(tmp_path):
    """Live periods: the daemon's store writer gets usage, the same as a replay of the same
    samples in one block would give over the same periods (both cut 1 s windows)."""
    from service.config import PrognosticsSettings, ServiceConfig
    from service.daemon import Daemon
    from service.wire.messages import encode_meas

    sim, meas = _scenario_run(duration_s=2.5, seed=9)
    store = tmp_path / "d.sqlite"
    cfg = ServiceConfig(store=str(store), publish_every=1000,
                        prognostics=PrognosticsSettings(period_window_s=1.0))  # fmt: skip
    d = Daemon(cfg, log_path=tmp_path / "d.mcap", log_process=False, gather_s=0)
    ch = [c for c in ("x_cmd", "i", "x_s", "x_j", "p1", "p2") if c in meas]
    n = len(meas["t"])
    for a in range(0, n, 50):
        rows = [{"seq": j, "t": float(meas["t"][j]), **{c: float(meas[c][j]) for c in ch}}
                for j in range(a, min(a + 50, n))]  # fmt: skip
        d.submit("fleet/AC1/ail_L/meas", encode_meas(rows))
    while d.queued:
        d.process_pending()
    d.stop()
    with open_store(store) as s:
        ps = s.periods("AC1/ail_L")
        assert len(ps) == 3 and all(p.source.startswith("live:ground1/0@") for p in ps)
    dt = np.diff(sim.t, prepend=0.0)
    assert sum(p.usage_travel_m for p in ps) == pytest.approx(
        np.sum(np.abs(sim.v_j) * dt), rel=0.03
    )
    assert all(p.usage_load_travel_j > 0 for p in ps)
    assert [p.usage_pressurised_s for p in ps] == pytest.approx([p.op_time_s for p in ps])


@pytest.mark.parametrize("value", [-1.0, math.inf])
def test_a_period_refuses_negative_or_infinite_usage(value):
    with pytest.raises(
        ValueError, match="usage_load_travel_j: expected a finite number >= 0 or NaN"
    ):
        Period(**{**_old_period(0).to_dict(), "usage_load_travel_j": value})
    with pytest.raises(ValueError, match="UsageConfig.reversal_m"):
        UsageConfig(reversal_m=value)
