"""The vectors of the monitor's process model on one baseline, one factory per process model:
``c_type_vectors`` (``models.eha_reduced``, the C-type laws) and ``wh_vectors``
(``models.eha_reduced_wh``). ``MonitorBank`` keeps them as one row per actuator
(``service.monitor.kernels.ModelRows``), built once per distinct baseline.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from models import eha_reduced as er
from models import eha_reduced_wh as erw
from service.monitor.config import Baseline, MonitorConfig, check_baseline_model
from service.monitor.kernels import CST_FIELDS, S_C_LK, S_I_B, S_P_SR, S_V_J, S_X_S
from service.monitor.outputs import MEAS_CHANNELS

__all__ = ["ModelVectors", "c_type_vectors", "wh_vectors", "model_vectors", "by_name"]

# filter units (scale, zscale): the scaled states and channels are of order 1, so the
# covariance arithmetic keeps its precision; units of the arithmetic, not settings
_FILTER_UNITS = {"x_j": 1e-3, "v_j": 1e-2, "f_r": 1e3, "p": 1e6, "c_lk": 1e-13, "i_b": 1e-4}


class ModelVectors(NamedTuple):
    """A process model on one baseline: its state names, reduced parameters, the state and
    channel scales (x_filter = x_SI / scale), process noise intensities q and measurement
    covariance R (filter units), the model's parameter vector, the bank's constants
    (``CST_FIELDS``) and the initial 1-sigmas [SI]."""

    names: tuple[str, ...]
    rp: er.ReducedParams
    scale: NDArray
    zscale: NDArray
    q: NDArray
    R: NDArray
    prm: NDArray
    cst: NDArray
    p0: NDArray


def by_name(names: Sequence[str], **values: float) -> NDArray:
    """A float vector laid out as ``names`` from one keyword per name (all required)."""
    if set(values) != set(names):
        raise ValueError(f"expected exactly {names}, got {sorted(values)}")
    return np.array([values[n] for n in names], float)


def _underlaps(n: float, x_u: float) -> float:
    """Spool opening [m] of ``n`` underlaps x_u, past which a gate holds a parameter
    (n = 0 or no underlap: inf, never)."""
    return n * x_u if n > 0.0 and x_u > 0.0 else math.inf


def _vectors(c: MonitorConfig, b: Baseline, names, extra, prm, h_max) -> ModelVectors:
    """The vectors common to the models; ``extra``: the model's own states' scale, q, p0."""
    rp = b.reduced_params()
    u = _FILTER_UNITS
    scale = by_name(names, x_s=b.x_ss, v_s=b.x_ss * b.omega_n, x_j=u["x_j"], v_j=u["v_j"],
                    f_r=u["f_r"], p_sr=u["p"], c_lk=u["c_lk"], i_b=u["i_b"],
                    **extra["scale"])  # fmt: skip
    pn = c.process
    q = by_name(names, **{n: getattr(pn, n) for n in er.STATE_NAMES}, **extra["q"])
    if c.channels == "reduced":  # parameters not observable from x_J alone
        q[[S_P_SR, S_C_LK, S_I_B]] *= c.reduced_param_q
    nz = c.noise
    r = by_name(MEAS_CHANNELS, x_s=nz.x_s_m, x_j=nz.x_j_m, p1=nz.p_pa, p2=nz.p_pa,
                p_sr=nz.p_sr_pa)  # fmt: skip
    zscale = by_name(MEAS_CHANNELS, x_s=b.x_ss, x_j=u["x_j"], p1=u["p"], p2=u["p"], p_sr=u["p"])
    p0 = by_name(names, x_s=c.init_sigma_x_s, v_s=c.init_sigma_v_s, x_j=c.init_sigma_x_j,
                 v_j=c.init_sigma_v_j, f_r=c.init_sigma_f_r, p_sr=c.init_sigma_p_sr,
                 c_lk=c.init_sigma_c_lk, i_b=c.init_sigma_i_b, **extra["p0"])  # fmt: skip
    a = c.alarms
    cst = by_name(
        CST_FIELDS,
        h_max=h_max,
        c_lk_max=c.c_lk_max / scale[S_C_LK],
        p_vap=rp.p_vap / scale[S_P_SR],
        p_sr_max=c.p_sr_max_ratio * b.p_sr_rated / scale[S_P_SR],
        nis_tau=c.nis_tau_s,
        nis_reinit=c.nis_reinit,
        c_lk0=b.c_lk,
        p_rated=b.p_sr_rated,
        arm=c.arm_s,
        leak_raise=a.leak_raise,
        leak_clear=a.leak_clear,
        supply_raise=a.supply_raise,
        supply_clear=a.supply_clear,
        hold=a.hold_s,
        leak_max_sigma=a.leak_max_sigma,
        leak_z=a.leak_z,
        supply_max_sigma=a.supply_max_sigma,
        gate_v=c.c_lk_gate_v / scale[S_V_J],
        gate_x_s=_underlaps(c.c_lk_gate_x_u, rp.x_u) / scale[S_X_S],
        gate_nis=c.c_lk_gate_nis,
        gate_p12=c.c_lk_gate_p12 * b.p_sr_rated,
        gate_p12_tau=c.c_lk_gate_p12_tau_s,
        adapt_nis=c.adapt_nis,
        adapt_max=c.adapt_max,
        adapt_reinit=c.adapt_reinit,
        adapt_p_sr=c.adapt_p_sr,
        gate_adapt=c.c_lk_gate_adapt,
        gate_i_b_x_s=_underlaps(c.i_b_gate_x_u, rp.x_u) / scale[S_X_S],
        mask_tau=a.leak_mask_tau_s,
        mask_supply=a.leak_mask_supply,
        mask_s=a.leak_mask_s,
        cusum_nu=c.c_lk_cusum_nu,
        cusum_h=c.c_lk_cusum_h,
        cusum_kick=(c.c_lk_cusum_kick * b.c_lk / scale[S_C_LK]) ** 2,
        gate_var_max=(c.c_lk_gated_sigma_max * b.c_lk / scale[S_C_LK]) ** 2,
        gate_v_flow=c.c_lk_gate_flow * b.c_lk / b.area / scale[S_V_J],
        gate_flow_s=c.c_lk_gate_flow_s,
        gate_flow_v_fast=c.c_lk_gate_flow_v_fast / scale[S_V_J],
        pool_h=c.c_lk_pool_h,
        pool_tol=c.c_lk_pool_tol,
        pool_d_min=c.c_lk_pool_d_min * b.c_lk / scale[S_C_LK],
    )
    R = np.diag((r / zscale) ** 2)
    return ModelVectors(tuple(names), rp, scale, zscale, (q / scale) ** 2, R, prm, cst, p0)


def c_type_vectors(config: MonitorConfig, baseline: Baseline) -> ModelVectors:
    """A C-type law's vectors (``models.eha_reduced``: 8 states)."""
    rp = baseline.reduced_params()
    none: dict[str, dict] = {"scale": {}, "q": {}, "p0": {}}
    return _vectors(config, baseline, er.STATE_NAMES, none, er.param_vector(rp), rp.h_max)


