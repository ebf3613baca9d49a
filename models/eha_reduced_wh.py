"""WH process model of the estimator: the C-types' eight filter states plus the two WH chamber
states (docs/models.md sections 2 and 7; docs/estimation.md, "WH process model").

States, in this order (SI)::

    x_s, v_s, x_j, v_j, f_r, p_sr, c_lk, i_b   (as models.eha_reduced)
    pt1, pt2 [Pa]                              (p~1, p~2: liquid-volume balances, eq. 5)

The spool is the exact zero-order-hold step of ``models.eha_reduced``; x_J, v_J, p~1 and p~2
advance by classic RK4 with the spool held over each substep. The chamber flows are the
four-land orifice law of docs/models.md eqs. 1-4 (K_o = sqrt(2 P_SR,rated) / (x_SS G_PQ)),
the chambers eq. 5 with the bulk modulus beta and the volumes V1,2 = V0 +- A x_J (eq. 5b: the
jack's position sets each chamber's stiffness; V0 the lumped mid-stroke volume), the
pressures P_k = max(p~_k, P_vap) (eq. 6),
the jack m dv_J/dt = A (P1 - P2) - F_R - c_v v_J - F_d tanh(v_J / v_f), with Karnopp
stiction (docs/estimation.md, "Stiction in the WH process model"): while |v_J| < v_stick and
the applied force |A P12 - F_R| <= F_s the jack is stuck (v_J relaxes to 0 with TAU_STICK),
and a v_J that crosses zero within a substep under such a force is set to 0 (an explicit
step of 1/3 ms changes v_J by up to a few mm/s, which would jump a narrow band); F_s = 0 is
the smooth friction alone. The measurement is direct: x_S, x_J, P1 = max(p~1, P_vap),
P2 = max(p~2, P_vap), P_SR.

Stiff modes (docs/models.md section 7; ``stiff_modes``): the chamber mode
beta/V (2 K_o (x_SS + x_SM) / sqrt(dp_lam) + C_Lk) and the hydraulic mode
w_h = sqrt(2 beta A^2 / (V m)) (eq. 10). RK4 is stable for |lambda h| up to 2.78 on the real
axis, so the longest substep is ``H_MAX`` = 1/3 ms at mid stroke: 3 substeps at the 1 ms
sample step. Off mid stroke the smaller chamber is stiffer by V0 / V_min, and ``n_substeps``
adds substeps once |lambda h| would pass RK4_H_TARGET = 2.5 (beyond about 9 mm).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from models import eha_reduced as er
from models.compiled import TAU_STICK, wh_orifice  # TAU_STICK: the HF plant's stuck relaxation
from models.eha_reduced import (
    K_AREA,
    K_C_V,
    K_F_D,
    K_K_SV,
    K_MASS,
    K_P_R,
    K_P_VAP,
    K_V_F,
    K_X_0,
    K_X_SM,
    N_PRM,
    ReducedParams,
    _spool_nb,
)
from models.params import WH_DP_LAM_FRACTION

__all__ = [
    "STATE_NAMES",
    "N_STATES",
    "IX",
    "H_MAX",
    "RK4_REAL_LIMIT",
    "K_WH_K",
    "K_WH_DP_LAM",
    "K_WH_ISQ_LAM",
    "K_WH_BV",
    "N_PRM_WH",
    "param_vector",
    "stiff_modes",
    "chamber_volumes",
    "n_substeps",
    "n_substeps_nb",
    "V_MIN_FRACTION",
    "step",
    "measure",
    "step_core_nb",
    "step_points_nb",
    "measure_nb",
    "rhs_nb",
    "land_flows",
]

STATE_NAMES: tuple[str, ...] = (*er.STATE_NAMES, "pt1", "pt2")
N_STATES = len(STATE_NAMES)
IX = {n: k for k, n in enumerate(STATE_NAMES)}
S_PT1, S_PT2 = IX["pt1"], IX["pt2"]
H_MAX = 1e-3 / 3.0  # longest RK4 substep [s] at mid stroke: 3 substeps at the 1 ms sample step
RK4_REAL_LIMIT = 2.785  # classic RK4 is stable for real lambda h in [-2.785, 0]
V_MIN_FRACTION = 0.25  # chamber volume floor / V0 (a guard past the stroke: V_dead / V0 = 0.29)
RK4_H_TARGET = 2.5  # n_substeps keeps the chamber mode's |lambda h| below this (margin to 2.785)

# parameter vector: models.eha_reduced's layout, then the WH constants (docs/models.md eq. 2, 3, 5)
(K_WH_K, K_WH_DP_LAM, K_WH_ISQ_LAM, K_WH_BV, K_WH_XS_S, K_WH_XS_R, K_WH_V0,
 K_WH_LAM0, K_WH_C_LAND, K_WH_F_S, K_WH_V_STICK) = range(N_PRM, N_PRM + 11)  # fmt: skip
N_PRM_WH = N_PRM + 11


def k_orifice(rp: ReducedParams) -> float:
    """K_o = sqrt(2 P_SR,rated) / (x_SS G_PQ) [m^2/(s Pa^0.5)] (docs/models.md eq. 2)."""
    return math.sqrt(2.0 * rp.p_sr_rated) / (rp.x_ss * rp.g_pq)


def param_vector(rp: ReducedParams, v_c: float, beta: float) -> NDArray:
    """Float64 vector of the compiled WH kernels: ``models.eha_reduced.param_vector`` (law
    WH, longest substep ``H_MAX``) followed by K_o, dp_lam, 1/sqrt(dp_lam), beta / V, the
    lands' underlaps, V0, the chamber mode, the land leak, F_s and v_stick."""
    a = np.empty(N_PRM_WH)
    a[:N_PRM] = er.param_vector(rp._replace(law="WH", h_max=min(rp.h_max, H_MAX)))
    dp_lam = WH_DP_LAM_FRACTION * rp.p_sr_rated
    a[K_WH_K] = k_orifice(rp)
    a[K_WH_DP_LAM] = dp_lam
    a[K_WH_ISQ_LAM] = 1.0 / math.sqrt(dp_lam)
    a[K_WH_BV] = beta / v_c
    a[K_WH_XS_S] = rp.x_ss * (1.0 + rp.skew)  # supply lands' underlap [m]
    a[K_WH_XS_R] = rp.x_ss * (1.0 - rp.skew)  # return lands' underlap [m]
    a[K_WH_V0] = v_c  # mid-stroke chamber volume V0 [m^3]
    a[K_WH_LAM0] = stiff_modes(rp, v_c, beta, 0.0)["chamber"]  # chamber mode at V0 [1/s]
    a[K_WH_C_LAND] = rp.c_land  # land-clearance leak, added to C_Lk [m^3/(s Pa)]
    a[K_WH_F_S] = rp.f_s  # breakaway friction [N] (0: no stiction)
    a[K_WH_V_STICK] = rp.v_stick  # stick band [m/s]
    return a


