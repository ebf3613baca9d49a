"""Flights as the life axis: the flight record of a log, replay --flight, the gap rule, the
batch replay of many logs into one store, and calibrate's check of the log's actuator. Real
logs of the HF bench (a few seconds each) through the real monitor and a SQLite store."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from service.cli import main
from service.log.flightrec import FlightRecord, flight_records, write_flight_log
from service.prognostics.life import FlightStamper
from service.replay import expand_logs, log_order, replay, replay_many
from service.store import open_store
from service.store.records import Period

DAY = 86400.0


@pytest.fixture(scope="module")
def meas():
    """One healthy 3 s log's measured signals (HF bench, the scenario's sensor noise)."""
    from service.monitor.calibration import measured_run
    from service.sim.scenarios import load_scenario

    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 3.0})
    return measured_run(sc)[1]


def _log(path, meas, ac="AC1", act="ail_L", flight=None, start_unix=None, t_shift=0.0):
    ch = {k: v for k, v in meas.items() if k != "t"}
    rec = FlightRecord(ac, act, flight if flight is not None else 0, start_unix)
    if flight is None:  # a log without a flight record
        from service.log import McapLogger

        names = ("t", *ch)
        vals = np.column_stack([meas["t"] + t_shift, *ch.values()])
        with McapLogger(path, background_flush=False) as lg:
            lg.log_block(f"/fleet/{ac}/{act}/meas", meas["t"] + t_shift, names, vals)
        return path
    return write_flight_log(path, rec, meas["t"] + t_shift, ch)


def _period(start_t, end_t, start_unix=None, flight=None, source="s"):
    return Period(
        actuator="AC1/a", start_t=start_t, end_t=end_t, op_time_s=end_t - start_t, samples=10,
        flight=flight, c_lk_mean=1.0, c_lk_sigma=0.0, c_lk_ratio=1.0, observable_samples=5,
        p_sr_mean=0.0, p_sr_min=0.0, i_b_mean=0.0, nis_mean=1.0, nis_in_band=1.0, alarms=0,
        bad_samples=0, dropped=0, source=source, start_unix=start_unix,
    )  # fmt: skip


def test_flight_record_round_trip_and_validation(tmp_path, meas):
    p = _log(tmp_path / "f.mcap", meas, flight=7, start_unix=1.7e9)
    (rec,) = flight_records(p)
    assert (rec.name, rec.flight, rec.start_unix) == ("AC1/ail_L", 7, 1.7e9)
    with pytest.raises(ValueError, match="flight"):
        FlightRecord.from_metadata({"aircraft": "A", "actuator": "b", "flight": "-1"})
    with pytest.raises(ValueError, match="start_unix"):
        FlightRecord.from_metadata({"aircraft": "A", "actuator": "b", "flight": "1",
                                    "start_unix": "nan"})  # fmt: skip


def test_gap_rule_and_calendar_time():
    st = FlightStamper(gap_s=1800.0)
    # sample times restart at 0 in every log: each log is a new flight
    a = st.stamp([_period(0.0, 3.0)])
    b = st.stamp([_period(0.0, 3.0, source="t")])
    assert a[0].flight == 0 and b[0].flight == 1
    # Unix sample times: calendar time is the sample time; 10 min apart -> same flight,
    # 2 h apart -> the next
    c = st.stamp([_period(1.7e9, 1.7e9 + 60)])
    d = st.stamp([_period(1.7e9 + 660, 1.7e9 + 700)])
    e = st.stamp([_period(1.7e9 + 7900, 1.7e9 + 7960)])
    assert c[0].start_unix == 1.7e9
    assert (c[0].flight, d[0].flight, e[0].flight) == (2, 2, 3)
    # a record's flight and start override; the caller's flight overrides the record
    rec = FlightRecord("AC1", "a", 40, 1.8e9)
    f = st.stamp([_period(5.0, 9.0)], records=[rec], first_t={"AC1/a": 5.0})
    assert (f[0].flight, f[0].start_unix) == (40, 1.8e9)
    g = st.stamp([_period(5.0, 9.0)], records=[rec], first_t={"AC1/a": 5.0}, flight=3)
    assert g[0].flight == 3


def test_replay_records_flight_and_calendar_time(tmp_path, meas):
    store = tmp_path / "h.sqlite"
    with_rec = _log(tmp_path / "a.mcap", meas, flight=12, start_unix=1.7e9 + 3 * DAY)
    bare = _log(tmp_path / "b.mcap", meas, t_shift=0.25)  # other samples than a.mcap's
    s = replay(with_rec, store=store)
    assert s.flights == {"AC1/ail_L": [12]}
    s = replay(bare, store=store)  # no record: the gap rule after flight 12
    assert s.flights == {"AC1/ail_L": [13]}
    bare2 = _log(tmp_path / "c.mcap", meas, t_shift=0.5)
    s = replay(bare2, store=store, flight=20, start_unix=1.7e9 + 9 * DAY)
    assert s.flights == {"AC1/ail_L": [20]}
    with open_store(store) as st:
        ps = sorted(st.periods("AC1/ail_L"), key=lambda p: p.flight)
    # the undated log without a record follows every dated period of its unit in life order
    # (docs/store.md): the gap rule now numbers it after flight 20
    assert [p.flight for p in ps] == [12, 20, 21]
    assert ps[0].start_unix == pytest.approx(1.7e9 + 3 * DAY, abs=1.0)
    assert ps[1].start_unix == pytest.approx(1.7e9 + 9 * DAY, abs=1.0)
    assert ps[2].start_unix is None
    # the history counts flights; calendar days per flight from the dated ones: 6 d / 8
    from service.prognostics.rul import history_of

    h = history_of("AC1/ail_L", ps)
    assert h.axis == "flights" and h.t_now() == 10.0
    assert h.days_per_flight() == pytest.approx(6.0 / 8.0, rel=1e-3)


def test_batch_replay_of_a_folder_in_flight_order(tmp_path, meas, capsys):
    folder = tmp_path / "logs"
    folder.mkdir()
    # written out of order, named so that the name order is not the flight order
    for k in (3, 0, 2, 1):
        # each flight its own samples (a log is identified by its samples, not its record)
        _log(folder / f"z{9 - k}.mcap", meas, flight=k, start_unix=1.7e9 + k * DAY,
             t_shift=0.001 * k)  # fmt: skip
        _log(folder / f"y{9 - k}.mcap", meas, act="ail_R", flight=k,
             start_unix=1.7e9 + k * DAY + 60, t_shift=0.001 * k)  # fmt: skip
    logs = log_order(expand_logs([folder]))
    assert [flight_records(p)[0].flight for p in logs] == [0, 0, 1, 1, 2, 2, 3, 3]
    assert expand_logs([str(folder / "z*.mcap")]) == sorted(folder.glob("z*.mcap"))
    store = tmp_path / "h.sqlite"
    assert main(["replay", str(folder), "--store", str(store), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["logs"] == 8 and out["failed"] == []
    assert out["actuators"]["AC1/ail_L"] == {"flights": 4, "first": 0, "last": 3}
    # again: idempotent
    assert main(["replay", str(folder), "--store", str(store), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["periods_new"] == 0
    # several logs need a store; --flight takes one log
    assert main(["replay", str(folder), "--json"]) == 2
    assert main(["replay", str(folder), "--store", str(store), "--flight", "3"]) == 2
    assert "one log" in capsys.readouterr().err
    # the same through the library, counting every log
    seen = []
    replay_many(logs[:2], store, on_log=lambda p, s, e: seen.append((p, e)))
    assert [e for _, e in seen] == [None, None]


def test_calibrate_checks_the_logs_actuator(tmp_path, meas, capsys):
    log = _log(tmp_path / "f0.mcap", meas, flight=0, start_unix=1.7e9)
    store = tmp_path / "h.sqlite"
    rc = main(["calibrate", "--log", str(log), "--actuator", "HX99/aileron_L",
               "--store", str(store)])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    assert "AC1/ail_L" in err and "HX99/aileron_L" in err
    if store.exists():
        with open_store(store) as st:
            assert st.latest_baseline("HX99/aileron_L") is None
    # without --actuator: the log's one actuator
    assert main(["calibrate", "--log", str(log), "--store", str(store), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["actuator"] == "AC1/ail_L" and out["version"] == 1
    # with the right one
    assert main(["calibrate", "--log", str(log), "--actuator", "AC1/ail_L", "--store",
                 str(store), "--json"]) == 0  # fmt: skip
    assert json.loads(capsys.readouterr().out)["version"] == 2
    # a log of two actuators needs --actuator to record in a store
    two = tmp_path / "two.mcap"
    from service.log import McapLogger

    names = ("t", *[k for k in meas if k != "t"])
    vals = np.column_stack([meas[k] for k in names])
    with McapLogger(two, background_flush=False) as lg:
        lg.log_block("/fleet/AC1/a/meas", meas["t"], names, vals)
        lg.log_block("/fleet/AC1/b/meas", meas["t"], names, vals)
    assert main(["calibrate", "--log", str(two), "--store", str(store)]) == 2
    assert "name one" in capsys.readouterr().err
    assert not math.isnan(out["baseline"]["c_lk"])


@pytest.mark.slow
def test_acceptance_fleet_through_calibrate_and_replay(tmp_path, capsys):
    """The held-apart acceptance fleet, small: every log goes in by the user's commands and
    comes out as one period per flight; the healthy units stay under 5 % within the
    horizon; the metrics are computed (their targets are figures of docs/prognostics.md)."""
    from tests.acceptance_fleet import run

    ev = run(seed=7, units=5, flights=14, work=tmp_path)
    capsys.readouterr()
    assert ev["healthy_units"] == 1
    assert ev["healthy_max_p_horizon"] is not None and ev["healthy_max_p_horizon"] <= 0.05
    with open_store(tmp_path / "acceptance.sqlite") as st:
        for a in st.actuators():
            ps = st.periods(a)
            assert sorted(p.flight for p in ps) == list(range(len(ps)))
            assert all(p.start_unix is not None for p in ps)
            assert st.latest_baseline(a) is not None
    for k in ("alpha_lambda_pct", "interval_coverage_pct", "kendall_tau"):
        assert k in ev
