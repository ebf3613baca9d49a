"""Compiled (numba) scalar kernels of the EHA bench (physics.md sections 2, 3 and 6).

Everything the fixed-step integrator needs is here as scalar ``@njit(cache=True)`` code:
the simplified laws (one function, model id branch), the HF land flows, the effective
bulk modulus, the 7-state right-hand side and the RK4 stepping loop. Parameters travel as
one float64 array built by :func:`param_array`. ``error_model="numpy"``: a division by
zero gives inf/nan instead of raising. The numpy functions in ``models.valve_laws`` and
``models.hf_valve`` are the readable reference; the tests hold these kernels to them.

Speed path: :func:`integrate` runs one loop per valve model (the law branch resolved at
compile time), with the RK4 stages in scalar locals (no arrays, no stores in the loop) and
the parameter- and input-only factors hoisted out of it. The simplified loops are bound by
the latency of the v_J -> dv_J dependency chain of each RK4 stage, so they evaluate the law
and the jack force rearranged to shorten it (:func:`_law_fast`: products with step factors
such as 1/(1 + G_PQ C_Lk) instead of divisions; :func:`_jack_accel_fast`: A/m P12 split off
the other forces); the HF loop is bound by pow() and takes the orifices' 4th root as two
square roots. Both change the results by round-off only (about 1e-14 of each state's range
on the bundled scenarios). :func:`rhs`, :func:`law_p12`, :func:`orifice_flow` keep the
plain formulas (bitwise as before); tests/test_compiled_speedpath.py holds every loop to
classic RK4 on :func:`rhs` and to values recorded before the speed path (rtol 1e-9).

State vector (always 7 slots): I, x_S, v_S, x_J, v_J, P1, P2. For the simplified valves
P1, P2 are unused (derivative 0) and P12 is algebraic.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from models.params import EHAParams, wh_params

__all__ = [
    "MODEL_IDS",
    "N_STATE",
    "TAU_STICK",
    "V_J_ZERO",
    "param_array",
    "law_p12",
    "orifice_flow",
    "beta_eff",
    "rhs",
    "integrate",
]

MODEL_IDS: dict[str, int] = {"HF": 0, "A": 1, "B": 2, "C1": 3, "C3": 4, "C5": 5, "WH": 6}
N_STATE = 7
TAU_STICK = 1e-3
"""Relaxation time of v_J while stuck (Karnopp band) [s]: removes the classic drift at
|v| < dv_k without a velocity reset that a smooth reference solver could not follow."""
V_J_ZERO = 1e-200
"""|v_J| below which the fixed-step loops set v_J to 0 [m/s]. While stuck, v_J decays by
exp(-h / TAU_STICK) per step into the subnormal range and then stays at a few times 5e-324
(the RK4 increment rounds to nothing); every operation on it is then a slow subnormal one
(about 30x slower steps). 1e-200 m/s is far below the round-off of any state."""

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
    I_WH_K,
    I_WH_DP_LAM,
    I_WH_ISQ_LAM,
    I_WH_BV,
    N_PRM,
) = range(47)


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
    wp = wh_params(p)  # WH: docs/models.md section 2
    a[I_WH_K] = wp.k_o
    a[I_WH_DP_LAM] = wp.dp_lam
    a[I_WH_ISQ_LAM] = 1.0 / math.sqrt(wp.dp_lam)
    a[I_WH_BV] = wp.beta / wp.v_c
    return a


# -- scalar building blocks ------------------------------------------------------------------
# Split so that the factors depending only on the parameters or on the inputs held over a
# step can be computed once outside a stepping loop; these keep the association order of
# the formulas (e.g. ``p_sr / x_ss * x_s`` = ``s_a * x_s`` with s_a = p_sr / x_ss), so
# law_p12, orifice_flow, beta_eff and rhs are bitwise the plain formulas.


@njit(cache=True, error_model="numpy")
def _law_consts(model, p_sr, c_lk, g_pq, x_ss, p_vap):
    """Input-only factors (s_a, s_b) of law ``model`` for :func:`_law_step`."""
    if model == 4:
        return g_pq * x_ss * c_lk, 0.0
    if model == 5:
        return max(p_sr, p_vap), c_lk * g_pq * x_ss
    return p_sr / x_ss, 1.0 + g_pq * c_lk


@njit(cache=True, error_model="numpy")
def _law_step(model, x_s, q_j, p_sr, g_pq, x_ss, s_a, s_b):
    """Law ``model`` with the input-only factors of :func:`_law_consts` (physics.md section 2)."""
    if model == 1:
        return (s_a * x_s - g_pq * q_j) / s_b
    if model == 2:
        y = min(max(s_a * x_s, -p_sr), p_sr)
        return (y - g_pq * q_j) / s_b
    if model == 3:
        y = min(max(s_a * x_s - g_pq * q_j, -p_sr), p_sr)
        return y / s_b
    if model == 4:
        y = min(max(p_sr * x_s / x_ss - g_pq * q_j, -p_sr), p_sr)
        return y / (1.0 + s_a / max(abs(x_s), x_ss))
    if model == 5:
        x_st = x_s - q_j * g_pq * x_ss / s_a
        return x_st * p_sr / (max(abs(x_st), x_ss) + s_b)
    return math.nan


@njit(cache=True, error_model="numpy", inline="always")
def law_p12(model, x_s, q_j, p_sr, g_pq, x_ss, c_lk, p_vap):
    """Simplified law ``model`` (1=A, 2=B, 3=C1, 4=C3, 5=C5), physics.md section 2.

    A: (P_SR/x_SS x_S - G_PQ Q_J) / (1 + G_PQ C_Lk); B clips the flow-free term, C1 the
    numerator to +-P_SR; C3 with the leakage term scaled by x_SS / max(|x_S|, x_SS); C5 on
    the equivalent opening x_S* = x_S - Q_J G_PQ x_SS / P_SR.
    """
    s_a, s_b = _law_consts(model, p_sr, c_lk, g_pq, x_ss, p_vap)
    return _law_step(model, x_s, q_j, p_sr, g_pq, x_ss, s_a, s_b)


@njit(cache=True, error_model="numpy")
def _orifice(a, dp, cw, s2r, dtr2, wc3, mu12, l_min, fast):
    # cw = cd w, s2r = sqrt(2 / rho), dtr2 = dp_tr^2, wc3 = w c_r^3, mu12 = 12 mu;
    # fast: the 4th root as two square roots (round-off apart from pow, several times cheaper)
    r = dp * dp + dtr2
    turb = cw * max(a, 0.0) * s2r * dp / (math.sqrt(math.sqrt(r)) if fast else r**0.25)
    g_lam = wc3 / (mu12 * (max(-a, 0.0) + l_min))
    return turb + g_lam * dp


@njit(cache=True, error_model="numpy", inline="always")
def orifice_flow(a, dp, cd, w, rho, dp_tr, c_r, mu, l_min):
    """One metering land (physics.md section 3): smoothed turbulent orifice + radial leakage."""
    return _orifice(
        a, dp, cd * w, math.sqrt(2.0 / rho), dp_tr * dp_tr, w * c_r**3, 12.0 * mu, l_min, False
    )


@njit(cache=True, error_model="numpy")
def _beta(p, beta_l, alpha0, kappa, inv_kappa, p_vap, p_atm):
    ps = max(p - p_vap, 1.0)
    alpha = alpha0 * (p_atm / ps) ** inv_kappa
    return beta_l / (1.0 + alpha * beta_l / (kappa * ps))


@njit(cache=True, error_model="numpy", inline="always")
def beta_eff(p, beta_l, alpha0, kappa, p_vap, p_atm):
    """Entrained-air bulk modulus beta(P) with vapour floor (physics.md section 3)."""
    return _beta(p, beta_l, alpha0, kappa, 1.0 / kappa, p_vap, p_atm)


@njit(cache=True, error_model="numpy")
def _drive_consts(prm):
    return (
        prm[I_K_P], prm[I_I_MAX], prm[I_INV_TAU_TM], prm[I_K_SV], prm[I_X_SM], prm[I_WN2],
        prm[I_C2ZW],
    )  # fmt: skip


@njit(cache=True, error_model="numpy")
def _drive(cur, x_s, v_s, x_j, x_cmd, dc):
    """ECU, torque motor and spool (physics.md section 3): dI, dx_S, dv_S and x_S clipped."""
    k_p, i_max, inv_tau_tm, k_sv, x_sm, wn2, c2zw = dc
    i_c = min(max(k_p * (x_cmd - x_j), -i_max), i_max)
    d_cur = (i_c - cur) * inv_tau_tm
    # spool: second order towards x_ref, hard limit +-x_SM (position frozen when pushing out)
    x_ref = min(max(k_sv * cur, -x_sm), x_sm)
    d_vs = wn2 * (x_ref - x_s) - c2zw * v_s
    pushing_out = (x_s >= x_sm and v_s > 0.0) or (x_s <= -x_sm and v_s < 0.0)
    d_xs = 0.0 if pushing_out else v_s
    return d_cur, d_xs, d_vs, min(max(x_s, -x_sm), x_sm)


@njit(cache=True, error_model="numpy")
def _jack_consts(prm):
    return (
        prm[I_AREA], prm[I_STROKE], prm[I_K_STOP], prm[I_C_STOP], prm[I_C_V], prm[I_F_S],
        prm[I_F_D], prm[I_DV_K], prm[I_INV_MASS], prm[I_INV_TAU_STICK],
    )  # fmt: skip


@njit(cache=True, error_model="numpy")
def _jack_accel(x_j, v_j, p12, f_r, jc):
    """dv_J: end stops (spring-damper on penetration, never pulling) and Karnopp friction."""
    area, stroke, k_stop, c_stop, c_v, f_s, f_d, dv_k, inv_m, inv_tau_stick = jc
    f_e = 0.0
    if x_j > stroke:
        f_e = max(k_stop * (x_j - stroke) + c_stop * v_j, 0.0)
    elif x_j < -stroke:
        f_e = min(k_stop * (x_j + stroke) + c_stop * v_j, 0.0)
    f_a = area * p12 - f_r - f_e
    if abs(v_j) < dv_k:
        if abs(f_a) <= f_s:
            return -v_j * inv_tau_stick  # stuck
        return (f_a - c_v * v_j - math.copysign(f_s, f_a)) * inv_m  # breakaway
    return (f_a - c_v * v_j - math.copysign(f_d, v_j)) * inv_m


@njit(cache=True, error_model="numpy")
def _hf_consts(prm):
    cd = prm[I_CD]
    w = prm[I_W]
    c_r = prm[I_C_R]
    kappa = prm[I_KAPPA]
    v_dead = prm[I_V_DEAD]
    area = prm[I_AREA]
    return (
        prm[I_P_R], prm[I_U1], prm[I_U2], prm[I_U3], prm[I_U4],
        cd * w, math.sqrt(2.0 / prm[I_RHO]), prm[I_DP_TR] * prm[I_DP_TR], w * c_r**3,
        12.0 * prm[I_MU], prm[I_L_MIN], area, area * prm[I_STROKE] + v_dead, 1e-3 * v_dead,
        prm[I_BETA_L], prm[I_ALPHA0], kappa, 1.0 / kappa, prm[I_P_VAP], prm[I_P_ATM],
    )  # fmt: skip


@njit(cache=True, error_model="numpy", inline="always")
def _chambers(xse, x_j, q_j, p1, p2, p_s, c_lk, hc, fast):
    """dP1, dP2 of the HF valve's chambers (physics.md section 3); ``fast``: see _orifice."""
    p_r, u1, u2, u3, u4, cw, s2r, dtr2, wc3, mu12, l_min = hc[:11]
    area, v0, v_min, bl, a0, kap, ikap, pv, pa = hc[11:]
    q1 = _orifice(u1 + xse, p_s - p1, cw, s2r, dtr2, wc3, mu12, l_min, fast)
    q2 = _orifice(u2 - xse, p1 - p_r, cw, s2r, dtr2, wc3, mu12, l_min, fast)
    q3 = _orifice(u3 - xse, p_s - p2, cw, s2r, dtr2, wc3, mu12, l_min, fast)
    q4 = _orifice(u4 + xse, p2 - p_r, cw, s2r, dtr2, wc3, mu12, l_min, fast)
    q_lk = c_lk * (p1 - p2)
    v1 = max(v0 + area * x_j, v_min)
    v2 = max(v0 - area * x_j, v_min)
    d_p1 = _beta(p1, bl, a0, kap, ikap, pv, pa) / v1 * (q1 - q2 - q_lk - q_j)
    d_p2 = _beta(p2, bl, a0, kap, ikap, pv, pa) / v2 * (q3 - q4 + q_lk + q_j)
    return d_p1, d_p2


