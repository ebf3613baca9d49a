"""Fleet simulator: the hidden truth is consistent, and a small fleet runs end to end through the real SQLite store and the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from service.cli import main
from service.replay.fleetsim import WEAR_LAWS, FleetSimConfig, draw_units
from service.store import open_store


def test_truth_end_of_life_crosses_the_threshold():
    cfg = FleetSimConfig(actuators=12, flights=50, seed=2, threshold_ratio=8.0)
    units = draw_units(cfg)
    assert {u.law for u in units} == set(WEAR_LAWS)
    for u in units:
        r = u.ratios()
        if u.law == "none":
            assert math.isinf(u.eol_flight) and np.all(r == 1.0)
            continue
        assert np.all(np.diff(r) >= 0)
        if math.isfinite(u.eol_flight):
            # flight k is at k + 1 on the life axis: the crossing lies between two flights
            j = int(math.floor(u.eol_flight))
            assert r[j - 1] < 8.0 <= r[j]
        # flights per day 1-3 with missed days; logs from a ground test to three times longer
        days = np.diff(u.flight_start_unix) / 86400.0
        assert days.min() >= 0 and days.max() < 30
        assert set(np.round(u.log_s[1:], 3)) <= {1.5, 2.0, 6.0}
        # each flight's load and amplitude about the operator's profile
        load, amp = np.asarray(u.flight_load), np.asarray(u.flight_amp)
        assert 0.8 <= u.profile["load"] <= 1.2 and 0.85 <= u.profile["amp"] <= 1.15
        assert np.all(np.abs(load / u.profile["load"] - 1.0) <= 0.35)
        assert np.all(np.abs(amp / u.profile["amp"] - 1.0) <= 0.25)
        assert np.std(load * amp) / np.mean(load * amp) > 0.15  # the usage varies per flight
        if u.law == "knee":
            # slow, then m times faster from the knee, linear after it, no jump
            d = u.damage()
            dk, m, k = u.wear["d_k"], u.wear["m"], u.wear["k"]
            assert 4.0 <= m <= 8.0
            assert u.ratio_at(dk) == pytest.approx(1.0 + k * dk)
            assert u.ratio_at(dk + 1.0) - u.ratio_at(dk) == pytest.approx(m * k)
            assert np.allclose(r, [u.ratio_at(x) for x in d])
        if u.law == "usage":
            inc = np.diff(u.damage())
            h = np.asarray(u.flight_hours[:-1])
            assert np.allclose(inc, h * load[:-1] * np.array([u.amp(i) for i in range(len(h))]))
        # plant variation within the stated tolerances
        assert 85.0 <= u.plant["mass"] <= 130.0
        assert 0.9e-4 <= u.plant["u1"] <= 1.2e-4
    assert draw_units(cfg)[3].wear == units[3].wear  # reproducible from the seed


@pytest.mark.slow
def test_fleet_sim_end_to_end(tmp_path, capsys):
    store = tmp_path / "fleet.sqlite"
    truth = tmp_path / "truth.json"
    args = ["fleet-sim", "--actuators", "6", "--flights", "14", "--seed", "3", "--store",
            str(store), "--truth", str(truth), "--evaluate", "--json", "--workers", "1"]  # fmt: skip
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    for k in ("actuators", "flights", "segments", "wall_s", "alpha_lambda_pct",
              "relative_accuracy_pct", "prognostic_horizon_pct", "healthy_units",
              "false_rul_warnings", "false_alarms", "interval_coverage_pct", "kendall_tau",
              "healthy_max_p_horizon", "logs", "ingest_wall_s"):  # fmt: skip
        assert k in out
    assert out["actuators"] == 6 and out["flights"] == 14
    tr = json.loads(truth.read_text())
    laws = [u["law"] for u in tr["units"]]
    assert out["healthy_units"] == laws.count("none") >= 1
    # units stop after the flight that reaches the end of life
    assert out["segments"] == out["logs"] == sum(u["flown"] for u in tr["units"])
    assert out["false_alarms"] == 0
    assert out["false_rul_warnings"] == 0
    assert out["healthy_max_p_horizon"] <= 0.05
    with open_store(store) as st:
        assert len(st.actuators()) == 6
        for u in tr["units"]:
            ps = sorted(st.periods(u["actuator"]), key=lambda p: p.flight)
            # one log per flight, through the replay: flight numbers and calendar times
            assert [p.flight for p in ps] == list(range(u["flown"]))
            assert [p.start_unix for p in ps] == u["flight_start_unix"][: u["flown"]]
            assert st.latest_baseline(u["actuator"]) is not None
            # the indicator follows the hidden truth (calibrated on the first flight); a
            # 1.5 s log at 1.45x the sensor noise reads a healthy unit within 10 %
            est = np.array([p.c_lk_ratio for p in ps])
            err = np.abs(est - np.array(u["ratio"]))
            assert np.mean(np.isfinite(err)) >= 0.8  # a short log may leave C_Lk unobservable
            assert np.nanmax(err) < 0.05 * max(u["ratio"]) + 0.11
            assert np.nanmedian(err) < 0.03 * max(u["ratio"]) + 0.03
            # and the monitor's usage follows each flight's load x amplitude
            lt = np.array([p.usage_load_travel_j / p.op_time_s for p in ps])[1:]
            true = np.array([u["flight_load"][k] * u["flight_amp"][k] for k in range(1, len(ps))])
            if len(lt) >= 4:
                assert np.corrcoef(lt, true)[0, 1] > 0.8
            assert st.rul(u["actuator"]) is not None
    # the scoring alone on the stored histories and the truth file: the same figures
    assert main(["fleet-sim", "--score-only", "--store", str(store), "--truth", str(truth),
                 "--json"]) == 0  # fmt: skip
    again = json.loads(capsys.readouterr().out)
    for k in ("alpha_lambda_pct", "interval_coverage_pct", "kendall_tau",
              "healthy_max_p_horizon", "scored_units", "by_law"):  # fmt: skip
        assert again[k] == out[k], k
    assert main(["fleet-sim", "--score-only", "--store", str(tmp_path / "none.sqlite"),
                 "--truth", str(truth)]) == 2  # fmt: skip
    assert "--store" in capsys.readouterr().err
    # the RUL command on the same store, with the fan plot
    png = tmp_path / "fan.png"
    assert main(["rul", "--store", str(store), "--json", "--png", str(png)]) == 0
    r = json.loads(capsys.readouterr().out)
    assert len(r["actuators"]) == 6 and r["threshold_ratio"] == pytest.approx(tr["threshold_ratio"])
    assert png.stat().st_size > 10_000


def test_mid_life_tau_counts_each_unit_from_its_mid_life():
    """Kendall's tau from mid-life: at each checkpoint only the units past their own
    mid-life (first prediction + half the rest of life) count, three or more of them."""
    from service.replay.fleetsim import mid_life_taus

    t_first = {"a": 8.0, "b": 8.0, "c": 8.0, "d": 8.0}
    eol = {"a": 12.0, "b": 16.0, "c": 20.0, "d": 40.0}  # mid-lives 10, 12, 14, 24
    rows = [
        [("a", 9.0, 1.0, 3.0), ("b", 9.0, 9.0, 7.0), ("c", 9.0, 5.0, 11.0)],  # none past
        # a, b, c past their mid-lives, ordered right; d (before its own) reversed
        [("a", 14.0, 0.5, 0.0), ("b", 14.0, 2.0, 2.0), ("c", 14.0, 6.0, 6.0),
         ("d", 14.0, 0.1, 26.0)],
        [("b", 16.0, 3.0, 0.0), ("c", 16.0, 1.0, 4.0), ("d", 16.0, 9.0, 24.0)],  # d not past
    ]  # fmt: skip
    assert mid_life_taus(rows, t_first, eol) == [1.0]
