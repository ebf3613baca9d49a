"""The monitor's compiled kernels (numba): the per-sample filter step and output row, and the
loops of the per-round path (``bank_step``, ``output_rows``) and of the block path
(``prepare_inputs``, ``block_steps``, ``block_rows``) that ``MonitorBank`` calls.

Array layouts are named by the constants below (module globals are compile-time constants in
numba, so a name costs nothing): filter state columns ``S_*`` (``models.eha_reduced``
state order), measurement channels ``Z_*``, input columns ``IN_*``, the bank's constant
vector ``C_*`` (built by name from ``CST_FIELDS``), counter columns ``CNT_*`` and step codes
``STEP_*``; the output columns ``EST_*``, ``RES_*``, ``HEALTH_*`` come from
``service.monitor.outputs``. Every array argument goes through ``borrowed_all``
(``service.compat.numba``): no atomic reference counting in the loops.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from models import eha_reduced as er
from models import eha_reduced_wh as erw
from models.eha_reduced import measure_nb, spool_coef_nb, step_core_nb
from models.eha_reduced_wh import measure_nb as measure_wh_nb
from models.eha_reduced_wh import step_core_nb as step_core_wh_nb
from service.compat.numba import borrowed_all
from service.monitor.outputs import (
    ALARM_LEAK,
    EST_C_LK_INCREASE,
    EST_C_LK_SIGMA,
    EST_P12,
    EST_P_SR_SIGMA,
    EST_STATE,
    FIRE_CLEARED,
    FIRE_RAISED,
    HEALTH_ALARM,
    HEALTH_LEAK_RATIO,
    HEALTH_NIS_AVG,
    HEALTH_SUPPLY_RATIO,
    N_ALARMS,
    RES_INNOV,
    RES_NIS,
    RES_NIS_DOF,
    RES_OL,
)
from service.monitor.ukf import ukf_one, ukf_one_wh

# filter state columns (X, P, OL rows)
S_X_S, S_V_S, S_X_J, S_V_J, S_F_R, S_P_SR, S_C_LK, S_I_B = (
    er.IX[n] for n in ("x_s", "v_s", "x_j", "v_j", "f_r", "p_sr", "c_lk", "i_b")
)
N_STATES = er.N_STATES  # C-type filter state; also the state columns of the output rows
N_STATES_WH = erw.N_STATES  # WH filter state: the C-type's, then the chamber states p~1, p~2
# measurement channels (z, mask, y columns)
Z_X_S, Z_X_J, Z_P1, Z_P2, Z_P_SR = (
    er.MEAS_NAMES.index(n) for n in ("x_s", "x_j", "p1", "p2", "p_sr")
)
N_CHANNELS = len(er.MEAS_NAMES)
# input columns of prepare_inputs: t, the channels, the current i and the command x_cmd
INPUT_COLUMNS: tuple[str, ...] = ("t", *er.MEAS_NAMES, "i", "x_cmd")
IN_T = INPUT_COLUMNS.index("t")
IN_Z = INPUT_COLUMNS.index(er.MEAS_NAMES[0])  # channel r at IN_Z + r
IN_I = INPUT_COLUMNS.index("i")
IN_X_CMD = INPUT_COLUMNS.index("x_cmd")

# the bank's constant vector (MonitorBank builds it by these names)
CST_FIELDS: tuple[str, ...] = (
    "h_max",  # longest model sub-step [s]
    "c_lk_max",  # C_Lk upper clip (filter units)
    "p_vap",  # P_SR lower clip (filter units)
    "p_sr_max",  # P_SR upper clip = rated (filter units)
    "nis_tau",  # NIS average time constant [s]
    "nis_reinit",  # re-initialise above this NIS/dof average
    "c_lk0",  # baseline C_Lk [m^3/s/Pa]
    "p_rated",  # rated P_SR [Pa]
    "arm",  # alarms armed this long after a (re-)init [s]
    "leak_raise",
    "leak_clear",
    "supply_raise",
    "supply_clear",
    "hold",  # alarm persistence [s]
    "leak_max_sigma",
    "supply_max_sigma",
    "gate_v",  # C_Lk learnt only below this |v_J| (filter units) ...
    "gate_x_s",  # ... with the spool within its underlap (filter units) ...
    "gate_nis",  # ... and the NIS/dof average below this
    "gate_p12",  # ... and while the measured |P1 - P2| is above this [Pa] ...
    "gate_p12_tau",  # ... low-passed over the samples before, with this time constant [s]
    "adapt_nis",  # a sample whose NIS/dof exceeds this is redone with inflated plant noise
    "adapt_max",  # ... scaled by NIS/dof / adapt_nis, at most this (adaptive process noise)
    "adapt_reinit",  # with adaptation on, one sample above this NIS/dof re-initialises
    "adapt_p_sr",  # the adaptive step scales P_SR's walk by g^adapt_p_sr (0: held)
    "gate_adapt",  # C_Lk held on a sample whose adaptive scale exceeds this (0: off)
    "gate_i_b_x_s",  # i_b held while |x_S| exceeds this (filter units; inf: never)
    "mask_tau",  # time constant of the lagged supply ratio [s]
    "mask_supply",  # supply transient: |P_SR/rated - its lagged value| above this ...
    "mask_s",  # ... freezes the leak alarm, and for this long after [s] (0: off)
    "cusum_nu",  # C_Lk change detector: drift of the CUSUM of standardised C_Lk updates
    "cusum_h",  # ... its threshold (0: off)
    "cusum_kick",  # ... the C_Lk variance added on a detection (filter units^2)
    "gate_var_max",  # while held, C_Lk's variance grows up to this (filter units^2; 0: no cap)
    "gate_v_flow",  # C_Lk held while |v_J| exceeds this times the gate's |P12| (filter units/Pa)
    "gate_flow_s",  # ... within this long after |v_J| last exceeded gate_flow_v_fast [s] (0: always)
    "gate_flow_v_fast",  # ... (filter units)
    "leak_z",  # leak alarm raised only while C_Lk / baseline - leak_z sigma >= leak_clear (0: off)
    "pool_h",  # the pooled C_Lk's own change test: threshold of its Page CUSUM (0: off)
    "pool_tol",  # ... its design shift: pool_tol x max(|pooled - baseline|, pool_d_min)
    "pool_d_min",  # ... (filter units)
)
(
    C_H_MAX,
    C_C_LK_MAX,
    C_P_VAP,
    C_P_SR_MAX,
    C_NIS_TAU,
    C_NIS_REINIT,
    C_C_LK0,
    C_P_RATED,
    C_ARM,
    C_LEAK_RAISE,
    C_LEAK_CLEAR,
    C_SUP_RAISE,
    C_SUP_CLEAR,
    C_HOLD,
    C_LEAK_SIG,
    C_SUP_SIG,
    C_GATE_V,
    C_GATE_XS,
    C_GATE_NIS,
    C_GATE_P12,
    C_GATE_P12_TAU,
    C_ADAPT_NIS,
    C_ADAPT_MAX,
    C_ADAPT_REINIT,
    C_ADAPT_P_SR,
    C_GATE_ADAPT,
    C_GATE_I_B_XS,
    C_MASK_TAU,
    C_MASK_SUPPLY,
    C_MASK_S,
    C_CUSUM_NU,
    C_CUSUM_H,
    C_CUSUM_KICK,
    C_GATE_VAR_MAX,
    C_GATE_V_FLOW,
    C_GATE_FLOW_S,
    C_GATE_FLOW_V_FAST,
    C_LEAK_Z,
    C_POOL_H,
    C_POOL_TOL,
    C_POOL_D_MIN,
) = range(len(CST_FIELDS))

# the bank's carry array (n_act, N_CARRY): the last current [A] (held when a sample has
# neither current nor command), the C_Lk change detector's CUSUMs (+, -) and its number of
# detections since the actuator was added, the low-passed measured P1 - P2 [Pa] of the
# C_Lk gate, and when the estimated |v_J| last exceeded gate_flow_v_fast [s]; then the pooled
# C_Lk (docs/estimation.md, "The pooled C_Lk"; filter units): its information and
# information-weighted sum since the last detected change, its own CUSUMs (+, -) and its
# number of detections
(CARRY_I, CARRY_GP, CARRY_GM, CARRY_N, CARRY_P12, CARRY_T_FAST, CARRY_PI, CARRY_PS,
 CARRY_HP, CARRY_HM, CARRY_PN) = range(11)  # fmt: skip
N_CARRY = 11
POOL_CARRY = slice(CARRY_PI, CARRY_PN)  # the pool's columns (restarted together)

# the bank's pending array (n_act, N_PENDING): per alarm, since when its change is due (NaN:
# none); then the supply tracker of the leak alarm's mask: the lagged supply ratio, the time
# the mask ends and the time of the lagged ratio (NaN: not started)
PEND_SR_LAG = N_ALARMS
PEND_MASK_END = N_ALARMS + 1
PEND_T_LAG = N_ALARMS + 2  # time of the lagged ratio [s]
N_PENDING = N_ALARMS + 3

# counter columns: prepare_inputs' cnt (n_act, 2) and block_steps' cnt (n_act, 3)
PREP_COUNTERS: tuple[str, ...] = ("bad_channel", "skipped_nan")
CNT_BAD_CHANNEL, CNT_SKIPPED_NAN = range(len(PREP_COUNTERS))
STEP_COUNTERS: tuple[str, ...] = ("skipped_time", "missing_channel", "accepted")
CNT_SKIPPED_TIME, CNT_MISSING_CHANNEL, CNT_ACCEPTED = range(len(STEP_COUNTERS))


# -- the kernels' arguments, grouped (the bank builds them; kernels read fields by name) ----
class BankState(NamedTuple):
    """The bank's per-actuator state, one row per actuator (``MonitorBank``)."""

    X: NDArray  # scaled filter state (n_act, n)
    PP: NDArray  # its covariance (n_act, n, n)
    OL: NDArray  # SI state of the parallel (open-loop) model (n_act, n)
    T_LAST: NDArray  # time of the last accepted sample [s]
    CARRY: NDArray  # (n_act, N_CARRY): CARRY_* columns
    NIS_AVG: NDArray  # NIS/dof average
    T_INIT: NDArray  # time of the last (re-)initialisation [s]
    ALARM: NDArray  # alarm states (n_act, N_ALARMS)
    PENDING: NDArray  # (n_act, N_PENDING): PEND_* columns