# -- WH valve (docs/models.md section 2) -----------------------------------------------------


@njit(cache=True, error_model="numpy")
def _wh_consts(prm):
    return (
        prm[I_P_R], prm[I_X_SS], prm[I_WH_K], prm[I_WH_DP_LAM], prm[I_WH_ISQ_LAM],
        prm[I_WH_BV], prm[I_P_VAP],
    )  # fmt: skip


@njit(cache=True, error_model="numpy", inline="always")
def wh_orifice(a, dp, k_o, dp_lam, isq_lam):
    """WH land flow K_o max(a, 0) r(dp) (docs/models.md eqs. 2-3): sign(dp) sqrt|dp| outside
    the laminar band |dp| < dp_lam, dp / sqrt(dp_lam) inside it (isq_lam = 1/sqrt(dp_lam))."""
    if a <= 0.0:
        return 0.0
    ad = abs(dp)
    if ad >= dp_lam:
        return k_o * a * math.copysign(math.sqrt(ad), dp)
    return k_o * a * dp * isq_lam


@njit(cache=True, error_model="numpy", inline="always")
def _wh_chambers(xse, q_j, pt1, pt2, p_sr, c_lk, wc):
    """dp~1, dp~2 and P12 of the WH valve (docs/models.md eqs. 1-6): chamber pressures
    P_k = max(p~_k, P_vap), lands underlapped by x_SS, lumped beta / V."""
    p_r, x_ss, k_o, dp_lam, isq_lam, bv, p_vap = wc
    p1 = max(pt1, p_vap)
    p2 = max(pt2, p_vap)
    p_s = p_r + p_sr
    a_p = x_ss + xse
    a_m = x_ss - xse
    q1 = wh_orifice(a_p, p_s - p1, k_o, dp_lam, isq_lam)
    q2 = wh_orifice(a_m, p1 - p_r, k_o, dp_lam, isq_lam)
    q3 = wh_orifice(a_m, p_s - p2, k_o, dp_lam, isq_lam)
    q4 = wh_orifice(a_p, p2 - p_r, k_o, dp_lam, isq_lam)
    p12 = p1 - p2
    q_lk = c_lk * p12
    return bv * (q1 - q2 - q_lk - q_j), bv * (q3 - q4 + q_lk + q_j), p12


