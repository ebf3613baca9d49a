"""WH valve model: four square-root lands from the C-types' parameters, two compressible
chambers with a lumped compliance, cavitation floor, no ceiling (docs/models.md section 2).

Numpy reference, every function broadcasts. ``models.compiled`` holds the scalar numba
versions used by the integrator; the tests hold them to these. Absolute pressures:
P_R = wp.p_r, P_S = P_R + P_SR.

The chamber states are liquid-volume balances p~1, p~2 [Pa]: above P_vap they are the
chamber pressures; below, the chamber sits at P_vap and (P_vap - p~) V / beta is the
volume of its vapour cavity (eq. 6), so a cavity must be refilled before the pressure
rises again (the water hammer on collapse).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from models.hf_valve import bisect_decreasing
from models.params import WHParams

__all__ = [
    "wh_orifice",
    "wh_land_flows",
    "wh_pressures",
    "wh_derivatives",
    "wh_static_pressures",
    "wh_static_p12",
]


def wh_orifice(a: ArrayLike, dp: ArrayLike, wp: WHParams) -> NDArray:
    """Land flow Q = K_o max(a, 0) r(dp), r = sign(dp) sqrt|dp| for |dp| >= dp_lam, else
    dp / sqrt(dp_lam) (docs/models.md eqs. 2-3). ``a`` opening [m], ``dp`` up - down [Pa]."""
    a = np.asarray(a, float)
    dp = np.asarray(dp, float)
    ad = np.abs(dp)
    r = np.where(ad >= wp.dp_lam, np.sign(dp) * np.sqrt(ad), dp / np.sqrt(wp.dp_lam))
    return wp.k_o * np.maximum(a, 0.0) * r


def wh_land_flows(
    x_s: ArrayLike, p1: ArrayLike, p2: ArrayLike, p_sr: ArrayLike, wp: WHParams
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Q1 (S->1), Q2 (1->R), Q3 (S->2), Q4 (2->R) at absolute P1, P2 (eq. 1): lands
    underlapped by x_SS, a1 = a4 = x_SS + x_S, a2 = a3 = x_SS - x_S."""
    x_s = np.asarray(x_s, float)
    p1 = np.asarray(p1, float)
    p2 = np.asarray(p2, float)
    p_s = wp.p_r + np.asarray(p_sr, float)
    a_p = wp.x_ss + x_s
    a_m = wp.x_ss - x_s
    return (
        wh_orifice(a_p, p_s - p1, wp),
        wh_orifice(a_m, p1 - wp.p_r, wp),
        wh_orifice(a_m, p_s - p2, wp),
        wh_orifice(a_p, p2 - wp.p_r, wp),
    )


def wh_pressures(pt1: ArrayLike, pt2: ArrayLike, wp: WHParams) -> tuple[NDArray, NDArray]:
    """Chamber pressures P_k = max(p~_k, P_vap) from the volume-balance states (eq. 6)."""
    return np.maximum(np.asarray(pt1, float), wp.p_vap), np.maximum(
        np.asarray(pt2, float), wp.p_vap
    )


def wh_derivatives(
    x_s: ArrayLike,
    v_j: ArrayLike,
    pt1: ArrayLike,
    pt2: ArrayLike,
    p_sr: ArrayLike,
    c_lk: ArrayLike,
    wp: WHParams,
    area: float,
) -> tuple[NDArray, NDArray]:
    """dp~1/dt = beta/V (Q1 - Q2 - Q_Lk - A v_J), dp~2/dt = beta/V (Q3 - Q4 + Q_Lk + A v_J),
    Q_Lk = C_Lk (P1 - P2), flows at P_k = max(p~_k, P_vap) (eqs. 5-6). ``x_s`` limited."""
    p1, p2 = wh_pressures(pt1, pt2, wp)
    q1, q2, q3, q4 = wh_land_flows(x_s, p1, p2, p_sr, wp)
    q_lk = np.asarray(c_lk, float) * (p1 - p2)
    q_j = area * np.asarray(v_j, float)
    k = wp.beta / wp.v_c
    return k * (q1 - q2 - q_lk - q_j), k * (q3 - q4 + q_lk + q_j)


def _residuals(x_s, q_j, p_sr, c_lk, p1, p2, wp):
    q1, q2, q3, q4 = wh_land_flows(x_s, p1, p2, p_sr, wp)
    q_lk = c_lk * (p1 - p2)
    return q1 - q2 - q_lk - q_j, q3 - q4 + q_lk + q_j


def wh_static_pressures(
    x_s: ArrayLike,
    q_j: ArrayLike,
    p_sr: ArrayLike,
    wp: WHParams,
    c_lk: ArrayLike | None = None,
    n_iter: int = 60,
) -> tuple[NDArray, NDArray]:
    """Steady-state (P1, P2) of the WH valve at (x_S, Q_J, P_SR): both chamber balances of
    eq. 5 at zero, solved by nested bisection (each residual decreases in its own pressure)
    on [P_vap, P_S + 10 P_SR]. Beyond the valve's capacity a pressure sits at the bound
    (P_vap: a cavitating chamber) and the balance is not met, as in ``hf_static_pressures``."""
    c = wp.c_lk if c_lk is None else c_lk
    x_s, q_j, p_sr, c = np.broadcast_arrays(
        np.asarray(x_s, float), np.asarray(q_j, float), np.asarray(p_sr, float),
        np.asarray(c, float),
    )  # fmt: skip
    shape = x_s.shape
    x_s, q_j, p_sr, c = (np.ravel(v) for v in (x_s, q_j, p_sr, c))
    lo = np.full(x_s.shape, wp.p_vap)
    hi = wp.p_r + p_sr + 10.0 * p_sr

    def p2_of(p1):
        return bisect_decreasing(
            lambda p2: _residuals(x_s, q_j, p_sr, c, p1, p2, wp)[1], lo, hi, n_iter
        )

    p1 = bisect_decreasing(
        lambda p1: _residuals(x_s, q_j, p_sr, c, p1, p2_of(p1), wp)[0], lo, hi, n_iter
    )
    return p1.reshape(shape), p2_of(p1).reshape(shape)


def wh_static_p12(
    x_s: ArrayLike,
    q_j: ArrayLike,
    p_sr: ArrayLike,
    wp: WHParams,
    c_lk: ArrayLike | None = None,
) -> NDArray:
    """Steady-state P12 = P1 - P2 of the WH valve (see :func:`wh_static_pressures`)."""
    p1, p2 = wh_static_pressures(x_s, q_j, p_sr, wp, c_lk)
    return p1 - p2