class ModelRows(NamedTuple):
    """Per-actuator rows of the process model on its baseline (one factory per process
    model builds them: ``service.monitor.model_rows``)."""

    q: NDArray  # process noise intensities, filter units (n_act, n)
    R: NDArray  # measurement noise covariance, filter units (n_act, m, m)
    scale: NDArray  # state scales (n_act, n): x_filter = x_SI / scale
    zscale: NDArray  # channel scales (n_act, m)
    prm: NDArray  # the model's parameter vector (n_act, n_prm)
    cst: NDArray  # the bank's constants (n_act, len(CST_FIELDS)): C_* columns


class Sigma(NamedTuple):
    """Unscented-transform weights (``service.monitor.ukf.merwe_weights``) and the spread c."""

    Wm: NDArray
    Wc: NDArray
    c: float


class Samples(NamedTuple):
    """A block of samples (``prepare_inputs``): actuator rows, times [s], scaled channels with
    their mask, candidates (a usable time and value), measured current [A] and command [m]
    (NaN: absent)."""

    ks: NDArray
    t: NDArray
    z: NDArray
    mask: NDArray
    cand: NDArray
    i_m: NDArray
    x_c: NDArray


class Stepped(NamedTuple):
    """Per sample of a block: innovations, NIS, NIS average, whether it has an output row,
    the snapshot its row is made of (X, diagonal of P, OL, T_INIT, NIS_AVG) and, per
    actuator, the STEP_COUNTERS."""

    y: NDArray
    nis: NDArray
    nis_avg: NDArray
    acc: NDArray
    SX: NDArray
    SPD: NDArray
    SOL: NDArray
    STI: NDArray
    SNA: NDArray
    SPL: NDArray  # the pool's information and sum (n, 2)
    cnt: NDArray


