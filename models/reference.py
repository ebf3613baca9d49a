"""Tight-tolerance reference of the EHA bench with scipy's solve_ivp (physics.md section 6).

Same right-hand side as the fixed-step integrator (``models.compiled.rhs``), integrated by
an adaptive implicit method piecewise between the scenario's input breakpoints, so the
only difference to :func:`models.eha.simulate` is the time discretisation. Inputs are
evaluated at the exact time (constant per segment when the profiles have no ramps or
periodic parts, which is then exact).
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from models import compiled as kern
from models.eha import SimResult, initial_state, sim_result
from models.params import EHAParams
from models.scenario import Scenario

__all__ = ["reference_solution", "DEFAULT_ATOL"]

DEFAULT_ATOL: NDArray = np.array([1e-10, 1e-12, 1e-9, 1e-11, 1e-9, 1e-1, 1e-1])
"""Absolute tolerances per state: I [A], x_S [m], v_S [m/s], x_J [m], v_J [m/s], P1, P2 [Pa]."""


def _is_piecewise_constant(scenario: Scenario) -> bool:
    profiles = [scenario.command, scenario.load, scenario.supply]
    if scenario.leak is not None:
        profiles.append(scenario.leak)
    return all(not p.periodic and all(e.ramp_s == 0 for e in p.events) for p in profiles)


def _breakpoints(scenario: Scenario) -> list[float]:
    ts = set(scenario.command.breakpoints())
    ts |= set(scenario.load.breakpoints())
    ts |= set(scenario.supply.breakpoints())
    if scenario.leak is not None:
        ts |= set(scenario.leak.breakpoints())
    end = scenario.n_steps() * scenario.step_s
    return sorted({0.0, end} | {t for t in ts if 0.0 < t < end})


def reference_solution(
    scenario: Scenario,
    valve: str = "HF",
    params: EHAParams | None = None,
    rtol: float = 1e-8,
    atol: float | NDArray | None = None,
    *,
    method: str = "Radau",
    out_every: int = 1,
) -> SimResult:
    """solve_ivp (``method``, default Radau) solution on the grid of ``simulate(out_every=...)``.

    Integrates piecewise between input breakpoints, each at its exact time (``simulate``
    moves a breakpoint that is off the step grid to the nearest step boundary); ``atol``
    defaults to :data:`DEFAULT_ATOL` (per state). ``wall_s`` is the wall time of the solve.
    About 1-4 s for paper_bench (piecewise-constant inputs); scenarios with ramps or
    periodic inputs evaluate the profiles at every right-hand-side call and are slower.
    """
    if valve not in kern.MODEL_IDS:
        raise ValueError(f"unknown valve model {valve!r}")
    model = kern.MODEL_IDS[valve]
    params = params or scenario.eha_params()
    prm = kern.param_array(params)
    atol = DEFAULT_ATOL if atol is None else atol
    h = scenario.step_s
    n_out = scenario.n_steps() // out_every + 1
    t_out = np.arange(n_out) * (out_every * h)
    bps = _breakpoints(scenario)
    const = _is_piecewise_constant(scenario)

    def inputs_at(t: float) -> NDArray:
        u = scenario.inputs(np.array([t]), params)
        return np.array([u["x_cmd"][0], u["f_r"][0], u["p_sr"][0], u["c_lk"][0]])

    u0 = inputs_at(0.5 * h)
    y = initial_state(params, valve, float(u0[2]), float(u0[3]))
    states = np.empty((n_out, kern.N_STATE))
    wall0 = time.perf_counter()
    for a, b in zip(bps[:-1], bps[1:], strict=True):
        if const:
            uc = inputs_at(0.5 * (a + b))

            def fun(t, yy, uc=uc):
                dy = np.empty(kern.N_STATE)
                kern.rhs(yy, uc[0], uc[1], uc[2], uc[3], prm, model, dy)
                return dy
        else:

            def fun(t, yy):
                uc = inputs_at(t)
                dy = np.empty(kern.N_STATE)
                kern.rhs(yy, uc[0], uc[1], uc[2], uc[3], prm, model, dy)
                return dy

        last = b == bps[-1]
        sel = (t_out >= a - 1e-12) & ((t_out < b - 1e-12) | last)
        t_ev = t_out[sel]
        if not t_ev.size or t_ev[-1] < b:
            t_ev = np.append(t_ev, b)
        t_ev = np.clip(t_ev, a, b)
        sol = solve_ivp(
            fun, (a, b), y, method=method, rtol=rtol, atol=atol, t_eval=t_ev,
            first_step=min(1e-6, b - a),
        )  # fmt: skip
        if not sol.success:
            raise RuntimeError(f"reference solve failed on [{a}, {b}]: {sol.message}")
        n_sel = int(sel.sum())
        states[sel] = sol.y[:, :n_sel].T
        y = sol.y[:, -1].copy()
    wall = time.perf_counter() - wall0
    return sim_result(scenario, valve, params, t_out, states, wall)
