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
- ``knee_exp``    Phi = [1, u, (exp(beta (u - tau)+) - 1) / beta], eta = (tau, beta): tau as
  the knee's, beta u_now on ``KNEE_BETA_SPAN`` (a knee, then growth: the rate w1 until tau,
  w1 + w2 exp(beta (u - tau)) after it; beta -> 0 would be the knee, a tau near the start an
  initial rate plus an exponential acceleration). Its crossing is closed form (Lambert's W).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.special import lambertw

__all__ = ["MODELS", "POWER_GRID", "BETA_SPAN", "BETA_GRID", "KNEE_BETA_SPAN", "basis",
           "basis_grid", "eta_grid", "crossing", "slope"]  # fmt: skip

MODELS: tuple[str, ...] = (
    "none", "linear", "exponential", "step", "power", "knee", "quadratic", "knee_exp",
)  # fmt: skip
POWER_GRID = np.geomspace(1.25, 4.0, 16)
"""Exponents p of the ``power`` model's grid."""
BETA_SPAN = np.geomspace(1e-2, 6.0, 120)
"""Exponential rates of the grid times the history's span, beta u_now (dimensionless)."""
BETA_GRID = BETA_SPAN  # kept name: the grid at u_now = 1
KNEE_BETA_SPAN = np.geomspace(1.0, 6.0, 9)
"""Growth rates after the knee of ``knee_exp`` times the history's span, beta u_now: from a
rate that grows by e over the history's span (slower growth extrapolates as the knee does
within the span, and the two models would share the knee's evidence) to the exponential's
largest."""


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
    if model == "knee_exp":
        tau, b = eta
        with np.errstate(over="ignore"):
            e = np.expm1(b * np.maximum(t - tau, 0.0)) / b
        return np.stack([one, t, e], axis=1)
    raise ValueError(f"unknown model {model!r}")


def basis_grid(model: str, t: NDArray, grid: NDArray) -> NDArray:
    """``basis`` at every eta of ``grid`` at once, (G, len(t), p)."""
    g = np.asarray(grid, float)[:, None]
    one = np.ones((len(g), len(t)))
    if model == "knee_exp":  # grid (G, 2): tau, beta
        tau, b = g[:, :, 0], g[:, :, 1]
        e = np.expm1(b * np.maximum(t[None, :] - tau, 0.0)) / b
        return np.stack([one, np.broadcast_to(t[None, :], one.shape), e], axis=2)
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
    """The grid of ``model``'s nonlinear parameter for observations at ``t`` (scaled, rising);
    (G,) or, for ``knee_exp``, (G, 2) rows (tau, beta); a single 0 for the linear models."""
    if model == "knee_exp":
        if len(t) < 5:
            return np.zeros((0, 2))
        tau = 0.5 * (t[1:-2] + t[2:-1])
        b = KNEE_BETA_SPAN / max(float(t[-1]), 1e-9)
        return np.stack(np.meshgrid(tau, b, indexing="ij"), axis=-1).reshape(-1, 2)
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
        elif model == "knee_exp":  # eta = (tau < t_now, beta)
            tau, b = float(eta[0]), float(eta[1])
            level = a + w[:, 1] * t_now + w[:, 2] * np.expm1(b * max(t_now - tau, 0.0)) / b
            tc = tau + _knee_exp_root(thr - a - w[:, 1] * tau, w[:, 1], w[:, 2], b,
                                      max(t_now - tau, 0.0))  # fmt: skip
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


def _knee_exp_root(d: NDArray, w1: NDArray, w2: NDArray, b: float, v_now: float) -> NDArray:
    """The first root v >= v_now of w1 v + w2 (exp(b v) - 1) / b = d (inf if none), per draw:
    with c = d + w2 / b and r = w2 / w1, z = W(k) for k = r exp(b c / w1) (Lambert's W, both
    real branches where -1/e <= k < 0) gives v = log(z / r) / b; w1 = 0: v = log(b c / w2) / b.
    Where k is beyond exp's range, log |z| comes from Newton's method on z + log |z| = log |k|."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        c = d + w2 / b
        r = w2 / w1
        lr = np.log(np.abs(r))
        lk = lr + b * c / w1
        pos = r > 0
        k = np.where(pos, 1.0, -1.0) * np.exp(np.clip(lk, -700.0, 700.0))
        two = ~pos & (k >= -np.exp(-1.0))  # two real roots
        lz0 = np.log(np.abs(lambertw(k, 0).real))
        lz1 = np.where(two, np.log(np.abs(lambertw(k, -1).real)), np.nan)
        lz0 = np.where(lk < -700.0, lk, lz0)  # W0(k) ~ k
        for sel, sgn, out in ((pos & (lk > 700.0), 1.0, lz0), (two & (lk < -700.0), -1.0, lz1)):
            if sel.any():  # W0 of a huge k (z > 0), W-1 of a tiny -k (z < -1)
                L = lk[sel]
                z = sgn * (np.abs(L) - np.log(np.abs(L))) if sgn > 0 else L - np.log(-L)
                for _ in range(6):
                    z = z - (z + np.log(np.abs(z)) - L) / (1.0 + 1.0 / z)
                out[sel] = np.log(np.abs(z))
        v0 = np.where(pos | two, (lz0 - lr) / b, np.nan)
        v1 = (lz1 - lr) / b
        v0 = np.where(np.isfinite(v0) & (v0 >= v_now), v0, np.inf)
        v1 = np.where(np.isfinite(v1) & (v1 >= v_now), v1, np.inf)
        vz = np.log(b * c / w2) / b  # w1 = 0
        vz = np.where(np.isfinite(vz) & (vz >= v_now), vz, np.inf)
    return np.where(w1 == 0, vz, np.minimum(v0, v1))


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
        if model == "knee_exp":
            v = np.maximum(np.where(np.isfinite(u), u, 0.0) - eta[0], 0.0)
            return w[:, 1] + w[:, 2] * np.exp(eta[1] * v) * (
                np.where(np.isfinite(u), u, 0) > eta[0]
            )
        if model == "power":
            uu = np.where(np.isfinite(u), np.maximum(u, 0.0), 0.0)
            return w[:, 1] * eta * uu ** (eta - 1.0)
    return np.zeros(len(w))