@njit(cache=True, error_model="numpy", inline="always")
def _rhs_wh(cur, x_s, v_s, x_j, v_j, pt1, pt2, x_cmd, f_r, p_sr, c_lk, dc, jc, wc):
    d_cur, d_xs, d_vs, xse = _drive(cur, x_s, v_s, x_j, x_cmd, dc)
    d_p1, d_p2, p12 = _wh_chambers(xse, jc[0] * v_j, pt1, pt2, p_sr, c_lk, wc)
    return d_cur, d_xs, d_vs, v_j, _jack_accel(x_j, v_j, p12, f_r, jc), d_p1, d_p2


@njit(cache=True, error_model="numpy")
def _integrate_wh(y, h, n_sub, k0, n_steps, u, prm, out_every, out):
    dc = _drive_consts(prm)
    jc = _jack_consts(prm)
    wc = _wh_consts(prm)
    hs = h / n_sub
    hh = 0.5 * hs
    h6 = hs / 6.0
    n_u = u.shape[0]
    y0, y1, y2, y3, y4, y5, y6 = y[0], y[1], y[2], y[3], y[4], y[5], y[6]
    x_cmd = f_r = p_sr = c_lk = 0.0
    cnt = k0 % out_every
    for k in range(n_steps):
        if k < n_u:  # row min(k, n_u - 1)
            x_cmd = u[k, 0]
            f_r = u[k, 1]
            p_sr = u[k, 2]
            c_lk = u[k, 3]
        for _ in range(n_sub):
            a0, a1, a2, a3, a4, a5, a6 = _rhs_wh(
                y0, y1, y2, y3, y4, y5, y6, x_cmd, f_r, p_sr, c_lk, dc, jc, wc
            )
            b0, b1, b2, b3, b4, b5, b6 = _rhs_wh(
                y0 + hh * a0, y1 + hh * a1, y2 + hh * a2, y3 + hh * a3, y4 + hh * a4,
                y5 + hh * a5, y6 + hh * a6, x_cmd, f_r, p_sr, c_lk, dc, jc, wc,
            )  # fmt: skip
            c0, c1, c2, c3, c4, c5, c6 = _rhs_wh(
                y0 + hh * b0, y1 + hh * b1, y2 + hh * b2, y3 + hh * b3, y4 + hh * b4,
                y5 + hh * b5, y6 + hh * b6, x_cmd, f_r, p_sr, c_lk, dc, jc, wc,
            )  # fmt: skip
            d0, d1, d2, d3, d4, d5, d6 = _rhs_wh(
                y0 + hs * c0, y1 + hs * c1, y2 + hs * c2, y3 + hs * c3, y4 + hs * c4,
                y5 + hs * c5, y6 + hs * c6, x_cmd, f_r, p_sr, c_lk, dc, jc, wc,
            )  # fmt: skip
            y0 += h6 * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
            y1 += h6 * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
            y2 += h6 * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
            y3 += h6 * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
            y4 += h6 * (a4 + 2.0 * b4 + 2.0 * c4 + d4)
            if abs(y4) < V_J_ZERO:
                y4 = 0.0
            y5 += h6 * (a5 + 2.0 * b5 + 2.0 * c5 + d5)
            y6 += h6 * (a6 + 2.0 * b6 + 2.0 * c6 + d6)
        cnt += 1
        if cnt == out_every:
            cnt = 0
            row = (k0 + k + 1) // out_every
            out[row, 0] = y0
            out[row, 1] = y1
            out[row, 2] = y2
            out[row, 3] = y3
            out[row, 4] = y4
            out[row, 5] = y5
            out[row, 6] = y6
    y[0], y[1], y[2], y[3], y[4], y[5], y[6] = y0, y1, y2, y3, y4, y5, y6


