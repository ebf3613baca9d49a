"""The WH valve model (docs/models.md): its equations against hand-computed values, the
compiled kernels against the numpy reference, its static characteristic against HF, and the
paper-bench and suite targets of issue 11 against HF."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models import compiled as kern
from models.eha import n_substeps, simulate
from models.hf_valve import hf_static_p12
from models.metrics import nrmse_pct
from models.params import DEFAULT_PARAMS, wh_params
from models.wh_valve import (
    wh_derivatives,
    wh_land_flows,
    wh_orifice,
    wh_static_p12,
    wh_static_pressures,
)
from service.sim.scenarios import load_scenario

P = DEFAULT_PARAMS
WP = wh_params(P)
P_SR = 20e6


# -- parameters and land law (eqs. 1-4) -------------------------------------------------------
def test_orifice_coefficient_from_c_type_parameters() -> None:
    # K_o = sqrt(2 P_SR,nom) / (x_SS G_PQ) = sqrt(4e7) / (1e-4 * 7.4e11) = 8.5467e-5
    assert WP.k_o == pytest.approx(math.sqrt(4e7) / 7.4e7, rel=1e-12)
    assert WP.k_o == pytest.approx(8.5467e-5, rel=1e-4)
    # the same valve as HF's turbulent land: Cd w sqrt(2 / rho) (physics.md section 3)
    assert WP.k_o == pytest.approx(P.cd * P.w_eff * math.sqrt(2.0 / P.rho), rel=1e-12)
    assert WP.dp_lam == pytest.approx(0.1e6)
    assert WP.v_c == pytest.approx(70e-6) and WP.beta == pytest.approx(1.4e9)


def test_orifice_hand_computed() -> None:
    k = WP.k_o
    # turbulent: a = 0.1 mm, dp = 1 MPa: K a sqrt(dp) = 8.5467e-5 * 1e-4 * 1000 = 8.5467e-6
    assert float(wh_orifice(1e-4, 1e6, WP)) == pytest.approx(k * 1e-4 * 1e3, rel=1e-12)
    assert float(wh_orifice(1e-4, -1e6, WP)) == pytest.approx(-k * 1e-4 * 1e3, rel=1e-12)
    # laminar band: dp = 0.05 MPa: K a dp / sqrt(dp_lam) = K a 5e4 / 316.23
    assert float(wh_orifice(1e-4, 5e4, WP)) == pytest.approx(k * 1e-4 * 5e4 / 1e5**0.5)
    # continuous at the band edge, closed land passes nothing
    assert float(wh_orifice(2e-4, 1e5 * (1 + 1e-12), WP)) == pytest.approx(
        float(wh_orifice(2e-4, 1e5 * (1 - 1e-12), WP)), rel=1e-9
    )
    assert float(wh_orifice(-1e-5, 5e6, WP)) == 0.0


def test_compiled_orifice_and_chambers_match_numpy() -> None:
    rng = np.random.default_rng(2)
    prm = kern.param_array(P)
    wc = kern._wh_consts(prm)
    n = 2000
    x_s = rng.uniform(-P.x_sm, P.x_sm, n)
    v_j = rng.uniform(-0.3, 0.3, n)
    pt1 = rng.uniform(-5e7, 6e7, n)  # below P_vap: a cavity; above P_S: water hammer
    pt2 = rng.uniform(-5e7, 6e7, n)
    p_sr = rng.uniform(0.0, 25e6, n)
    c_lk = rng.uniform(0.0, 5e-12, n)
    d1, d2 = wh_derivatives(x_s, v_j, pt1, pt2, p_sr, c_lk, WP, P.area)
    for k in range(n):
        g1, g2, p12 = kern._wh_chambers(
            x_s[k], P.area * v_j[k], pt1[k], pt2[k], p_sr[k], c_lk[k], wc
        )
        scale = WP.beta / WP.v_c * 1e-3  # 1 L/s of flow
        assert g1 == pytest.approx(d1[k], rel=1e-12, abs=1e-12 * scale)
        assert g2 == pytest.approx(d2[k], rel=1e-12, abs=1e-12 * scale)
        assert p12 == max(pt1[k], P.p_vap) - max(pt2[k], P.p_vap)
        dp = rng.uniform(-3e7, 3e7) * rng.choice([1.0, 1e-3])
        a = rng.uniform(-2e-4, 6e-4)
        assert kern.wh_orifice(a, dp, wc[2], wc[3], wc[4]) == pytest.approx(
            float(wh_orifice(a, dp, WP)), rel=1e-13, abs=1e-25
        )


def test_rhs_wh_matches_numpy_chambers() -> None:
    prm = kern.param_array(P)
    y = np.array([0.004, 2e-4, 0.01, 0.01, -0.05, 15e6, -3e6])  # chamber 2 cavitating
    dy = np.empty(7)
    kern.rhs(y, 0.02, 1e4, 10e6, 2e-13, prm, kern.MODEL_IDS["WH"], dy)
    d1, d2 = wh_derivatives(2e-4, -0.05, 15e6, -3e6, 10e6, 2e-13, WP, P.area)
    assert dy[5] == pytest.approx(float(d1), rel=1e-12)
    assert dy[6] == pytest.approx(float(d2), rel=1e-12)
    # jack force from P12 = P1 - P_vap (the cavity holds chamber 2 at vapour pressure)
    p12 = 15e6 - P.p_vap
    f = P.area * p12 - 1e4 - P.c_v * (-0.05) + P.f_d
    assert dy[4] == pytest.approx(f / P.mass, rel=1e-12)


def test_cavity_is_a_volume_below_vapour_pressure() -> None:
    """Below P_vap the state no longer changes the flows (eq. 6): the derivative is the
    same at p~2 = -1 MPa and -30 MPa, and the chamber pressure is P_vap."""
    a = wh_derivatives(3e-4, -0.05, 12e6, -1e6, 10e6, 2e-13, WP, P.area)
    b = wh_derivatives(3e-4, -0.05, 12e6, -30e6, 10e6, 2e-13, WP, P.area)
    assert a[0] == b[0] and a[1] == b[1]
    # the cavity grows at the jack flow less what land 4 feeds from return at P_R - P_vap
    q4 = WP.k_o * (WP.x_ss + 3e-4) * math.sqrt(P.p_r - P.p_vap)
    q_lk = P.c_lk * (12e6 - P.p_vap)
    assert float(a[1]) == pytest.approx(WP.beta / WP.v_c * (q4 + q_lk - P.area * 0.05), rel=1e-9)


# -- static characteristic (eq. 7) ------------------------------------------------------------
def test_static_null_and_blocked_port_hand_computed() -> None:
    p1, p2 = wh_static_pressures(0.0, 0.0, P_SR, WP)
    assert float(p1) == pytest.approx(P.p_r + P_SR / 2, abs=1.0)
    assert float(p2) == pytest.approx(P.p_r + P_SR / 2, abs=1.0)
    # no leakage, x_S = x_SS / 2, all lands turbulent: P1 - P_R = P_SR (u+x)^2 / ((u+x)^2 +
    # (u-x)^2) = 18 MPa, P12 = P_SR 2 u x / (u^2 + x^2) = 16 MPa
    wp0 = WP._replace(c_lk=0.0)
    assert float(wh_static_p12(0.5e-4, 0.0, P_SR, wp0)) == pytest.approx(16e6, rel=1e-9)
    # x_S = x_SS, C_Lk = 2e-13: lands 2, 3 closed; the leakage drops d = P_S - P1 = P2 - P_R
    # inside the laminar band: 2 K_o x_SS d / sqrt(dp_lam) = C_Lk (P_SR - 2 d)
    k = 2 * WP.k_o * WP.x_ss / math.sqrt(WP.dp_lam)
    d = P.c_lk * P_SR / (k + 2 * P.c_lk)
    assert d < WP.dp_lam
    assert float(wh_static_p12(1e-4, 0.0, P_SR, WP)) == pytest.approx(P_SR - 2 * d, rel=1e-9)


def test_static_characteristic_close_to_hf_and_above_p_sr() -> None:
    """The P12-x_S family (seed Fig. 2) against HF's: RMS difference 3.1 % of P_SR (at most
    2.9 % for |Q_J| <= 3 L/min, 12 % at the +-6 L/min peaks, where HF's clearance leakage
    lowers the peak), with the water-hammer branch above P_SR where the jack drives flow
    back through the valve."""
    x_s = np.linspace(-P.x_sm, P.x_sm, 41)
    q_j = np.array([-1e-4, -5e-5, 0.0, 5e-5, 1e-4])
    xs, qj = np.meshgrid(x_s, q_j)
    wh = wh_static_p12(xs, qj, P_SR, WP)
    hf = hf_static_p12(xs, qj, P_SR, P)
    d = np.abs(wh - hf)
    assert np.sqrt(np.mean(d**2)) < 0.04 * P_SR
    assert d[1:4].max() < 0.035 * P_SR and d.max() < 0.15 * P_SR
    assert wh[0].max() > 2.2 * P_SR and hf[0].max() > 2.2 * P_SR  # Q_J = -6 L/min
    assert wh[0].max() == pytest.approx(hf[0].max(), rel=0.06)
    np.testing.assert_allclose(wh, -wh[::-1, ::-1], atol=1e-3 * P_SR)  # odd symmetry


# -- paper bench targets (issue 11) ------------------------------------------------------------
@pytest.fixture(scope="module")
def paper_runs():
    sc = load_scenario("paper_bench")
    return {v: simulate(sc, v) for v in ("HF", "C5", "WH")}


def test_paper_bench_nrmse_targets(paper_runs) -> None:
    hf, wh, c5 = paper_runs["HF"], paper_runs["WH"], paper_runs["C5"]
    p12 = nrmse_pct(wh.p12, hf.p12)
    x_j = nrmse_pct(wh.x_j, hf.x_j)
    assert p12 <= 2.5  # target: at most half of C5's 5.04 %
    assert p12 <= 0.5 * nrmse_pct(c5.p12, hf.p12)
    assert x_j <= 30.0  # C-types about 150 %
    assert nrmse_pct(c5.x_j, hf.x_j) > 100.0  # the seed's finding still holds
    # measured 0.86 % and 0.69 %: a regression guard well inside the targets
    assert p12 < 1.5 and x_j < 1.5


def test_paper_bench_water_hammer_peak(paper_runs) -> None:
    hf, wh = paper_runs["HF"], paper_runs["WH"]
    after = wh.t >= 0.75  # load reversal at P_SR = 10 MPa
    peak_wh = np.abs(wh.p12[after]).max()
    peak_hf = np.abs(hf.p12[after]).max()
    assert peak_hf == pytest.approx(46.9e6, rel=0.01)
    assert peak_wh > 10e6  # above P_SR
    assert abs(peak_wh - peak_hf) <= 0.25 * peak_hf  # measured 42.3 MPa: -10 %


def test_paper_bench_back_driving_speed(paper_runs) -> None:
    """After the supply drop the 12 kN load exceeds A P_SR = 10 kN: HF and WH are back-driven
    against land 1 (P1 > P_S) with chamber 2 at vapour pressure; C5 runs to the end stop."""
    hf, wh, c5 = paper_runs["HF"], paper_runs["WH"], paper_runs["C5"]
    w = (hf.t > 0.5) & (hf.t < 0.7)
    v_hf, v_wh = hf.v_j[w].mean(), wh.v_j[w].mean()
    assert v_hf == pytest.approx(-0.0534, rel=0.02)
    assert abs(v_wh - v_hf) <= 0.30 * abs(v_hf)
    assert np.all(wh.p2[w] == P.p_vap)  # cavitating
    assert np.all(wh.p1[w] > P.p_r + 10e6)  # above the supply: held against land 1
    # hand check (eq. 9): the jack flow leaves chamber 1 back through land 1 and the leak,
    # P1 - P_S = P12 + P_vap - P_R - P_SR, P12 from the force balance at the mean speed
    p12 = (12e3 + P.c_v * v_wh - P.f_d) / P.area
    q1 = WP.k_o * (WP.x_ss + P.x_sm) * math.sqrt(p12 + P.p_vap - P.p_r - 10e6)
    assert -v_wh == pytest.approx((q1 + P.c_lk * p12) / P.area, rel=0.01)
    w5 = (c5.t > 0.35) & (c5.t < 0.5)
    assert np.abs(c5.v_j[w5]).max() > 0.5  # C5: up to 1 m/s towards the stop


def test_stable_at_monitor_step_and_coarse() -> None:
    """At a 1 ms step (3 substeps) WH stays on its 1e-4 s run."""
    sc = load_scenario("paper_bench")
    fine = simulate(sc, "WH")
    coarse_sc = sc.model_copy(update={"step_s": 1e-3})
    assert n_substeps(coarse_sc.eha_params(), "WH", 1e-3) == 3
    assert n_substeps(sc.eha_params(), "WH", 1e-4) == 1
    coarse = simulate(coarse_sc, "WH")
    assert np.all(np.isfinite(coarse.p12))
    assert nrmse_pct(coarse.x_j, fine.x_j[::10]) < 0.1
    assert nrmse_pct(coarse.p12, fine.p12[::10]) < 0.5


def test_land_flows_balance_at_rest() -> None:
    q1, q2, q3, q4 = wh_land_flows(0.0, P.p_r + 10e6, P.p_r + 10e6, P_SR, WP)
    assert float(q1) == pytest.approx(float(q2)) and float(q3) == pytest.approx(float(q4))
    assert float(q1) == pytest.approx(WP.k_o * WP.x_ss * math.sqrt(10e6), rel=1e-12)
