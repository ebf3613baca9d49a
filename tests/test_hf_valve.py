"""HF four-way valve and chambers (physics.md section 3): orifice law, bulk modulus, static
pressure balance, consistency with the simplified laws, fluid conservation, compiled kernels."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

from models import compiled as kern
from models.hf_valve import (
    beta_eff,
    chamber_derivatives,
    chamber_volumes,
    hf_static_p12,
    hf_static_pressures,
    land_flows,
    land_openings,
    orifice_flow,
    orifice_slope,
)
from models.params import DEFAULT_PARAMS

P = DEFAULT_PARAMS
P_SR = 20e6


def test_orifice_flow_hand_value() -> None:
    # a = 0.1 mm, dp = 10 MPa: Cd w a = 0.61 * 2.8893e-3 * 1e-4 = 1.7625e-7 m^2,
    # sqrt(2/rho) dp / (dp^2 + dp_tr^2)^(1/4) = sqrt(2 dp / rho) (1 + 1e-4)^(-1/4)
    #   = 153.39 * 0.999975; turbulent 2.7035e-5 m^3/s.
    # G_lam = w c_r^3 / (12 mu l_min) = 2.8893e-3 * 1.5625e-17 / 7.14e-7 = 6.323e-14,
    #   laminar 6.32e-7 m^3/s. Total 2.767e-5 m^3/s.
    q = float(orifice_flow(1e-4, 1e7, P))
    assert q == pytest.approx(2.767e-5, rel=1e-3)
    # closed land (a = -0.1 mm): laminar only, G_lam = w c_r^3 / (12 mu (1e-4 + 5e-6))
    g_closed = P.w_eff * P.c_r**3 / (12 * P.mu * 1.05e-4)
    assert float(orifice_flow(-1e-4, 1e7, P)) == pytest.approx(g_closed * 1e7, rel=1e-12)
    # odd in dp
    assert float(orifice_flow(3e-4, -2e6, P)) == pytest.approx(-float(orifice_flow(3e-4, 2e6, P)))


def test_orifice_slope_matches_finite_difference() -> None:
    a = np.array([-1e-4, 0.0, 1e-4, 6e-4, 6e-4])
    dp = np.array([1e6, 5e4, 0.0, -3e5, 1.5e7])
    eps = 1.0
    fd = (orifice_flow(a, dp + eps, P) - orifice_flow(a, dp - eps, P)) / (2 * eps)
    np.testing.assert_allclose(orifice_slope(a, dp, P), fd, rtol=1e-6)
    # bounded slope at dp = 0: Cd w a sqrt(2/rho) / sqrt(dp_tr) (+ laminar)
    k0 = P.cd * P.w_eff * 6e-4 * math.sqrt(2 / P.rho) / math.sqrt(P.dp_tr)
    assert float(orifice_slope(6e-4, 0.0, P)) == pytest.approx(k0, rel=1e-3)


def test_beta_eff_values() -> None:
    # 20 MPa: alpha = 0.002 (101.3e3/19.999e6)^(1/1.4) = 4.62e-5;
    #   alpha beta_l / (kappa P*) = 2.31e-3 -> beta = 1.4e9 / 1.00231 = 1.3968e9
    assert float(beta_eff(20e6, P)) == pytest.approx(1.3968e9, rel=1e-3)
    # 1 atm: alpha = 0.0020142, ratio = 20.08 -> beta = 1.4e9 / 21.08 = 6.64e7
    assert float(beta_eff(101.3e3, P)) == pytest.approx(6.64e7, rel=2e-3)
    # floor: at and below P_vap the modulus is tiny (P* = 1 Pa), monotone in P
    p = np.array([0.0, 1e3, 2e3, 1e4, 1e5, 1e6, 1e7, 3e7])
    b = beta_eff(p, P)
    assert b[0] == b[1] and b[0] < 1.0
    assert np.all(np.diff(b[1:]) > 0) and b[-1] < P.beta_l


def test_blocked_port_reaches_p_sr_at_x_ss() -> None:
    # pure turbulent law: P12 = P_SR 2 u x / (u^2 + x^2) -> 1 at x = u, 0.8 at x = u/2
    u = P.x_ss
    y0 = hf_static_p12(np.array([0.5 * u, u]), 0.0, P_SR, P, c_lk=0.0) / P_SR
    assert y0[1] == pytest.approx(1.0, abs=0.01)  # 0.9976 (laminar leakage, dp_tr smoothing)
    assert y0[0] == pytest.approx(0.8, rel=0.05)  # 0.780
    # with the seed C_Lk the leakage takes about 1 %
    y1 = float(hf_static_p12(u, 0.0, P_SR, P)) / P_SR
    assert 0.97 < y1 < y0[1]
    # the supply dependence: P12/P_SR at x = u is nearly independent of P_SR
    y2 = float(hf_static_p12(u, 0.0, 10e6, P, c_lk=0.0)) / 10e6
    assert y2 == pytest.approx(y0[1], abs=0.005)


def _no_load_flow(x_s: float) -> float:
    """Q_J with P12 = 0 (root of the monotone static characteristic)."""
    return brentq(lambda q: float(hf_static_p12(x_s, q, P_SR, P)), -1e-3, 1e-3, xtol=1e-15)


def test_no_load_flow_gain() -> None:
    g_q = P.cd * P.w_eff * math.sqrt(P_SR / P.rho)  # 0.61 * 2.8893e-3 * 153.39 = 0.27027 m^2/s
    assert g_q == pytest.approx(0.27027, rel=1e-4)
    assert P.g_q == pytest.approx(g_q, rel=1e-12)
    # beyond the underlap (one land of each pair shut) the slope is G_Q
    slope = (_no_load_flow(5e-4) - _no_load_flow(3e-4)) / 2e-4
    assert slope == pytest.approx(g_q, rel=0.01)
    # inside it both pairs meter: Q_J = G_Q ((u + x) - (u - x)) = 2 G_Q x
    assert _no_load_flow(5e-5) / 5e-5 == pytest.approx(2 * g_q, rel=0.01)
    # at full stroke: G_Q (u + x_SM) = 0.27027 * 6e-4 = 1.62e-4 m^3/s = 162 mm/s on A = 1e-3 m^2
    assert _no_load_flow(5e-4) == pytest.approx(1.62e-4, rel=0.01)


def test_static_p12_odd_symmetry_and_monotone() -> None:
    rng = np.random.default_rng(5)
    n = 3000
    x_s = rng.uniform(-5e-4, 5e-4, n)
    q_j = rng.uniform(-3e-4, 3e-4, n)
    p_sr = rng.uniform(1e6, 25e6, n)
    a = hf_static_p12(x_s, q_j, p_sr, P)
    b = hf_static_p12(-x_s, -q_j, p_sr, P)
    np.testing.assert_allclose(b, -a, rtol=0, atol=1e-6 * 25e6)
    # P12 decreases with Q_J at fixed spool position
    q = np.linspace(-2e-4, 2e-4, 401)
    y = hf_static_p12(2e-4, q, P_SR, P)
    assert np.all(np.diff(y) <= 1e-6)


def test_static_broadcasting() -> None:
    x_s = np.linspace(-5e-4, 5e-4, 7)[:, None]
    q_j = np.linspace(-1e-4, 1e-4, 4)[None, :]
    y = hf_static_p12(x_s, q_j, P_SR, P)
    assert y.shape == (7, 4)
    assert y[2, 3] == pytest.approx(float(hf_static_p12(x_s[2, 0], q_j[0, 3], P_SR, P)), abs=1e-3)
    assert hf_static_p12(1e-4, 0.0, np.array([5e6, 10e6, 20e6]), P).shape == (3,)


def test_static_balance_or_physical_clip() -> None:
    """Every point either balances both chambers or sits at a documented bound."""
    rng = np.random.default_rng(11)
    n = 5000
    x_s = rng.uniform(-5e-4, 5e-4, n)
    q_j = rng.uniform(-4e-4, 4e-4, n)  # up to 2.5x the valve's capacity
    p_sr = rng.uniform(0.5e6, 25e6, n)
    p1, p2 = hf_static_pressures(x_s, q_j, p_sr, P)
    p_s = P.p_r + p_sr
    lo, hi = P.p_vap, p_s + 10 * p_sr
    assert np.all(np.isfinite(p1)) and np.all(np.isfinite(p2))
    assert np.all((p1 >= lo) & (p1 <= hi) & (p2 >= lo) & (p2 <= hi))
    a1, a2, a3, a4 = land_openings(x_s, P)
    f1 = orifice_flow(a1, p_s - p1, P) - orifice_flow(a2, p1 - P.p_r, P) - P.c_lk * (p1 - p2) - q_j
    f2 = orifice_flow(a3, p_s - p2, P) - orifice_flow(a4, p2 - P.p_r, P) + P.c_lk * (p1 - p2) + q_j
    tol = 1e-9 * P.g_q * P.x_ss
    ok1 = (np.abs(f1) < tol) | ((p1 <= lo) & (f1 < 0)) | ((p1 >= hi) & (f1 > 0))
    ok2 = (np.abs(f2) < tol) | ((p2 <= lo) & (f2 < 0)) | ((p2 >= hi) & (f2 > 0))
    assert np.all(ok1 & ok2)
    # within capacity (Q_J along the spool opening and well below G_Q (u + |x_S|)) nothing
    # is clipped
    cap = 0.3 * P.g_q * (P.x_ss + np.abs(x_s)) * np.sqrt(p_sr / P_SR)
    inside = (q_j * x_s >= 0) & (np.abs(q_j) < cap)
    assert inside.sum() > 100
    assert np.all(np.abs(f1[inside]) < tol) and np.all(np.abs(f2[inside]) < tol)
    # the bisection fallback gives the same answer as Newton
    sub = slice(0, 300)
    b1, b2 = hf_static_pressures(x_s[sub], q_j[sub], p_sr[sub], P, newton_iter=0)
    np.testing.assert_allclose(b1, p1[sub], rtol=0, atol=10.0)
    np.testing.assert_allclose(b2, p2[sub], rtol=0, atol=10.0)


def test_null_balance_pressure() -> None:
    # symmetric valve, x_S = 0, Q_J = 0: P1 = P2 = (P_S + P_R)/2 = 10.5 MPa
    p1, p2 = hf_static_pressures(0.0, 0.0, P_SR, P)
    assert float(p1) == pytest.approx(10.5e6, rel=1e-9)
    assert float(p2) == pytest.approx(10.5e6, rel=1e-9)


# -- fluid conservation in the chambers ---------------------------------------------------
SEALED = P.with_overrides(u1=-1e-4, u2=-1e-4, u3=-1e-4, u4=-1e-4, c_r=1e-9)


def test_sealed_chambers_exchange_only_through_leakage_and_compressibility() -> None:
    """All lands overlapped (clearance leakage ~1e-26 m^3/s/Pa): V1/beta1 dP1/dt + dV1/dt
    and V2/beta2 dP2/dt + dV2/dt are -Q_Lk and +Q_Lk, so the stored liquid is conserved."""
    rng = np.random.default_rng(2)
    n = 500
    x_s = rng.uniform(-4e-5, 4e-5, n)  # lands stay overlapped
    x_j = rng.uniform(-0.04, 0.04, n)
    v_j = rng.uniform(-0.2, 0.2, n)
    p1 = rng.uniform(1e5, 3e7, n)
    p2 = rng.uniform(1e5, 3e7, n)
    c_lk = 1e-12
    d1, d2 = chamber_derivatives(x_s, x_j, v_j, p1, p2, P_SR, c_lk, SEALED)
    v1, v2 = chamber_volumes(x_j, SEALED)
    s1 = v1 / beta_eff(p1, SEALED) * d1 + SEALED.area * v_j  # dV1/dt = +A v_J
    s2 = v2 / beta_eff(p2, SEALED) * d2 - SEALED.area * v_j  # dV2/dt = -A v_J
    q_lk = c_lk * (p1 - p2)
    np.testing.assert_allclose(s1, -q_lk, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(s2, q_lk, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(s1 + s2, 0.0, atol=1e-15)


def test_leakage_equalisation_conserves_stored_liquid() -> None:
    """Jack locked, lands sealed, P1 = 15 MPa and P2 = 1 MPa equalise through C_Lk. The
    final pressure is where int dP/beta(P) lost by chamber 1 equals that gained by chamber 2
    (equal volumes): beta(P) varies with P (entrained air), so it is not the plain mean."""
    c_lk = 1e-11

    def f(t, y):
        d1, d2 = chamber_derivatives(0.0, 0.0, 0.0, y[0], y[1], P_SR, c_lk, SEALED)
        return [float(d1), float(d2)]

    sol = solve_ivp(f, (0, 0.1), [15e6, 1e6], method="Radau", rtol=1e-10, atol=1e-3)
    p1_end, p2_end = sol.y[:, -1]

    def inv_beta(p: float) -> float:
        return 1.0 / float(beta_eff(p, SEALED))

    def stored(pf: float) -> float:
        return quad(inv_beta, pf, 15e6, limit=200)[0] - quad(inv_beta, 1e6, pf, limit=200)[0]

    p_f = brentq(stored, 1e6, 15e6, xtol=1e-3)
    assert p1_end == pytest.approx(p_f, abs=50.0)
    assert p2_end == pytest.approx(p_f, abs=50.0)
    assert abs(p_f - 8e6) > 1e4  # the air makes it differ from the mean (7.99 MPa here)


# -- compiled kernels against the numpy reference ------------------------------------------
def test_compiled_orifice_and_beta_match_numpy() -> None:
    rng = np.random.default_rng(9)
    a = rng.uniform(-6e-4, 6e-4, 800)
    dp = rng.uniform(-3e7, 3e7, 800)
    p = rng.uniform(-1e5, 4e7, 800)
    ref_q = orifice_flow(a, dp, P)
    ref_b = beta_eff(p, P)
    got_q = [
        kern.orifice_flow(a[k], dp[k], P.cd, P.w_eff, P.rho, P.dp_tr, P.c_r, P.mu, P.l_min)
        for k in range(a.size)
    ]
    got_b = [
        kern.beta_eff(p[k], P.beta_l, P.alpha0, P.kappa, P.p_vap, P.p_atm) for k in range(p.size)
    ]
    np.testing.assert_allclose(got_q, ref_q, rtol=1e-12, atol=1e-22)
    np.testing.assert_allclose(got_b, ref_b, rtol=1e-12)


def test_compiled_rhs_chambers_match_numpy() -> None:
    params = P.with_overrides(u1=1.2e-4, u2=0.8e-4, u3=1.1e-4, u4=0.9e-4)  # asymmetric lands
    prm = kern.param_array(params)
    rng = np.random.default_rng(4)
    n = 800
    y = np.column_stack(
        [
            rng.uniform(-0.01, 0.01, n),  # I
            rng.uniform(-6e-4, 6e-4, n),  # x_S (also beyond the limit)
            rng.uniform(-1, 1, n),  # v_S
            rng.uniform(-0.055, 0.055, n),  # x_J (also inside the stops)
            rng.uniform(-0.5, 0.5, n),  # v_J
            rng.uniform(0, 3e7, n),  # P1
            rng.uniform(0, 3e7, n),  # P2
        ]
    )
    p_sr = rng.uniform(1e6, 25e6, n)
    c_lk = rng.uniform(0, 1e-12, n)
    dy = np.empty(kern.N_STATE)
    got = np.empty((n, 2))
    for k in range(n):
        kern.rhs(y[k], 0.0, 0.0, p_sr[k], c_lk[k], prm, 0, dy)
        got[k] = dy[5], dy[6]
    xse = np.clip(y[:, 1], -params.x_sm, params.x_sm)
    d1, d2 = chamber_derivatives(xse, y[:, 3], y[:, 4], y[:, 5], y[:, 6], p_sr, c_lk, params)
    np.testing.assert_allclose(got[:, 0], d1, rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(got[:, 1], d2, rtol=1e-12, atol=1e-6)
    # and the land flows balance the way the numpy flows say at the null state
    q1, q2, q3, q4 = land_flows(0.0, 10.5e6, 10.5e6, P_SR, P)
    assert float(q1 - q2) == pytest.approx(0.0, abs=1e-18)
    assert float(q3 - q4) == pytest.approx(0.0, abs=1e-18)