@njit(cache=True, error_model="numpy")
def _p12_of_state(y, p_sr, c_lk, prm, model):
    if model == 0:
        return y[5] - y[6]
    if model == 6:
        p_vap = prm[I_P_VAP]
        return max(y[5], p_vap) - max(y[6], p_vap)
    x_sm = prm[I_X_SM]
    xse = min(max(y[1], -x_sm), x_sm)
    return law_p12(
        model, xse, prm[I_AREA] * y[4], p_sr, prm[I_G_PQ], prm[I_X_SS], c_lk, prm[I_P_VAP]
    )


@njit(cache=True, error_model="numpy", inline="always")
def rhs(y, x_cmd, f_r, p_sr, c_lk, prm, model, dy):
    """Right-hand side of the closed-loop EHA (physics.md section 3), written into ``dy``.

    The readable array form (used by ``models.reference`` and the tests); :func:`integrate`
    evaluates the same blocks with the constants hoisted out of its loop and the fast
    variants (_law_fast, _jack_accel_fast, the orifices' square roots): equal up to round-off.
    """
    d_cur, d_xs, d_vs, xse = _drive(y[0], y[1], y[2], y[3], x_cmd, _drive_consts(prm))
    jc = _jack_consts(prm)
    v_j = y[4]
    q_j = jc[0] * v_j
    if model == 0:
        p1 = y[5]
        p2 = y[6]
        d_p1, d_p2 = _chambers(
            xse, y[3], q_j, p1, p2, prm[I_P_R] + p_sr, c_lk, _hf_consts(prm), False
        )
        p12 = p1 - p2
    elif model == 6:
        d_p1, d_p2, p12 = _wh_chambers(xse, q_j, y[5], y[6], p_sr, c_lk, _wh_consts(prm))
    else:
        g_pq = prm[I_G_PQ]
        x_ss = prm[I_X_SS]
        s_a, s_b = _law_consts(model, p_sr, c_lk, g_pq, x_ss, prm[I_P_VAP])
        p12 = _law_step(model, xse, q_j, p_sr, g_pq, x_ss, s_a, s_b)
        d_p1 = 0.0
        d_p2 = 0.0
    dy[0] = d_cur
    dy[1] = d_xs
    dy[2] = d_vs
    dy[3] = v_j
    dy[4] = _jack_accel(y[3], v_j, p12, f_r, jc)
    dy[5] = d_p1
    dy[6] = d_p2


