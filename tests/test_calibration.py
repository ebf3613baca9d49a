"""Baseline identification from healthy HF data, and the baseline file round trip."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from models.params import EHAParams
from service.cli import main
from service.monitor import Baseline, MonitorConfig
from service.monitor.calibration import calibrate, identify_baseline, measured_run, run_monitor
from service.sim.scenarios import load_scenario

P = EHAParams()


@pytest.fixture(scope="module")
def healthy():
    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 3.0})
    return measured_run(sc)


def test_identified_gains_match_the_hf_valve_linearised_at_null(healthy):
    """Matched underlapped lands at null (physics.md section 3): Q = K_q x_S - K_c P12 with
    K_q = 2 G_Q (twice the secant flow gain) and K_c = 1/G_PQ + G_lam (laminar land
    clearance flow, w c_r^3 / (12 mu l_min)); the leak adds C_Lk. Noise-free signals."""
    sim, _ = healthy
    truth = {"t": sim.t, "x_s": sim.x_s, "x_j": sim.x_j, "p1": sim.p1, "p2": sim.p2}
    b = identify_baseline(truth, "C5")
    k_q = b.p_sr_rated / (b.x_ss * b.g_pq)
    assert k_q == pytest.approx(2 * P.g_q, rel=0.02)
    g_lam = P.w_eff * P.c_r**3 / (12 * P.mu * P.l_min)
    assert 1 / b.g_pq + b.c_lk == pytest.approx(1 / P.g_pq + g_lam + P.c_lk, rel=0.03)
    assert b.p_r == pytest.approx(P.p_r, rel=0.05)


def test_noisy_identification_close_to_noise_free(healthy):
    sim, meas = healthy
    truth = {"t": sim.t, "x_s": sim.x_s, "x_j": sim.x_j, "p1": sim.p1, "p2": sim.p2}
    a, b = identify_baseline(truth, "C5"), identify_baseline(meas, "C5")
    assert b.x_ss * b.g_pq == pytest.approx(a.x_ss * a.g_pq, rel=0.03)  # flow gain
    assert b.g_pq == pytest.approx(a.g_pq, rel=0.05)


@pytest.mark.slow
def test_calibrated_monitor_reads_nominal_leakage_on_healthy_data(healthy):
    _, meas = healthy
    nominal = Baseline.nominal("C5")
    outs, _ = run_monitor(meas, MonitorConfig(model="C5"), nominal)
    c_nom = np.mean([o.est["c_lk"] for o in outs if o.t > 1.0])
    base = calibrate(meas, "C5", passes=1)
    outs, _ = run_monitor(meas, MonitorConfig(model="C5"), base)
    c_cal = np.mean([o.est["c_lk"] for o in outs if o.t > 1.0])
    assert abs(c_cal - 2e-13) < 0.2e-13
    assert abs(c_nom - 2e-13) > 3 * abs(c_cal - 2e-13)  # the mismatch calibration removes


def test_baseline_save_load_round_trip(tmp_path):
    b = Baseline.default().model_copy(update={"source": "test", "c_lk": 3.5e-13})
    f = tmp_path / "b.json"
    b.save(f)
    assert Baseline.load(f) == b
    assert json.loads(f.read_text())["c_lk"] == 3.5e-13


def test_cli_calibrate_writes_a_loadable_baseline(tmp_path, capsys):
    sc = tmp_path / "h.toml"
    src = load_scenario("healthy_noise")
    text = (
        f'name = "h"\nduration_s = 1.5\n[command]\ninitial = 0.0\nperiodic = ['
        f'{{ kind = "sine", amplitude = 0.002, freq_hz = 0.3 }}]\n[load]\ninitial = 4000.0\n'
        f"[sensors]\nx_s_m = {src.sensors.x_s_m}\nx_j_m = {src.sensors.x_j_m}\n"
        f"p_pa = {src.sensors.p_pa}\nseed = 7\n"
    )
    sc.write_text(text)
    out = tmp_path / "base.json"
    rc = main(["calibrate", "--scenario", str(sc), "--out", str(out), "--passes", "0", "--json",
               "--model", "C5"])  # fmt: skip
    assert rc == 0
    res = json.loads(capsys.readouterr().out)
    b = Baseline.load(out)
    assert res["baseline"]["g_pq"] == b.g_pq and math.isfinite(b.x_ss)
    assert 1.7 < 1e-4 / b.x_ss < 2.2  # the tangent pressure gain at null: about 2x secant


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_cli_calibrate_errors(tmp_path, capsys):
    assert main(["calibrate", "--scenario", "nope", "--out", str(tmp_path / "x")]) == 2
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not mcap")
    assert main(["calibrate", "--log", str(bad), "--out", str(tmp_path / "x")]) == 2
    assert "error" in capsys.readouterr().err


def test_bank_rows_are_the_per_sample_monitors_numbers():
    """calibrate() runs the monitor through one update_arrays call: the same estimates, bit
    for bit, as Monitor.update sample by sample (run_monitor)."""
    from service.monitor import EST_KEYS, MonitorConfig
    from service.monitor.calibration import bank_rows

    _, meas = measured_run(load_scenario("healthy_noise").model_copy(update={"duration_s": 1.0}))
    outs, _ = run_monitor(meas)
    rows = bank_rows(meas, MonitorConfig(), None)
    per_sample = np.array([[o.est[k] for k in EST_KEYS] for o in outs if o is not None])
    assert rows.est.shape == per_sample.shape and rows.est.shape[0] > 900
    assert np.array_equal(rows.est, per_sample)