class Rows(NamedTuple):
    """Output rows: est, res, health (``service.monitor.outputs``), fire (FIRE_*) and pool (the
    pooled C_Lk and its 1-sigma [m^3/s/Pa], ``BankRows.pooled``)."""

    est: NDArray
    res: NDArray
    health: NDArray
    fire: NDArray
    pool: NDArray


UKF_FAILED = 2  # status of service.monitor.ukf.ukf_one: no positive definite factor
# codes of step_one / block_steps
STEP_OK = 0  # stepped
STEP_BROKEN = 1  # non-finite or not positive definite: re-initialise
STEP_DIVERGED = 2  # NIS average above nis_reinit, or (adaptive) one sample above adapt_reinit:
# re-initialise, keep the parameters
STEP_INIT = 3  # first sample or gap: (re-)initialise from this sample, not stepped


@njit(cache=True, inline="always")
def _ukf(x, P, z, mask, i_f, dt, n_sub, q, R, sc, zs, w, prm, y, ws, n, again):
    """One UKF step on the bank's process model: WH (n = 10) or a C-type law (n = 8);
    ``again``: the last step redone with process noise q (``service.monitor.ukf.ukf_one``)."""
    Wm, Wc, c = w.Wm, w.Wc, w.c
    redo = bool(again)  # a run-time flag, not a literal: one compiled step for both uses
    if n == N_STATES_WH:  # the WH process model (models.eha_reduced_wh)
        return ukf_one_wh(x, P, z, mask, i_f, dt, n_sub, q, R, sc, zs, Wm, Wc, c, prm, y, ws, redo)
    return ukf_one(x, P, z, mask, i_f, dt, n_sub, q, R, sc, zs, Wm, Wc, c, prm, y, ws, redo)


@njit(cache=True, inline="always")
def pool_add(cr, d_i, d_s, c_walk, c0, cst_k):
    """One learnt sample into the pooled C_Lk of carry row ``cr`` (docs/estimation.md, "The
    pooled C_Lk"): its information d_i = 1/P+ - 1/P- and d_s = m+/P+ - m-/P- (the walk
    filter's C_Lk update read as a measurement z = d_s / d_i of variance 1 / d_i), added to
    the pool's information I and sum S (pooled C_Lk = S / I, sigma 1 / sqrt(I)). First the
    pool's own change test: a two-sided adaptive Page CUSUM of the log-likelihood ratio of a
    shift delta, increment delta (d_s - (S / I) d_i) - delta^2 d_i / 2, where delta is the
    walk filter's prior ``c_walk`` (the recent information) less the pool, at least
    pool_tol x max(|S / I - c0|, pool_d_min) each way. Past pool_h the pool starts again
    from this sample. Returns True on a detection."""
    h = cst_k[C_POOL_H]
    if h > 0.0 and cr[CARRY_PI] > 0.0:
        m = cr[CARRY_PS] / cr[CARRY_PI]
        d_lo = cst_k[C_POOL_TOL] * max(abs(m - c0), cst_k[C_POOL_D_MIN])
        d_p = max(c_walk - m, d_lo)
        d_m = max(m - c_walk, d_lo)
        e = d_s - m * d_i
        hp = max(0.0, cr[CARRY_HP] + d_p * e - 0.5 * d_p * d_p * d_i)
        hm = max(0.0, cr[CARRY_HM] - d_m * e - 0.5 * d_m * d_m * d_i)
        if hp > h or hm > h:
            cr[CARRY_PI] = d_i
            cr[CARRY_PS] = d_s
            cr[CARRY_HP] = cr[CARRY_HM] = 0.0
            cr[CARRY_PN] += 1.0
            return True
        cr[CARRY_HP] = hp
        cr[CARRY_HM] = hm
    cr[CARRY_PI] += d_i
    cr[CARRY_PS] += d_s
    return False


