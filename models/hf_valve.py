"""High-fidelity four-way spool valve and chambers, numpy reference (physics.md section 3).

Absolute pressures throughout: P_R = params.p_r, P_S = P_R + P_SR. Every function
broadcasts its array arguments. ``models.compiled`` holds the scalar numba versions used by
the integrator; the tests hold them to these.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from models.params import EHAParams

__all__ = [
    "orifice_flow",
    "orifice_slope",
    "land_openings",
    "land_flows",
    "beta_eff",
    "chamber_volumes",
    "chamber_derivatives",
    "hf_static_pressures",
    "hf_static_p12",
    "hf_static_hold",
]


def orifice_flow(a: ArrayLike, dp: ArrayLike, params: EHAParams) -> NDArray:
    """Land flow Q = Cd w max(a,0) sqrt(2/rho) dp / (dp^2+dp_tr^2)^(1/4) + G_lam dp.

    G_lam = w c_r^3 / (12 mu (max(-a,0) + l_min)) is the radial-clearance leakage
    (physics.md section 3). ``a`` opening [m] (>0 open), ``dp`` upstream-downstream [Pa].
    """
    a = np.asarray(a, float)
    dp = np.asarray(dp, float)
    p = params
    turb = p.cd * p.w_eff * np.maximum(a, 0.0) * np.sqrt(2.0 / p.rho) * dp
    turb = turb / (dp * dp + p.dp_tr * p.dp_tr) ** 0.25
    g_lam = p.w_eff * p.c_r**3 / (12.0 * p.mu * (np.maximum(-a, 0.0) + p.l_min))
    return turb + g_lam * dp


def orifice_slope(a: ArrayLike, dp: ArrayLike, params: EHAParams) -> NDArray:
    """dQ/d(dp) of :func:`orifice_flow`: K a (dp^2/2 + dp_tr^2) / (dp^2+dp_tr^2)^(5/4) + G_lam.

    Bounded by K a / sqrt(dp_tr) at dp = 0 (K = Cd w sqrt(2/rho)).
    """
    a = np.asarray(a, float)
    dp = np.asarray(dp, float)
    p = params
    s = dp * dp + p.dp_tr * p.dp_tr
    k = p.cd * p.w_eff * np.maximum(a, 0.0) * np.sqrt(2.0 / p.rho)
    g_lam = p.w_eff * p.c_r**3 / (12.0 * p.mu * (np.maximum(-a, 0.0) + p.l_min))
    return k * (0.5 * dp * dp + p.dp_tr**2) / s**1.25 + g_lam


def land_openings(x_s: ArrayLike, params: EHAParams) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """a1 = u1 + x_S (S->1), a2 = u2 - x_S (1->R), a3 = u3 - x_S (S->2), a4 = u4 + x_S (2->R)."""
    x_s = np.asarray(x_s, float)
    p = params
    return p.u1 + x_s, p.u2 - x_s, p.u3 - x_s, p.u4 + x_s


def land_flows(
    x_s: ArrayLike, p1: ArrayLike, p2: ArrayLike, p_sr: ArrayLike, params: EHAParams
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Q1 (S->1), Q2 (1->R), Q3 (S->2), Q4 (2->R) [m^3/s] at absolute P1, P2 (physics.md 3)."""
    p1 = np.asarray(p1, float)
    p2 = np.asarray(p2, float)
    p_r = params.p_r
    p_s = p_r + np.asarray(p_sr, float)
    a1, a2, a3, a4 = land_openings(x_s, params)
    return (
        orifice_flow(a1, p_s - p1, params),
        orifice_flow(a2, p1 - p_r, params),
        orifice_flow(a3, p_s - p2, params),
        orifice_flow(a4, p2 - p_r, params),
    )


def beta_eff(p: ArrayLike, params: EHAParams) -> NDArray:
    """beta(P) = beta_l / (1 + alpha beta_l / (kappa P*)), P* = max(P - P_vap, 1 Pa),
    alpha = alpha0 (P_atm / P*)^(1/kappa) (physics.md section 3)."""
    pr = params
    ps = np.maximum(np.asarray(p, float) - pr.p_vap, 1.0)
    alpha = pr.alpha0 * (pr.p_atm / ps) ** (1.0 / pr.kappa)
    return pr.beta_l / (1.0 + alpha * pr.beta_l / (pr.kappa * ps))


def chamber_volumes(x_j: ArrayLike, params: EHAParams) -> tuple[NDArray, NDArray]:
    """V1,2 = V0 +- A x_J, V0 = A stroke + V_dead, floored at 1e-3 V_dead (deep in a stop)."""
    x_j = np.asarray(x_j, float)
    p = params
    v_min = 1e-3 * p.v_dead
    return np.maximum(p.v0 + p.area * x_j, v_min), np.maximum(p.v0 - p.area * x_j, v_min)


