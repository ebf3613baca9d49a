"""The monitor on the WH process model (models/eha_reduced_wh.py, docs/estimation.md "WH
process model"): the compiled model and UKF step against numpy, the stiff modes against the
integrator, healthy and leak-step runs on the HF bench, the CLI, and the C-type outputs
unchanged."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from _c_type import c_type_config

from models import eha_reduced_wh as erw
from service.monitor import Baseline, MonitorBank, MonitorConfig
from service.monitor.calibration import measured_run, run_monitor
from service.monitor.ukf import BatchUKF, process_covariance, ukf_step_batch
from service.sim.scenarios import load_scenario

BASE = Baseline.default("WH")
RP = BASE.reduced_params()
PRM = erw.param_vector(RP, BASE.v_c, BASE.beta)
X_SI = np.array([1.1e-5, 2e-4, 1e-3, 2e-3, 4000.0, 19.5e6, 3e-13, 5e-5, 12.6e6, 8.4e6])


def test_compiled_step_and_measure_equal_numpy():
    rng = np.random.default_rng(1)
    X = X_SI * (1.0 + 0.3 * rng.standard_normal((40, 10)))
    X[::5, 8] = -2e5  # chamber 1 cavitating (p~ below P_vap: a cavity volume)
    out = np.empty(10)
    zo = np.empty(5)
    for x in X:
        erw.step_nb(x, 2.3e-4, 1e-3, 1, PRM, out)
        np.testing.assert_allclose(out, erw.step(x, 2.3e-4, 1e-3, RP, 1, BASE.v_c, BASE.beta),
                                   rtol=1e-11, atol=1e-12)  # fmt: skip
        erw.measure_nb(x, PRM, zo)
        np.testing.assert_array_equal(zo, erw.measure(x, RP))
    assert erw.measure(X[0], RP)[2] == RP.p_vap  # P1 = max(p~1, P_vap) (docs/models.md eq. 6)


def test_stiff_modes_damped_by_one_ros2_step_at_1_ms():
    """docs/models.md section 7: chamber mode 6.5e3 1/s, hydraulic 632 rad/s; one ROS2 step
    per 1 ms sample damps the chamber mode (|R| < 0.21) and keeps the hydraulic ringing
    (|R| > 0.999 on the imaginary axis)."""
    m = erw.stiff_modes(RP, BASE.v_c, BASE.beta, c_lk=1e-11)
    assert m["hydraulic"] == pytest.approx(632.5, rel=0.01)
    assert 6.0e3 < m["chamber"] < 7.0e3
    assert abs(erw.ros2_amplification(-m["chamber"] * 1e-3)) < 0.21
    assert abs(erw.ros2_amplification(1j * m["hydraulic"] * 1e-3)) > 0.999
    # a locked, loaded jack released at the 1 ms step (1 step) against 1000 RK4 substeps
    x0 = X_SI.copy()
    x0[[0, 1, 3, 7]] = 0.0
    x0[[8, 9]] = 13.0e6, 7.0e6  # 6 MPa against a 4 kN load: the hydraulic mode rings
    a, b = x0.copy(), x0.copy()
    out = np.empty(10)
    for _ in range(50):
        erw.step_nb(a, 0.0, 1e-3, 1, PRM, out)
        a = out.copy()
        b = erw.step_rk4(b, 0.0, 1e-3, RP, 1000, BASE.v_c, BASE.beta)
    assert abs(a[8] - b[8]) < 0.03 * abs(x0[8] - x0[9])
    assert abs(a[3] - b[3]) < 1e-3


def test_wh_kernel_equals_batch_ukf_on_the_numpy_model():
    n, m = 10, 5
    bank = MonitorBank(MonitorConfig(model="WH"))
    scale, zscale = bank.scale, bank._zscale
    x = (X_SI / scale)[None]
    P = np.diag((bank._p0 / scale) ** 2)[None]
    q, R = bank._q, bank.R
    z_si = np.array([[1.2e-5, 1.01e-3, 12.7e6, 8.3e6, 0.0]])
    mask = np.array([[True, True, True, True, False]])
    z = np.where(mask, z_si / zscale, 0.0)
    dt, i = 1e-3, 2.3e-4
    ukf = BatchUKF(n, alpha=0.5)

    def fx(s):
        out = erw.step(s * scale, i, dt, RP, 1, BASE.v_c, BASE.beta)
        out[..., 4:8] = (s * scale)[..., 4:8]
        return out / scale

    sig_f, xp, Pp = ukf.predict(x, P, fx, process_covariance(q, n) * dt)
    ref = ukf.update(sig_f, xp, Pp, lambda s: erw.measure(s * scale, RP) / zscale, z, R, mask)
    y, nis, st = np.zeros((1, m)), np.zeros(1), np.zeros(1, np.int64)
    w = ukf.w
    ukf_step_batch(
        x, P, z, mask, np.array([i]), np.array([dt]), np.array([1]), q, R, scale, zscale,
        w.Wm, w.Wc, w.c, bank._prm, y, nis, st,
    )  # fmt: skip
    assert st[0] == 0
    np.testing.assert_allclose(x, ref.x, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(P, 0.5 * (ref.P + np.swapaxes(ref.P, 1, 2)), rtol=1e-6, atol=1e-10)
    assert nis[0] == pytest.approx(ref.nis[0], rel=1e-8)


def _run(name: str, duration: float):
    sc = load_scenario(name).model_copy(update={"duration_s": duration})
    _, meas = measured_run(sc)
    outs, mon = run_monitor(meas, MonitorConfig(model="WH"))
    return [o for o in outs if o is not None], mon


def test_healthy_run_no_false_alarm_nis_in_band():
    from scipy.stats import chi2

    outs, mon = _run("healthy_noise", 3.0)
    assert mon.counters["reinit"] == 0
    assert not any(o.events for o in outs)
    late = [o for o in outs if o.t >= 0.5]
    lo, hi = chi2.ppf(0.025, 4), chi2.ppf(0.975, 4)
    in_band = np.mean([lo <= o.res["nis"] <= hi for o in late])
    assert in_band > 0.90  # measured 94 %
    c = np.mean([o.est["c_lk"] for o in outs if o.t >= 2.0])
    assert c == pytest.approx(2e-13, rel=0.10)  # calibrated: nominal within 10 %
    assert math.isfinite(outs[-1].est["p12"])


def test_leak_step_increase_within_10_percent():
    outs, mon = _run("leak_step", 4.0)
    assert [(e.kind, e.state) for o in outs for e in o.events] == [("leak", "raised")]
    raised = next(e.t for o in outs for e in o.events)
    assert 1.5 < raised < 2.5
    inc = np.mean([o.est["c_lk_increase"] for o in outs if o.t >= 3.0])
    assert inc == pytest.approx(6e-13, rel=0.10)  # 1x -> 4x nominal: +6e-13 (measured +0.4 %)
    assert mon.counters["reinit"] == 0


def test_estimate_cli_model_wh(capsys):
    from service.cli import main

    rc = main(["estimate", "--scenario", "leak_step", "--duration", "3.0", "--model", "WH",
               "--json"])  # fmt: skip
    assert rc == 0
    r = json.loads(capsys.readouterr().out)
    assert r["model"] == "WH"
    assert abs(r["c_lk_error_pct"]) < 10.0
    assert r["false_alarms"] == 0 and r["counters"]["reinit"] == 0
    assert [(a["kind"], a["state"]) for a in r["alarms"]] == [("leak", "raised")]


def test_unknown_model_rejected_and_wh_config():
    with pytest.raises(ValueError):
        MonitorBank(MonitorConfig(model="XX"))
    bank = MonitorBank(MonitorConfig(model="WH"))
    assert bank.nx == 10 and bank.ukf.w.Wm.shape == (21,)
    assert bank._cst[0] == pytest.approx(1e-3)  # h_max: one ROS2 step per 1 ms sample


# evaluation/outputs_hash.py --duration-s 1.0 on the branch base (before the WH process model)
C5_HASHES_1S = {
    "leak_step": "f38cf6ed25e9932b58355e98e8d0a1dbe21acd996bd9aa710e02bea2d6a095b2",
    "supply_drop": "8aaafa986abda11002f57047e74fa61e8cafa7bd7df10ae6e35189811c5b19c2",
}


C5_CONFIG = c_type_config("C5")


def test_c_type_outputs_unchanged():
    from evaluation import outputs_hash as mod

    for name in ("leak_step", "supply_drop"):
        assert mod.scenario_hash(name, 1.0, config=C5_CONFIG)[0] == C5_HASHES_1S[name]


# evaluation/outputs_hash.py --duration-s 1.0 with WH's one ROS2 step per sample (decisions/0012;
# the full-length hashes are in docs/evaluation.md, "Output hashes")
WH_HASHES_1S = {
    "leak_step": "22ca73fb20c83728e9028690d6a6e2f8a38f88303714258017c387004881fb3f",
    "supply_drop": "b731521ce23dd967ee68119d3bd5475e17c47299ff8e98e3c82b001a2e9578da",
}


def test_wh_outputs_are_those_of_the_one_step_integrator():
    from evaluation import outputs_hash as mod

    for name in ("leak_step", "supply_drop"):
        assert mod.scenario_hash(name, 1.0)[0] == WH_HASHES_1S[name]
