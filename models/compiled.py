"""Compiled (numba) scalar kernels of the EHA bench (physics.md sections 2, 3 and 6).

Everything the fixed-step integrator needs is here as scalar ``@njit(cache=True)`` code:
the simplified laws (one function, model id branch), the HF land flows, the effective
bulk modulus, the 7-state right-hand side and the RK4 stepping loop. Parameters travel as
one float64 array built by :func:`param_array`. ``error_model="numpy"``: a division by
zero gives inf/nan instead of raising; helpers are inlined into the loop
(``inline="always"``) and remain callable from Python for the tests. The numpy functions in
``models.valve_laws`` and ``models.hf_valve`` are the readable reference; the tests hold
these kernels to them.

State vector (always 7 slots): I, x_S, v_S, x_J, v_J, P1, P2. For the simplified valves
P1, P2 are unused (derivative 0) and P12 is algebraic.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from models.params import EHAParams

__all__ = [
    "MODEL_IDS",
    "N_STATE",
    "TAU_STICK",
    "param_array",
    "law_p12",
    "orifice_flow",
    "beta_eff",
    "rhs",
    "integrate",
]

MODEL_IDS: dict[str, int] = {"HF": 0, "A": 1, "B": 2, "C1": 3, "C3": 4, "C5": 5}
N_STATE = 7
TAU_STICK = 1e-3
"""Relaxation time of v_J while stuck (Karnopp band) [s]: removes the classic drift at
|v| < dv_k without a velocity reset that a smooth reference solver could not follow."""

# parameter array layout
(
    I_P_R,
    I_U1,
    I_U2,
    I_U3,
    I_U4,
    I_CD,
    I_W,
    I_X_SM,
    I_C_R,
    I_L_MIN,
    I_DP_TR,
    I_RHO,
    I_MU,
    I_BETA_L,
    I_ALPHA0,
    I_KAPPA,
    I_P_VAP,
    I_P_ATM,
    I_I_MAX,
    I_K_SV,
    I_TAU_TM,
    I_OMEGA_N,
    I_ZETA,
    I_AREA,
    I_STROKE,
    I_V_DEAD,
    I_MASS,
    I_C_V,
    I_F_S,
    I_F_D,
    I_DV_K,
    I_K_STOP,
    I_C_STOP,
    I_K_P,
    I_G_PQ,
    I_X_SS,
    I_TAU_STICK,
    I_INV_TAU_TM,
    I_WN2,
    I_C2ZW,
    I_INV_MASS,
    I_INV_TAU_STICK,
    N_PRM,
) = range(43)


def param_array(p: EHAParams) -> np.ndarray:
    """Float64 parameter vector of the compiled kernels (layout: the I_* constants)."""
    a = np.empty(N_PRM)
    a[I_P_R] = p.p_r
    a[I_U1], a[I_U2], a[I_U3], a[I_U4] = p.u1, p.u2, p.u3, p.u4
    a[I_CD] = p.cd
    a[I_W] = p.w_eff
    a[I_X_SM] = p.x_sm
    a[I_C_R] = p.c_r
    a[I_L_MIN] = p.l_min
    a[I_DP_TR] = p.dp_tr
    a[I_RHO] = p.rho
    a[I_MU] = p.mu
    a[I_BETA_L] = p.beta_l
    a[I_ALPHA0] = p.alpha0
    a[I_KAPPA] = p.kappa
    a[I_P_VAP] = p.p_vap
    a[I_P_ATM] = p.p_atm
    a[I_I_MAX] = p.i_max
    a[I_K_SV] = p.k_sv
    a[I_TAU_TM] = p.tau_tm
    a[I_OMEGA_N] = p.omega_n
    a[I_ZETA] = p.zeta
    a[I_AREA] = p.area
    a[I_STROKE] = p.stroke
    a[I_V_DEAD] = p.v_dead
    a[I_MASS] = p.mass
    a[I_C_V] = p.c_v
    a[I_F_S] = p.f_s
    a[I_F_D] = p.f_d
    a[I_DV_K] = p.dv_k
    a[I_K_STOP] = p.k_stop
    a[I_C_STOP] = p.c_stop
    a[I_K_P] = p.k_p
    a[I_G_PQ] = p.g_pq
    a[I_X_SS] = p.x_ss
    a[I_TAU_STICK] = TAU_STICK
    # reciprocals and products precomputed for the stepping loop
    a[I_INV_TAU_TM] = 1.0 / p.tau_tm
    a[I_WN2] = p.omega_n**2
    a[I_C2ZW] = 2.0 * p.zeta * p.omega_n
    a[I_INV_MASS] = 1.0 / p.mass
    a[I_INV_TAU_STICK] = 1.0 / TAU_STICK
    return a


@njit(cache=True, error_model="numpy", inline="always")
def law_p12(model, x_s, q_j, p_sr, g_pq, x_ss, c_lk, p_vap):
    """Simplified law ``model`` (1=A, 2=B, 3=C1, 4=C3, 5=C5), physics.md section 2."""
    if model == 1:
        return (p_sr / x_ss * x_s - g_pq * q_j) / (1.0 + g_pq * c_lk)
    if model == 2:
        y = min(max(p_sr / x_ss * x_s, -p_sr), p_sr)
        return (y - g_pq * q_j) / (1.0 + g_pq * c_lk)
    if model == 3:
        y = min(max(p_sr / x_ss * x_s - g_pq * q_j, -p_sr), p_sr)
        return y / (1.0 + g_pq * c_lk)
    if model == 4:
        y = min(max(p_sr * x_s / x_ss - g_pq * q_j, -p_sr), p_sr)
        return y / (1.0 + g_pq * x_ss * c_lk / max(abs(x_s), x_ss))
    if model == 5:
        x_st = x_s - q_j * g_pq * x_ss / max(p_sr, p_vap)
        return x_st * p_sr / (max(abs(x_st), x_ss) + c_lk * g_pq * x_ss)
    return math.nan


@njit(cache=True, error_model="numpy", inline="always")
def orifice_flow(a, dp, cd, w, rho, dp_tr, c_r, mu, l_min):
    """One metering land (physics.md section 3): smoothed turbulent orifice + radial leakage."""
    turb = cd * w * max(a, 0.0) * math.sqrt(2.0 / rho) * dp / (dp * dp + dp_tr * dp_tr) ** 0.25
    g_lam = w * c_r**3 / (12.0 * mu * (max(-a, 0.0) + l_min))
    return turb + g_lam * dp


@njit(cache=True, error_model="numpy", inline="always")
def beta_eff(p, beta_l, alpha0, kappa, p_vap, p_atm):
    """Entrained-air bulk modulus beta(P) with vapour floor (physics.md section 3)."""
    ps = max(p - p_vap, 1.0)
    alpha = alpha0 * (p_atm / ps) ** (1.0 / kappa)
    return beta_l / (1.0 + alpha * beta_l / (kappa * ps))


@njit(cache=True, error_model="numpy")
def _p12_of_state(y, p_sr, c_lk, prm, model):
    if model == 0:
        return y[5] - y[6]
    x_sm = prm[I_X_SM]
    xse = min(max(y[1], -x_sm), x_sm)
    return law_p12(
        model, xse, prm[I_AREA] * y[4], p_sr, prm[I_G_PQ], prm[I_X_SS], c_lk, prm[I_P_VAP]
    )


@njit(cache=True, error_model="numpy", inline="always")
def rhs(y, x_cmd, f_r, p_sr, c_lk, prm, model, dy):
    """Right-hand side of the closed-loop EHA (physics.md section 3), written into ``dy``."""
    i_max = prm[I_I_MAX]
    x_sm = prm[I_X_SM]
    cur = y[0]
    x_s = y[1]
    v_s = y[2]
    x_j = y[3]
    v_j = y[4]
    # ECU and torque motor
    i_c = min(max(prm[I_K_P] * (x_cmd - x_j), -i_max), i_max)
    dy[0] = (i_c - cur) * prm[I_INV_TAU_TM]
    # spool: second order towards x_ref, hard limit +-x_SM (position frozen when pushing out)
    x_ref = min(max(prm[I_K_SV] * cur, -x_sm), x_sm)
    dy[2] = prm[I_WN2] * (x_ref - x_s) - prm[I_C2ZW] * v_s
    if (x_s >= x_sm and v_s > 0.0) or (x_s <= -x_sm and v_s < 0.0):
        dy[1] = 0.0
    else:
        dy[1] = v_s
    xse = min(max(x_s, -x_sm), x_sm)
    area = prm[I_AREA]
    q_j = area * v_j
    if model == 0:
        p1 = y[5]
        p2 = y[6]
        p_r = prm[I_P_R]
        p_s = p_r + p_sr
        cd = prm[I_CD]
        w = prm[I_W]
        rho = prm[I_RHO]
        dp_tr = prm[I_DP_TR]
        c_r = prm[I_C_R]
        mu = prm[I_MU]
        l_min = prm[I_L_MIN]
        q1 = orifice_flow(prm[I_U1] + xse, p_s - p1, cd, w, rho, dp_tr, c_r, mu, l_min)
        q2 = orifice_flow(prm[I_U2] - xse, p1 - p_r, cd, w, rho, dp_tr, c_r, mu, l_min)
        q3 = orifice_flow(prm[I_U3] - xse, p_s - p2, cd, w, rho, dp_tr, c_r, mu, l_min)
        q4 = orifice_flow(prm[I_U4] + xse, p2 - p_r, cd, w, rho, dp_tr, c_r, mu, l_min)
        q_lk = c_lk * (p1 - p2)
        v0 = area * prm[I_STROKE] + prm[I_V_DEAD]
        v_min = 1e-3 * prm[I_V_DEAD]
        v1 = max(v0 + area * x_j, v_min)
        v2 = max(v0 - area * x_j, v_min)
        bl = prm[I_BETA_L]
        a0 = prm[I_ALPHA0]
        kap = prm[I_KAPPA]
        pv = prm[I_P_VAP]
        pa = prm[I_P_ATM]
        dy[5] = beta_eff(p1, bl, a0, kap, pv, pa) / v1 * (q1 - q2 - q_lk - q_j)
        dy[6] = beta_eff(p2, bl, a0, kap, pv, pa) / v2 * (q3 - q4 + q_lk + q_j)
        p12 = p1 - p2
    else:
        p12 = law_p12(model, xse, q_j, p_sr, prm[I_G_PQ], prm[I_X_SS], c_lk, prm[I_P_VAP])
        dy[5] = 0.0
        dy[6] = 0.0
    # jack: end stops (spring-damper on penetration, never pulling) and Karnopp friction
    stroke = prm[I_STROKE]
    f_e = 0.0
    if x_j > stroke:
        f_e = max(prm[I_K_STOP] * (x_j - stroke) + prm[I_C_STOP] * v_j, 0.0)
    elif x_j < -stroke:
        f_e = min(prm[I_K_STOP] * (x_j + stroke) + prm[I_C_STOP] * v_j, 0.0)
    f_a = area * p12 - f_r - f_e
    inv_m = prm[I_INV_MASS]
    f_s = prm[I_F_S]
    dy[3] = v_j
    if abs(v_j) < prm[I_DV_K]:
        if abs(f_a) <= f_s:
            dy[4] = -v_j * prm[I_INV_TAU_STICK]  # stuck
        else:
            dy[4] = (f_a - prm[I_C_V] * v_j - math.copysign(f_s, f_a)) * inv_m  # breakaway
    else:
        dy[4] = (f_a - prm[I_C_V] * v_j - math.copysign(prm[I_F_D], v_j)) * inv_m


@njit(cache=True, error_model="numpy")
def integrate(y, h, n_sub, k0, n_steps, u, prm, model, out_every, out):
    """Advance ``y`` in place over ``n_steps`` classic RK4 steps of ``h`` (global steps
    k0..k0+n-1), each split into ``n_sub`` substeps.

    ``u`` is (n_u, 4): x_cmd, f_r, p_sr, c_lk held over local step k (row min(k, n_u - 1)).
    After global step g = k0 + k the state goes to ``out[(g + 1) // out_every]`` whenever
    ``(g + 1) % out_every == 0`` (row 0 is left for the initial state).
    """
    n = y.shape[0]
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    yt = np.empty(n)
    hs = h / n_sub
    n_u = u.shape[0]
    for j in range(n):
        yt[j] = y[j]
    ns = n if model == 0 else 5  # P1, P2 are not states of the simplified models
    for k in range(n_steps):
        r = min(k, n_u - 1)
        x_cmd = u[r, 0]
        f_r = u[r, 1]
        p_sr = u[r, 2]
        c_lk = u[r, 3]
        for _ in range(n_sub):
            rhs(y, x_cmd, f_r, p_sr, c_lk, prm, model, k1)
            for j in range(ns):
                yt[j] = y[j] + 0.5 * hs * k1[j]
            rhs(yt, x_cmd, f_r, p_sr, c_lk, prm, model, k2)
            for j in range(ns):
                yt[j] = y[j] + 0.5 * hs * k2[j]
            rhs(yt, x_cmd, f_r, p_sr, c_lk, prm, model, k3)
            for j in range(ns):
                yt[j] = y[j] + hs * k3[j]
            rhs(yt, x_cmd, f_r, p_sr, c_lk, prm, model, k4)
            for j in range(ns):
                y[j] += hs / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        g1 = k0 + k + 1
        if g1 % out_every == 0:
            row = g1 // out_every
            for j in range(n):
                out[row, j] = y[j]
