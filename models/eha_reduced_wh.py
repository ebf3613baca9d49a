"""WH process model of the estimator: the C-types' eight filter states plus the two WH chamber
states (docs/models.md sections 2 and 7; docs/estimation.md, "WH process model").

States, in this order (SI)::

    x_s, v_s, x_j, v_j, f_r, p_sr, c_lk, i_b   (as models.eha_reduced)
    pt1, pt2 [Pa]                              (p~1, p~2: liquid-volume balances, eq. 5)

The chamber flows are the four-land orifice law of docs/models.md eqs. 1-4
(K_o = sqrt(2 P_SR,rated) / (x_SS G_PQ)), the chambers eq. 5 with the bulk modulus beta and
the volumes V1,2 = V0 +- A x_J (eq. 5b: the jack's position sets each chamber's stiffness;
V0 the lumped mid-stroke volume), the pressures P_k = max(p~_k, P_vap) (eq. 6), the jack
m dv_J/dt = A (P1 - P2) - F_R - c_v v_J - F_d tanh(v_J / v_f), with Karnopp stiction
(docs/estimation.md, "Stiction in the WH process model"): while |v_J| < v_stick and the
applied force |A P12 - F_R| <= F_s the jack is stuck (v_J relaxes to 0 with TAU_STICK), and
a v_J that crosses zero within a step under such a force is set to 0; F_s = 0 is the smooth
friction alone. The measurement is direct: x_S, x_J, P1 = max(p~1, P_vap),
P2 = max(p~2, P_vap), P_SR.

Integration (docs/models.md section 7; decisions/0012): one step per 1 ms sample
(``H_MAX``; a longer interval is split into steps of at most H_MAX). The spool takes the
exact zero-order-hold step of ``models.eha_reduced``; (x_J, v_J, p~1, p~2) take one step of
ROS2, the two-stage linearly implicit (Rosenbrock-W) method of Verwer et al. (1999),
gamma = 1 - 1/sqrt(2)::

    (I - gamma h J) k1 = f(t0, y0)                           (spool at its start position)
    (I - gamma h J) k2 = f(t0 + h, y0 + h k1) - 2 k1         (spool at its end position)
    y1 = y0 + 3/2 h k1 + 1/2 h k2

J is the analytic Jacobian of (v_J, p~1, p~2) on themselves at y0 (orifice slopes, leak,
cavitation, friction or the stuck relaxation) with dx_J/dt = v_J; the volumes' dependence
on x_J is left out. ROS2 is second order for any J (a W-method). With J exact its stability
function R(z) = (1 + (1 - 2 gamma) z) / (1 - gamma z)^2 (``ros2_amplification``) is
A-stable with R(-inf) = 0 (L-stable): on the real axis |R| <= (sqrt 2 - 1) / 2 = 0.21 beyond
|z| = 2.4, so the stiff chamber mode (up to 6.5e3 1/s at mid stroke and 2.6e4 1/s at the
chamber floor, |lambda h| up to 26; ``stiff_modes``) is damped at least 4.8-fold per step
wherever the jack is, its error alternating in sign. On the imaginary axis |R| = 0.9995 at
the hydraulic mode's |lambda h| = 0.63: the water hammer's ringing keeps its amplitude
(gamma = 1 + 1/sqrt(2), the other L-stable choice, damps it by 16 % per step; decision
record 0012). ``step_rk4`` keeps the classic RK4 scheme the filter used before (3 substeps
per ms at mid stroke, up to 11 at the chamber floor), the fine-step reference of the tests.
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
    "GAMMA",
    "K_WH_K",
    "K_WH_DP_LAM",
    "K_WH_ISQ_LAM",
    "K_WH_BV",
    "N_PRM_WH",
    "param_vector",
    "stiff_modes",
    "chamber_volumes",
    "ros2_amplification",
    "jacobian",
    "V_MIN_FRACTION",
    "step",
    "step_rk4",
    "measure",
    "step_core_nb",
    "step_points_nb",
    "measure_nb",
    "rhs_nb",
    "rhs_jac_nb",
    "land_flows",
]

STATE_NAMES: tuple[str, ...] = (*er.STATE_NAMES, "pt1", "pt2")
N_STATES = len(STATE_NAMES)
IX = {n: k for k, n in enumerate(STATE_NAMES)}
S_PT1, S_PT2 = IX["pt1"], IX["pt2"]
H_MAX = 1e-3  # longest integration step [s]: one ROS2 step per 1 ms sample
GAMMA = 1.0 - 1.0 / math.sqrt(2.0)  # ROS2's gamma: L-stable, the hydraulic mode kept (0012)
V_MIN_FRACTION = 0.25  # chamber volume floor / V0 (a guard past the stroke: V_dead / V0 = 0.29)

# parameter vector: models.eha_reduced's layout, then the WH constants (docs/models.md eq. 2, 3, 5)
(K_WH_K, K_WH_DP_LAM, K_WH_ISQ_LAM, K_WH_BV, K_WH_XS_S, K_WH_XS_R, K_WH_V0,
 K_WH_LAM0, K_WH_C_LAND, K_WH_F_S, K_WH_V_STICK) = range(N_PRM, N_PRM + 11)  # fmt: skip
N_PRM_WH = N_PRM + 11


def k_orifice(rp: ReducedParams) -> float:
    """K_o = sqrt(2 P_SR,rated) / (x_SS G_PQ) [m^2/(s Pa^0.5)] (docs/models.md eq. 2)."""
    return math.sqrt(2.0 * rp.p_sr_rated) / (rp.x_ss * rp.g_pq)


def param_vector(rp: ReducedParams, v_c: float, beta: float) -> NDArray:
    """Float64 vector of the compiled WH kernels: ``models.eha_reduced.param_vector`` (law
    WH, longest step ``H_MAX``) followed by K_o, dp_lam, 1/sqrt(dp_lam), beta / V, the
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
    w_h (eq. 10) [rad/s], friction F_d / (v_f m) [1/s], each at V0; at the chamber floor
    V_MIN_FRACTION V0 the chamber mode is 1 / V_MIN_FRACTION times larger."""
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
def ros2_amplification(z):
    """ROS2's stability function R(z) = (1 + (1 - 2 gamma) z) / (1 - gamma z)^2 (exact J):
    the factor by which one step scales a mode exp(lambda t), z = lambda h (complex)."""
    z = np.asarray(z, complex)
    return (1.0 + (1.0 - 2.0 * GAMMA) * z) / (1.0 - GAMMA * z) ** 2


def _orifice(a, dp, k_o, dp_lam):
    r = np.where(np.abs(dp) >= dp_lam, np.sign(dp) * np.sqrt(np.abs(dp)), dp / math.sqrt(dp_lam))
    return k_o * np.maximum(a, 0.0) * r


def _land(a, dp, k_o, dp_lam, c_land):
    """One land: the orifice (eqs. 2-3) plus, while it is open, its laminar clearance leak
    c_land dp (docs/estimation.md, "Land clearance leak (WH)")."""
    return _orifice(a, dp, k_o, dp_lam) + np.where(a > 0.0, c_land * dp, 0.0)


def _land_slope(a, dp, k_o, dp_lam, c_land):
    """(flow, d flow / d dp) of one land (``_land``): K_o a / (2 sqrt|dp|) outside the
    laminar band, K_o a / sqrt(dp_lam) inside it, plus c_land while open."""
    ad = np.abs(dp)
    turb = ad >= dp_lam
    sq = np.sqrt(np.maximum(ad, dp_lam))
    am = k_o * np.maximum(a, 0.0)
    g = np.where(a > 0.0, c_land, 0.0)
    q = am * np.where(turb, np.sign(dp) * sq, dp / math.sqrt(dp_lam)) + g * dp
    s = am * np.where(turb, 0.5 / sq, 1.0 / math.sqrt(dp_lam)) + g
    return q, s


def chamber_volumes(x_j, area: float, v_c: float):
    """V1,2 = V0 +- A x_J [m^3], floored at V_MIN_FRACTION V0 (docs/models.md eq. 5b)."""
    v_min = V_MIN_FRACTION * v_c
    return np.maximum(v_c + area * x_j, v_min), np.maximum(v_c - area * x_j, v_min)


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


def jacobian(x_s, x_j, v_j, pt1, pt2, f_r, p_sr, c_lk, rp: ReducedParams, beta, v_c):
    """The Jacobian ROS2 uses: d(dv_J/dt, dp~1/dt, dp~2/dt) / d(v_J, p~1, p~2) at the spool
    position ``x_s`` seen from the hydraulic null, as a (..., 3, 3) array (rows v_J, p~1,
    p~2). A chamber below P_vap does not feel its own state (eq. 6); while stuck, dv_J/dt =
    -v_J / TAU_STICK."""
    p1, p2 = np.maximum(pt1, rp.p_vap), np.maximum(pt2, rp.p_vap)
    c1, c2 = (pt1 > rp.p_vap).astype(float), (pt2 > rp.p_vap).astype(float)
    k_o, dp_lam = k_orifice(rp), WH_DP_LAM_FRACTION * rp.p_sr_rated
    p_s = rp.p_r + p_sr
    xs_s, xs_r = rp.x_ss * (1.0 + rp.skew), rp.x_ss * (1.0 - rp.skew)
    s1 = _land_slope(xs_s + x_s, p_s - p1, k_o, dp_lam, rp.c_land)[1]
    s2 = _land_slope(xs_r - x_s, p1 - rp.p_r, k_o, dp_lam, rp.c_land)[1]
    s3 = _land_slope(xs_s - x_s, p_s - p2, k_o, dp_lam, rp.c_land)[1]
    s4 = _land_slope(xs_r + x_s, p2 - rp.p_r, k_o, dp_lam, rp.c_land)[1]
    v1, v2 = chamber_volumes(x_j, rp.area, v_c)
    bv1, bv2 = beta / v1, beta / v2
    stuck = (np.abs(v_j) < rp.v_stick) & (np.abs(rp.area * (p1 - p2) - f_r) <= rp.f_s)
    th = np.tanh(v_j / rp.v_f)
    j_vv = np.where(
        stuck, -1.0 / TAU_STICK, -(rp.c_v + rp.f_d * (1.0 - th * th) / rp.v_f) / rp.mass
    )
    am = np.where(stuck, 0.0, rp.area / rp.mass)
    rows = (
        (j_vv, am * c1, -am * c2),
        (-bv1 * rp.area, -bv1 * (s1 + s2 + c_lk) * c1, bv1 * c_lk * c2),
        (bv2 * rp.area, bv2 * c_lk * c1, -bv2 * (s3 + s4 + c_lk) * c2),
    )
    return np.stack([np.stack(np.broadcast_arrays(*r), axis=-1) for r in rows], axis=-2)


def _inv3(m):
    """Inverse of the 3x3 matrix ``m`` (nine entries, row by row) by its adjugate: plain
    arithmetic, so that the compiled kernel inlines the same formula on scalars."""
    a, b, c, d, e, f, g, h, i = m
    ei, fh, fg, di, dh, eg = e * i, f * h, f * g, d * i, d * h, e * g
    r = 1.0 / (a * (ei - fh) - b * (di - fg) + c * (dh - eg))
    return (
        (ei - fh) * r, (c * h - b * i) * r, (b * f - c * e) * r,
        (fg - di) * r, (a * i - c * g) * r, (c * d - a * f) * r,
        (dh - eg) * r, (b * g - a * h) * r, (a * e - b * d) * r,
    )  # fmt: skip


def _ros2(y, x_l0, x_l1, h, f_r, p_ev, c_ev, rp, beta, v_c):
    """One ROS2 step of y = (x_J, v_J, p~1, p~2) over h, the lands at x_l0 (stage 1) and x_l1
    (stage 2)."""
    g = GAMMA * h
    jm = jacobian(x_l0, *y, f_r, p_ev, c_ev, rp, beta, v_c)
    eye = np.eye(3)
    inv = _inv3(tuple((eye[r, c] - g * jm[..., r, c]) for r in range(3) for c in range(3)))

    def solve(r0, r1, r2, r3):  # (I - g J) k = r, with dx_J/dt = v_J: k_x = r_x + g k_v
        kv = inv[0] * r1 + inv[1] * r2 + inv[2] * r3
        k1 = inv[3] * r1 + inv[4] * r2 + inv[5] * r3
        k2 = inv[6] * r1 + inv[7] * r2 + inv[8] * r3
        return r0 + g * kv, kv, k1, k2

    ka = solve(*_rhs(x_l0, *y, f_r, p_ev, c_ev, rp, beta, v_c))
    yb = tuple(u + h * k for u, k in zip(y, ka, strict=True))
    fb = _rhs(x_l1, *yb, f_r, p_ev, c_ev, rp, beta, v_c)
    kb = solve(*(f - 2.0 * k for f, k in zip(fb, ka, strict=True)))
    return tuple(u + 1.5 * h * a + 0.5 * h * b for u, a, b in zip(y, ka, kb, strict=True))


def _catch(v_new, v_j, pt1, pt2, f_r, rp):
    """A v_J that crossed zero within the step under an applied force that cannot break away:
    stuck, v_J = 0."""
    f_a = rp.area * (np.maximum(pt1, rp.p_vap) - np.maximum(pt2, rp.p_vap)) - f_r
    stuck = (v_new * v_j < 0.0) & (np.abs(f_a) <= rp.f_s) & (rp.f_s > 0.0)
    return np.where(stuck, 0.0, v_new)


def _unpack(x: NDArray) -> tuple[NDArray, ...]:
    """The ten states of ``x`` (..., 10), in order: x_s, v_s, x_j, v_j, f_r, p_sr, c_lk, i_b,
    pt1, pt2 (views)."""
    return tuple(x[..., k] for k in range(N_STATES))


def step(x: NDArray, i, dt, rp: ReducedParams, n_sub: int, v_c: float, beta: float) -> NDArray:
    """Advance WH states ``x`` (..., 10) by ``dt`` with current ``i`` held, in ``n_sub``
    steps (1 at the monitor's 1 ms sample): per step the exact spool step, then one ROS2 step
    of (x_J, v_J, p~1, p~2) (module docstring). Parameters (f_r, p_sr, c_lk, i_b) are copied
    through; evaluated with C_Lk >= 0, P_SR >= P_vap."""
    x_s, v_s, x_j, v_j, f_r, p_sr, c_lk, i_b, pt1, pt2 = _unpack(x)
    p_ev, c_ev = np.maximum(p_sr, rp.p_vap), np.maximum(c_lk, 0.0)
    h = np.asarray(dt, float) / n_sub
    for _ in range(n_sub):
        x_l0 = np.clip(x_s, -rp.x_sm, rp.x_sm) - rp.x_0  # the lands see x_S - x_0
        x_s, v_s = er.spool_step(x_s, v_s, i + i_b, h, rp)
        y = (x_j, v_j, pt1, pt2)
        x_j, v_new, pt1, pt2 = _ros2(y, x_l0, x_s - rp.x_0, h, f_r, p_ev, c_ev, rp, beta, v_c)
        v_j = _catch(v_new, v_j, pt1, pt2, f_r, rp)
    return np.stack([x_s, v_s, x_j, v_j, f_r, p_sr, c_lk, i_b, pt1, pt2], axis=-1)


def step_rk4(x: NDArray, i, dt, rp: ReducedParams, n_sub: int, v_c: float, beta: float) -> NDArray:
    """The explicit scheme the filter used before ROS2, kept as the tests' fine-step
    reference: per substep the exact spool step, then one classic RK4 step of (x_J, v_J,
    p~1, p~2) with the spool held at its new position. Stable only while the chamber mode's
    |lambda h| < 2.785 (3 substeps per ms at mid stroke, up to 11 at the chamber floor)."""
    x_s, v_s, x_j, v_j, f_r, p_sr, c_lk, i_b, pt1, pt2 = _unpack(x)
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
        v_j = _catch(v_new, v_j, pt1, pt2, f_r, rp)
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
_inv3_nb = njit(**_NB, inline="always")(_inv3)


@njit(**_NB, inline="always")
def land_nb(a, dp, k_o, dp_lam, isq, g):
    """Scalar ``_land``: orifice flow plus the laminar leak g dp of an open land."""
    q = wh_orifice(a, dp, k_o, dp_lam, isq)
    return q + g * dp if a > 0.0 else q


@njit(**_NB, inline="always")
def land_slope_nb(a, dp, k_o, dp_lam, isq, g):
    """Scalar ``_land_slope``: (flow, d flow / d dp) of one land."""
    if a <= 0.0:
        return 0.0, 0.0
    ka = k_o * a
    ad = abs(dp)
    if ad >= dp_lam:
        r = math.sqrt(ad)
        return ka * math.copysign(r, dp) + g * dp, 0.5 * ka / r + g
    return ka * dp * isq + g * dp, ka * isq + g


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
def rhs_jac_nb(x_s, x_j, v_j, pt1, pt2, f_r, p_s, c_lk, prm):
    """``rhs_nb`` and, as ``jacobian``, the nine entries of d(dv_J/dt, dp~1/dt, dp~2/dt) /
    d(v_J, p~1, p~2), row by row: (acc, d1, d2, j00, ..., j22)."""
    p_vap, p_r = prm[K_P_VAP], prm[K_P_R]
    xs_s, xs_r = prm[K_WH_XS_S], prm[K_WH_XS_R]
    k_o, dp_lam, isq, bv = prm[K_WH_K], prm[K_WH_DP_LAM], prm[K_WH_ISQ_LAM], prm[K_WH_BV]
    area, mass = prm[K_AREA], prm[K_MASS]
    c1 = 1.0 if pt1 > p_vap else 0.0  # a cavitating chamber does not feel its state (eq. 6)
    c2 = 1.0 if pt2 > p_vap else 0.0
    p1 = max(pt1, p_vap)
    p2 = max(pt2, p_vap)
    g = prm[K_WH_C_LAND]
    q1, s1 = land_slope_nb(xs_s + x_s, p_s - p1, k_o, dp_lam, isq, g)
    q2, s2 = land_slope_nb(xs_r - x_s, p1 - p_r, k_o, dp_lam, isq, g)
    q3, s3 = land_slope_nb(xs_s - x_s, p_s - p2, k_o, dp_lam, isq, g)
    q4, s4 = land_slope_nb(xs_r + x_s, p2 - p_r, k_o, dp_lam, isq, g)
    p12 = p1 - p2
    q_lk = c_lk * p12
    q_j = area * v_j
    f_a = area * p12 - f_r
    if abs(v_j) < prm[K_WH_V_STICK] and abs(f_a) <= prm[K_WH_F_S]:
        acc = -v_j / TAU_STICK
        j_vv = -1.0 / TAU_STICK
        am = 0.0
    else:
        th = math.tanh(v_j / prm[K_V_F])
        f_d, c_v = prm[K_F_D], prm[K_C_V]
        acc = (f_a - c_v * v_j - f_d * th) / mass
        j_vv = -(c_v + f_d * (1.0 - th * th) / prm[K_V_F]) / mass
        am = area / mass
    v0 = prm[K_WH_V0]
    v_min = V_MIN_FRACTION * v0
    bv1 = bv * v0 / max(v0 + area * x_j, v_min)
    bv2 = bv * v0 / max(v0 - area * x_j, v_min)
    return (
        acc, bv1 * (q1 - q2 - q_lk - q_j), bv2 * (q3 - q4 + q_lk + q_j),
        j_vv, am * c1, -am * c2,
        -bv1 * area, -bv1 * (s1 + s2 + c_lk) * c1, bv1 * c_lk * c2,
        bv2 * area, bv2 * c_lk * c1, -bv2 * (s3 + s4 + c_lk) * c2,
    )  # fmt: skip


@njit(**_NB)  # called, not inlined: one compile for the filter and the parallel model
def step_core_nb(x, i, h, n_sub, prm, coef, out):
    """Scalar ``step`` with the spool transition ``coef`` of the step h precomputed:
    x (10,) -> out (10,)."""
    x_s, v_s, x_j, v_j, pt1, pt2 = x[0], x[1], x[2], x[3], x[8], x[9]
    f_r = x[4]
    p_s = prm[K_P_R] + max(x[5], prm[K_P_VAP])
    c_lk = max(x[6], 0.0)
    x_sm = prm[K_X_SM]
    x_ref = min(max(prm[K_K_SV] * (i + x[7]), -x_sm), x_sm)
    x_0 = prm[K_X_0]  # hydraulic null: the lands see x_S - x_0
    g = GAMMA * h
    h15, h05 = 1.5 * h, 0.5 * h
    f_s, area, p_vap = prm[K_WH_F_S], prm[K_AREA], prm[K_P_VAP]
    for _ in range(n_sub):
        x_l0 = min(max(x_s, -x_sm), x_sm) - x_0
        x_s, v_s = _spool_nb(x_s, v_s, x_ref, x_sm, coef)
        f1, f2, f3, j0, j1, j2, j3, j4, j5, j6, j7, j8 = rhs_jac_nb(
            x_l0, x_j, v_j, pt1, pt2, f_r, p_s, c_lk, prm
        )
        m0, m1, m2, m3, m4, m5, m6, m7, m8 = _inv3_nb((
            1.0 - g * j0, -g * j1, -g * j2, -g * j3, 1.0 - g * j4, -g * j5, -g * j6, -g * j7,
            1.0 - g * j8,
        ))  # fmt: skip
        a1 = m0 * f1 + m1 * f2 + m2 * f3  # stage 1: (I - g J) k = f, k_x = v_J + g k_v
        a2 = m3 * f1 + m4 * f2 + m5 * f3
        a3 = m6 * f1 + m7 * f2 + m8 * f3
        a0 = v_j + g * a1
        e1, e2, e3 = rhs_nb(
            x_s - x_0, x_j + h * a0, v_j + h * a1, pt1 + h * a2, pt2 + h * a3, f_r, p_s, c_lk,
            prm,
        )  # fmt: skip
        r0 = v_j + h * a1 - 2.0 * a0  # stage 2: f(y + h k1) - 2 k1
        r1 = e1 - 2.0 * a1
        r2 = e2 - 2.0 * a2
        r3 = e3 - 2.0 * a3
        b1 = m0 * r1 + m1 * r2 + m2 * r3
        b2 = m3 * r1 + m4 * r2 + m5 * r3
        b3 = m6 * r1 + m7 * r2 + m8 * r3
        b0 = r0 + g * b1
        x_j += h15 * a0 + h05 * b0
        v_new = v_j + (h15 * a1 + h05 * b1)
        pt1 += h15 * a2 + h05 * b2
        pt2 += h15 * a3 + h05 * b3
        if v_new * v_j < 0.0 and f_s > 0.0:  # v_J crossed zero within the step:
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