# -- fixed-step RK4 loops, one specialisation per valve model -----------------------------
# Scalar locals for the stages (no arrays, no stores in the loop), the law branch resolved
# at compile time (``model`` is a closure constant of each simplified loop), the input-only
# factors recomputed only while the input row changes, no modulo per step for the output
# stride, no division on the simplified loops' v_J path (except C5 past |x_S*| > x_SS),
# no pow() for the HF orifices.
# The small helpers are inlined by LLVM; _rhs5, _rhs7 and _chambers at the numba IR level
# (LLVM left some as calls). IR-level inlining of everything tripled the compile time.


@njit(cache=True, error_model="numpy")
def _law_fast_consts(model, p_sr, c_lk, area, g_pq, x_ss, p_vap):
    """Step factors (f0, f1, f2) of law ``model`` for :func:`_law_fast`."""
    if model == 4:  # C3
        return p_sr / x_ss, g_pq * area, g_pq * x_ss * c_lk
    if model == 5:  # C5; f2: P12 / x_S* while |x_S*| <= x_SS
        f1 = c_lk * g_pq * x_ss
        return area * g_pq * x_ss / max(p_sr, p_vap), f1, p_sr / (x_ss + f1)
    return p_sr / x_ss, g_pq * area, 1.0 / (1.0 + g_pq * c_lk)  # A, B, C1


