"""``calibrate --actuator --store``, ``baselines`` and ``fleet`` on both store backends."""

from __future__ import annotations

import json

import pytest
from test_store import make_period

from service.cli import main
from service.sim.scenarios import load_scenario
from service.store import AlarmEvent, open_store


@pytest.fixture(scope="module")
def short_healthy(tmp_path_factory):
    """A 1.5 s healthy scenario file (as in test_calibration)."""
    src = load_scenario("healthy_noise")
    sc = tmp_path_factory.mktemp("sc") / "h.toml"
    sc.write_text(
        f'name = "h"\nduration_s = 1.5\n[command]\ninitial = 0.0\nperiodic = ['
        f'{{ kind = "sine", amplitude = 0.002, freq_hz = 0.3 }}]\n[load]\ninitial = 4000.0\n'
        f"[sensors]\nx_s_m = {src.sensors.x_s_m}\nx_j_m = {src.sensors.x_j_m}\n"
        f"p_pa = {src.sensors.p_pa}\nseed = 7\n"
    )
    return sc


@pytest.fixture(scope="module")
def healthy_log(short_healthy, tmp_path_factory):
    """An MCAP log of the short healthy run (``estimate --out``)."""
    log = tmp_path_factory.mktemp("log") / "healthy.mcap"
    assert main(["estimate", "--scenario", str(short_healthy), "--out", str(log), "--json"]) == 0
    return log


@pytest.mark.slow
def test_calibrate_records_versions_and_baselines_lists_them(
    store_url, short_healthy, healthy_log, tmp_path, capsys
):
    a = "AC001/elevator_L"
    rc = main(["calibrate", "--scenario", str(short_healthy), "--passes", "0",
               "--actuator", a, "--store", store_url, "--json"])  # fmt: skip
    assert rc == 0
    first = json.loads(capsys.readouterr().out)
    assert first["version"] == 1 and first["actuator"] == a and first["out"] is None
    out = tmp_path / "b.json"
    rc = main(["calibrate", "--log", str(healthy_log), "--passes", "0", "--actuator", a,
               "--store", store_url, "--out", str(out), "--json"])  # fmt: skip
    assert rc == 0
    second = json.loads(capsys.readouterr().out)
    assert second["version"] == 2 and out.exists()

    assert main(["baselines", "--store", store_url, "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [(b["actuator"], b["version"]) for b in listed["baselines"]] == [(a, 2)]
    b2 = listed["baselines"][0]
    assert b2["source"] == f"log {healthy_log}" and b2["figures"]["passes"] == 0
    assert b2["baseline"]["g_pq"] == second["baseline"]["g_pq"]
    assert b2["baseline"] == second["baseline"]  # the stored version is what calibrate printed
    assert b2["baseline"]["law"] == second["baseline"]["law"] == "WH"  # the default model
    assert b2["figures"]["samples"] > 1000

    with open_store(store_url) as s:
        s.ensure_actuator("AC002/rudder")
    assert main(["baselines", "--store", store_url, "--all"]) == 0
    text = capsys.readouterr().out
    assert text.count(a) == 2 and "(superseded)" in text
    assert "AC002/rudder" in text and "not commissioned" in text


def test_store_command_errors_name_the_field(store_url, short_healthy, tmp_path, capsys):
    sc = str(short_healthy)
    assert (
        main(["calibrate", "--scenario", sc, "--actuator", "elevator", "--store", store_url]) == 2
    )
    assert "--actuator" in capsys.readouterr().err
    assert main(["calibrate", "--scenario", sc, "--actuator", "A/b", "--store", "mysql://x/y"]) == 2
    err = capsys.readouterr().err
    assert "--store: store: unsupported URL scheme 'mysql'" in err
    assert main(["calibrate", "--scenario", sc, "--store", store_url]) == 2
    assert "--store needs --actuator" in capsys.readouterr().err
    assert main(["calibrate", "--scenario", sc]) == 2
    assert "--out" in capsys.readouterr().err
    missing = tmp_path / "none" / "h.sqlite"
    assert main(["baselines", "--store", str(missing)]) == 2
    assert "does not exist" in capsys.readouterr().err and not missing.exists()
    with open_store(store_url):
        pass
    assert main(["baselines", "--store", store_url, "--actuator", "AC9/nope"]) == 2
    assert "--actuator: unknown actuator 'AC9/nope'" in capsys.readouterr().err
    assert main(["fleet", "--store", str(missing)]) == 2
    with pytest.raises(SystemExit) as e:
        main(["fleet", "--nope"])
    assert e.value.code == 2


def test_fleet_ranks_by_rul_then_alarms_then_ratio(store_url, capsys):
    with open_store(store_url) as s:
        # a: RUL 50 h; b: RUL 500 h; c, d, e: no RUL; c has alarms; d has a higher ratio than e
        for name, ratio in (("AC1/a", 1.5), ("AC1/b", 2.0), ("AC2/c", 1.1), ("AC2/d", 1.8),
                            ("AC2/e", 1.2)):  # fmt: skip
            s.add_periods(make_period(name, k, ratio=ratio) for k in range(3, 9, 3))
        s.add_alarms([AlarmEvent("AC2/c", 1.0 + k, "leak", 1.0, "x") for k in range(9)])
        s.put_rul("AC1/a", {"median_h": 50.0, "lo_h": 30.0, "hi_h": 90.0, "p_horizon": 0.7})
        s.put_rul("AC1/b", {"median_h": 500.0, "lo_h": 300.0, "hi_h": 900.0, "p_horizon": 0.0})
        s.add_baseline("AC1/a", {"c_lk": 1e-12}, "test", {})
    assert main(["fleet", "--store", store_url, "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    order = [r["actuator"] for r in res["fleet"]]
    assert order == ["AC1/a", "AC1/b", "AC2/c", "AC2/d", "AC2/e"]
    top = res["fleet"][0]
    assert top["rank"] == 1 and top["commissioned"] is True
    assert top["rul_interval"]["median_h"] == 50.0 and top["rul_interval"]["hi_h"] == 90.0
    assert top["last"]["c_lk_ratio"] == 1.5 and top["periods"] == 2
    assert res["fleet"][2]["alarm_events"] == 9 and res["fleet"][3]["rul_interval"] is None
    assert main(["fleet", "--store", store_url, "--top", "2"]) == 0
    text = capsys.readouterr().out
    assert "5 actuators" in text and "4 not commissioned" in text and "50 [30-90]" in text
    assert "AC2/c" not in text.split("\n", 1)[1]