def stiff_modes(rp: ReducedParams, v_c: float, beta: float, c_lk: float) -> dict[str, float]:
    """The fastest modes of the WH filter model (docs/models.md sections 3 and 7) and
    |lambda| H_MAX for each: chamber (laminar band, spool at full stroke) [1/s], hydraulic
    w_h (eq. 10) [rad/s], friction F_d / (v_f m) [1/s]."""
    dp_lam = WH_DP_LAM_FRACTION * rp.p_sr_rated
    lam_c = (
        beta
        / v_c
        * (2.0 * k_orifice(rp) * (rp.x_ss + rp.x_sm) / math.sqrt(dp_lam) + c_lk + 2.0 * rp.c_land)
    )
    w_h = math.sqrt(2.0 * beta * rp.area**2 / (v_c * rp.mass))
    lam_f = rp.f_d / (rp.v_f * rp.mass)
    return {
        "chamber": lam_c,
        "hydraulic": w_h,
        "friction": lam_f,
        "chamber_h": lam_c * H_MAX,
        "hydraulic_h": w_h * H_MAX,
        "friction_h": lam_f * H_MAX,
    }


# -- numpy reference (vectorised over leading axes), held to the compiled kernels by tests ---
def _orifice(a, dp, k_o, dp_lam):
    r = np.where(np.abs(dp) >= dp_lam, np.sign(dp) * np.sqrt(np.abs(dp)), dp / math.sqrt(dp_lam))
    return k_o * np.maximum(a, 0.0) * r


def _land(a, dp, k_o, dp_lam, c_land):
    """One land: the orifice (eqs. 2-3) plus, while it is open, its laminar clearance leak
    c_land dp (docs/estimation.md, "Land clearance leak (WH)")."""
    return _orifice(a, dp, k_o, dp_lam) + np.where(a > 0.0, c_land * dp, 0.0)