@njit(cache=True, inline="always")
def pool_restart(cr):
    """Empties the pooled C_Lk of carry row ``cr`` (a change the walk's detector read)."""
    for r in range(CARRY_PI, CARRY_PN):
        cr[r] = 0.0


@njit(cache=True)  # called, not inlined: one compile for its two callers
def step_one(j, k, sm, bs, mr, w, ws, y, nis, nis_avg, coef, tmp):
    """Sample j of actuator k (in place on the bank state ``bs``): inputs (measured current,
    else the ECU law on x_cmd), UKF step, parallel model, constraints, NIS average. Returns
    STEP_OK, STEP_BROKEN (non-finite / not positive definite) or STEP_DIVERGED (NIS average).
    sm: the ``Samples``; mr: the ``ModelRows``, row k; w: the ``Sigma`` weights."""
    t, z, mask, i_m, x_c = sm.t, sm.z, sm.mask, sm.i_m, sm.x_c
    X, PP, OL, T_LAST, CARRY, NIS_AVG = bs.X, bs.PP, bs.OL, bs.T_LAST, bs.CARRY, bs.NIS_AVG
    q_k, R_k, sc_k, zs_k = mr.q[k], mr.R[k], mr.scale[k], mr.zscale[k]
    prm_k, cst_k = mr.prm[k], mr.cst[k]
    n = X.shape[1]
    k_p, i_max = prm_k[er.K_K_P], prm_k[er.K_I_MAX]
    dt = t[j] - T_LAST[k]
    n_sub = max(1, int(math.ceil(dt / cst_k[C_H_MAX] - 1e-9)))
    if not math.isnan(i_m[j]):
        i_f = i_m[j]
    elif not math.isnan(x_c[j]):
        i_f = min(max(k_p * (x_c[j] - X[k, S_X_J] * sc_k[S_X_J]), -i_max), i_max)
    else:
        i_f = CARRY[k, CARRY_I]
    i_ol = i_f if math.isnan(x_c[j]) else min(max(k_p * (x_c[j] - OL[k, S_X_J]), -i_max), i_max)
    CARRY[k, CARRY_I] = i_f
    # observability gate: C_Lk only from the valve's linear region at low speed
    gate = abs(X[k, S_V_J]) > cst_k[C_GATE_V] or abs(X[k, S_X_S]) > cst_k[C_GATE_XS]
    if cst_k[C_GATE_FLOW_S] > 0.0 and abs(X[k, S_V_J]) > cst_k[C_GATE_FLOW_V_FAST]:
        CARRY[k, CARRY_T_FAST] = t[j]  # only c_lk_gate_flow_s reads it
    gate = gate or NIS_AVG[k] > cst_k[C_GATE_NIS]
    # ... and with a pressure difference that carries a leak flow (C_Lk P12) above the flow
    # error of the valve's null (docs/estimation.md, observability gate), judged on a low-pass
    # of the measured P1 - P2 over the samples before this one: a gate on the sample's own
    # noisy value opens on the samples whose noise raises |P12|, and near the threshold that
    # selection biases C_Lk
    if cst_k[C_GATE_P12] > 0.0:
        both_p = mask[j, Z_P1] and mask[j, Z_P2]
        p12_m = z[j, Z_P1] * zs_k[Z_P1] - z[j, Z_P2] * zs_k[Z_P2] if both_p else math.nan
        tau = cst_k[C_GATE_P12_TAU]
        p12_g = CARRY[k, CARRY_P12] if tau > 0.0 else p12_m
        if not both_p:
            gate = True  # no measured P12 in this sample: it carries no leak information
        elif not math.isnan(p12_g):
            gate = gate or abs(p12_g) < cst_k[C_GATE_P12]
            # ... and, if set (off by default), with the jack's flow A |v_J| under a few
            # times the baseline leak flow C_Lk |P12| (within gate_flow_s of the last fast
            # motion, if that is set): a relative error of the modelled jack flow reads as
            # a leak of that many times the error (docs/estimation.md,
            # "A speed gate relative to the leak flow")
            if cst_k[C_GATE_V_FLOW] > 0.0:
                recent = t[j] - CARRY[k, CARRY_T_FAST] < cst_k[C_GATE_FLOW_S]
                if cst_k[C_GATE_FLOW_S] <= 0.0 or recent:
                    gate = gate or abs(X[k, S_V_J]) > cst_k[C_GATE_V_FLOW] * abs(p12_g)
        if both_p and tau > 0.0:
            CARRY[k, CARRY_P12] += (1.0 - math.exp(-dt / tau)) * (p12_m - CARRY[k, CARRY_P12])
    c_prior, p_prior = X[k, S_C_LK], PP[k, S_C_LK, S_C_LK]
    # the null bias i_b is learnt near null only: the spool model (a linear lag, no flow
    # forces, no stroke limit) does not follow a spool opened past its underlap
    hold_ib = abs(X[k, S_X_S]) > cst_k[C_GATE_I_B_XS]
    b_prior, pb_prior = X[k, S_I_B], PP[k, S_I_B, S_I_B]
    dof = 0.0
    for r in range(mask.shape[1]):
        if mask[j, r]:
            dof += 1.0
    # adaptive process noise (docs/estimation.md, "Adaptive process noise"): if this
    # sample's NIS/dof passes adapt_nis, redo the step from its prediction (kept in ws) with
    # the plant states' process noise (not the parameters') scaled by NIS/dof / adapt_nis
    thr = cst_k[C_ADAPT_NIS]
    q_sv = tmp[n : 2 * n]
    nis_j, st = _ukf(X[k], PP[k], z[j], mask[j], i_f, dt, n_sub, q_k, R_k, sc_k, zs_k, w,
                     prm_k, y[j], ws, n, False)  # fmt: skip
    capped = False
    g = 1.0
    if thr > 0.0 and dof > 0.0 and nis_j > thr * dof:
        # a sample no plant transient explains (a dead or swapped sensor): diverged
        capped = nis_j > cst_k[C_ADAPT_REINIT] * dof
        g = min(nis_j / (thr * dof), cst_k[C_ADAPT_MAX])
    if cst_k[C_GATE_ADAPT] > 0.0 and g > cst_k[C_GATE_ADAPT]:
        gate = True  # a transient the model does not explain: no leak information
    if g > 1.0:
        g_p = min(g ** cst_k[C_ADAPT_P_SR], cst_k[C_ADAPT_MAX])  # P_SR's scale (exponent 0: held)
        for r in range(n):
            if r == S_P_SR:
                q_sv[r] = q_k[r] * g_p
            else:
                q_sv[r] = q_k[r] * (1.0 if S_P_SR <= r <= S_I_B else g)
        nis_j, st = _ukf(X[k], PP[k], z[j], mask[j], i_f, dt, n_sub, q_sv, R_k, sc_k, zs_k,
                         w, prm_k, y[j], ws, n, True)  # fmt: skip
    if gate:  # Schmidt (consider) update of C_Lk: prior mean and variance, cross terms kept
        X[k, S_C_LK] = c_prior
        v_held = p_prior + q_k[S_C_LK] * dt
        if cst_k[C_GATE_VAR_MAX] > 0.0:
            v_held = max(p_prior, min(v_held, cst_k[C_GATE_VAR_MAX]))
        PP[k, S_C_LK, S_C_LK] = v_held
    else:
        # the pooled C_Lk keeps what this update learnt (pool_add)
        p_minus = p_prior + q_k[S_C_LK] * dt
        p_plus = PP[k, S_C_LK, S_C_LK]
        if 0.0 < p_plus < p_minus:
            pool_add(CARRY[k], 1.0 / p_plus - 1.0 / p_minus,
                     X[k, S_C_LK] / p_plus - c_prior / p_minus, c_prior,
                     cst_k[C_C_LK0] / sc_k[S_C_LK], cst_k)  # fmt: skip
        if cst_k[C_CUSUM_H] > 0.0:
            # C_Lk change detector (docs/estimation.md, "C_Lk change detector (WH)"): the
            # update standardised by its model variance (prior - posterior) is N(0, 1) and
            # white while C_Lk holds still; a two-sided CUSUM of it past cusum_h reads a
            # change, the variance added lets the filter follow it at once, and the pooled
            # C_Lk starts again
            v_upd = p_minus - p_plus
            if v_upd > 0.0:
                u = (X[k, S_C_LK] - c_prior) / math.sqrt(v_upd)
                gp = max(0.0, CARRY[k, CARRY_GP] + u - cst_k[C_CUSUM_NU])
                gm = max(0.0, CARRY[k, CARRY_GM] - u - cst_k[C_CUSUM_NU])
                if gp > cst_k[C_CUSUM_H] or gm > cst_k[C_CUSUM_H]:
                    PP[k, S_C_LK, S_C_LK] += cst_k[C_CUSUM_KICK]
                    CARRY[k, CARRY_N] += 1.0
                    pool_restart(CARRY[k])
                    gp = gm = 0.0
                CARRY[k, CARRY_GP] = gp
                CARRY[k, CARRY_GM] = gm
    if hold_ib:  # the same for i_b
        X[k, S_I_B] = b_prior
        PP[k, S_I_B, S_I_B] = pb_prior + q_k[S_I_B] * dt
    nis[j] = nis_j
    # the parallel (open-loop) model, driven by the command, with the estimated load
    OL[k, S_F_R] = X[k, S_F_R] * sc_k[S_F_R]
    h = dt / n_sub
    spool_coef_nb(h, prm_k, coef)
    if n == N_STATES_WH:
        step_core_wh_nb(OL[k], i_ol, h, n_sub, prm_k, coef, tmp)
    else:
        step_core_nb(OL[k], i_ol, h, n_sub, prm_k, coef, tmp)
    for r in range(n):
        OL[k, r] = tmp[r]
    # constraints: C_Lk >= 0, P_vap <= P_SR <= rated
    X[k, S_C_LK] = min(max(X[k, S_C_LK], 0.0), cst_k[C_C_LK_MAX])
    X[k, S_P_SR] = min(max(X[k, S_P_SR], cst_k[C_P_VAP]), cst_k[C_P_SR_MAX])
    a = 1.0 - math.exp(-dt / cst_k[C_NIS_TAU])
    avg = NIS_AVG[k] + a * (nis_j / max(dof, 1.0) - NIS_AVG[k])
    nis_avg[j] = avg
    ok = st != UKF_FAILED and math.isfinite(avg)
    for r in range(n):
        if not math.isfinite(X[k, r]):
            ok = False
        for s_ in range(n):
            if not math.isfinite(PP[k, r, s_]):
                ok = False
    T_LAST[k] = t[j]
    if ok:
        NIS_AVG[k] = avg
        return STEP_DIVERGED if avg > cst_k[C_NIS_REINIT] or capped else STEP_OK
    NIS_AVG[k] = 0.0
    return STEP_BROKEN


