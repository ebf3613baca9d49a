"""The paths of the degradation models (``degradation``): each model's basis Phi(u; eta), the
grid of its nonlinear parameter eta, and the crossing time and slope of a noise-free path
y = Phi(u; eta) w, per draw of w. u is the scaled life axis (``degradation`` module docstring).

- ``none``        Phi = [1]                                   (no wear)
- ``linear``      Phi = [1, t]
- ``exponential`` Phi = [1, (exp(beta u) - 1) / beta], eta = beta > 0 on a log grid of
  beta u_now in [``BETA_SPAN`` range] (relative to the history's own span u_now)
  (MATLAB's exponential degradation model y = phi + theta exp(beta t) with phi = w0 - w1/beta,
  theta = w1/beta; w1 is the initial wear rate, so beta -> 0 is the linear model)
- ``step``        Phi = [1, H(t - tau), (t - tau)+], eta = tau on the observed times
  (a step of the indicator followed by linear growth)
- ``power``       Phi = [1, u^p], eta = p on ``POWER_GRID`` (wear that accelerates slower
  than an exponential)
- ``knee``        Phi = [1, u, (u - tau)+], eta = tau between observations with at least two
  on either side (a broken stick: the wear rate changes once at an unknown knee, without a
  jump; the posterior over tau is its profile of the marginal likelihood). After a knee the
  path goes on at the new rate w1 + w2; an accelerating model (exponential, power) takes
  over the extrapolation only where its evidence beats the knee's.
- ``quadratic``   Phi = [1, u, u^2] (wear with an initial rate and a constant acceleration:
  the exponential's initial rate, without its runaway; the power model, whose path starts
  flat, misses the initial rate of such a path, which the exponential then reads as an
  acceleration that goes on)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["MODELS", "POWER_GRID", "BETA_SPAN", "BETA_GRID", "basis", "basis_grid", "eta_grid",
           "crossing", "slope"]  # fmt: skip

MODELS: tuple[str, ...] = ("none", "linear", "exponential", "step", "power", "knee", "quadratic")
POWER_GRID = np.geomspace(1.25, 4.0, 16)
"""Exponents p of the ``power`` model's grid."""
BETA_SPAN = np.geomspace(1e-2, 6.0, 120)
"""Exponential rates of the grid times the history's span, beta u_now (dimensionless)."""
BETA_GRID = BETA_SPAN  # kept name: the grid at u_now = 1


def basis(model: str, t: NDArray, eta: float) -> NDArray:
    """Phi(t; eta) of the module docstring, (len(t), p)."""
    one = np.ones_like(t)
    if model == "none":
        return one[:, None]
    if model == "linear":
        return np.stack([one, t], axis=1)
    if model == "exponential":
        return np.stack([one, np.expm1(eta * t) / eta], axis=1)
    if model == "step":
        d = t - eta
        return np.stack([one, (d > 0).astype(float), np.maximum(d, 0.0)], axis=1)
    if model == "power":
        return np.stack([one, np.maximum(t, 0.0) ** eta], axis=1)
    if model == "knee":
        return np.stack([one, t, np.maximum(t - eta, 0.0)], axis=1)
    if model == "quadratic":
        return np.stack([one, t, t * t], axis=1)
    raise ValueError(f"unknown model {model!r}")


def basis_grid(model: str, t: NDArray, grid: NDArray) -> NDArray:
    """``basis`` at every eta of ``grid`` at once, (G, len(t), p)."""
    g = np.asarray(grid, float)[:, None]
    one = np.ones((len(g), len(t)))
    if model == "exponential":
        cols = [one, np.expm1(g * t[None, :]) / g]
    elif model == "step":
        d = t[None, :] - g
        cols = [one, (d > 0).astype(float), np.maximum(d, 0.0)]
    elif model == "power":
        cols = [one, np.maximum(t, 0.0)[None, :] ** g]
    elif model == "knee":
        cols = [one, np.broadcast_to(t[None, :], one.shape), np.maximum(t[None, :] - g, 0.0)]
    else:
        return np.stack([basis(model, t, float(e)) for e in grid])
    return np.stack(cols, axis=2)