def chamber_volumes(x_j, area: float, v_c: float):
    """V1,2 = V0 +- A x_J [m^3], floored at V_MIN_FRACTION V0 (docs/models.md eq. 5b)."""
    v_min = V_MIN_FRACTION * v_c
    return np.maximum(v_c + area * x_j, v_min), np.maximum(v_c - area * x_j, v_min)


def n_substeps(x_j: float, dt: float, rp: ReducedParams, v_c: float, beta: float) -> int:
    """RK4 substeps over ``dt`` [s] at jack position ``x_j`` [m], at least dt / H_MAX: the
    chamber mode (``stiff_modes``, at V0) scales as V0 / V_min(x_J), and |lambda h| stays
    below RK4_H_TARGET."""
    v_min = float(min(chamber_volumes(x_j, rp.area, v_c)))
    lam = stiff_modes(rp, v_c, beta, 0.0)["chamber"] * v_c / v_min
    return max(1, math.ceil(dt / H_MAX - 1e-9), math.ceil(dt * lam / RK4_H_TARGET - 1e-9))


def land_flows(x_l, p1, p2, p_sr, rp: ReducedParams):
    """Q1 (S->1), Q2 (1->R), Q3 (S->2), Q4 (2->R) [m^3/s] of the filter's lands (docs/models.md
    eqs. 1-4 with the land skew, plus each open land's clearance leak ``rp.c_land``) at the
    spool position seen from the hydraulic null ``x_l`` = x_S - x_0 [m] and absolute P1, P2."""
    k_o, dp_lam = k_orifice(rp), WH_DP_LAM_FRACTION * rp.p_sr_rated
    p_s = rp.p_r + p_sr
    xs_s, xs_r = rp.x_ss * (1.0 + rp.skew), rp.x_ss * (1.0 - rp.skew)
    return (
        _land(xs_s + x_l, p_s - p1, k_o, dp_lam, rp.c_land),
        _land(xs_r - x_l, p1 - rp.p_r, k_o, dp_lam, rp.c_land),
        _land(xs_s - x_l, p_s - p2, k_o, dp_lam, rp.c_land),
        _land(xs_r + x_l, p2 - rp.p_r, k_o, dp_lam, rp.c_land),
    )


def _rhs(x_s, x_j, v_j, pt1, pt2, f_r, p_sr, c_lk, rp, beta, v_c):
    p1, p2 = np.maximum(pt1, rp.p_vap), np.maximum(pt2, rp.p_vap)
    q1, q2, q3, q4 = land_flows(x_s, p1, p2, p_sr, rp)
    p12 = p1 - p2
    q_lk = c_lk * p12
    q_j = rp.area * v_j
    f_a = rp.area * p12 - f_r
    acc = np.where(
        (np.abs(v_j) < rp.v_stick) & (np.abs(f_a) <= rp.f_s),
        -v_j / TAU_STICK,  # stuck: friction holds the applied force (Karnopp)
        (f_a - rp.c_v * v_j - rp.f_d * np.tanh(v_j / rp.v_f)) / rp.mass,
    )
    v1, v2 = chamber_volumes(x_j, rp.area, v_c)
    return v_j, acc, beta / v1 * (q1 - q2 - q_lk - q_j), beta / v2 * (q3 - q4 + q_lk + q_j)