@njit(cache=True)  # called, not inlined: one compile for its two callers
def row_one(j, kk, k, X, PD, OL, T_INIT, NIS_AVG, pl_i, pl_s, mr, sm, y, nis, ALARM, PENDING, ro,
            xs, zo):  # fmt: skip
    """Flat output row j of actuator k (est: (state, sigma) pairs, P12, C_Lk increase; res:
    innovations, NIS, dof, open-loop residuals = measured minus parallel model; health: leak
    and supply ratios, alarm states, NIS average) and the alarms with hysteresis, persistence,
    the sigma gate and the leak alarm's supply-transient mask (fire: FIRE_RAISED or
    FIRE_CLEARED this sample, else 0). The filter state is row kk of X, PD (the diagonal of
    P), OL, T_INIT and NIS_AVG: the bank's row k, or the snapshot of sample j taken by
    ``block_steps``; the alarm state (ALARM, PENDING) is the bank's row k. scale, zscale,
    prm, cst (``ModelRows`` mr) hold one row per actuator (its baseline): row k; sm: the
    ``Samples``; ro: the ``Rows`` written."""
    sc_k, zs_k, prm_k, cst_k = mr.scale[k], mr.zscale[k], mr.prm[k], mr.cst[k]
    z, mask, t = sm.z, sm.mask, sm.t
    est, res, health, fire = ro.est, ro.res, ro.health, ro.fire
    n = X.shape[1]
    m = z.shape[1]
    c_lk0, p_rated = cst_k[C_C_LK0], cst_k[C_P_RATED]
    wh = n == N_STATES_WH
    for r in range(N_STATES):
        xs[r] = X[kk, r] * sc_k[r]
        est[j, EST_STATE + 2 * r] = xs[r]
        est[j, EST_STATE + 2 * r + 1] = math.sqrt(max(PD[kk, r], 0.0)) * sc_k[r]
    if wh:  # WH chamber states: not output columns, P1 and P2 come through the measurement
        for r in range(N_STATES, n):
            xs[r] = X[kk, r] * sc_k[r]
        measure_wh_nb(xs, prm_k, zo)
    else:
        measure_nb(xs, prm_k, zo)
    est[j, EST_P12] = zo[Z_P1] - zo[Z_P2]
    est[j, EST_C_LK_INCREASE] = xs[S_C_LK] - c_lk0
    # the pooled C_Lk (pool_add; pl_i, pl_s its information and sum): without pooled
    # information, the filter's own estimate
    if pl_i > 0.0:
        ro.pool[j, 0] = max(pl_s / pl_i, 0.0) * sc_k[S_C_LK]
        ro.pool[j, 1] = sc_k[S_C_LK] / math.sqrt(pl_i)
    else:
        ro.pool[j, 0] = xs[S_C_LK]
        ro.pool[j, 1] = est[j, EST_C_LK_SIGMA]
    if wh:
        measure_wh_nb(OL[kk], prm_k, zo)
    else:
        measure_nb(OL[kk], prm_k, zo)
    dof = 0.0
    for r in range(m):
        res[j, RES_INNOV + r] = y[j, r] * zs_k[r]
        if mask[j, r]:
            dof += 1.0
            res[j, RES_OL + r] = z[j, r] * zs_k[r] - zo[r]
        else:
            res[j, RES_OL + r] = 0.0
    res[j, RES_NIS] = nis[j]
    res[j, RES_NIS_DOF] = dof
    lr = xs[S_C_LK] / c_lk0 if c_lk0 > 0 else 0.0
    sr = xs[S_P_SR] / p_rated
    sd_l = est[j, EST_C_LK_SIGMA] / c_lk0 if c_lk0 > 0 else 0.0
    sd_s = est[j, EST_P_SR_SIGMA] / p_rated
    armed = t[j] - T_INIT[kk] >= cst_k[C_ARM]
    # a supply transient confounds the leak estimate (C_Lk and P_SR both explain the chamber
    # pressures until P_SR has followed): the leak alarm keeps its state while the supply
    # ratio leaves its lagged value by more than mask_supply, and mask_s after
    # (docs/estimation.md, "Leak alarm during a supply transient")
    masked = False
    if cst_k[C_MASK_S] > 0.0:
        sr_lag, t_lag = PENDING[k, PEND_SR_LAG], PENDING[k, PEND_T_LAG]
        if math.isnan(sr_lag) or not t[j] > t_lag:
            sr_lag = sr
        elif abs(sr - sr_lag) > cst_k[C_MASK_SUPPLY]:
            PENDING[k, PEND_MASK_END] = t[j] + cst_k[C_MASK_S]
        if not math.isnan(t_lag) and t[j] > t_lag:
            sr_lag += (1.0 - math.exp(-(t[j] - t_lag) / cst_k[C_MASK_TAU])) * (sr - sr_lag)
        PENDING[k, PEND_SR_LAG] = sr_lag
        PENDING[k, PEND_T_LAG] = t[j]
        end = PENDING[k, PEND_MASK_END]
        masked = (not math.isnan(end)) and t[j] < end
    for a in range(N_ALARMS):
        on = ALARM[k, a]
        if a == ALARM_LEAK:
            # raised only where the posterior rules out a plant still at the clear level:
            # the estimate leak_z sigmas above it (docs/estimation.md, "Alarms")
            want = (
                lr <= cst_k[C_LEAK_CLEAR]
                if on
                else (
                    lr >= cst_k[C_LEAK_RAISE]
                    and sd_l < cst_k[C_LEAK_SIG]
                    and lr - cst_k[C_LEAK_Z] * sd_l >= cst_k[C_LEAK_CLEAR]
                )
            )
        else:
            want = (
                sr >= cst_k[C_SUP_CLEAR]
                if on
                else (sr <= cst_k[C_SUP_RAISE] and sd_s < cst_k[C_SUP_SIG])
            )
        fire[j, a] = 0
        if a == ALARM_LEAK and masked:
            PENDING[k, a] = math.nan  # frozen: the persistence starts again after the mask
        elif want and armed:
            if math.isnan(PENDING[k, a]):
                PENDING[k, a] = t[j]
            if t[j] - PENDING[k, a] >= cst_k[C_HOLD] - 1e-12:
                ALARM[k, a] = not on
                PENDING[k, a] = math.nan
                fire[j, a] = FIRE_CLEARED if on else FIRE_RAISED
        else:
            PENDING[k, a] = math.nan
    health[j, HEALTH_LEAK_RATIO] = lr
    health[j, HEALTH_SUPPLY_RATIO] = sr
    for a in range(N_ALARMS):
        health[j, HEALTH_ALARM + a] = 1.0 if ALARM[k, a] else 0.0
    health[j, HEALTH_NIS_AVG] = NIS_AVG[kk]