def eta_grid(model: str, t: NDArray) -> NDArray:
    if model == "exponential":
        return BETA_SPAN / max(float(t[-1]), 1e-9)
    if model == "step":
        # change points between observations, at least two points after and one before
        if len(t) < 4:
            return np.zeros(0)
        return 0.5 * (t[:-3] + t[1:-2])
    if model == "power":
        return POWER_GRID
    if model == "knee":
        # knees between observations, at least two points on either side
        if len(t) < 5:
            return np.zeros(0)
        return 0.5 * (t[1:-2] + t[2:-1])
    return np.zeros(1)


def crossing(model: str, w: NDArray, eta: float, thr: float, t_now: float) -> NDArray:
    """Crossing times of the noise-free paths Phi(t; eta) w = thr after t_now (inf if none);
    t_now where the path is already above."""
    a = w[:, 0]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if model == "none":
            tc = np.full(len(w), np.inf)
            level = a
        elif model == "linear":
            level = a + w[:, 1] * t_now
            tc = np.where(w[:, 1] > 0, (thr - a) / w[:, 1], np.inf)
        elif model == "exponential":
            c = w[:, 1]
            level = a + c * np.expm1(eta * t_now) / eta
            arg = 1.0 + eta * (thr - a) / c
            tc = np.where((c > 0) & (arg > 0), np.log(arg) / eta, np.inf)
        elif model == "power":
            c = w[:, 1]
            level = a + c * max(t_now, 0.0) ** eta
            tc = np.where((c > 0) & (thr > a), ((thr - a) / c) ** (1.0 / eta), np.inf)
        elif model == "quadratic":  # first root of w0 - thr + w1 u + w2 u^2 after t_now
            b, c = w[:, 1], w[:, 2]
            level = a + b * t_now + c * t_now**2
            tc = _quadratic_root(a - thr, b, c, t_now)
        elif model == "knee":  # eta = tau < t_now: linear at w1 + w2 from the knee on
            c = w[:, 1] + w[:, 2]
            level = a + w[:, 1] * t_now + w[:, 2] * max(t_now - eta, 0.0)
            tc = np.where(c > 0, t_now + (thr - level) / c, np.inf)
        else:  # step, eta = tau < t_now
            s, c = w[:, 1], w[:, 2]
            level = a + s + c * max(t_now - eta, 0.0)
            tc = np.where(c > 0, eta + (thr - a - s) / c, np.inf)
    tc = np.where(level >= thr, t_now, tc)
    return np.where(np.isfinite(tc), np.maximum(tc, t_now), np.inf)


def _quadratic_root(a: NDArray, b: NDArray, c: NDArray, t_now: float) -> NDArray:
    """The first root u >= t_now of a + b u + c u^2 (inf if none), per draw."""
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - 4.0 * a * c
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -0.5 * (b + np.where(b >= 0, sq, -sq))
        r1 = np.where(c != 0, q / c, np.inf)
        r2 = np.where(q != 0, a / q, np.inf)
        lin = np.where(b > 0, -a / b, np.inf)  # c = 0: the linear root
        r1 = np.where(c == 0, lin, r1)
        r2 = np.where(c == 0, np.inf, r2)
        ok = disc >= 0
        r1 = np.where(ok & np.isfinite(r1) & (r1 >= t_now), r1, np.inf)
        r2 = np.where(ok & np.isfinite(r2) & (r2 >= t_now), r2, np.inf)
    return np.minimum(r1, r2)


def slope(model: str, w: NDArray, eta: float, u: NDArray) -> NDArray:
    """d(path)/du at ``u`` (per draw)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if model == "linear":
            return w[:, 1]
        if model == "exponential":
            return w[:, 1] * np.exp(eta * np.where(np.isfinite(u), u, 0.0))
        if model == "step":
            return w[:, 2]
        if model == "knee":
            return w[:, 1] + w[:, 2] * (np.where(np.isfinite(u), u, np.inf) > eta)
        if model == "quadratic":
            return w[:, 1] + 2.0 * w[:, 2] * np.where(np.isfinite(u), u, 0.0)
        if model == "power":
            uu = np.where(np.isfinite(u), np.maximum(u, 0.0), 0.0)
            return w[:, 1] * eta * uu ** (eta - 1.0)
    return np.zeros(len(w))
