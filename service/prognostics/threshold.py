"""Failure threshold of the internal leakage C_Lk, derived from the actuator itself.

At a hold under an external load F the jack does not move, so the leakage flow across the
piston ports, Q_Lk = C_Lk P12 with P12 = F / A, must be supplied by the servovalve through an
opening x_S. The proportional ECU only opens the valve from a position error: i = k_p e and
x_S = K_sv i (steady state of the torque motor and spool), so the static error is

    e_ss = x_S / (K_sv k_p),   where x_S solves  P12_HF(x_S, Q_J = 0, P_SR; C_Lk) = F / A

(the HF valve's static balance, ``models.hf_valve.hf_static_p12``). P12 at a fixed opening
falls as C_Lk rises, so e_ss grows with C_Lk. The unit has failed when it can no longer hold
its rated load within its static position tolerance e_tol:

    C_Lk,fail  solves  P12_HF(x_tol, 0, P_SR; C_Lk) = F_rated / A,   x_tol = K_sv k_p e_tol

(x_tol clipped at the spool stroke x_SM and at K_sv i_max). The rated load defaults to 2/3 of
the stall load A P_SR (the design point of maximum hydraulic power); the tolerance defaults to
1 mm (1 % of the 100 mm full stroke). docs/prognostics.md gives the numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.optimize import brentq

from models.hf_valve import hf_static_p12
from models.params import EHAParams

__all__ = ["LeakThreshold", "leak_threshold", "static_error", "DEFAULT_TOLERANCE_M"]

DEFAULT_TOLERANCE_M = 1e-3
"""Default static position tolerance at rated load [m] (1 % of the full stroke)."""


@dataclass(frozen=True)
class LeakThreshold:
    """The failure threshold: absolute C_Lk [m^3/s/Pa] and as a ratio to the baseline C_Lk."""

    c_lk_fail: float
    ratio: float
    load_n: float
    tolerance_m: float
    c_lk_nominal: float
    e_ss_nominal_m: float

    def as_dict(self) -> dict[str, float]:
        """Plain dict (JSON)."""
        return dict(self.__dict__)


def _p12(x_s: float, c_lk: float, p: EHAParams) -> float:
    return float(hf_static_p12(x_s, 0.0, p.p_sr, p, c_lk))


def static_error(c_lk: float, load_n: float, params: EHAParams | None = None) -> float:
    """Static position error e_ss = x_S / (K_sv k_p) [m] holding ``load_n`` at leakage ``c_lk``
    (module docstring); inf when no reachable opening holds the load."""
    p = params or EHAParams()
    target = load_n / p.area
    x_max = min(p.x_sm, p.k_sv * p.i_max)
    if _p12(x_max, c_lk, p) < target:
        return math.inf
    x_s = brentq(lambda x: _p12(x, c_lk, p) - target, 0.0, x_max, xtol=1e-10)
    return x_s / (p.k_sv * p.k_p)


def leak_threshold(
    params: EHAParams | None = None,
    *,
    load_n: float | None = None,
    tolerance_m: float = DEFAULT_TOLERANCE_M,
    c_lk_baseline: float | None = None,
) -> LeakThreshold:
    """C_Lk,fail of the module docstring; ``ratio`` = C_Lk,fail / ``c_lk_baseline`` (default
    the parameter set's nominal C_Lk, which is also the monitor baseline's C_Lk)."""
    p = params or EHAParams()
    load = (2.0 / 3.0) * p.area * p.p_sr if load_n is None else float(load_n)
    target = load / p.area
    x_tol = min(p.k_sv * p.k_p * tolerance_m, p.x_sm, p.k_sv * p.i_max)
    c0 = p.c_lk if c_lk_baseline is None else float(c_lk_baseline)
    if _p12(x_tol, p.c_lk, p) < target:
        raise ValueError("the nominal unit cannot hold the load within the tolerance")
    hi = max(p.c_lk, 1e-16) * 2.0
    while _p12(x_tol, hi, p) >= target:
        hi *= 2.0
        if hi > 1e-8:
            raise ValueError("no leakage threshold below 1e-8 m^3/s/Pa")
    c_fail = brentq(lambda c: _p12(x_tol, c, p) - target, p.c_lk, hi, xtol=1e-18, rtol=1e-10)
    return LeakThreshold(
        c_lk_fail=float(c_fail),
        ratio=float(c_fail / c0),
        load_n=load,
        tolerance_m=float(tolerance_m),
        c_lk_nominal=c0,
        e_ss_nominal_m=static_error(p.c_lk, load, p),
    )