def step(x: NDArray, i, dt, rp: ReducedParams, n_sub: int, v_c: float, beta: float) -> NDArray:
    """Advance WH states ``x`` (..., 10) by ``dt`` with current ``i`` held: per substep the
    exact spool step, then one RK4 step of (x_J, v_J, p~1, p~2) with the spool held.
    Parameters (f_r, p_sr, c_lk, i_b) are copied through; evaluated with C_Lk >= 0,
    P_SR >= P_vap."""
    x_s, v_s, x_j, v_j = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
    f_r, p_sr, c_lk, i_b = x[..., 4], x[..., 5], x[..., 6], x[..., 7]
    pt1, pt2 = x[..., 8], x[..., 9]
    p_ev, c_ev = np.maximum(p_sr, rp.p_vap), np.maximum(c_lk, 0.0)
    h = np.asarray(dt, float) / n_sub
    for _ in range(n_sub):
        x_s, v_s = er.spool_step(x_s, v_s, i + i_b, h, rp)

        def f(y, x_s=x_s - rp.x_0):  # the lands see the spool from its hydraulic null
            return _rhs(x_s, *y, f_r, p_ev, c_ev, rp, beta, v_c)

        y = (x_j, v_j, pt1, pt2)
        ka = f(y)
        kb = f(tuple(u + 0.5 * h * d for u, d in zip(y, ka, strict=True)))
        kc = f(tuple(u + 0.5 * h * d for u, d in zip(y, kb, strict=True)))
        kd = f(tuple(u + h * d for u, d in zip(y, kc, strict=True)))
        x_j, v_new, pt1, pt2 = (
            u + h / 6.0 * (a + 2.0 * b + 2.0 * c + d)
            for u, a, b, c, d in zip(y, ka, kb, kc, kd, strict=True)
        )
        # v_J crossed zero within the substep and the applied force cannot break away: stuck
        f_a = rp.area * (np.maximum(pt1, rp.p_vap) - np.maximum(pt2, rp.p_vap)) - f_r
        stuck = (v_new * v_j < 0.0) & (np.abs(f_a) <= rp.f_s) & (rp.f_s > 0.0)
        v_j = np.where(stuck, 0.0, v_new)
    return np.stack([x_s, v_s, x_j, v_j, f_r, p_sr, c_lk, i_b, pt1, pt2], axis=-1)


def measure(x: NDArray, rp: ReducedParams) -> NDArray:
    """Measurement model (..., 5): x_S, x_J, max(p~1, P_vap), max(p~2, P_vap), P_SR (eq. 6)."""
    return np.stack(
        [
            x[..., 0],
            x[..., 2],
            np.maximum(x[..., 8], rp.p_vap),
            np.maximum(x[..., 9], rp.p_vap),
            x[..., 5],
        ],
        axis=-1,
    )


# -- compiled scalar versions (numba) --------------------------------------------------------
_NB = {"cache": True, "error_model": "numpy"}


@njit(**_NB, inline="always")
def land_nb(a, dp, k_o, dp_lam, isq, g):
    """Scalar ``_land``: orifice flow plus the laminar leak g dp of an open land."""
    q = wh_orifice(a, dp, k_o, dp_lam, isq)
    return q + g * dp if a > 0.0 else q


@njit(**_NB, inline="always")
def rhs_nb(x_s, x_j, v_j, pt1, pt2, f_r, p_s, c_lk, prm):
    """(dv_J/dt, dp~1/dt, dp~2/dt) of docs/models.md eqs. 1-6 and 5b with the jack equation;
    p_s = P_R + P_SR (absolute supply)."""
    p_vap, p_r = prm[K_P_VAP], prm[K_P_R]
    xs_s, xs_r = prm[K_WH_XS_S], prm[K_WH_XS_R]  # supply and return lands' underlaps
    k_o, dp_lam, isq, bv = prm[K_WH_K], prm[K_WH_DP_LAM], prm[K_WH_ISQ_LAM], prm[K_WH_BV]
    area = prm[K_AREA]
    p1 = max(pt1, p_vap)
    p2 = max(pt2, p_vap)
    g = prm[K_WH_C_LAND]  # laminar clearance leak of an open land
    q1 = land_nb(xs_s + x_s, p_s - p1, k_o, dp_lam, isq, g)
    q2 = land_nb(xs_r - x_s, p1 - p_r, k_o, dp_lam, isq, g)
    q3 = land_nb(xs_s - x_s, p_s - p2, k_o, dp_lam, isq, g)
    q4 = land_nb(xs_r + x_s, p2 - p_r, k_o, dp_lam, isq, g)
    p12 = p1 - p2
    q_lk = c_lk * p12
    q_j = area * v_j
    f_a = area * p12 - f_r
    if abs(v_j) < prm[K_WH_V_STICK] and abs(f_a) <= prm[K_WH_F_S]:
        acc = -v_j / TAU_STICK  # stuck: friction holds the applied force (Karnopp)
    else:
        acc = (f_a - prm[K_C_V] * v_j - prm[K_F_D] * math.tanh(v_j / prm[K_V_F])) / prm[K_MASS]
    v0 = prm[K_WH_V0]  # chambers V0 +- A x_J (eq. 5b): bv = beta / V0 scaled by V0 / V_k
    v_min = V_MIN_FRACTION * v0
    bv1 = bv * v0 / max(v0 + area * x_j, v_min)
    bv2 = bv * v0 / max(v0 - area * x_j, v_min)
    return acc, bv1 * (q1 - q2 - q_lk - q_j), bv2 * (q3 - q4 + q_lk + q_j)