def chamber_derivatives(
    x_s: ArrayLike,
    x_j: ArrayLike,
    v_j: ArrayLike,
    p1: ArrayLike,
    p2: ArrayLike,
    p_sr: ArrayLike,
    c_lk: ArrayLike,
    params: EHAParams,
) -> tuple[NDArray, NDArray]:
    """dP1/dt = beta(P1)/V1 (Q1 - Q2 - Q_Lk - A v_J); dP2/dt = beta(P2)/V2 (Q3 - Q4 + Q_Lk + A v_J).

    Q_Lk = C_Lk (P1 - P2) (physics.md section 3). ``x_s`` is the spool position already
    limited to +-x_SM.
    """
    p1 = np.asarray(p1, float)
    p2 = np.asarray(p2, float)
    q1, q2, q3, q4 = land_flows(x_s, p1, p2, p_sr, params)
    q_lk = np.asarray(c_lk, float) * (p1 - p2)
    q_j = params.area * np.asarray(v_j, float)
    v1, v2 = chamber_volumes(x_j, params)
    dp1 = beta_eff(p1, params) / v1 * (q1 - q2 - q_lk - q_j)
    dp2 = beta_eff(p2, params) / v2 * (q3 - q4 + q_lk + q_j)
    return dp1, dp2


def _residuals(x_s, q_j, p_s, c_lk, p1, p2, params):
    p_r = params.p_r
    a1, a2, a3, a4 = land_openings(x_s, params)
    f1 = (
        orifice_flow(a1, p_s - p1, params)
        - orifice_flow(a2, p1 - p_r, params)
        - c_lk * (p1 - p2)
        - q_j
    )
    f2 = (
        orifice_flow(a3, p_s - p2, params)
        - orifice_flow(a4, p2 - p_r, params)
        + c_lk * (p1 - p2)
        + q_j
    )
    return f1, f2


def bisect_decreasing(f, lo: NDArray, hi: NDArray, n_iter: int) -> NDArray:
    """Element-wise root of ``f`` decreasing in its argument on [lo, hi] (the bound if none
    inside): ``n_iter`` halvings of the bracket."""
    a, b = lo.copy(), hi.copy()
    for _ in range(n_iter):
        m = 0.5 * (a + b)
        pos = f(m) > 0
        a = np.where(pos, m, a)
        b = np.where(pos, b, m)
    return 0.5 * (a + b)


def _bisect_p2(x_s, q_j, p_s, c_lk, p1, lo, hi, params, n_iter):
    """P2 solving f2(P1, P2) = 0 (f2 decreasing in P2), clipped to [lo, hi]."""
    return bisect_decreasing(
        lambda p2: _residuals(x_s, q_j, p_s, c_lk, p1, p2, params)[1],
        np.broadcast_to(lo, p1.shape),
        np.broadcast_to(hi, p1.shape),
        n_iter,
    )