@njit(cache=True, error_model="numpy")
def _law_fast(model, x_s, v_j, p_sr, x_ss, f0, f1, f2):
    """:func:`law_p12` at Q_J = A v_J, rearranged for a short v_J -> P12 latency (products of
    step factors instead of divisions): equal up to round-off (physics.md section 2)."""
    if model == 1:
        return (f0 * x_s - f1 * v_j) * f2
    if model == 2:
        return (min(max(f0 * x_s, -p_sr), p_sr) - f1 * v_j) * f2
    if model == 3:
        return min(max(f0 * x_s - f1 * v_j, -p_sr), p_sr) * f2
    if model == 4:
        m = max(abs(x_s), x_ss)
        r = m / (m + f2)  # 1 / (1 + f2 / m) in one division; x_S only: off the v_J chain
        return min(max(f0 * x_s - f1 * v_j, -p_sr), p_sr) * r
    if model == 5:
        x_st = x_s - f0 * v_j
        a = abs(x_st)
        if a <= x_ss:
            return x_st * f2
        return x_st * p_sr / (a + f1)
    return math.nan


@njit(cache=True, error_model="numpy")
def _jack_accel_fast(x_j, v_j, p12, f_r, jc, area_m):
    """:func:`_jack_accel` with A P12 / m split off the other forces (area_m = A / m): equal
    up to round-off, P12 -> dv_J in one product and one difference."""
    area, stroke, k_stop, c_stop, c_v, f_s, f_d, dv_k, inv_m, inv_tau_stick = jc
    f_e = 0.0
    if x_j > stroke:
        f_e = max(k_stop * (x_j - stroke) + c_stop * v_j, 0.0)
    elif x_j < -stroke:
        f_e = min(k_stop * (x_j + stroke) + c_stop * v_j, 0.0)
    if abs(v_j) < dv_k:
        f_a = area * p12 - f_r - f_e
        if abs(f_a) <= f_s:
            return -v_j * inv_tau_stick  # stuck
        return area_m * p12 - (f_r + f_e + c_v * v_j + math.copysign(f_s, f_a)) * inv_m
    return area_m * p12 - (f_r + f_e + c_v * v_j + math.copysign(f_d, v_j)) * inv_m


@njit(cache=True, error_model="numpy", inline="always")
def _rhs5(model, cur, x_s, v_s, x_j, v_j, x_cmd, f_r, p_sr, f0, f1, f2, x_ss, area_m, dc, jc):
    d_cur, d_xs, d_vs, xse = _drive(cur, x_s, v_s, x_j, x_cmd, dc)
    p12 = _law_fast(model, xse, v_j, p_sr, x_ss, f0, f1, f2)
    return d_cur, d_xs, d_vs, v_j, _jack_accel_fast(x_j, v_j, p12, f_r, jc, area_m)