@njit(cache=True)
def bank_step(sm, bs, mr, w, ws, y, nis, nis_avg, flag):
    """One sample for each actuator sm.ks[j] through ``step_one``; flag[j] its return code."""
    sm, bs, mr = borrowed_all(sm), borrowed_all(bs), borrowed_all(mr)
    wm, wc = borrowed_all((w.Wm, w.Wc))
    w = Sigma(wm, wc, w.c)
    ws = borrowed_all(ws)
    y, nis, nis_avg, flag = borrowed_all((y, nis, nis_avg, flag))
    n = bs.X.shape[1]
    coef = np.empty(4)
    tmp = np.empty(n * (n + 3))  # model output, then step_one's scratch
    for j in range(sm.ks.shape[0]):
        flag[j] = step_one(j, sm.ks[j], sm, bs, mr, w, ws, y, nis, nis_avg, coef, tmp)


@njit(cache=True)
def output_rows(bs, PD, mr, sm, y, nis, ro):
    """The output row of each actuator sm.ks[j] through ``row_one`` (PD: diagonals of P)."""
    sm, bs, mr, ro = borrowed_all(sm), borrowed_all(bs), borrowed_all(mr), borrowed_all(ro)
    PD, y, nis = borrowed_all((PD, y, nis))
    xs = np.empty(bs.X.shape[1])
    zo = np.empty(sm.z.shape[1])
    for j in range(sm.ks.shape[0]):
        k = sm.ks[j]
        row_one(j, k, k, bs.X, PD, bs.OL, bs.T_INIT, bs.NIS_AVG, bs.CARRY[k, CARRY_PI],
                bs.CARRY[k, CARRY_PS], mr, sm, y, nis, bs.ALARM, bs.PENDING, ro, xs, zo)  # fmt: skip