def hf_static_pressures(
    x_s: ArrayLike,
    q_j: ArrayLike,
    p_sr: ArrayLike,
    params: EHAParams,
    c_lk: ArrayLike | None = None,
    *,
    tol_pa: float = 1e-3,
    newton_iter: int = 80,
) -> tuple[NDArray, NDArray]:
    """Steady-state absolute chamber pressures (P1, P2) of the HF valve (physics.md section 3).

    Solves Q1 - Q2 - Q_Lk = Q_J and Q3 - Q4 + Q_Lk = -Q_J, Q_Lk = C_Lk (P1 - P2), with
    x_s, q_j, p_sr (and c_lk, default params.c_lk) broadcast. Method: damped 2-D Newton
    from the null balance; points that do not converge (kinks, beyond capacity) are solved
    by nested bisection on the monotone reduced residual f1(P1, P2*(P1))
    (``newton_iter=0`` forces bisection everywhere).

    Clipping: pressures are confined to [P_vap, P_S + 10 P_SR]. When Q_J exceeds what the
    valve can feed (e.g. the supply side of a chamber would have to go below vapour
    pressure) the balance has no solution in that range and the pressure sits at the bound
    (P_vap, or P_S + 10 P_SR for a jack forced backwards through closed lands): the flow
    balance is then not met. ``x_s`` is not limited here (pass a physically reachable spool
    position).
    """
    p = params
    c = p.c_lk if c_lk is None else c_lk
    x_s, q_j, p_sr, c = np.broadcast_arrays(
        np.asarray(x_s, float), np.asarray(q_j, float), np.asarray(p_sr, float),
        np.asarray(c, float),
    )  # fmt: skip
    shape = x_s.shape
    x_s, q_j, p_sr, c = (np.ravel(v) for v in (x_s, q_j, p_sr, c))
    p_r = p.p_r
    p_s = p_r + p_sr
    lo = np.full(x_s.shape, p.p_vap)
    hi = p_s + 10.0 * p_sr
    p1 = 0.5 * (p_s + p_r)
    p2 = p1.copy()
    a1, a2, a3, a4 = land_openings(x_s, p)
    max_step = 0.25 * p_sr
    converged = np.zeros(x_s.shape, bool)
    act = np.arange(x_s.size)  # indices still iterating (compacted each pass)
    for _ in range(newton_iter):
        xa, qa, psa, ca = x_s[act], q_j[act], p_s[act], c[act]
        loa, hia, msa = lo[act], hi[act], max_step[act]
        q1, q2 = p1[act], p2[act]
        f1, f2 = _residuals(xa, qa, psa, ca, q1, q2, p)
        j11 = -orifice_slope(a1[act], psa - q1, p) - orifice_slope(a2[act], q1 - p_r, p) - ca
        j22 = -orifice_slope(a3[act], psa - q2, p) - orifice_slope(a4[act], q2 - p_r, p) - ca
        det = j11 * j22 - ca * ca
        d1 = -(f1 * j22 - ca * f2) / det
        d2 = -(j11 * f2 - ca * f1) / det
        # active set: a pressure held at a bound that Newton pushes further stays there,
        # the other one takes the 1-D Newton step
        out1 = ((q1 <= loa) & (d1 < 0)) | ((q1 >= hia) & (d1 > 0))
        out2 = ((q2 <= loa) & (d2 < 0)) | ((q2 >= hia) & (d2 > 0))
        d1 = np.where(out1, 0.0, np.where(out2, -f1 / j11, d1))
        d2 = np.where(out2, 0.0, np.where(out1, -f2 / j22, d2))
        p1n = np.clip(q1 + np.clip(d1, -msa, msa), loa, hia)
        p2n = np.clip(q2 + np.clip(d2, -msa, msa), loa, hia)
        done = (np.abs(p1n - q1) < tol_pa) & (np.abs(p2n - q2) < tol_pa)
        p1[act] = p1n
        p2[act] = p2n
        converged[act[done]] = True
        act = act[~done]
        if act.size == 0:
            break
    # verify: a free pressure must balance its chamber; a clipped one must have its
    # residual pointing beyond the bound (f decreasing in its own pressure)
    f1, f2 = _residuals(x_s, q_j, p_s, c, p1, p2, p)
    q_scale = p.g_q * p.x_ss * 1e-9 + 1e-16
    ok1 = (np.abs(f1) < q_scale) | ((p1 <= lo) & (f1 < 0)) | ((p1 >= hi) & (f1 > 0))
    ok2 = (np.abs(f2) < q_scale) | ((p2 <= lo) & (f2 < 0)) | ((p2 >= hi) & (f2 > 0))
    ok = converged & ok1 & ok2
    bad = ~ok
    if bad.any():
        xs_b, qj_b, ps_b, c_b = x_s[bad], q_j[bad], p_s[bad], c[bad]
        lo_b, hi_b = lo[bad], hi[bad]
        a = lo_b.copy()
        b = hi_b.copy()
        n_in = 56
        for _ in range(56):
            m = 0.5 * (a + b)
            p2m = _bisect_p2(xs_b, qj_b, ps_b, c_b, m, lo_b, hi_b, p, n_in)
            f1m, _ = _residuals(xs_b, qj_b, ps_b, c_b, m, p2m, p)
            pos = f1m > 0
            a = np.where(pos, m, a)
            b = np.where(pos, b, m)
        p1b = 0.5 * (a + b)
        p1[bad] = p1b
        p2[bad] = _bisect_p2(xs_b, qj_b, ps_b, c_b, p1b, lo_b, hi_b, p, n_in)
    return p1.reshape(shape), p2.reshape(shape)


def hf_static_p12(
    x_s: ArrayLike,
    q_j: ArrayLike,
    p_sr: ArrayLike,
    params: EHAParams,
    c_lk: ArrayLike | None = None,
) -> NDArray:
    """Steady-state P12 = P1 - P2 of the HF valve at (x_S, Q_J, P_SR), broadcast.

    See :func:`hf_static_pressures` for the flow balance, the solver and the clipping of
    pressures to [P_vap, P_S + 10 P_SR] when Q_J exceeds the valve's capacity.
    """
    p1, p2 = hf_static_pressures(x_s, q_j, p_sr, params, c_lk)
    return p1 - p2


def hf_static_hold(
    p12: float, p_sr: float, params: EHAParams, c_lk: float | None = None, x_max: float = 8e-5
) -> tuple[float, float, float]:
    """(x_S [m], P1, P2 [Pa]) of the HF valve holding the jack still (Q_J = 0) at load
    pressure ``p12`` and supply ``p_sr``: the root of :func:`hf_static_p12` in x_S (monotone at
    Q_J = 0), bracketed by +-``x_max``, then its absolute chamber pressures."""
    from scipy.optimize import brentq

    x_s = brentq(
        lambda x: float(hf_static_p12(x, 0.0, p_sr, params, c_lk)) - p12, -x_max, x_max, xtol=1e-14
    )
    p1, p2 = hf_static_pressures(x_s, 0.0, p_sr, params, c_lk)
    return float(x_s), float(p1), float(p2)
