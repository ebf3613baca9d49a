"""``servowatch estimate`` end to end (HF truth + monitor), JSON contract and outputs."""

from __future__ import annotations

import json

import pytest

from service.cli import main

KEYS = {
    "scenario", "model", "channels", "duration_s", "wall_s", "update_us_median", "truth",
    "estimate", "c_lk_error_pct", "p_sr_error_pct", "alarms", "false_alarms",
    "detection_delay_s", "nis_in_band_pct",
}  # fmt: skip


def run_json(capsys, *args) -> dict:
    assert main(["estimate", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_json_contract_on_a_leak_step(capsys):
    r = run_json(capsys, "--scenario", "leak_step", "--duration", "3.0")
    assert set(r) >= KEYS
    assert set(r["truth"]) == {"c_lk", "p_sr"}
    assert set(r["estimate"]) == {"c_lk", "c_lk_sigma", "p_sr", "p_sr_sigma"}
    assert r["duration_s"] == pytest.approx(3.0)
    assert r["truth"]["c_lk"] == pytest.approx(8e-13)
    assert abs(r["c_lk_error_pct"]) < 10.0
    assert [(a["kind"], a["state"]) for a in r["alarms"]] == [("leak", "raised")]
    assert r["false_alarms"] == 0
    assert 0.0 <= r["detection_delay_s"] < 1.0
    assert r["nis_in_band_pct"] > 80.0


def test_reduced_channels_and_another_law(capsys):
    r = run_json(capsys, "--scenario", "supply_drop", "--duration", "1.0", "--channels",
                 "reduced", "--model", "C1")  # fmt: skip
    assert r["channels"] == "reduced" and r["model"] == "C1"
    assert r["counters"]["accepted"] == 1001


@pytest.mark.slow
def test_png_and_mcap_outputs(tmp_path, capsys):
    png, mcap = tmp_path / "e.png", tmp_path / "e.mcap"
    rc = main(["estimate", "--scenario", "healthy_noise", "--duration", "0.6",
               "--png", str(png), "--out", str(mcap)])  # fmt: skip
    assert rc == 0
    assert png.stat().st_size > 10_000
    from service.log import read_log

    topics = {}
    for topic, _t, msg in read_log(mcap):
        topics.setdefault(topic, msg)
    assert set(topics) >= {"/estimate/healthy_noise/est", "/estimate/healthy_noise/meas"}
    assert "c_lk_sigma" in topics["/estimate/healthy_noise/est"]
    out = capsys.readouterr().out
    assert "C_Lk" in out and "P_SR" in out


def test_errors_exit_2(capsys):
    assert main(["estimate", "--scenario", "no_such_file"]) == 2
    assert main(["estimate", "--scenario", "healthy_noise", "--model", "Q7"]) == 2
    assert main(["estimate", "--scenario", "healthy_noise", "--duration", "-1"]) == 2
    with pytest.raises(SystemExit) as e:
        main(["estimate", "--scenario", "healthy_noise", "--channels", "some"])
    assert e.value.code == 2