@njit(**_NB, inline="always")
def n_substeps_nb(x_j, dt, prm):
    """Scalar ``n_substeps`` on the parameter vector."""
    v0 = prm[K_WH_V0]
    v_min = max(v0 - prm[K_AREA] * abs(x_j), V_MIN_FRACTION * v0)
    n_h = int(math.ceil(dt / H_MAX - 1e-9))
    return max(1, n_h, int(math.ceil(dt * prm[K_WH_LAM0] * v0 / v_min / RK4_H_TARGET - 1e-9)))


@njit(**_NB)  # called, not inlined: one compile for the filter and the parallel model
def step_core_nb(x, i, h, n_sub, prm, coef, out):
    """Scalar ``step`` with the spool transition ``coef`` of the substep h precomputed:
    x (10,) -> out (10,)."""
    x_s, v_s, x_j, v_j, pt1, pt2 = x[0], x[1], x[2], x[3], x[8], x[9]
    f_r = x[4]
    p_s = prm[K_P_R] + max(x[5], prm[K_P_VAP])
    c_lk = max(x[6], 0.0)
    x_sm = prm[K_X_SM]
    x_ref = min(max(prm[K_K_SV] * (i + x[7]), -x_sm), x_sm)
    x_0 = prm[K_X_0]  # hydraulic null: the lands see x_S - x_0
    hh = 0.5 * h
    h6 = h / 6.0
    f_s, area, p_vap = prm[K_WH_F_S], prm[K_AREA], prm[K_P_VAP]
    for _ in range(n_sub):
        x_s, v_s = _spool_nb(x_s, v_s, x_ref, x_sm, coef)
        x_l = x_s - x_0
        a1, a2, a3 = rhs_nb(x_l, x_j, v_j, pt1, pt2, f_r, p_s, c_lk, prm)
        a0 = v_j
        b0 = v_j + hh * a1
        b1, b2, b3 = rhs_nb(
            x_l, x_j + hh * a0, b0, pt1 + hh * a2, pt2 + hh * a3, f_r, p_s, c_lk, prm
        )
        c0 = v_j + hh * b1
        c1, c2, c3 = rhs_nb(
            x_l, x_j + hh * b0, c0, pt1 + hh * b2, pt2 + hh * b3, f_r, p_s, c_lk, prm
        )
        d0 = v_j + h * c1
        d1, d2, d3 = rhs_nb(x_l, x_j + h * c0, d0, pt1 + h * c2, pt2 + h * c3, f_r, p_s, c_lk, prm)
        x_j += h6 * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
        v_new = v_j + h6 * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
        pt1 += h6 * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
        pt2 += h6 * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
        if v_new * v_j < 0.0 and f_s > 0.0:  # v_J crossed zero within the substep:
            f_a = area * (max(pt1, p_vap) - max(pt2, p_vap)) - f_r
            if abs(f_a) <= f_s:
                v_new = 0.0  # ... and the applied force cannot break away: stuck
        v_j = v_new
    out[0], out[1], out[2], out[3] = x_s, v_s, x_j, v_j
    out[4], out[5], out[6], out[7] = x[4], x[5], x[6], x[7]
    out[8], out[9] = pt1, pt2


@njit(**_NB)
def step_points_nb(X, i, h, n_sub, prm, coef, out, w):
    """``step_core_nb`` for every row of X (K, 10) into out (K, 10) (the sigma points of a
    filter step); w: unused scratch (the signature of ``models.eha_reduced.step_points_nb``)."""
    for k in range(X.shape[0]):
        step_core_nb(X[k], i, h, n_sub, prm, coef, out[k])


@njit(**_NB)
def step_nb(x, i, dt, n_sub, prm, out):
    """Scalar ``step``: x (10,) -> out (10,)."""
    coef = np.empty(4)
    h = dt / n_sub
    er.spool_coef_nb(h, prm, coef)
    step_core_nb(x, i, h, n_sub, prm, coef, out)


@njit(**_NB, inline="always")
def measure_nb(x, prm, out):
    """Scalar ``measure``: x (10,) -> out (5,) = x_S, x_J, P1, P2, P_SR."""
    p_vap = prm[K_P_VAP]
    out[0] = x[0]
    out[1] = x[2]
    out[2] = max(x[8], p_vap)
    out[3] = max(x[9], p_vap)
    out[4] = x[5]
