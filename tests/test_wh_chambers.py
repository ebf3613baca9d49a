"""WH's chambers in the filter (docs/estimation.md, "Stroke-dependent chambers and the supply
walk"): the volumes V0 +- A x_J and their stiffness, the chambers' common-mode process noise,
and P_SR's random walk freed by the adaptive step on a supply drop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models import eha_reduced_wh as erw
from service.cli.commands.estimate import evaluate
from service.monitor import Baseline, MonitorBank, MonitorConfig
from service.monitor.calibration import measured_run
from service.monitor.ukf import BatchUKF, process_covariance, ukf_step_batch
from service.sim.scenarios import load_scenario

BASE = Baseline.default("WH")
RP = BASE.reduced_params()
PRM = erw.param_vector(RP, BASE.v_c, BASE.beta)
V0, AREA = BASE.v_c, BASE.area  # 7e-5 m^3, 1e-3 m^2


def test_chamber_volumes_and_stiffness_by_hand():
    v1, v2 = erw.chamber_volumes(0.02, AREA, V0)
    assert (v1, v2) == pytest.approx((9e-5, 5e-5), rel=1e-12)
    lam0 = erw.stiff_modes(RP, V0, BASE.beta, 0.0)["chamber"]  # 6.49e3 1/s at V0
    k_o = math.sqrt(2 * RP.p_sr_rated) / (RP.x_ss * RP.g_pq)
    by_hand = (
        BASE.beta
        / V0
        * (2 * k_o * (RP.x_ss + RP.x_sm) / math.sqrt(5e-3 * RP.p_sr_rated) + 2 * RP.c_land)
    )
    assert lam0 == pytest.approx(by_hand, rel=1e-12)
    assert lam0 == pytest.approx(6489, rel=1e-3)  # the datasheet baseline
    # past the stroke the floor 0.25 V0 holds: the chamber mode is 4 times V0's, 2.6e4 1/s;
    # one ROS2 step of 1 ms damps it 7.6-fold (|R(-26)| = 0.13; tests/test_wh_ros2.py)
    assert min(erw.chamber_volumes(-0.09, AREA, V0)) == pytest.approx(0.25 * V0)
    assert abs(erw.ros2_amplification(-4 * lam0 * 1e-3)) == pytest.approx(0.1316, abs=1e-3)


def test_each_chamber_stiffness_follows_its_volume():
    """Spool at null, chambers equal, jack moving: the orifices balance, so dp~1/dt = -beta
    A v_J / V1 and dp~2/dt = beta A v_J / V2 (docs/models.md eq. 5b), by hand; the compiled
    right-hand side agrees."""
    rp = RP._replace(x_0=0.0, skew=0.0)
    prm = erw.param_vector(rp, V0, BASE.beta)
    p = rp.p_r + 0.5 * 20e6
    x_j, v_j = 0.03, 0.01
    _, d1, d2 = erw.rhs_nb(0.0, x_j, v_j, p, p, 0.0, rp.p_r + 20e6, 0.0, prm)
    assert d1 == pytest.approx(-BASE.beta * AREA * v_j / (V0 + AREA * x_j), rel=1e-9)
    assert d2 == pytest.approx(BASE.beta * AREA * v_j / (V0 - AREA * x_j), rel=1e-9)
    assert d2 / -d1 == pytest.approx(10e-5 / 4e-5, rel=1e-9)


def test_compiled_step_equals_numpy_off_mid_stroke():
    x = np.array([1.1e-5, 2e-4, -0.032, 4e-3, 4000.0, 19.5e6, 3e-13, 5e-5, 12.6e6, 8.4e6])
    out = np.empty(10)
    for n_sub in (1, 2):  # one step per 1 ms sample; a longer interval is split
        erw.step_nb(x, 2.3e-4, n_sub * 1e-3, n_sub, PRM, out)
        ref = erw.step(x, 2.3e-4, n_sub * 1e-3, RP, n_sub, V0, BASE.beta)
        np.testing.assert_allclose(out, ref, rtol=1e-11, atol=1e-12)


def test_one_step_at_the_stroke_end_keeps_the_chamber_on_its_reference():
    """Near the end stop (x_J = -48 mm, V1 = 2.2e-5 m^3), spool wide open into chamber 1:
    after 50 ms at one ROS2 step per sample chamber 1 sits within 1 kPa of a 100-substep RK4
    reference; the explicit RK4 scheme at the mid-stroke 3 substeps is past its stability
    limit in the laminar band and settles 40 kPa off."""
    x = np.array([5e-4, 0.0, -0.048, 0.0, 0.0, 20e6, 0.0, 0.0, 20e6, 1e6])
    rp = RP._replace(mass=1e9)  # jack held: the chamber mode alone
    one = x.copy()
    with np.errstate(all="ignore"):
        for _ in range(50):
            one = erw.step(one, 0.01, 1e-3, rp, 1, V0, BASE.beta)
        runs = {}
        for n in (3, 100):
            y = x.copy()
            for _ in range(50):
                y = erw.step_rk4(y, 0.01, 1e-3, rp, n, V0, BASE.beta)
            runs[n] = y[8]
    assert abs(one[8] - runs[100]) < 1e3
    assert abs(runs[3] - runs[100]) > 2e4


def test_common_mode_process_noise_by_hand():
    """The chamber columns of q hold the differential and common modes (p~1 -+ p~2)/sqrt 2:
    Var p~k = (d + s)/2, Cov = (s - d)/2 per second. With every channel masked the step adds
    exactly that to the propagated covariance."""
    q = np.arange(1.0, 11.0)
    Q = process_covariance(q, 10)
    assert np.allclose(np.diag(Q)[:8], q[:8]) and Q[8, 8] == Q[9, 9] == 9.5
    assert Q[8, 9] == Q[9, 8] == 0.5
    # p~1 - p~2 has variance d = 9, p~1 + p~2 has s = 10 (times 2: the sqrt 2 of the modes)
    u = np.array([1.0, -1.0])
    assert u @ Q[8:, 8:] @ u == pytest.approx(2 * 9.0)
    assert np.ones(2) @ Q[8:, 8:] @ np.ones(2) == pytest.approx(2 * 10.0)
    # the compiled step adds it (dt = 1 ms): two q vectors that differ in the modes only
    bank = MonitorBank(MonitorConfig(model="WH"))
    x0 = np.array([1.1e-5, 2e-4, 1e-3, 2e-3, 4000.0, 19.5e6, 3e-13, 5e-5, 12.6e6, 8.4e6])
    ukf = BatchUKF(10, alpha=0.5)
    w = ukf.w
    Ps = []
    for qq in (bank._q, bank._q * np.r_[np.ones(8), 4.0, 0.25]):
        x = (x0 / bank.scale)[None]
        P = np.diag((bank._p0 / bank.scale) ** 2)[None]
        y, nis, st = np.zeros((1, 5)), np.zeros(1), np.zeros(1, np.int64)
        ukf_step_batch(x, P, np.zeros((1, 5)), np.zeros((1, 5), bool), np.array([2.3e-4]),
                       np.array([1e-3]), np.array([1]), qq, bank.R, bank.scale, bank._zscale,
                       w.Wm, w.Wc, w.c, bank._prm, y, nis, st)  # fmt: skip
        assert st[0] == 0
        Ps.append(P[0])
    dQ = (process_covariance(bank._q * np.r_[np.ones(8), 4.0, 0.25], 10)
          - process_covariance(bank._q, 10)) * 1e-3  # fmt: skip
    np.testing.assert_allclose(Ps[1] - Ps[0], dQ, rtol=1e-9, atol=1e-15)


def test_supply_walk_and_chamber_modes_from_the_settings():
    cfg = MonitorConfig(model="WH", process={"p_sr": 1e6, "p_ch_common": 1e6})
    bank = MonitorBank(cfg)
    assert bank._q[5] == pytest.approx((1e6 / bank.scale[5]) ** 2)
    assert bank._q[8] == bank._q[9]  # equal modes: uncorrelated chambers


@pytest.mark.slow
def test_supply_walk_freed_by_the_adaptive_step():
    """Bundled supply drop (20 -> 14 MPa step): WH's slow P_SR walk alone settles within 5 %
    only after 0.05 s; joined to the adaptive step (the default) within 0.02 s, with a
    steady P_SR on the healthy run within 0.12 % RMS (the 2e6 walk: 0.25 %)."""
    drop = load_scenario("supply_drop")
    fast = evaluate(drop, MonitorConfig(model="WH"))
    held = evaluate(drop, MonitorConfig(model="WH", adapt_p_sr=0.0))
    assert fast["p_sr_settle_s"] <= 0.02 < 0.05 <= held["p_sr_settle_s"]
    assert fast["p_sr_rms_pct"] < held["p_sr_rms_pct"]
    healthy = load_scenario("healthy_noise")
    h = evaluate(healthy, MonitorConfig(model="WH"))
    wide = evaluate(healthy, MonitorConfig(model="WH", process={"p_sr": 2e6, "p_ch_common": 1e6}))
    assert h["p_sr_rms_pct"] < 0.12 < 0.2 < wide["p_sr_rms_pct"]
    assert math.isfinite(h["c_lk_rms_pct"]) and h["false_alarms"] == 0


def test_measured_run_has_no_supply_sensor_by_default():
    """The bundled figures read P_SR from the chambers only: no supply transducer."""
    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 0.05})
    assert "p_sr" not in measured_run(sc)[1]


@pytest.mark.slow
def test_c_lk_held_on_samples_far_outside_the_model():
    """est_overload: the 1 ms step to a 24 kN load moved C_Lk to 1.27x nominal, held there
    through the back-driving (the speed gate). Holding C_Lk on a sample whose adaptive scale
    NIS/dof / adapt_nis exceeds 20 (the WH default) brings the run's C_Lk RMS from 19.7 % to
    14.1 % (with i_b held past the underlap; 21.5 % to 16.2 % before); on the healthy run
    (nothing that far outside the model) it changes nothing."""
    over = load_scenario("est_overload")
    held = evaluate(over, MonitorConfig(model="WH"))
    free = evaluate(over, MonitorConfig(model="WH", c_lk_gate_adapt=0.0))
    assert held["c_lk_rms_pct"] < 16.0
    assert free["c_lk_rms_pct"] > held["c_lk_rms_pct"] + 4.0
    healthy = load_scenario("healthy_noise")
    a = evaluate(healthy, MonitorConfig(model="WH"))
    b = evaluate(healthy, MonitorConfig(model="WH", c_lk_gate_adapt=0.0))
    assert a["c_lk_rms_pct"] == b["c_lk_rms_pct"]
