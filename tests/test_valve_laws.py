"""Simplified valve laws A..C5 (physics.md section 2): hand-computed points, invariants,
broadcasting, and the compiled scalar kernel held to the numpy reference."""

from __future__ import annotations

import numpy as np
import pytest

from models import compiled as kern
from models.params import DEFAULT_PARAMS, ValveParams, simplified_params
from models.valve_laws import LAW_NAMES, p12

# seed values: G_PQ = 7.4e11 Pa s/m^3, x_SS = 0.1 mm, C_Lk = 2e-13 m^3/s/Pa, P_SR = 20 MPa
VP = ValveParams(g_pq=7.4e11, x_ss=1e-4, c_lk=2e-13, p_vap=1e3)
P_SR = 20e6
# G_P = P_SR / x_SS = 2e11 Pa/m; 1 + G_PQ C_Lk = 1 + 0.148 = 1.148


def test_derived_params_match_seed() -> None:
    vp = simplified_params(DEFAULT_PARAMS)
    # w is derived from the seed G_PQ, so G_PQ = G_P / G_Q comes back to 7.4e11
    assert vp.g_pq == pytest.approx(7.4e11, rel=1e-12)
    assert vp.x_ss == 1e-4
    # w = sqrt(P_SR rho) / (Cd x_SS G_PQ) = sqrt(2e7*850)/(0.61*1e-4*7.4e11) = 2.889 mm
    assert DEFAULT_PARAMS.w_eff == pytest.approx(2.889e-3, rel=1e-3)


# Linear zone: x_S = 2e-5 m, Q_J = 1e-6 m^3/s.
#   G_P x_S = 4e6 Pa; G_PQ Q_J = 0.74e6 Pa; 4e6 - 0.74e6 = 3.26e6; /1.148 = 2.83972e6 Pa.
#   C3: same numerator, denominator 1 + G_PQ x_SS C_Lk / x_SS = 1.148 -> 2.83972e6.
#   C5: x_St = 2e-5 - 1e-6*7.4e11*1e-4/2e7 = 2e-5 - 3.7e-6 = 1.63e-5;
#       P12 = 1.63e-5*2e7 / (1e-4 + 2e-13*7.4e11*1e-4 = 1.148e-4) = 326/1.148e-4 = 2.83972e6.
# Saturated zone: x_S = 2e-4 m, Q_J = 1e-5 m^3/s.
#   A : (4e7 - 7.4e6)/1.148 = 3.26e7/1.148 = 2.83972e7 (> P_SR: A does not saturate)
#   B : (sat(4e7) = 2e7 - 7.4e6)/1.148 = 1.26e7/1.148 = 1.09756e7
#   C1: sat(3.26e7) = 2e7, /1.148 = 1.74216e7
#   C3: sat(3.26e7) = 2e7, /(1 + 7.4e11*1e-4*2e-13/2e-4 = 1.074) = 1.86220e7
#   C5: x_St = 2e-4 - 1e-5*7.4e11*1e-4/2e7 = 1.63e-4; 1.63e-4*2e7/(1.63e-4 + 1.48e-5)
#       = 3260/1.778e-4 = 1.83352e7
LIN = 3.26e6 / 1.148
HAND = {
    "A": (LIN, 3.26e7 / 1.148),
    "B": (LIN, 1.26e7 / 1.148),
    "C1": (LIN, 2e7 / 1.148),
    "C3": (LIN, 2e7 / 1.074),
    "C5": (LIN, 3260.0 / 1.778e-4),
}


@pytest.mark.parametrize("law", LAW_NAMES)
def test_hand_computed_points(law: str) -> None:
    lin, sat = HAND[law]
    assert float(p12(law, 2e-5, 1e-6, P_SR, VP)) == pytest.approx(lin, rel=1e-9)
    assert float(p12(law, 2e-4, 1e-5, P_SR, VP)) == pytest.approx(sat, rel=1e-9)
    assert lin == pytest.approx(2.83972e6, rel=1e-5)


def _random_points(n: int = 4000, seed: int = 1):
    rng = np.random.default_rng(seed)
    x_s = rng.uniform(-5e-4, 5e-4, n)
    q_j = rng.uniform(-3e-4, 3e-4, n)
    p_sr = rng.uniform(1e6, 25e6, n)
    return x_s, q_j, p_sr


@pytest.mark.parametrize("law", LAW_NAMES)
def test_odd_symmetry(law: str) -> None:
    x_s, q_j, p_sr = _random_points()
    a = p12(law, x_s, q_j, p_sr, VP)
    b = p12(law, -x_s, -q_j, p_sr, VP)
    np.testing.assert_allclose(b, -a, rtol=1e-12, atol=1e-6)


@pytest.mark.parametrize("law", ["C1", "C3", "C5"])
def test_c_types_never_exceed_p_sr(law: str) -> None:
    x_s, q_j, p_sr = _random_points(20000)
    y = p12(law, x_s, q_j, p_sr, VP)
    assert np.all(np.abs(y) <= p_sr * (1 + 1e-12))
    # they do reach close to it (within the leakage factor) somewhere in this range
    assert np.max(np.abs(y) / p_sr) > 0.85


def test_a_exceeds_p_sr() -> None:
    x_s, q_j, p_sr = _random_points(20000)
    y = p12("A", x_s, q_j, p_sr, VP)
    assert np.max(np.abs(y) / p_sr) > 2.0


def test_c1_saturation_level() -> None:
    # P12 -> P_SR / (1 + G_PQ C_Lk) = 20e6 / 1.148 = 17.4216 MPa, for any C_Lk
    for c_lk in (0.0, 2e-13, 1e-12):
        vp = VP._replace(c_lk=c_lk)
        y = p12("C1", np.array([1e-3, -1e-3]), 0.0, P_SR, vp)
        np.testing.assert_allclose(y, [P_SR / (1 + 7.4e11 * c_lk), -P_SR / (1 + 7.4e11 * c_lk)])
    assert float(p12("C1", 1e-3, 0.0, P_SR, VP)) == pytest.approx(17.4216e6, rel=1e-5)


@pytest.mark.parametrize("law", LAW_NAMES)
def test_broadcasting(law: str) -> None:
    x_s = np.linspace(-3e-4, 3e-4, 5)[:, None]
    q_j = np.linspace(-1e-4, 1e-4, 3)[None, :]
    y = p12(law, x_s, q_j, P_SR, VP)
    assert y.shape == (5, 3)
    # element (i, j) equals the scalar evaluation
    assert y[1, 2] == pytest.approx(float(p12(law, x_s[1, 0], q_j[0, 2], P_SR, VP)), rel=1e-14)
    # a vector of supply pressures against a scalar point
    assert p12(law, 1e-4, 0.0, np.array([10e6, 20e6]), VP).shape == (2,)


def test_law_names_and_model_ids_agree() -> None:
    assert set(LAW_NAMES) | {"HF", "WH"} == set(kern.MODEL_IDS)


@pytest.mark.parametrize("law", LAW_NAMES)
def test_compiled_law_matches_numpy(law: str) -> None:
    rng = np.random.default_rng(7)
    x_s, q_j, p_sr = _random_points(1500, seed=3)
    c_lk = rng.uniform(0.0, 2e-12, x_s.size)
    ref = p12(law, x_s, q_j, p_sr, VP._replace(c_lk=c_lk))
    mid = kern.MODEL_IDS[law]
    got = np.array(
        [
            kern.law_p12(mid, x_s[k], q_j[k], p_sr[k], VP.g_pq, VP.x_ss, c_lk[k], VP.p_vap)
            for k in range(x_s.size)
        ]
    )
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-6)