def wh_vectors(config: MonitorConfig, baseline: Baseline) -> ModelVectors:
    """WH's vectors (``models.eha_reduced_wh``: the C-type states plus the chamber states
    p~1, p~2). The chamber columns of q hold the differential and the common mode's random
    walks, (p~1 - p~2)/sqrt 2 and (p~1 + p~2)/sqrt 2 (``service.monitor.ukf``)."""
    rp = baseline.reduced_params()
    pn, c, u = config.process, config, _FILTER_UNITS
    extra = {
        "scale": {"pt1": u["p"], "pt2": u["p"]},
        "q": {"pt1": pn.p_ch, "pt2": pn.p_ch_common},
        "p0": {"pt1": c.init_sigma_p_ch, "pt2": c.init_sigma_p_ch},
    }
    prm = erw.param_vector(rp, baseline.v_c, baseline.beta)
    return _vectors(config, baseline, erw.STATE_NAMES, extra, prm, min(rp.h_max, erw.H_MAX))


def model_vectors(config: MonitorConfig, baseline: Baseline) -> ModelVectors:
    """The factory of ``config.model`` on ``baseline`` (refused if identified for another
    model: ``BaselineModelError``)."""
    check_baseline_model(baseline, config.model)
    return (wh_vectors if config.model == "WH" else c_type_vectors)(config, baseline)
