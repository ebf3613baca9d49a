"""Simplified fluid-dynamic servovalve laws P12 = f(x_S, Q_J, P_SR) (physics.md section 2).

Every law is algebraic and vectorised: x_s, q_j, p_sr and the parameters broadcast against
each other, so one call evaluates a whole P12-x_S characteristic, all UKF sigma points or a
fleet. The pressure gain follows the supply, G_P = P_SR / x_SS (x_SS is geometry).

Units: x_s [m], q_j [m^3/s], p_sr [Pa], g_pq [Pa s/m^3], x_ss [m], c_lk [m^3/s/Pa].
These numpy functions are the readable reference; ``models.compiled`` holds scalar
numba versions that the tests hold to these.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from models.params import ValveParams

__all__ = ["p12_a", "p12_b", "p12_c1", "p12_c3", "p12_c5", "LAWS", "LAW_NAMES", "p12"]


def _sat(y: NDArray, p_sr: NDArray) -> NDArray:
    """sat(y): clip y to [-P_SR, +P_SR]."""
    return np.minimum(np.maximum(y, -p_sr), p_sr)


def p12_a(x_s: ArrayLike, q_j: ArrayLike, p_sr: ArrayLike, g_pq, x_ss, c_lk, p_vap=1e3) -> NDArray:
    """Model A (seed eq. 1, leakage loop solved): (G_P x_S - G_PQ Q_J) / (1 + G_PQ C_Lk)."""
    x_s, q_j, p_sr = np.asarray(x_s, float), np.asarray(q_j, float), np.asarray(p_sr, float)
    g_p = p_sr / x_ss
    return (g_p * x_s - g_pq * q_j) / (1.0 + g_pq * c_lk)


def p12_b(x_s: ArrayLike, q_j: ArrayLike, p_sr: ArrayLike, g_pq, x_ss, c_lk, p_vap=1e3) -> NDArray:
    """Model B (seed Fig. 4): (sat(G_P x_S) - G_PQ Q_J) / (1 + G_PQ C_Lk)."""
    x_s, q_j, p_sr = np.asarray(x_s, float), np.asarray(q_j, float), np.asarray(p_sr, float)
    g_p = p_sr / x_ss
    return (_sat(g_p * x_s, p_sr) - g_pq * q_j) / (1.0 + g_pq * c_lk)


def p12_c1(x_s: ArrayLike, q_j: ArrayLike, p_sr: ArrayLike, g_pq, x_ss, c_lk, p_vap=1e3) -> NDArray:
    """Model C1 (seed Fig. 5): sat(G_P x_S - G_PQ Q_J) / (1 + G_PQ C_Lk)."""
    x_s, q_j, p_sr = np.asarray(x_s, float), np.asarray(q_j, float), np.asarray(p_sr, float)
    g_p = p_sr / x_ss
    return _sat(g_p * x_s - g_pq * q_j, p_sr) / (1.0 + g_pq * c_lk)


def p12_c3(x_s: ArrayLike, q_j: ArrayLike, p_sr: ArrayLike, g_pq, x_ss, c_lk, p_vap=1e3) -> NDArray:
    """Model C3 (seed eq. 2): sat(P_SR x_S/x_SS - G_PQ Q_J) / (1 + G_PQ x_SS C_Lk / max(|x_S|, x_SS))."""
    x_s, q_j, p_sr = np.asarray(x_s, float), np.asarray(q_j, float), np.asarray(p_sr, float)
    p12p = _sat(p_sr * x_s / x_ss - g_pq * q_j, p_sr)
    return p12p / (1.0 + g_pq * x_ss * c_lk / np.maximum(np.abs(x_s), x_ss))


def p12_c5(x_s: ArrayLike, q_j: ArrayLike, p_sr: ArrayLike, g_pq, x_ss, c_lk, p_vap=1e3) -> NDArray:
    """Model C5 (seed eqs. 3-4).

    x_St = x_S - Q_J G_PQ x_SS / max(P_SR, P_vap);
    P12 = x_St P_SR / (max(|x_St|, x_SS) + C_Lk G_PQ x_SS).
    """
    x_s, q_j, p_sr = np.asarray(x_s, float), np.asarray(q_j, float), np.asarray(p_sr, float)
    x_st = x_s - q_j * g_pq * x_ss / np.maximum(p_sr, p_vap)
    return x_st * p_sr / (np.maximum(np.abs(x_st), x_ss) + c_lk * g_pq * x_ss)


LawFn = Callable[..., NDArray]
LAWS: dict[str, LawFn] = {"A": p12_a, "B": p12_b, "C1": p12_c1, "C3": p12_c3, "C5": p12_c5}
LAW_NAMES: tuple[str, ...] = tuple(LAWS)


def p12(model: str, x_s: ArrayLike, q_j: ArrayLike, p_sr: ArrayLike, vp: ValveParams) -> NDArray:
    """Evaluate simplified law ``model`` (one of LAW_NAMES) with parameters ``vp``."""
    try:
        law = LAWS[model]
    except KeyError:
        raise ValueError(f"unknown valve model {model!r}; expected one of {LAW_NAMES}") from None
    return law(x_s, q_j, p_sr, vp.g_pq, vp.x_ss, vp.c_lk, vp.p_vap)