@njit(cache=True, nogil=True)
def prepare_inputs(ks, vals, present, use, zscale, cnt):
    """``MonitorBank._inputs`` compiled (numpy's per-call cost on short blocks was a tenth of
    the filter step): vals (n, 8) as t, x_s, x_j, p1, p2, p_sr, i, x_cmd, present (n, 8) ->
    (t (0 where not usable), z (scaled, 0 where masked), mask, cand, i_m, x_c (NaN where not
    usable)); cnt[k] += bad_channel (present and not finite, in a sample with a usable time),
    skipped_nan (no usable value)."""
    n = ks.shape[0]
    m = zscale.shape[1]
    t_out = np.empty(n)
    z = np.empty((n, m))
    mask = np.empty((n, m), np.bool_)
    cand = np.empty(n, np.bool_)
    i_m = np.empty(n)
    x_c = np.empty(n)
    for j in range(n):
        t_ok = present[j, IN_T] and math.isfinite(vals[j, IN_T])
        n_bad = 0
        any_m = False
        for r in range(m):
            v = vals[j, IN_Z + r]
            fin = math.isfinite(v)
            ok = present[j, IN_Z + r] and fin and use[r]
            mask[j, r] = ok
            z[j, r] = v / zscale[ks[j], r] if ok else 0.0
            any_m = any_m or ok
            if present[j, IN_Z + r] and not fin and use[r]:
                n_bad += 1
        vi, vx = vals[j, IN_I], vals[j, IN_X_CMD]
        i_ok = present[j, IN_I] and math.isfinite(vi)
        x_ok = present[j, IN_X_CMD] and math.isfinite(vx)
        i_m[j] = vi if i_ok else math.nan
        x_c[j] = vx if x_ok else math.nan
        if present[j, IN_I] and not i_ok:
            n_bad += 1
        if present[j, IN_X_CMD] and not x_ok:
            n_bad += 1
        cand[j] = t_ok and (i_ok or x_ok or any_m)
        t_out[j] = vals[j, IN_T] if t_ok else 0.0
        if t_ok:
            cnt[ks[j], CNT_BAD_CHANNEL] += n_bad
        if not cand[j]:
            cnt[ks[j], CNT_SKIPPED_NAN] += 1
    return t_out, z, mask, cand, i_m, x_c


