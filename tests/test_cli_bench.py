"""``servowatch simulate`` and ``servowatch compare``: JSON contracts, MCAP output, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.cli import main

SHORT = """
name = "short_bench"
duration_s = 0.12
step_s = 1e-4
[command]
events = [{ t = 0.0, value = 0.01 }]
[load]
events = [{ t = 0.08, value = 5000.0 }]
"""


@pytest.fixture
def short_scenario(tmp_path):
    p = tmp_path / "short.toml"
    p.write_text(SHORT)
    return p


def test_simulate_json_contract_and_mcap(short_scenario, tmp_path, capsys):
    out = tmp_path / "run.mcap"
    png = tmp_path / "run.png"
    rc = main(
        [
            "simulate",
            "--scenario",
            str(short_scenario),
            "--valve",
            "C5",
            "--json",
            "--out",
            str(out),
            "--png",
            str(png),
        ]
    )
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d) == {
        "valve",
        "scenario",
        "duration_s",
        "wall_s",
        "realtime_factor",
        "peak_abs_p12_pa",
        "max_abs_v_j_m_s",
        "final_x_j_m",
    }
    assert d["valve"] == "C5" and d["scenario"] == "short_bench"
    assert d["duration_s"] == pytest.approx(0.12)
    assert d["wall_s"] > 0 and d["realtime_factor"] == pytest.approx(0.12 / d["wall_s"])
    # C-type valves never exceed P_SR (20 MPa on this scenario)
    assert 0 < d["peak_abs_p12_pa"] <= 20e6
    # the step of 10 mm is mostly done in 0.12 s at up to ~160 mm/s
    assert 0.005 < d["final_x_j_m"] < 0.0105
    assert png.stat().st_size > 10_000

    from mcap.reader import make_reader

    with open(out, "rb") as f:
        msgs = [
            (ch.topic, m.log_time, json.loads(m.data))
            for _s, ch, m in make_reader(f).iter_messages()
        ]
    assert len(msgs) == 1201  # one message per sample, t = 0 .. 0.12 s at 1e-4 s
    assert {t for t, _, _ in msgs} == {"/bench/C5/state"}
    assert msgs[0][1] == 0 and msgs[-1][1] == pytest.approx(0.12e9, abs=1)
    last = msgs[-1][2]
    assert last["x_j"] == pytest.approx(d["final_x_j_m"])
    assert {"x_s", "v_j", "p12", "p1", "p2", "f_r", "p_sr", "i"} <= set(last)


def test_simulate_bad_scenario_names_file_and_field(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('duration_s = 1.0\nstep_s = "fast"\n')
    assert main(["simulate", "--scenario", str(bad), "--valve", "HF"]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "step_s" in err


def test_simulate_unknown_valve_is_usage_error(short_scenario):
    with pytest.raises(SystemExit) as ei:
        main(["simulate", "--scenario", str(short_scenario), "--valve", "C7"])
    assert ei.value.code == 2


def test_compare_json_contract(short_scenario, tmp_path, capsys):
    png = tmp_path / "cmp.png"
    rc = main(["compare", "--scenario", str(short_scenario), "--json", "--png", str(png)])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert d["reference"] == "HF" and d["scenario"] == "short_bench" and d["hf_wall_s"] > 0
    assert set(d["models"]) == {"A", "B", "C1", "C3", "C5", "WH"}
    for m in d["models"].values():
        assert set(m["nrmse_pct"]) == {"x_j", "v_j", "p12", "x_s"}
        assert all(np.isfinite(v) and v >= 0 for v in m["nrmse_pct"].values())
        assert m["wall_s"] > 0
    # on an unsaturated, lightly loaded step the C5 law follows HF position closely,
    # while B (saturation before the flow feedback) is far too slow (seed section 4)
    assert d["models"]["C5"]["nrmse_pct"]["x_j"] < 10.0
    assert d["models"]["B"]["nrmse_pct"]["x_j"] > d["models"]["C5"]["nrmse_pct"]["x_j"]
    assert png.stat().st_size > 10_000
