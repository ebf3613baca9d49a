"""Closed-loop EHA bench: fixed-step simulation and incremental stepper (physics.md section 3).

ECU (proportional position loop, current limit) -> torque motor (first order) -> spool
(second order, limited to +-x_SM) -> fluid-dynamic valve -> jack (mass, viscous and
Karnopp dry friction, end stops). The valve is either the HF model ("HF", 7 states with
the two compressible chambers), a simplified algebraic law ("A", "B", "C1", "C3", "C5",
5 states; P12 = law(x_S, A v_J, P_SR) with parameters from ``simplified_params``) or the
WH model ("WH", 7 states: the C-types' parameters, square-root lands and two lumped
chambers with a cavitation floor, docs/models.md; parameters from ``wh_params``).

Integration (``models.compiled.integrate``): classic RK4 for every valve. The
simplified laws are stiff in v_J (dP12/dQ_J ~ -G_PQ, lambda ~ -A^2 G_PQ / m = -6446 1/s,
|h lambda| = 0.64 at 1e-4 s: well inside RK4's region; a Rosenbrock-W ROS2 variant was
tried and, at equal cost, was less accurate than RK4 at a larger step). Default step 1e-4 s, inputs held constant over each step at their mid-step value, so input
discontinuities placed on step boundaries are honoured exactly. If the stiffness estimate
of :func:`n_substeps` exceeds the explicit part's stability limit the step is split into
substeps.

Karnopp friction (physics.md section 3): stuck while |v_J| < dv_k and |A P12 - F_R -
F_endstop| <= F_s (v_J then relaxes to 0 with time constant ``compiled.TAU_STICK``, and
the fixed-step loops set it to 0 once below ``compiled.V_J_ZERO`` = 1e-200 m/s instead of
leaving it parked at a slow subnormal); breakaway with F_s sign(F) in the band; Coulomb
F_d sign(v_J) outside it.

For the simplified valves the reported chamber pressures are the symmetric split
P1 = P_R + (P_SR + P12)/2, P2 = P_R + (P_SR - P12)/2 (not states of those models). For WH
the states 5, 6 are the chambers' volume balances p~1, p~2 and the reported pressures are
P_k = max(p~_k, P_vap) (docs/models.md eq. 6).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from models import compiled as kern
from models.hf_valve import hf_static_pressures, orifice_slope
from models.params import EHAParams, simplified_params, wh_params
from models.scenario import Scenario
from models.valve_laws import p12 as law_p12

__all__ = [
    "VALVE_MODELS",
    "SimResult",
    "simulate",
    "EHAStepper",
    "initial_state",
    "n_substeps",
    "state_outputs",
]

VALVE_MODELS: tuple[str, ...] = ("HF", "A", "B", "C1", "C3", "C5", "WH")

_RK4_LIMIT = 2.5  # |h lambda| kept below RK4's real-axis stability bound 2.785


@dataclass
class SimResult:
    """Bench signals sampled every ``out_every`` steps, t[0] = 0 (SI units).

    For simplified valves p1/p2 are the symmetric split around the supply mid-pressure
    (see module docstring). q_j = A v_J. i_c is the ECU command, i the torque-motor current.
    """

    valve: str
    t: NDArray
    x_cmd: NDArray
    f_r: NDArray
    p_sr: NDArray
    c_lk: NDArray
    i_c: NDArray
    i: NDArray
    x_s: NDArray
    v_s: NDArray
    x_j: NDArray
    v_j: NDArray
    p1: NDArray
    p2: NDArray
    p12: NDArray
    q_j: NDArray
    wall_s: float


def _check_valve(valve: str) -> int:
    try:
        return kern.MODEL_IDS[valve]
    except KeyError:
        raise ValueError(f"unknown valve model {valve!r}; expected one of {VALVE_MODELS}") from None


def n_substeps(params: EHAParams, valve: str, step_s: float) -> int:
    """RK4 substeps per step so that |h lambda| <= 2.5 (real-axis bound 2.785) for a
    conservative estimate of the fastest modes.

    All valves: torque motor 1/tau_tm, spool 2 w_n, end stop sqrt(k/m) + c/m, stick
    relaxation. WH: the chambers beta/V (2 K_o (x_SS + x_SM) / sqrt(dp_lam) + C_Lk) and
    the hydraulic frequency sqrt(2 beta A^2 / (V m)) (6.5e3 1/s with the defaults: one
    substep at 1e-4 s, three at 1 ms). HF: the chambers beta_l / V_dead (2 max orifice slope + C_Lk) (orifice
    slope bounded via dp_tr) and the hydraulic frequency near a stop. Simplified valves:
    the jack-velocity stiffness A^2 G_PQ / m (dP12/dQ_J ~ -G_PQ): 6446 1/s with the
    defaults, so one substep up to 3.9e-4 s, three at a 1 ms step.
    """
    p = params
    lam = [
        1.0 / p.tau_tm,
        2.0 * p.omega_n,
        math.sqrt(p.k_stop / p.mass) + p.c_stop / p.mass,
        1.0 / kern.TAU_STICK,
    ]
    if valve == "HF":
        a_max = max(abs(p.u1), abs(p.u2), abs(p.u3), abs(p.u4)) + p.x_sm
        s_max = float(orifice_slope(a_max, 0.0, p))
        lam.append(p.beta_l / p.v_dead * (2.0 * s_max + p.c_lk))
        lam.append(math.sqrt(p.beta_l * p.area**2 * (1.0 / p.v_dead) / p.mass))
    elif valve == "WH":
        wp = wh_params(p)
        s_max = wp.k_o * (wp.x_ss + p.x_sm) / math.sqrt(wp.dp_lam)  # laminar band slope
        bv = wp.beta / wp.v_c
        lam.append(bv * (2.0 * s_max + p.c_lk))
        lam.append(math.sqrt(2.0 * bv * p.area**2 / p.mass))
    else:
        lam.append(p.area**2 * p.g_pq / p.mass)
    return max(1, math.ceil(step_s * max(lam) / _RK4_LIMIT))


def initial_state(
    params: EHAParams, valve: str, p_sr: float, c_lk: float, x_j: float = 0.0
) -> NDArray:
    """Rest state: I = 0, spool centred, jack at x_j at rest; HF chambers at the null balance
    pressures of ``hf_static_pressures(0, 0, p_sr)`` (about (P_S + P_R)/2 for a symmetric valve)."""
    y = np.zeros(kern.N_STATE)
    y[3] = x_j
    if valve == "WH":  # symmetric lands: null balance at mid-pressure (docs/models.md eq. 7)
        y[5] = y[6] = params.p_r + 0.5 * p_sr
    elif valve == "HF":
        p1, p2 = hf_static_pressures(0.0, 0.0, p_sr, params, c_lk)
        y[5], y[6] = float(p1), float(p2)
    else:
        y[5] = y[6] = params.p_r + 0.5 * p_sr
    return y


def state_outputs(
    valve: str,
    params: EHAParams,
    y: NDArray,
    x_cmd: NDArray,
    p_sr: NDArray,
    c_lk: NDArray,
) -> dict[str, NDArray]:
    """Derived signals from states ``y`` (..., 7) and the inputs at the same instants."""
    p = params
    x_s = np.clip(y[..., 1], -p.x_sm, p.x_sm)
    v_s = y[..., 2]
    v_s = np.where(
        ((y[..., 1] >= p.x_sm) & (v_s > 0)) | ((y[..., 1] <= -p.x_sm) & (v_s < 0)), 0.0, v_s
    )
    q_j = p.area * y[..., 4]
    if valve == "HF":
        p1, p2 = y[..., 5], y[..., 6]
        p12 = p1 - p2
    elif valve == "WH":
        p1 = np.maximum(y[..., 5], p.p_vap)
        p2 = np.maximum(y[..., 6], p.p_vap)
        p12 = p1 - p2
    else:
        vp = simplified_params(p)._replace(c_lk=c_lk)
        p12 = law_p12(valve, x_s, q_j, p_sr, vp)
        p1 = p.p_r + 0.5 * (p_sr + p12)
        p2 = p.p_r + 0.5 * (p_sr - p12)
    i_c = np.clip(p.k_p * (x_cmd - y[..., 3]), -p.i_max, p.i_max)
    return {
        "i_c": i_c,
        "i": y[..., 0].copy(),
        "x_s": x_s,
        "v_s": v_s,
        "x_j": y[..., 3].copy(),
        "v_j": y[..., 4].copy(),
        "p1": np.asarray(p1, float).copy(),
        "p2": np.asarray(p2, float).copy(),
        "p12": np.asarray(p12, float),
        "q_j": q_j,
    }


def _inputs_matrix(scenario: Scenario, params: EHAParams, t: NDArray) -> NDArray:
    u = scenario.inputs(t, params)
    return np.ascontiguousarray(np.stack([u["x_cmd"], u["f_r"], u["p_sr"], u["c_lk"]], axis=1))


_CHUNK = 20000  # steps per kernel call (progress granularity, input buffer size)


def _piecewise_constant(scenario: Scenario) -> bool:
    profiles = [scenario.command, scenario.load, scenario.supply]
    if scenario.leak is not None:
        profiles.append(scenario.leak)
    return all(not p.periodic and all(e.ramp_s == 0 for e in p.events) for p in profiles)


def _segments(
    scenario: Scenario, params: EHAParams, h: float, n_steps: int, per_step: bool = False
):
    """Yield (k0, n, u): ``n`` steps from global step k0 with inputs ``u`` (one row per step,
    or a single row when the inputs are constant over the segment and not ``per_step``).
    Inputs are the profiles at mid-step, so a step or kink placed on a step boundary is
    honoured exactly."""
    if _piecewise_constant(scenario) and not per_step:
        cuts = {0, n_steps}
        for prof in (scenario.command, scenario.load, scenario.supply, scenario.leak):
            if prof is None:
                continue
            for tb in prof.breakpoints():
                kb = math.ceil(tb / h - 0.5)  # first step whose midpoint is at or after tb
                if 0 < kb < n_steps:
                    cuts.add(kb)
        cuts.update(range(_CHUNK, n_steps, _CHUNK))
        edges = sorted(cuts)
        u = _inputs_matrix(scenario, params, (np.array(edges[:-1]) + 0.5) * h)
        for i, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
            yield a, b - a, u[i : i + 1]
    else:
        for a in range(0, n_steps, _CHUNK):
            m = min(_CHUNK, n_steps - a)
            yield a, m, _inputs_matrix(scenario, params, (a + np.arange(m) + 0.5) * h)


def sim_result(
    scenario: Scenario,
    valve: str,
    params: EHAParams,
    t_out: NDArray,
    states: NDArray,
    wall_s: float,
) -> SimResult:
    """A :class:`SimResult` from the states sampled at ``t_out`` (inputs re-sampled there)."""
    u_out = scenario.inputs(t_out, params)
    sig = state_outputs(valve, params, states, u_out["x_cmd"], u_out["p_sr"], u_out["c_lk"])
    return SimResult(
        valve=valve,
        t=t_out,
        x_cmd=u_out["x_cmd"],
        f_r=u_out["f_r"],
        p_sr=u_out["p_sr"],
        c_lk=u_out["c_lk"],
        wall_s=wall_s,
        **sig,
    )


def simulate(
    scenario: Scenario,
    valve: str = "HF",
    params: EHAParams | None = None,
    *,
    out_every: int = 1,
    progress: Callable[[float], None] | None = None,
    x_fb_noise: NDArray | None = None,
) -> SimResult:
    """Run the closed-loop bench over ``scenario`` with valve model ``valve`` (fixed step).

    Step = scenario.step_s (substeps from :func:`n_substeps`); params=None uses
    scenario.eha_params(). Inputs are held at their mid-step value. Output every
    ``out_every`` steps from t = 0. ``progress`` receives the fraction done, at most about
    five times per second and once at the end. ``x_fb_noise`` [m], one value per output
    sample: the error of the ECU's position feedback, held from its sample to the next
    (I_c = K_p (x_cmd - x_J - n), fed as a command of x_cmd - n); None = the true x_J.
    """
    model = _check_valve(valve)
    if out_every < 1:
        raise ValueError("out_every must be >= 1")
    params = params or scenario.eha_params()
    prm = kern.param_array(params)
    h = scenario.step_s
    n_steps = scenario.n_steps()
    n_sub = n_substeps(params, valve, h)
    n_out = n_steps // out_every + 1
    t_out = np.arange(n_out) * (out_every * h)
    u0 = _inputs_matrix(scenario, params, np.array([0.5 * h]))[0]
    y = initial_state(params, valve, float(u0[2]), float(u0[3]))
    states = np.empty((n_out, kern.N_STATE))
    states[0] = y
    if x_fb_noise is not None:
        x_fb_noise = np.asarray(x_fb_noise, float)
        if x_fb_noise.shape != (n_out,) or not np.all(np.isfinite(x_fb_noise)):
            raise ValueError(f"x_fb_noise: expected {n_out} finite values, one per output sample")
    wall0 = time.perf_counter()
    last_report = wall0
    for k0, m, u in _segments(scenario, params, h, n_steps, per_step=x_fb_noise is not None):
        if x_fb_noise is not None:
            u = u.copy()
            u[:, 0] -= x_fb_noise[(k0 + np.arange(m)) // out_every]
        kern.integrate(y, h, n_sub, k0, m, u, prm, model, out_every, states)
        if progress is not None:
            now = time.perf_counter()
            if now - last_report >= 0.2 and k0 + m < n_steps:
                progress((k0 + m) / n_steps)
                last_report = now
    wall = time.perf_counter() - wall0
    if progress is not None:
        progress(1.0)
    return sim_result(scenario, valve, params, t_out, states, wall)


class EHAStepper:
    """Incremental bench for a wall-clock-paced virtual actuator or a monitor test.

    ``advance`` integrates ``n_steps`` steps with the inputs held constant; ``signals``
    returns the current measurements. The state starts at rest (null balance, x_J = 0) at
    the first ``advance``'s supply pressure and leakage.
    """

    def __init__(self, params: EHAParams, valve: str = "HF", step_s: float = 1e-4) -> None:
        self.model = _check_valve(valve)
        self.valve = valve
        self.params = params
        self.step_s = float(step_s)
        self._prm = kern.param_array(params)
        self._n_sub = n_substeps(params, valve, self.step_s)
        self._y: NDArray | None = None
        self._u = np.zeros((1, 4))
        self._u[0] = (0.0, 0.0, params.p_sr, params.c_lk)
        self._out = np.empty((1, kern.N_STATE))
        self.t: float = 0.0
        self._t0 = 0.0
        self._k = 0

    @property
    def state(self) -> NDArray:
        """Copy of the state vector (I, x_S, v_S, x_J, v_J, P1, P2)."""
        if self._y is None:
            self._y = initial_state(self.params, self.valve, self._u[0, 2], self._u[0, 3])
        return self._y.copy()

    def reset(self, state: NDArray | None = None, t: float = 0.0) -> None:
        """Back to rest (or to ``state``) at time ``t``."""
        if state is not None and np.shape(state) != (kern.N_STATE,):
            raise ValueError(
                f"state must have {kern.N_STATE} entries (I, x_S, v_S, x_J, v_J, P1, P2)"
            )
        self._y = None if state is None else np.array(state, float)
        self._k = 0
        self._t0 = t
        self.t = t

    def advance(self, n_steps: int, x_cmd: float, f_r: float, p_sr: float, c_lk: float) -> None:
        """Integrate ``n_steps`` fixed steps with constant inputs (SI units)."""
        self._u[0] = (x_cmd, f_r, max(p_sr, 0.0), max(c_lk, 0.0))
        if self._y is None:
            self._y = initial_state(self.params, self.valve, self._u[0, 2], self._u[0, 3])
        if n_steps <= 0:
            return
        kern.integrate(
            self._y, self.step_s, self._n_sub, 0, int(n_steps), self._u, self._prm, self.model,
            int(n_steps) + 1, self._out,
        )  # fmt: skip
        self._k += int(n_steps)
        self.t = self._t0 + self._k * self.step_s

    def signals(self) -> dict[str, float]:
        """Current t, x_cmd, i (A), x_s, v_s, x_j, v_j, p1, p2, p12, p_sr, c_lk (SI)."""
        if self._y is None:
            self._y = initial_state(self.params, self.valve, self._u[0, 2], self._u[0, 3])
        y = self._y
        p = self.params
        x_cmd, _, p_sr, c_lk = (float(v) for v in self._u[0])
        x_s = min(max(float(y[1]), -p.x_sm), p.x_sm)
        v_s = float(y[2])
        if (y[1] >= p.x_sm and v_s > 0) or (y[1] <= -p.x_sm and v_s < 0):
            v_s = 0.0
        if self.model == 0:
            p1, p2 = float(y[5]), float(y[6])
            p12 = p1 - p2
        elif self.valve == "WH":
            p1, p2 = max(float(y[5]), p.p_vap), max(float(y[6]), p.p_vap)
            p12 = p1 - p2
        else:
            prm = self._prm
            p12 = float(
                kern.law_p12(
                    self.model, x_s, p.area * float(y[4]), p_sr, prm[kern.I_G_PQ],
                    prm[kern.I_X_SS], c_lk, p.p_vap,
                )
            )  # fmt: skip
            p1 = p.p_r + 0.5 * (p_sr + p12)
            p2 = p.p_r + 0.5 * (p_sr - p12)
        return {
            "t": self.t,
            "x_cmd": x_cmd,
            "i": float(y[0]),
            "x_s": x_s,
            "v_s": v_s,
            "x_j": float(y[3]),
            "v_j": float(y[4]),
            "p1": p1,
            "p2": p2,
            "p12": p12,
            "p_sr": p_sr,
            "c_lk": c_lk,
        }