@njit(cache=True, nogil=True)  # other threads (receivers, loggers) run meanwhile
def block_steps(j0, emit0, sm, bs, mr, w, max_gap, expect, ws, so):
    """The samples j0.. of a block (``Samples`` sm) in order, each through the time checks and
    ``step_one`` on the bank state ``bs`` (the code of the per-round path, so the same bits);
    after its step, the state a sample's output row is made of (X, diagonal of P, OL, T_INIT,
    NIS_AVG of its actuator) is copied into row j of so.SX, SPD, SOL, STI, SNA (``Stepped``
    so) for ``block_rows``. Returns (j, code): code 0 when done; 3 when sample j needs a
    (re-)initialisation (first sample or gap; not stepped), 1/2 when its step
    broke/diverged. The caller re-initialises and resumes with (j, emit0=True), which takes
    sample j's snapshot without stepping it. so.acc[j]: sample j has an output row;
    so.cnt[k]: skipped_time, missing_channel, accepted (stepped samples only)."""
    # every array through borrowed_all (see service.monitor.ukf): numba would otherwise
    # reference-count the arrays with atomic operations at every sample
    sm, bs, mr, so = borrowed_all(sm), borrowed_all(bs), borrowed_all(mr), borrowed_all(so)
    wm, wc = borrowed_all((w.Wm, w.Wc))
    w = Sigma(wm, wc, w.c)
    ws = borrowed_all(ws)
    expect = borrowed_all((expect,))[0]
    ks, t, mask, cand = sm.ks, sm.t, sm.mask, sm.cand
    X, PP, OL, T_LAST = bs.X, bs.PP, bs.OL, bs.T_LAST
    cnt = so.cnt
    m = sm.z.shape[1]
    n = X.shape[1]
    coef = np.empty(4)
    tmp = np.empty(n * (n + 3))  # model output, then step_one's scratch
    for j in range(j0, ks.shape[0]):
        k = ks[j]
        if not (emit0 and j == j0):
            if not cand[j]:
                continue
            if t[j] <= T_LAST[k]:
                cnt[k, CNT_SKIPPED_TIME] += 1
                continue
            for r in range(m):
                if expect[r] and not mask[j, r]:
                    cnt[k, CNT_MISSING_CHANNEL] += 1
            if not math.isfinite(T_LAST[k]) or t[j] - T_LAST[k] > max_gap:
                return j, STEP_INIT
            cnt[k, CNT_ACCEPTED] += 1
            code = step_one(j, k, sm, bs, mr, w, ws, so.y, so.nis, so.nis_avg, coef, tmp)
            if code != STEP_OK:
                return j, code
        so.acc[j] = True
        for r in range(n):
            so.SX[j, r] = X[k, r]
            so.SPD[j, r] = PP[k, r, r]
            so.SOL[j, r] = OL[k, r]
        so.STI[j] = bs.T_INIT[k]
        so.SNA[j] = bs.NIS_AVG[k]
        so.SPL[j, 0] = bs.CARRY[k, CARRY_PI]
        so.SPL[j, 1] = bs.CARRY[k, CARRY_PS]
    return ks.shape[0], STEP_OK


@njit(cache=True, nogil=True)
def block_rows(sm, so, mr, ALARM, PENDING, ro):
    """The output rows of the samples with so.acc[j], in order, from their ``block_steps``
    snapshots (``Stepped`` so), through ``row_one`` (alarms: the bank's ALARM, PENDING)."""
    sm, so, mr, ro = borrowed_all(sm), borrowed_all(so), borrowed_all(mr), borrowed_all(ro)
    ALARM, PENDING = borrowed_all((ALARM, PENDING))
    xs = np.empty(so.SX.shape[1])
    zo = np.empty(sm.z.shape[1])
    for j in range(sm.ks.shape[0]):
        if so.acc[j]:
            row_one(j, j, sm.ks[j], so.SX, so.SPD, so.SOL, so.STI, so.SNA, so.SPL[j, 0],
                    so.SPL[j, 1], mr, sm, so.y, so.nis, ALARM, PENDING, ro, xs, zo)  # fmt: skip