def _make_simplified_loop(model: int):
    def _integrate_simplified(y, h, n_sub, k0, n_steps, u, prm, out_every, out):
        dc = _drive_consts(prm)
        jc = _jack_consts(prm)
        g_pq = prm[I_G_PQ]
        x_ss = prm[I_X_SS]
        p_vap = prm[I_P_VAP]
        hs = h / n_sub
        hh = 0.5 * hs
        h6 = hs / 6.0
        n_u = u.shape[0]
        y0, y1, y2, y3, y4, y5, y6 = y[0], y[1], y[2], y[3], y[4], y[5], y[6]
        area = prm[I_AREA]
        area_m = area * prm[I_INV_MASS]
        x_cmd = f_r = p_sr = f0 = f1 = f2 = 0.0
        cnt = k0 % out_every
        for k in range(n_steps):
            if k < n_u:  # row min(k, n_u - 1)
                x_cmd = u[k, 0]
                f_r = u[k, 1]
                p_sr = u[k, 2]
                f0, f1, f2 = _law_fast_consts(model, p_sr, u[k, 3], area, g_pq, x_ss, p_vap)
            for _ in range(n_sub):
                a0, a1, a2, a3, a4 = _rhs5(
                    model, y0, y1, y2, y3, y4, x_cmd, f_r, p_sr, f0, f1, f2, x_ss, area_m, dc, jc
                )
                b0, b1, b2, b3, b4 = _rhs5(
                    model, y0 + hh * a0, y1 + hh * a1, y2 + hh * a2, y3 + hh * a3, y4 + hh * a4,
                    x_cmd, f_r, p_sr, f0, f1, f2, x_ss, area_m, dc, jc,
                )  # fmt: skip
                c0, c1, c2, c3, c4 = _rhs5(
                    model, y0 + hh * b0, y1 + hh * b1, y2 + hh * b2, y3 + hh * b3, y4 + hh * b4,
                    x_cmd, f_r, p_sr, f0, f1, f2, x_ss, area_m, dc, jc,
                )  # fmt: skip
                d0, d1, d2, d3, d4 = _rhs5(
                    model, y0 + hs * c0, y1 + hs * c1, y2 + hs * c2, y3 + hs * c3, y4 + hs * c4,
                    x_cmd, f_r, p_sr, f0, f1, f2, x_ss, area_m, dc, jc,
                )  # fmt: skip
                y0 += h6 * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
                y1 += h6 * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
                y2 += h6 * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
                y3 += h6 * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
                y4 += h6 * (a4 + 2.0 * b4 + 2.0 * c4 + d4)
                if abs(y4) < V_J_ZERO:
                    y4 = 0.0
            cnt += 1
            if cnt == out_every:
                cnt = 0
                row = (k0 + k + 1) // out_every
                out[row, 0] = y0
                out[row, 1] = y1
                out[row, 2] = y2
                out[row, 3] = y3
                out[row, 4] = y4
                out[row, 5] = y5
                out[row, 6] = y6
        y[0], y[1], y[2], y[3], y[4] = y0, y1, y2, y3, y4

    # one qualified name per model: its own cache index and symbol (loops of one name compiled
    # in different processes would collide when loaded from the cache)
    _integrate_simplified.__qualname__ += f"_{model}"
    return njit(cache=True, error_model="numpy")(_integrate_simplified)


_LOOP_A = _make_simplified_loop(1)
_LOOP_B = _make_simplified_loop(2)
_LOOP_C1 = _make_simplified_loop(3)
_LOOP_C3 = _make_simplified_loop(4)
_LOOP_C5 = _make_simplified_loop(5)


@njit(cache=True, error_model="numpy", inline="always")
def _rhs7(cur, x_s, v_s, x_j, v_j, p1, p2, x_cmd, f_r, p_s, c_lk, dc, jc, hc):
    d_cur, d_xs, d_vs, xse = _drive(cur, x_s, v_s, x_j, x_cmd, dc)
    d_p1, d_p2 = _chambers(xse, x_j, jc[0] * v_j, p1, p2, p_s, c_lk, hc, True)
    return d_cur, d_xs, d_vs, v_j, _jack_accel(x_j, v_j, p1 - p2, f_r, jc), d_p1, d_p2


