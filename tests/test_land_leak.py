"""The WH filter's land clearance leak ``c_land`` (docs/estimation.md, "Land clearance leak
(WH)"): its value, its flows, the calibration's split, and why it is there: the HF valve's
laminar clearance flow does not scale with the supply, the orifices' pressure coefficient does."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.eha_reduced_wh import K_WH_C_LAND, N_PRM_WH, land_flows, param_vector
from models.hf_valve import hf_static_pressures
from models.params import EHAParams
from service.monitor import Baseline, MonitorConfig
from service.monitor.calibration import calibrate, identify_baseline, measured_run
from service.sim.scenarios import load_scenario

P = EHAParams()


def test_g_lam_open_by_hand():
    """w c_r^3 / (12 mu l_min), w = sqrt(P_SR rho) / (Cd x_SS G_PQ,seed) (physics.md 3.5)."""
    w = math.sqrt(20e6 * P.rho) / (P.cd * 1e-4 * P.g_pq_seed)
    g = w * (2.5e-6) ** 3 / (12 * 0.0119 * 5e-6)
    assert P.g_lam_open == pytest.approx(g, rel=1e-12)
    assert P.g_lam_open == pytest.approx(6.32e-14, rel=1e-3)  # about a third of C_Lk


def test_nominal_baselines_carry_it_for_wh_only():
    assert Baseline.nominal("WH").c_land == pytest.approx(P.g_lam_open)
    assert Baseline.nominal("C5").c_land == 0.0
    rp = Baseline.nominal("WH").reduced_params()
    prm = param_vector(rp, 7e-5, 1.4e9)
    assert len(prm) == N_PRM_WH and prm[K_WH_C_LAND] == pytest.approx(P.g_lam_open)


def test_open_lands_act_as_a_cross_port_leak():
    """All four lands open, matched, P1 + P2 = P_S + P_R: the clearance share of chamber 1's
    net flow Q1 - Q2 is c_land (P_S - P1) - c_land (P1 - P_R) = -c_land P12."""
    rp = Baseline.nominal("WH").reduced_params()
    rp0 = rp._replace(c_land=0.0)
    p_sr, p12 = 20e6, 3e6
    p1 = rp.p_r + 0.5 * (p_sr + p12)
    p2 = rp.p_r + 0.5 * (p_sr - p12)
    q = land_flows(10e-6, p1, p2, p_sr, rp)
    q0 = land_flows(10e-6, p1, p2, p_sr, rp0)
    assert (q[0] - q[1]) - (q0[0] - q0[1]) == pytest.approx(-rp.c_land * p12, rel=1e-12)
    assert (q[2] - q[3]) - (q0[2] - q0[3]) == pytest.approx(rp.c_land * p12, rel=1e-12)


def test_a_closed_land_has_no_clearance_leak():
    """Past the underlap, lands 2 and 3 are closed: only lands 1 and 4 carry c_land dp."""
    rp = Baseline.nominal("WH").reduced_params()
    x = 1.5 * rp.x_ss
    p1, p2 = rp.p_r + 12e6, rp.p_r + 8e6
    q = land_flows(x, p1, p2, 20e6, rp)
    q0 = land_flows(x, p1, p2, 20e6, rp._replace(c_land=0.0))
    assert q[1] == q0[1] == 0.0 and q[2] == q0[2] == 0.0
    assert q[0] - q0[0] == pytest.approx(rp.c_land * (rp.p_r + 20e6 - p1), rel=1e-12)
    assert q[3] - q0[3] == pytest.approx(rp.c_land * (p2 - rp.p_r), rel=1e-12)


def _implied_c_lk(rp, x_s, p1, p2, p_sr):
    """The leak the filter's lands need for the HF static point (blocked jack): (Q1 - Q2) / P12."""
    q1, q2, _, _ = land_flows(x_s, p1, p2, p_sr, rp)
    return (q1 - q2) / (p1 - p2)


def test_supply_independent_leak_reading_at_a_hold():
    """The HF valve held at blocked ports with its leak C_Lk, at the rated supply and at 0.6 of
    it. A WH law that lumps the clearance flow into its orifices' pressure coefficient (1/G_PQ
    + G_lam, what the calibration identifies at rated supply) reads the reduced supply's leak
    low by about 0.1 C_Lk; with the clearance leak apart it reads C_Lk at both supplies."""
    x_s = np.array([5e-6, 15e-6, 30e-6])
    nom = Baseline.nominal("WH")
    rp = nom.reduced_params()._replace(g_pq=P.g_pq, x_ss=P.x_ss)
    k_q = 2 * P.p_sr / (P.x_ss * P.g_pq)  # null flow gain, held by the lumped law
    g_lumped = 1.0 / (1.0 / P.g_pq + P.g_lam_open)
    rp_lumped = rp._replace(c_land=0.0, g_pq=g_lumped, x_ss=2 * P.p_sr / (k_q * g_lumped))
    err = {}
    for ratio in (1.0, 0.6):
        p_sr = ratio * P.p_sr
        p1, p2 = hf_static_pressures(x_s, 0.0, p_sr, P)
        for name, r in (("apart", rp), ("lumped", rp_lumped)):
            err[name, ratio] = (_implied_c_lk(r, x_s, p1, p2, p_sr) - P.c_lk) / P.c_lk
    assert np.all(np.abs(err["apart", 1.0]) < 0.02)
    assert np.all(np.abs(err["apart", 0.6]) < 0.02)
    assert np.all(np.abs(err["lumped", 1.0]) < 0.02)  # the same reading at rated supply...
    assert np.all(err["lumped", 0.6] < -0.06)  # ... and a low one at 0.6 of it


def test_calibration_recovers_the_valve_geometry():
    """Noise-free healthy run: with the clearance leak apart, WH's null fit gives the valve's
    x_SS (100 um) within 1.5 % and G_PQ (7.4e11) within 1 %, and after the bias passes both
    stay within 2 %; lumped, the null fit reads x_SS 5 % wide."""
    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 3.0})
    sim, _ = measured_run(sc)
    keys = ("t", "x_cmd", "i", "x_s", "x_j", "p1", "p2")
    truth = {k: getattr(sim, k) for k in keys}
    lsq = identify_baseline(truth, "WH")
    assert lsq.c_land == pytest.approx(P.g_lam_open)
    assert lsq.x_ss == pytest.approx(P.x_ss, rel=0.015)
    assert lsq.g_pq == pytest.approx(P.g_pq, rel=0.01)
    b = calibrate(truth, config=MonitorConfig(model="WH"))
    assert b.x_ss == pytest.approx(P.x_ss, rel=0.02)
    assert b.g_pq == pytest.approx(P.g_pq, rel=0.02)
    # without the split the null fit's 1/G_PQ carries G_lam at the same flow gain: x_SS wider
    x_lumped = lsq.x_ss * lsq.g_pq * (1.0 / lsq.g_pq + lsq.c_land)
    assert x_lumped > 1.045 * P.x_ss


def test_calibration_names_a_clearance_leak_above_the_null_coefficient():
    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 2.0})
    sim, _ = measured_run(sc)
    truth = {"t": sim.t, "x_s": sim.x_s, "x_j": sim.x_j, "p1": sim.p1, "p2": sim.p2}
    import service.monitor.calibration as cal

    big = Baseline.nominal("WH").model_copy(update={"c_land": 1e-11})
    orig = cal.Baseline.nominal
    try:
        cal.Baseline.nominal = classmethod(lambda cls, law="C5", params=None: big)
        with pytest.raises(ValueError, match="c_land"):
            identify_baseline(truth, "WH")
    finally:
        cal.Baseline.nominal = orig
