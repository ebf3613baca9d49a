"""Simplified (C-type) EHA process model for the estimator (physics.md sections 2, 3).

No chamber states: the load pressure P12 = law(x_S, A v_J, P_SR) is algebraic (a valve law of
``models.valve_laws``). States, in this order (the filter state, SI units)::

    x_s [m], v_s [m/s], x_j [m], v_j [m/s], f_r [N], p_sr [Pa], c_lk [m^3/s/Pa], i_b [A]

The first four are the plant states; f_r (external load), p_sr (supply), c_lk (internal
leakage) and i_b (servovalve null bias, x_ref = K_sv (i + i_b)) are slowly varying parameters
(random walks in the filter). The measured servovalve
current i is an input; the spool is the second-order lag of physics.md section 3 driven by
K_sv i, discretised exactly (zero-order hold). The jack velocity is stiff through the law
(pole near -A^2 G_PQ / m, about -7400 1/s), so it is advanced linearly-implicitly
(Rosenbrock-Euler with a finite-difference Jacobian), which is stable at any step.

Everything is vectorised over leading batch axes (sigma points x actuators): a state array
has shape ``(..., 8)`` and every parameter broadcasts against ``(...)``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from models.compiled import law_p12
from models.params import EHAParams
from models.valve_laws import LAWS

__all__ = [
    "STATE_NAMES",
    "N_STATES",
    "IX",
    "MEAS_NAMES",
    "ReducedParams",
    "reduced_params",
    "spool_step",
    "p12_state",
    "jack_accel",
    "step",
    "measure",
    "ecu_current",
    "param_vector",
    "step_nb",
    "step_core_nb",
    "step_points_nb",
    "spool_coef_nb",
    "measure_nb",
]

STATE_NAMES: tuple[str, ...] = ("x_s", "v_s", "x_j", "v_j", "f_r", "p_sr", "c_lk", "i_b")
N_STATES = len(STATE_NAMES)
IX = {n: k for k, n in enumerate(STATE_NAMES)}
MEAS_NAMES: tuple[str, ...] = ("x_s", "x_j", "p1", "p2", "p_sr")


class ReducedParams(NamedTuple):
    """Parameters of the simplified EHA model (SI). ``x_ss``/``g_pq`` are *effective* values
    (calibrated against the plant, see ``service.monitor.calibration``)."""

    law: str = "C5"
    g_pq: float = 7.4e11  # effective G_PQ at the rated supply [Pa s/m^3]
    p_sr_rated: float = 20e6  # [Pa]
    g_pq_exp: float = 0.5  # G_PQ ~ (P_SR / rated)^g_pq_exp (physics.md section 3: sqrt)
    x_ss: float = 1e-4  # effective saturation spool displacement (G_P = P_SR / x_SS) [m]
    p_vap: float = 1e3  # [Pa]
    p_r: float = 0.5e6  # return pressure, absolute [Pa] (chamber pressures P1, P2)
    area: float = 1e-3  # [m^2]
    mass: float = 100.0  # [kg]
    c_v: float = 2000.0  # viscous friction [N s/m]
    f_d: float = 400.0  # Coulomb friction [N], smoothed by tanh(v / v_f)
    v_f: float = 2e-3  # friction smoothing velocity [m/s]
    k_sv: float = 0.05  # [m/A]
    x_sm: float = 5e-4  # spool stroke limit [m]
    omega_n: float = 2 * math.pi * 150.0  # [rad/s]
    zeta: float = 0.7
    k_p: float = 2.0  # ECU position gain [A/m] (used only when the current is not measured)
    i_max: float = 0.01  # [A]
    h_max: float = 1e-3  # longest internal integration substep [s]
    x_u: float = 0.0  # land underlap [m]: beyond it one land pair closes (x_eq); 0 = off
    x_0: float = 0.0  # hydraulic null of the spool [m]: the law sees x_S - x_0 (land mismatch)
    skew: float = 0.0  # WH only: supply lands underlapped x_SS (1 + skew), return x_SS (1 - skew)
    c_land: float = 0.0  # WH only: laminar land-clearance leak, a cross-port leak [m^3/(s Pa)]
    f_s: float = 0.0  # WH only: breakaway (static) friction [N]; 0 = no stiction
    v_stick: float = 3e-4  # WH only: stick band [m/s]: |v_J| below it the jack can stick


def x_eq(x_s, x_u: float):
    """Equivalent opening of the null-calibrated law (docs/estimation.md section "Large
    openings"): an underlapped four-land spool passes its no-load flow through both land
    pairs while |x_S| <= u (flow gain 2 G_Q, the gain the calibration identifies) and
    through one pair beyond (Q = G_Q (|x_S| + u), physics.md section 3), so the law is fed
    x_eq = x_S for |x_S| <= u and sign(x_S) (|x_S| + u) / 2 beyond (x_u = 0: x_eq = x_S)."""
    x_s = np.asarray(x_s, float)
    if x_u <= 0.0:
        return x_s
    return np.where(np.abs(x_s) <= x_u, x_s, np.sign(x_s) * 0.5 * (np.abs(x_s) + x_u))


def reduced_params(p: EHAParams | None = None, law: str = "C5", **overrides) -> ReducedParams:
    """Nominal simplified-model parameters derived from the HF set (physics.md section 3)."""
    p = p or EHAParams()
    rp = ReducedParams(
        law=law,
        g_pq=p.g_pq,
        x_ss=p.x_ss,
        p_vap=p.p_vap,
        p_r=p.p_r,
        p_sr_rated=p.p_sr,
        area=p.area,
        mass=p.mass,
        c_v=p.c_v,
        f_d=p.f_d,
        k_sv=p.k_sv,
        x_sm=p.x_sm,
        omega_n=p.omega_n,
        zeta=p.zeta,
        k_p=p.k_p,
        i_max=p.i_max,
        x_u=abs(p.u1),
    )
    return rp._replace(**overrides)


def ecu_current(x_cmd: NDArray, x_j: NDArray, rp: ReducedParams) -> NDArray:
    """ECU law i_c = clip(K_p (x_cmd - x_J), -i_max, i_max) (physics.md section 3)."""
    return np.clip(rp.k_p * (x_cmd - x_j), -rp.i_max, rp.i_max)


def spool_step(x_s: NDArray, v_s: NDArray, i: NDArray, h: NDArray | float, rp: ReducedParams):
    """Exact zero-order-hold step of x_S'' = w_n^2 (x_ref - x_S) - 2 zeta w_n x_S'
    with x_ref = clip(K_sv i, -x_SM, x_SM) (physics.md section 3), for 0 < zeta < 1."""
    w, z = rp.omega_n, rp.zeta
    sig = z * w
    wd = w * math.sqrt(1.0 - z * z)
    e = np.exp(-sig * h)
    c, s = np.cos(wd * h), np.sin(wd * h)
    x_ref = np.clip(rp.k_sv * i, -rp.x_sm, rp.x_sm)
    dx = x_s - x_ref
    x_new = x_ref + e * ((c + sig / wd * s) * dx + s / wd * v_s)
    v_new = e * (-(w * w) / wd * s * dx + (c - sig / wd * s) * v_s)
    return np.clip(x_new, -rp.x_sm, rp.x_sm), v_new


def p12_state(x_s, v_j, p_sr, c_lk, rp: ReducedParams) -> NDArray:
    """Load pressure P12 = law(x_S, A v_J, P_SR) with the effective valve parameters."""
    g_pq = g_pq_at(p_sr, rp)
    return LAWS[rp.law](
        x_eq(np.asarray(x_s) - rp.x_0, rp.x_u), rp.area * v_j, p_sr, g_pq, rp.x_ss, c_lk, rp.p_vap
    )


def g_pq_at(p_sr, rp: ReducedParams):
    """G_PQ at supply P_SR: G_PQ = sqrt(P_SR rho) / (Cd w x_SS) (physics.md section 3), i.e.
    the rated value times (P_SR / rated)^g_pq_exp (exponent 0: the seed's constant G_PQ)."""
    if rp.g_pq_exp == 0.0:
        return rp.g_pq
    return rp.g_pq * (np.maximum(p_sr, rp.p_vap) / rp.p_sr_rated) ** rp.g_pq_exp


def jack_accel(x_s, v_j, f_r, p_sr, c_lk, rp: ReducedParams) -> NDArray:
    """dv_J/dt = (A P12 - F_R - c_v v_J - F_d tanh(v_J / v_f)) / m (physics.md section 1)."""
    p12 = p12_state(x_s, v_j, p_sr, c_lk, rp)
    f = rp.area * p12 - f_r - rp.c_v * v_j - rp.f_d * np.tanh(v_j / rp.v_f)
    return f / rp.mass


def step(x: NDArray, i: NDArray, dt: NDArray, rp: ReducedParams, n_sub: int) -> NDArray:
    """Advance states ``x`` (..., 8) by ``dt`` (broadcast to x[..., 0]) with current ``i`` held.

    ``n_sub`` substeps of h = dt / n_sub: exact spool step, then a linearly-implicit
    (Rosenbrock-Euler) velocity update v+ = v + h a / (1 - h da/dv), then x_J += h v+.
    Parameters (f_r, p_sr, c_lk) are held constant over the step (random walks).
    """
    x_s, v_s, x_j, v_j = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
    f_r, p_sr, c_lk, i_b = x[..., 4], x[..., 5], x[..., 6], x[..., 7]
    h = np.asarray(dt, float) / n_sub
    dv = 1e-5
    for _ in range(n_sub):
        x_s, v_s = spool_step(x_s, v_s, i + i_b, h, rp)
        a0 = jack_accel(x_s, v_j, f_r, p_sr, c_lk, rp)
        a1 = jack_accel(x_s, v_j + dv, f_r, p_sr, c_lk, rp)
        jac = np.minimum((a1 - a0) / dv, 0.0)  # only the damping part is made implicit
        v_j = v_j + h * a0 / (1.0 - h * jac)
        x_j = x_j + h * v_j
    return np.stack([x_s, v_s, x_j, v_j, f_r, p_sr, c_lk, i_b], axis=-1)


def measure(x: NDArray, rp: ReducedParams) -> NDArray:
    """Measurement model (..., 5): x_S, x_J, P1, P2, P_SR.

    P1 = P_R + (P_SR + P12) / 2, P2 = P_R + (P_SR - P12) / 2 (P12 evaluated with C_Lk >= 0,
    P_SR >= P_vap): exact for a symmetric valve
    with incompressible chambers (the sum P1 + P2 = P_S + P_R holds for any flow and leakage
    when the four lands are matched, physics.md section 3).
    """
    p_sr = x[..., 5]
    p12 = p12_state(
        x[..., 0], x[..., 3], np.maximum(p_sr, rp.p_vap), np.maximum(x[..., 6], 0.0), rp
    )
    half = 0.5 * p_sr
    return np.stack(
        [x[..., 0], x[..., 2], rp.p_r + half + 0.5 * p12, rp.p_r + half - 0.5 * p12, p_sr],
        axis=-1,
    )


# -- compiled scalar version (numba), held to the numpy functions above by tests/test_ukf.py --
(
    K_G_PQ,
    K_X_SS,
    K_P_VAP,
    K_P_R,
    K_AREA,
    K_MASS,
    K_C_V,
    K_F_D,
    K_V_F,
    K_K_SV,
    K_X_SM,
    K_OMEGA_N,
    K_ZETA,
    K_K_P,
    K_I_MAX,
    K_H_MAX,
    K_LAW,
    K_P_SR_RATED,
    K_G_PQ_EXP,
    K_X_U,
    K_X_0,
    N_PRM,
) = range(22)


def param_vector(rp: ReducedParams) -> NDArray:
    """Float64 parameter vector of the compiled kernels (layout: the K_* constants)."""
    from models.compiled import MODEL_IDS

    a = np.empty(N_PRM)
    a[K_G_PQ], a[K_X_SS], a[K_P_VAP], a[K_P_R] = rp.g_pq, rp.x_ss, rp.p_vap, rp.p_r
    a[K_AREA], a[K_MASS], a[K_C_V], a[K_F_D], a[K_V_F] = rp.area, rp.mass, rp.c_v, rp.f_d, rp.v_f
    a[K_K_SV], a[K_X_SM], a[K_OMEGA_N], a[K_ZETA] = rp.k_sv, rp.x_sm, rp.omega_n, rp.zeta
    a[K_K_P], a[K_I_MAX], a[K_H_MAX] = rp.k_p, rp.i_max, rp.h_max
    a[K_LAW] = MODEL_IDS[rp.law]
    a[K_P_SR_RATED], a[K_G_PQ_EXP] = rp.p_sr_rated, rp.g_pq_exp
    a[K_X_U], a[K_X_0] = rp.x_u, rp.x_0
    return a


# Speed (these run 2 x 17 times per UKF step): error_model="numpy" (no zero-division checks;
# no divisor here can be 0), helpers inlined and fed scalars (an array passed to a call that
# is not inlined is reference-counted with atomic operations, which cost more than the
# physics), and the square-root supply law of G_PQ through math.sqrt (correctly rounded;
# pow(r, 0.5) is within an ulp of it).
_NB = {"cache": True, "error_model": "numpy"}


@njit(**_NB, inline="always")
def _g_pq_nb(p_sr, prm):
    g, e = prm[K_G_PQ], prm[K_G_PQ_EXP]
    if e != 0.0:
        r = max(p_sr, prm[K_P_VAP]) / prm[K_P_SR_RATED]
        g = g * (math.sqrt(r) if e == 0.5 else r**e)
    return g


@njit(**_NB, inline="always")
def _x_eq_nb(x_s, x_u):
    """Scalar ``x_eq``."""
    if x_u <= 0.0 or abs(x_s) <= x_u:
        return x_s
    return math.copysign(0.5 * (abs(x_s) + x_u), x_s)


@njit(**_NB, inline="always")
def _friction_nb(v_j, f_d, v_f):
    """Coulomb friction F_d tanh(v_J / v_f)."""
    return f_d * math.tanh(v_j / v_f)


@njit(**_NB, inline="always")
def _accel_nb(x_s, v_j, f_r, p_sr, c_lk, g_pq, law, area, x_ss, p_vap, c_v, mass, fric):
    """dv_J/dt with the friction term ``fric`` = _friction_nb(v_j, ...); x_s is the
    equivalent opening (``_x_eq_nb``)."""
    p12 = law_p12(law, x_s, area * v_j, p_sr, g_pq, x_ss, c_lk, p_vap)
    f = area * p12 - f_r - c_v * v_j - fric
    return f / mass


@njit(**_NB, inline="always")
def _spool_nb(x_s, v_s, x_ref, x_sm, coef):
    """One exact spool substep (transition ``coef``), then the stroke limit: (x_s, v_s)."""
    dx = x_s - x_ref
    xn = x_ref + coef[0] * dx + coef[1] * v_s
    v_s = coef[2] * dx + coef[3] * v_s
    return min(max(xn, -x_sm), x_sm), v_s


@njit(**_NB, inline="always")
def _jack_nb(v_j, a0, a1, h, dv):
    """Linearly-implicit velocity substep from a0 = a(v_j), a1 = a(v_j + dv)."""
    jac = min((a1 - a0) / dv, 0.0)  # only the damping part is made implicit
    return v_j + h * a0 / (1.0 - h * jac)


@njit(**_NB, inline="always")
def spool_coef_nb(h, prm, coef):
    """Zero-order-hold transition of the spool over a substep h: coef = (a11, a12, a21, a22)."""
    w, z = prm[K_OMEGA_N], prm[K_ZETA]
    sig = z * w
    wd = w * math.sqrt(1.0 - z * z)
    e = math.exp(-sig * h)
    c, s = math.cos(wd * h), math.sin(wd * h)
    coef[0] = e * (c + sig / wd * s)
    coef[1] = e * s / wd
    coef[2] = -e * (w * w) / wd * s
    coef[3] = e * (c - sig / wd * s)


_DV = 1e-5  # velocity increment of the finite-difference Jacobian [m/s]


@njit(**_NB)  # called, not inlined: one compile for the filter and the parallel model
def step_core_nb(x, i, h, n_sub, prm, coef, out):
    """``step_nb`` with the spool transition ``coef`` of the substep h precomputed."""
    x_s, v_s, x_j, v_j = x[0], x[1], x[2], x[3]
    f_r = x[4]
    p_sr = max(x[5], prm[K_P_VAP])
    c_lk = max(x[6], 0.0)
    g_pq = _g_pq_nb(p_sr, prm)
    x_sm = prm[K_X_SM]
    x_ref = min(max(prm[K_K_SV] * (i + x[7]), -x_sm), x_sm)
    dv = _DV
    law, area, x_ss, p_vap = int(prm[K_LAW]), prm[K_AREA], prm[K_X_SS], prm[K_P_VAP]
    c_v, f_d, v_f, mass = prm[K_C_V], prm[K_F_D], prm[K_V_F], prm[K_MASS]
    x_u, x_0 = prm[K_X_U], prm[K_X_0]
    for _ in range(n_sub):
        x_s, v_s = _spool_nb(x_s, v_s, x_ref, x_sm, coef)
        v1 = v_j + dv
        fr0, fr1 = _friction_nb(v_j, f_d, v_f), _friction_nb(v1, f_d, v_f)
        x_e = _x_eq_nb(x_s - x_0, x_u)
        a0 = _accel_nb(x_e, v_j, f_r, p_sr, c_lk, g_pq, law, area, x_ss, p_vap, c_v, mass, fr0)
        a1 = _accel_nb(x_e, v1, f_r, p_sr, c_lk, g_pq, law, area, x_ss, p_vap, c_v, mass, fr1)
        v_j = _jack_nb(v_j, a0, a1, h, dv)
        x_j = x_j + h * v_j
    out[0], out[1], out[2], out[3] = x_s, v_s, x_j, v_j
    out[4], out[5], out[6], out[7] = x[4], x[5], x[6], x[7]


@njit(**_NB)
def step_points_nb(X, i, h, n_sub, prm, coef, out, w):
    """``step_core_nb`` for every row of X (K, 8) into out (K, 8), bitwise the same row by
    row, for the K sigma points of a filter step. One point's step is a chain of divisions
    and tanh calls (latency-bound); here each substep runs in stages over all the points
    (spool, friction, accelerations), whose short independent iterations overlap. The
    friction tanh is evaluated once per distinct velocity: the sigma points of columns
    4..7 of the (lower) Cholesky factor keep the centre's v_J. w: scratch (K, 6)."""
    K = X.shape[0]
    x_sm, p_vap, k_sv = prm[K_X_SM], prm[K_P_VAP], prm[K_K_SV]
    dv = _DV
    law, area, x_ss = int(prm[K_LAW]), prm[K_AREA], prm[K_X_SS]
    c_v, f_d, v_f, mass = prm[K_C_V], prm[K_F_D], prm[K_V_F], prm[K_MASS]
    x_u, x_0 = prm[K_X_U], prm[K_X_0]
    for k in range(K):
        for r in range(8):
            out[k, r] = X[k, r]
        p_sr = max(X[k, 5], p_vap)
        w[k, 0] = p_sr
        w[k, 1] = max(X[k, 6], 0.0)
        w[k, 2] = _g_pq_nb(p_sr, prm)
        w[k, 3] = min(max(k_sv * (i + X[k, 7]), -x_sm), x_sm)
    for _ in range(n_sub):
        for k in range(K):
            out[k, 0], out[k, 1] = _spool_nb(out[k, 0], out[k, 1], w[k, 3], x_sm, coef)
        v0 = out[0, 3]
        for k in range(K):
            v_j = out[k, 3]
            if k > 0 and v_j == v0 and math.copysign(1.0, v_j) == math.copysign(1.0, v0):
                w[k, 4], w[k, 5] = w[0, 4], w[0, 5]
            else:
                w[k, 4] = _friction_nb(v_j, f_d, v_f)
                w[k, 5] = _friction_nb(v_j + dv, f_d, v_f)
        for k in range(K):
            x_s, v_j, f_r = _x_eq_nb(out[k, 0] - x_0, x_u), out[k, 3], out[k, 4]
            p_sr, c_lk, g_pq = w[k, 0], w[k, 1], w[k, 2]
            a0 = _accel_nb(
                x_s, v_j, f_r, p_sr, c_lk, g_pq, law, area, x_ss, p_vap, c_v, mass, w[k, 4]
            )
            a1 = _accel_nb(
                x_s, v_j + dv, f_r, p_sr, c_lk, g_pq, law, area, x_ss, p_vap, c_v, mass, w[k, 5]
            )
            v_j = _jack_nb(v_j, a0, a1, h, dv)
            out[k, 3] = v_j
            out[k, 2] = out[k, 2] + h * v_j


@njit(**_NB)
def step_nb(x, i, dt, n_sub, prm, out):
    """Scalar ``step`` (same algebra): x (8,) -> out (8,); parameters clipped for evaluation
    (C_Lk >= 0, P_SR >= P_vap) but copied through unchanged."""
    coef = np.empty(4)
    h = dt / n_sub
    spool_coef_nb(h, prm, coef)
    step_core_nb(x, i, h, n_sub, prm, coef, out)


@njit(**_NB, inline="always")
def measure_nb(x, prm, out):
    """Scalar ``measure``: x (8,) -> out (5,) = x_S, x_J, P1, P2, P_SR."""
    p_sr = x[5]
    p_ev = max(p_sr, prm[K_P_VAP])
    p12 = law_p12(
        int(prm[K_LAW]),
        _x_eq_nb(x[0] - prm[K_X_0], prm[K_X_U]),
        prm[K_AREA] * x[3],
        p_ev,
        _g_pq_nb(p_ev, prm),
        prm[K_X_SS],
        max(x[6], 0.0),
        prm[K_P_VAP],
    )
    out[0] = x[0]
    out[1] = x[2]
    out[2] = prm[K_P_R] + 0.5 * p_sr + 0.5 * p12
    out[3] = prm[K_P_R] + 0.5 * p_sr - 0.5 * p12
    out[4] = p_sr