@njit(cache=True, error_model="numpy")
def _integrate_hf(y, h, n_sub, k0, n_steps, u, prm, out_every, out):
    dc = _drive_consts(prm)
    jc = _jack_consts(prm)
    hc = _hf_consts(prm)
    p_r = prm[I_P_R]
    hs = h / n_sub
    hh = 0.5 * hs
    h6 = hs / 6.0
    n_u = u.shape[0]
    y0, y1, y2, y3, y4, y5, y6 = y[0], y[1], y[2], y[3], y[4], y[5], y[6]
    x_cmd = f_r = p_s = c_lk = 0.0
    cnt = k0 % out_every
    for k in range(n_steps):
        if k < n_u:  # row min(k, n_u - 1)
            x_cmd = u[k, 0]
            f_r = u[k, 1]
            p_s = p_r + u[k, 2]
            c_lk = u[k, 3]
        for _ in range(n_sub):
            a0, a1, a2, a3, a4, a5, a6 = _rhs7(
                y0, y1, y2, y3, y4, y5, y6, x_cmd, f_r, p_s, c_lk, dc, jc, hc
            )
            b0, b1, b2, b3, b4, b5, b6 = _rhs7(
                y0 + hh * a0, y1 + hh * a1, y2 + hh * a2, y3 + hh * a3, y4 + hh * a4,
                y5 + hh * a5, y6 + hh * a6, x_cmd, f_r, p_s, c_lk, dc, jc, hc,
            )  # fmt: skip
            c0, c1, c2, c3, c4, c5, c6 = _rhs7(
                y0 + hh * b0, y1 + hh * b1, y2 + hh * b2, y3 + hh * b3, y4 + hh * b4,
                y5 + hh * b5, y6 + hh * b6, x_cmd, f_r, p_s, c_lk, dc, jc, hc,
            )  # fmt: skip
            d0, d1, d2, d3, d4, d5, d6 = _rhs7(
                y0 + hs * c0, y1 + hs * c1, y2 + hs * c2, y3 + hs * c3, y4 + hs * c4,
                y5 + hs * c5, y6 + hs * c6, x_cmd, f_r, p_s, c_lk, dc, jc, hc,
            )  # fmt: skip
            y0 += h6 * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
            y1 += h6 * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
            y2 += h6 * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
            y3 += h6 * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
            y4 += h6 * (a4 + 2.0 * b4 + 2.0 * c4 + d4)
            if abs(y4) < V_J_ZERO:
                y4 = 0.0
            y5 += h6 * (a5 + 2.0 * b5 + 2.0 * c5 + d5)
            y6 += h6 * (a6 + 2.0 * b6 + 2.0 * c6 + d6)
        cnt += 1
        if cnt == out_every:
            cnt = 0
            row = (k0 + k + 1) // out_every
            out[row, 0] = y0
            out[row, 1] = y1
            out[row, 2] = y2
            out[row, 3] = y3
            out[row, 4] = y4
            out[row, 5] = y5
            out[row, 6] = y6
    y[0], y[1], y[2], y[3], y[4], y[5], y[6] = y0, y1, y2, y3, y4, y5, y6


# the loop of each valve model id (MODEL_IDS)
_LOOPS = (_integrate_hf, _LOOP_A, _LOOP_B, _LOOP_C1, _LOOP_C3, _LOOP_C5, _integrate_wh)


def integrate(y, h, n_sub, k0, n_steps, u, prm, model, out_every, out) -> None:
    """Advance ``y`` in place over ``n_steps`` classic RK4 steps of ``h`` (global steps
    k0..k0+n-1), each split into ``n_sub`` substeps.

    ``u`` is (n_u, 4): x_cmd, f_r, p_sr, c_lk held over local step k (row min(k, n_u - 1)).
    After global step g = k0 + k the state goes to ``out[(g + 1) // out_every]`` whenever
    ``(g + 1) % out_every == 0`` (row 0 is left for the initial state). Classic RK4 on
    :func:`rhs` up to round-off; one specialised loop per valve model (see module docstring),
    chosen here in Python, so that a run compiles only its own model's loop.
    """
    if not 0 <= model < len(_LOOPS):
        raise ValueError("unknown valve model id")
    _LOOPS[model](y, h, n_sub, k0, n_steps, u, prm, out_every, out)
