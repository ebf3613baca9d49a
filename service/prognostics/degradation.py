"""Degradation models of the C_Lk ratio y against a life axis t, Bayesian with a fleet prior.

The life axis is whatever the history supports (flights, or operating hours; ``rul``); the
models see it scaled, u = t / T with T the fleet's typical history span (``FleetPrior.t_scale``,
learned; default: the history's own span), so that no prior or grid assumes the length of a
period or a unit of time. Every model is linear in its weights w given at most one nonlinear
parameter eta on a grid, y = Phi(u; eta) w + e, e ~ N(0, sigma^2) (docs/prognostics.md,
"Degradation models"; the models' paths, grids and crossings are in ``paths``).

Residual correlation: when the residuals about the posterior-mean path are positively
correlated (lag-one autocorrelation rho > 0, a sign that no model describes the path
exactly), sigma is inflated by sqrt((1 + rho) / (1 - rho)) (the variance of a trend fitted
to AR(1) errors) and the posterior computed again, so the intervals widen rather than trust
a misfitting model. The path's diffusion about the model (``diffusion``) spreads each
draw's crossing time to first order (a drifted random walk's first passage).

Wear spread: the wear per step varies (hours, load, cycles per flight), so the path is a
random walk about its trend. The measurement noise sigma_m^2 and the wear's squared
coefficient of variation cv^2 are told apart by the lag-one autocovariance of the increments
(``measurement_noise``, ``usage_spread``); the posterior is then computed again under that
noise model, Cov = sigma_m^2 I + the spread accumulated along the path
(``_refit_with_wear_spread``), and each draw's crossing is spread by cv sqrt(steps ahead).

Prior: w ~ N(m0, V0) (per model, learned from the fleet, ``FleetPrior``), eta uniform on its
grid, sigma^2 fixed per unit (its robust first-difference estimate shrunk toward the fleet's).
Then the posterior of w for each eta is Gaussian (precision A = V0^-1 + Phi'Phi / sigma^2)
and the evidence p(y | model, eta) = N(y; Phi m0, sigma^2 I + Phi V0 Phi') is closed form;
model weights are prior(model) x evidence (Bayesian model averaging). The RUL to a threshold
is sampled from that mixture: for each draw the crossing time of the noise-free path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from service.prognostics.paths import (
    BETA_GRID,
    BETA_SPAN,
    MODELS,
    basis,
    basis_grid,
    crossing,
    eta_grid,
    slope,
)

if TYPE_CHECKING:
    from service.prognostics.trend import TrendFit

# ``trend`` (numba) is imported where the opt-in switch is on (``FleetPrior.robust_trend``):
# with it off, fitting imports nothing more than before

__all__ = [
    "MODELS",
    "ALL_MODELS",
    "robust_trend_prior",
    "ModelPrior",
    "FleetPrior",
    "Fit",
    "noise_sigma",
    "fit_history",
    "sample_crossing",
    "sample_paths",
    "learn_fleet_prior",
    "BETA_GRID",
    "BETA_SPAN",
]


ALL_MODELS: tuple[str, ...] = (*MODELS, "trend")
"""The parametric family and the trend model (``trend``: a local linear trend whose rate
diffuses, decision record 0031), the models of a prior with ``robust_trend`` on."""

TREND_P0 = 0.1
"""The trend model's prior probability before the fleet (``robust_trend_prior``)."""


@dataclass(frozen=True)
class ModelPrior:
    """Gaussian prior N(mean, diag(sd^2)) of one model's weights."""

    mean: tuple[float, ...]
    sd: tuple[float, ...]


def _default_priors() -> dict[str, ModelPrior]:
    # weights per unit of u (one typical history span): wear rates up to ~10 ratio units
    # per span (the failure threshold is ~11) are plausible a priori
    return {
        "none": ModelPrior((1.0,), (0.3,)),
        "linear": ModelPrior((1.0, 0.0), (0.3, 8.0)),
        "exponential": ModelPrior((1.0, 0.0), (0.3, 8.0)),
        "step": ModelPrior((1.0, 0.0, 0.0), (0.3, 2.0, 8.0)),
        "power": ModelPrior((1.0, 0.0), (0.3, 8.0)),
        "knee": ModelPrior((1.0, 0.0, 0.0), (0.3, 8.0, 8.0)),
        "quadratic": ModelPrior((1.0, 0.0, 0.0), (0.3, 8.0, 8.0)),
    }


@dataclass(frozen=True)
class FleetPrior:
    """Fleet-level prior: model probabilities, weight priors per model, indicator noise."""

    p_model: dict[str, float] = field(
        default_factory=lambda: {
            "none": 0.4,
            "linear": 0.1,
            "exponential": 0.1,
            "step": 0.1,
            "power": 0.1,
            "knee": 0.1,
            "quadratic": 0.1,
        }  # fmt: skip
    )
    weights: dict[str, ModelPrior] = field(default_factory=_default_priors)
    sigma: float = 0.03
    sigma_strength: float = 5.0
    units: int = 0
    t_scale: float | None = None
    q2_rel: float = 0.0  # fleet's path diffusion, q^2 t_scale (ratio^2 per history span)
    cv2: float = 0.0  # fleet's usage spread per observation step (``usage_spread``)
    sigma_m2: float | None = None  # fleet's measurement noise variance (``measurement_noise``)
    kappa: float = 1.0  # interval widening learned by hindcasts on the fleet (``hindcast``)
    p_axis: dict[str, float] = field(default_factory=lambda: {"flights": 1.0})
    """Prior probability of each life axis (``rul.USAGE_AXES``), learned from the fleet."""
    usage_ref: dict[str, float] = field(default_factory=dict)
    """The fleet's median usage per operating second of each usage axis (its unit)."""
    p_trend_g: tuple[float, ...] | None = None
    """The trend model's prior over its growth cells (``trend.G_SPAN``), learned from the
    fleet's evidence (None: uniform)."""
    p_trend_q: tuple[float, ...] | None = None
    """The trend model's prior over its rate diffusions (``trend.Q_DEV``), learned likewise."""
    nu: float = 4.0
    """Degrees of freedom of the readings' Student-t noise, learned from the fleet (before it:
    ``trend.NU``)."""
    nu_ll: tuple[float, ...] | None = None
    """The fleet's log likelihood of nu per residual on ``trend.NU_GRID`` (``unit_nu``)."""
    robust_trend: bool = False
    """Opt-in (decision records 0030-0032; ``robust_trend_prior``): the Student-t readings and
    the trend model beside the family. Off (the default): the family under Gaussian noise
    alone, and none of the four fields above is used."""

    def as_dict(self) -> dict:
        """Plain dict (JSON)."""
        return {
            "p_model": dict(self.p_model),
            "weights": {
                k: {"mean": list(v.mean), "sd": list(v.sd)} for k, v in self.weights.items()
            },
            "sigma": self.sigma,
            "units": self.units,
            "t_scale": self.t_scale,
            "q2_rel": self.q2_rel,
            "cv2": self.cv2,
            "sigma_m2": self.sigma_m2,
            "kappa": self.kappa,
            "p_axis": dict(self.p_axis),
            "usage_ref": dict(self.usage_ref),
        } | (self._robust_dict() if self.robust_trend else {})

    def _robust_dict(self) -> dict:
        return {
            "robust_trend": True,
            "p_trend_g": None if self.p_trend_g is None else list(self.p_trend_g),
            "p_trend_q": None if self.p_trend_q is None else list(self.p_trend_q),
            "nu": self.nu,
            "nu_ll": None if self.nu_ll is None else list(self.nu_ll),
        }


def robust_trend_prior(base: FleetPrior | None = None) -> FleetPrior:
    """``base`` (default: the vague ``FleetPrior()``) with the opt-in Student-t readings and
    trend model on (``FleetPrior.robust_trend``): the trend model's prior probability
    ``TREND_P0`` beside the family's."""
    base = base or FleetPrior()
    if base.robust_trend:
        return base
    return replace(base, robust_trend=True, p_model={**base.p_model, "trend": TREND_P0})


@dataclass
class Fit:
    """Posterior of one history: per model the grid of eta, the posterior weight of each grid
    point (summing to the model's posterior probability), means and covariances of w."""

    t_now: float
    sigma: float
    t_scale: float
    p_model: dict[str, float]
    grids: dict[str, NDArray]
    post: dict[str, NDArray]
    means: dict[str, NDArray]
    covs: dict[str, NDArray]
    log_evidence: dict[str, float]
    q2: float = 0.0  # diffusion of the path about the model [ratio^2 per unit of t]
    cv2: float = 0.0  # squared coefficient of variation of the wear per step (usage spread)
    dt: float = 1.0  # mean spacing of the observations [units of t]
    trend: TrendFit | None = None  # the trend model's cells (``trend``)
    lam: NDArray | None = None  # the readings' Student-t scales (``trend.scale_weights``)

    def log_marginal(self, p_model: dict[str, float]) -> float:
        """log p(y | axis): the models' evidences weighted by their prior ``p_model`` (how
        well this life axis explains the history, all models together)."""
        v = [z + math.log(p_model[m]) for m, z in self.log_evidence.items()
             if z > -math.inf and p_model.get(m, 0.0) > 0]  # fmt: skip
        if not v:
            return -math.inf
        mx = max(v)
        return mx + math.log(sum(math.exp(x - mx) for x in v))

    def best(self) -> str:
        """The model with the largest posterior probability."""
        return max(self.p_model, key=self.p_model.__getitem__)

    def mean_path(self, t: NDArray) -> NDArray:
        """Posterior-mean indicator at times ``t`` (model-averaged)."""
        t = np.asarray(t, float) / self.t_scale
        y = np.zeros_like(t)
        for m in MODELS:
            g = np.flatnonzero(self.post[m] > 1e-9)
            if len(g) == 0:
                continue
            phi = basis_grid(m, t, self.grids[m][g])  # (G, n, p)
            y += np.einsum("g,gnp,gp->n", self.post[m][g], phi, self.means[m][g])
        if self.trend is not None and self.p_model.get("trend", 0.0) > 1e-9:
            y += self.p_model["trend"] * self.trend.mean_path(t)
        return y


def noise_sigma(y: NDArray) -> float:
    """Robust indicator noise from second differences (blind to a linear trend, a step
    spoils only three of them): 1.4826 MAD(diff2 y) / sqrt(6); NaN below 4 points."""
    y = np.asarray(y, float)
    if len(y) < 4:
        return math.nan
    d = np.diff(y, 2)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(6.0))


def _fit_model(
    model: str, t: NDArray, y: NDArray, sigma: float, prior: ModelPrior,
    chol: NDArray | None = None, lam: NDArray | None = None,
):  # fmt: skip
    """Gaussian posteriors and log evidences of one model over its grid (batched). ``chol``:
    the Cholesky factor C of the noise covariance (then ``sigma`` is 1): the model is whitened
    by C^-1 and the evidence corrected by -log|C|."""
    grid = eta_grid(model, t)
    if len(grid) == 0:
        return grid, np.full(0, -np.inf), np.zeros((0, 0)), np.zeros((0, 0, 0))
    Phi = basis_grid(model, t, grid)  # (G, n, p)
    logdet_c = 0.0
    if chol is not None:
        c_inv = np.linalg.inv(chol)  # n x n, once per model: whitening is then a product
        Phi = c_inv @ Phi
        y = c_inv @ y
        logdet_c = float(np.log(np.diagonal(chol)).sum())
    elif lam is not None:  # noise sigma^2 / lambda_k: whitened by sqrt(lambda_k)
        sl = np.sqrt(lam)
        Phi = Phi * sl[None, :, None]
        y = y * sl
        logdet_c = -0.5 * float(np.log(lam).sum())
    m0 = np.asarray(prior.mean, float)
    v0 = np.asarray(prior.sd, float) ** 2
    s2 = sigma * sigma
    A = np.einsum("gnp,gnq->gpq", Phi, Phi) / s2 + np.diag(1.0 / v0)
    b = m0 / v0 + np.einsum("gnp,n->gp", Phi, y) / s2
    L = np.linalg.cholesky(A)
    mn = np.linalg.solve(A, b[..., None])[..., 0]
    logdet_A = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
    n = len(y)
    logev = (
        -0.5 * n * math.log(2 * math.pi * s2)
        - 0.5 * float(y @ y) / s2
        - 0.5 * float(m0 @ (m0 / v0))
        + 0.5 * np.einsum("gp,gp->g", b, mn)
        - 0.5 * float(np.log(v0).sum())
        - 0.5 * logdet_A
        - logdet_c
    )
    cov = np.linalg.inv(A)
    return grid, logev, mn, cov


def fit_history(
    t_h: Sequence[float], y: Sequence[float], prior: FleetPrior | None = None,
    z2_out: list | None = None,
) -> Fit:  # fmt: skip
    """Posterior of the models (module docstring) for one unit's history: ``t_h`` its
    life axis (flights or operating hours, increasing), ``y`` the C_Lk ratio (NaN entries are
    ignored); ``z2_out`` gets its readings' squared standardised residuals (``learn_nu``)."""
    prior = prior or FleetPrior()
    t = np.asarray(t_h, float)
    y = np.asarray(y, float)
    ok = np.isfinite(t) & np.isfinite(y)
    t, y = t[ok], y[ok]
    if len(t) == 0:
        raise ValueError("fit_history: no finite point")
    t_now = float(t[-1])
    scale = prior.t_scale if prior.t_scale else max(t_now, 1e-9)
    t = t / scale
    s_u = noise_sigma(y)
    k0 = prior.sigma_strength
    n_d = max(len(y) - 3, 0) if math.isfinite(s_u) else 0
    s2 = (k0 * prior.sigma**2 + n_d * (s_u**2 if n_d else 0.0)) / (k0 + n_d)
    sigma = max(math.sqrt(s2), 1e-4)
    lam = _student_t_scales(t, y, sigma, prior, z2_out) if prior.robust_trend else None
    fit = _posterior(t, y, sigma, prior, t_now, scale, lam=lam)
    r = y - fit.mean_path(t * scale)
    rho = _lag1(r if lam is None else np.sqrt(lam) * r)
    if rho > 0:
        fit = _posterior(t, y, sigma * math.sqrt((1 + rho) / (1 - rho)), prior, t_now, scale,
                         lam=lam)  # fmt: skip
    # path diffusion about the model: the unit's estimate shrunk toward the fleet's (weight
    # of the fleet: sigma_strength points)
    q2_u, n_q = diffusion(t * scale, y - fit.mean_path(t * scale))
    q2_f = prior.q2_rel / scale
    fit.q2 = (k0 * q2_f + n_q * q2_u) / (k0 + n_q) if n_q else q2_f
    # the wear's own spread per step, against the measurement noise of the increments (the
    # unit's, shrunk toward the fleet's; with neither, all of sigma counts as measurement
    # noise, the cautious reading)
    s2m_u, n_m = measurement_noise(_increments(t * scale, y, fit)[0])
    s2m_f = prior.sigma_m2 if prior.sigma_m2 is not None else sigma**2
    s2m = (k0 * s2m_f + n_m * s2m_u) / (k0 + n_m)
    cv2_u, n_c = usage_spread(t * scale, y, fit, s2m)
    fit.cv2 = (k0 * prior.cv2 + n_c * cv2_u) / (k0 + n_c) if n_c else prior.cv2
    fit.dt = float(np.mean(np.diff(t * scale))) if len(t) > 1 else 1.0
    if fit.cv2 > 0 and len(t) >= 6:
        fit = _refit_with_wear_spread(t, y, sigma, prior, t_now, scale, fit, s2m)
    return fit


def _student_t_scales(t, y, sigma, prior: FleetPrior, z2_out: list | None) -> NDArray:
    """The readings' Student-t scales (``robust_trend`` on, decision record 0030): by EM
    under the trend model (``trend.scale_weights``) at the fleet's nu, then at the unit's own
    (``unit_nu``: its residuals' tails, the fleet's curve as its prior)."""
    from service.prognostics.trend import scale_weights, unit_nu

    lw = prior.weights["linear"]
    m0, sd0 = np.asarray(lw.mean, float), np.asarray(lw.sd, float)
    z2: list[float] = []
    lam = scale_weights(t, y, sigma, m0, sd0, nu=prior.nu, z2_out=z2)
    if z2_out is not None:
        z2_out.extend(z2)
    nu_u = unit_nu(np.asarray(z2), prior.nu_ll, prior.sigma_strength)
    if nu_u is not None and nu_u != prior.nu:
        lam = scale_weights(t, y, sigma, m0, sd0, nu=nu_u)
    return lam


def _refit_with_wear_spread(t, y, sigma, prior, t_now, scale, fit: Fit, s2m: float) -> Fit:
    """The posterior again under the noise model the RUL's spread uses: measurement noise
    sigma_m^2 plus the wear's own spread accumulated along the path, Cov(y_i, y_j) =
    sigma_m^2 delta_ij + V_min(i,j), V_k = cv^2 sum_l<k s_l^2 / dt_l (``usage_spread``; s_l the
    first fit's path increments). A path whose wear per step varies is then not read as a
    curve (a chance acceleration over a few flights weighs as the random walk it is)."""
    tt = t * scale
    dt = np.diff(tt)
    mp = fit.mean_path(tt)
    inc = np.where(dt > 0, np.diff(mp) ** 2 / np.where(dt > 0, dt, 1.0), 0.0)
    v = np.concatenate(([0.0], np.cumsum(fit.cv2 * inc)))
    if v[-1] <= 0:
        return fit
    idx = np.arange(len(t))
    if fit.lam is None:  # Gaussian readings (``robust_trend`` off)
        cov = max(s2m, 1e-6) * np.eye(len(t)) + v[np.minimum.outer(idx, idx)]
        out = _posterior(t, y, sigma, prior, t_now, scale, np.linalg.cholesky(cov))
        out.q2, out.cv2, out.dt = fit.q2, fit.cv2, fit.dt
        return out
    # the readings' scales of the first fit (``fit_history``), not estimated again about this
    # path: its wear spread comes from the first fit's increments, a transient's jump would
    # be read as wear spread and kept
    lam = fit.lam
    rvar = max(s2m, 1e-6) / lam
    cov = np.diag(rvar) + v[np.minimum.outer(idx, idx)]
    out = _posterior(t, y, sigma, prior, t_now, scale, np.linalg.cholesky(cov), lam=lam,
                     noise=(rvar, np.diff(v, prepend=0.0)))  # fmt: skip
    out.q2, out.cv2, out.dt = fit.q2, fit.cv2, fit.dt
    return out


def _increments(t: NDArray, y: NDArray, fit: Fit) -> tuple[NDArray, NDArray]:
    """The increments y_k+1 - y_k about the posterior-mean path's, e_k = y_k+1 - y_k - s_k,
    and x_k = s_k^2 / dt_k (s_k the path's increment over dt_k), over the steps dt_k > 0."""
    dt = np.diff(t)
    ok = dt > 0
    mp = fit.mean_path(t)
    return np.diff(y)[ok] - np.diff(mp)[ok], np.diff(mp)[ok] ** 2 / dt[ok]


def measurement_noise(e: NDArray) -> tuple[float, int]:
    """Variance sigma_m^2 of the indicator's measurement noise from the increments ``e`` about
    the path (``_increments``): e_k = s_k eps_k + v_k+1 - v_k (eps the wear's own variation
    per step, v the measurement noise, both independent) has lag-one autocovariance
    -sigma_m^2 whatever the wear's variation, so sigma_m^2 = -gamma_1 (clipped to
    [0, gamma_0 / 2]); and the number of products it rests on (0: fewer than 5)."""
    e = np.asarray(e, float)
    if len(e) < 6:
        return 0.0, 0
    g0 = float(np.mean(e**2))
    g1 = float(np.mean(e[1:] * e[:-1]))
    return min(max(-g1, 0.0), 0.5 * g0), len(e) - 1


def usage_spread(t: NDArray, y: NDArray, fit: Fit, s2m: float) -> tuple[float, int]:
    """Squared coefficient of variation cv^2 of the wear per step of the life axis (units
    that fly longer or harder some flights wear more in them): E[e_k^2] = 2 sigma_m^2 +
    cv^2 s_k^2 / dt_k (``_increments``; ``s2m`` = sigma_m^2, ``measurement_noise``). cv^2 by
    the method of moments over the steps whose expected wear stands above the measurement
    noise (x_k > 2 sigma_m^2; a path without wear says nothing of its spread), floored at 0,
    and the number of steps it rests on (0: fewer than 3)."""
    if len(t) < 6:
        return 0.0, 0
    e, x = _increments(t, y, fit)
    sig = x > 2.0 * s2m
    if sig.sum() < 3 or float(np.sum(x[sig])) <= 0:
        return 0.0, 0
    return max(float(np.sum(e[sig] ** 2 - 2.0 * s2m)) / float(np.sum(x[sig])), 0.0), int(sig.sum())


def _lag1(r: NDArray, max_rho: float = 0.9) -> float:
    """Lag-one autocorrelation of residuals, in [0, max_rho] (0 below 6 points)."""
    if len(r) < 6:
        return 0.0
    r = r - r.mean()
    den = float(r @ r)
    if den <= 0:
        return 0.0
    return min(max(float(r[1:] @ r[:-1]) / den, 0.0), max_rho)


def _posterior(t, y, sigma, prior, t_now, scale, chol=None, lam=None, noise=None) -> Fit:
    """The models' posteriors at a fixed sigma and the readings' scales ``lam`` (noise
    sigma^2 / lam_k), or a noise covariance's Cholesky factor ``chol`` (``fit_history``) with
    ``noise`` = (reading variances, wear-spread variance per step) for the trend model."""
    grids, post, means, covs, logz = {}, {}, {}, {}, {}
    tot = []
    for m in MODELS:
        g, le, mn, cv = _fit_model(m, t, y, 1.0 if chol is not None else sigma,
                                   prior.weights[m], chol, lam)  # fmt: skip
        grids[m], means[m], covs[m] = g, mn, cv
        if len(g) == 0 or prior.p_model.get(m, 0.0) <= 0:
            logz[m] = -math.inf
            post[m] = np.zeros(len(g))
            continue
        mx = float(le.max())
        z = mx + math.log(float(np.exp(le - mx).mean()))  # eta uniform on the grid
        logz[m] = z
        post[m] = np.exp(le - mx) / np.exp(le - mx).sum()
        tot.append(z + math.log(prior.p_model[m]))
    tf = None
    models = ALL_MODELS if prior.robust_trend else MODELS
    if prior.robust_trend and prior.p_model.get("trend", 0.0) > 0 and len(t) >= 5 and t[0] > 0:
        from service.prognostics.trend import fit_trend

        lam1 = np.ones(len(t)) if lam is None else lam
        rvar, lvar = noise if noise is not None else (sigma * sigma / lam1, None)
        lw = prior.weights["linear"]
        tf = fit_trend(t, y, rvar, lvar, np.asarray(lw.mean, float), np.asarray(lw.sd, float),
                       prior.p_trend_g, prior.p_trend_q)  # fmt: skip
        logz["trend"] = tf.log_evidence
        tot.append(tf.log_evidence + math.log(prior.p_model["trend"]))
    elif prior.robust_trend:
        logz["trend"] = -math.inf
    mx = max(tot)
    norm = sum(math.exp(v - mx) for v in tot)
    p_model = {}
    for m in models:
        if logz[m] == -math.inf:
            p_model[m] = 0.0
        else:
            p_model[m] = math.exp(logz[m] + math.log(prior.p_model[m]) - mx) / norm
        if m in post:
            post[m] = post[m] * p_model[m]
    if tf is not None:
        grids["trend"] = np.arange(len(tf.w), dtype=float)
        post["trend"] = tf.w * p_model["trend"]
    fit = Fit(t_now, sigma, float(scale), p_model, grids, post, means, covs, logz, trend=tf)
    fit.lam = lam
    return fit


def diffusion(t: NDArray, r: NDArray, max_lag: int = 8) -> tuple[float, int]:
    """Diffusion q^2 of a random walk in the residuals ``r`` about the model at times ``t``
    (var(r_j - r_i) = 2 s^2 + q^2 (t_j - t_i): the robust variance of the index-lag-l
    differences against their mean time lag, l = 1..``max_lag``, slope by least squares,
    floored at 0) and the number of differences it rests on (0: too few points)."""
    t, r = np.asarray(t, float), np.asarray(r, float)
    n = len(r)
    if n < 6:
        return 0.0, 0
    lags = range(1, min(max_lag, n // 2) + 1)
    v, dt = [], []
    for lag in lags:
        d = r[lag:] - r[:-lag]
        v.append((1.4826 * np.median(np.abs(d - np.median(d)))) ** 2)
        dt.append(float(np.mean(t[lag:] - t[:-lag])))
    v, dt = np.asarray(v), np.asarray(dt)
    if len(v) < 2 or np.ptp(dt) <= 0:
        return 0.0, 0
    slope = float(np.polyfit(dt, v, 1)[0])
    return max(slope, 0.0), n - 1


def sample_crossing(
    fit: Fit, threshold: float, n: int = 4000, rng: np.random.Generator | None = None
) -> NDArray:
    """Draws of the life-axis time at which the indicator path reaches ``threshold`` (inf: never),
    from the model-averaged posterior of ``fit``."""
    rng = rng or np.random.default_rng(0)
    keys, probs = [], []
    for m in MODELS:
        for g, pw in enumerate(fit.post[m]):
            if pw > 1e-12:
                keys.append((m, g))
                probs.append(pw)
    p_tr = fit.p_model.get("trend", 0.0) if fit.trend is not None else 0.0
    if p_tr > 1e-12:
        keys.append(("trend", -1))
        probs.append(p_tr)
    probs = np.asarray(probs) / np.sum(probs)
    counts = rng.multinomial(n, probs)
    out = []
    for (m, g), c in zip(keys, counts, strict=True):
        if c == 0:
            continue
        if m == "trend":  # its paths simulated (``trend.TrendFit.crossing``), 3 spans ahead
            assert fit.trend is not None
            uc, sl = fit.trend.crossing(threshold, int(c), rng, reach=3.0)
            tc, sl = uc * fit.t_scale, sl / fit.t_scale
        else:
            w = rng.multivariate_normal(fit.means[m][g], fit.covs[m][g], size=int(c),
                                        method="cholesky")  # fmt: skip
            eta = float(fit.grids[m][g])
            uc = crossing(m, w, eta, threshold, fit.t_now / fit.t_scale)
            tc = uc * fit.t_scale
        if fit.q2 > 0:
            # first passage of the path plus a random walk of diffusion q2 (inverse-Gaussian
            # spread about the crossing, to first order): dt = q W(tc - t_now) / slope(tc)
            if m != "trend":  # the trend's slope at its crossing comes with it
                sl = slope(m, w, eta, uc) / fit.t_scale
            ahead = np.isfinite(tc) & (tc > fit.t_now) & (sl > 0)
            z = rng.standard_normal(len(tc))
            with np.errstate(invalid="ignore", divide="ignore"):
                d = np.sqrt(fit.q2 * np.maximum(tc - fit.t_now, 0.0)) * z / sl
            tc = np.where(ahead, np.maximum(tc + np.where(ahead, d, 0.0), fit.t_now), tc)
        if fit.cv2 > 0:
            # usage spread: the steps needed for the remaining wear vary, sd cv sqrt(n dt)
            ahead = np.isfinite(tc) & (tc > fit.t_now)
            n_left = np.where(ahead, tc - fit.t_now, 0.0)
            z = rng.standard_normal(len(tc))
            tc = np.where(ahead, np.maximum(tc + np.sqrt(fit.cv2 * n_left * fit.dt) * z,
                                            fit.t_now), tc)  # fmt: skip
        out.append(tc)
    return np.concatenate(out)


def learn_fleet_prior(
    histories: Sequence[tuple[NDArray, NDArray]],
    base: FleetPrior | None = None,
    min_points: int = 5,
) -> FleetPrior:
    """Empirical-Bayes fleet prior from the histories (t_h, y) of many units: each unit is
    fitted under ``base`` (vague default), its posterior over the models counted (expected
    counts, Dirichlet(1) smoothing: the fleet averages its units' models rather than their
    choices) and its most probable model's posterior-mean weights pooled; a model's prior mean is the pooled mean
    and its sd the pooled spread (floored at the base sd / 4, inflated x 2 for units not yet
    seen). The noise sigma is the median of the units' robust estimates."""
    base = base or FleetPrior()
    spans = [
        float(np.asarray(t, float)[np.isfinite(np.asarray(t, float))].max())
        for t, _ in histories
        if np.isfinite(np.asarray(t, float)).any()
    ]
    spans = [s for s in spans if s > 0]
    if base.t_scale is None and spans:
        base = replace(base, t_scale=float(np.median(spans)))
    counts = dict.fromkeys(ALL_MODELS if base.robust_trend else MODELS, 1.0)
    z2s: list[float] = []
    tg = tq = np.ones(0)  # Dirichlet(1) counts of the trend's cells over the units
    if base.robust_trend:
        from service.prognostics.trend import G_SPAN, Q_DEV

        tg, tq = np.ones(len(G_SPAN)), np.ones(len(Q_DEV))
    ws: dict[str, list[NDArray]] = {m: [] for m in MODELS}
    sig = []
    q2s: list[float] = []
    cv2s: list[float] = []
    s2ms: list[float] = []
    fits: list[tuple[NDArray, NDArray, Fit]] = []
    used = 0
    for t, y in histories:
        t, y = np.asarray(t, float), np.asarray(y, float)
        ok = np.isfinite(t) & np.isfinite(y)
        t, y = t[ok], y[ok]
        if len(t) < min_points:
            continue
        used += 1
        s = noise_sigma(y)
        if math.isfinite(s):
            sig.append(s)
        f = fit_history(t, y, base, z2_out=z2s)
        fits.append((t, y, f))
        s2m_u, n_m = measurement_noise(_increments(t, y, f)[0])
        if n_m:
            s2ms.append(s2m_u)
        q2_u, n_q = diffusion(t, y - f.mean_path(t))
        if n_q:
            q2s.append(q2_u * base.t_scale if base.t_scale else q2_u * float(t[-1]))
        best = f.best()
        for m, pm in f.p_model.items():  # the unit's posterior over the models, not its choice
            counts[m] += pm
        if f.trend is not None:  # the unit's evidence over the trend's cells
            wc = f.trend.w.reshape(len(tg), len(tq))
            tg += wc.sum(axis=1)
            tq += wc.sum(axis=0)
        if best in ws:
            g = int(np.argmax(f.post[best]))
            ws[best].append(f.means[best][g])
    if used == 0:
        return base
    s2m_f = float(np.median(s2ms)) if s2ms else None
    for t, y, f in fits:
        c2, n_c = usage_spread(t, y, f, s2m_f if s2m_f is not None else 0.0)
        if n_c and f.best() != "none":
            cv2s.append(c2)
    tot = sum(counts.values())
    robust = {}
    if base.robust_trend:  # the trend's cells, the readings' tails (decision records 0030-1)
        from service.prognostics.trend import learn_nu

        nu_f, nu_ll = learn_nu(np.asarray(z2s))
        robust = dict(p_trend_g=tuple(float(v) for v in tg / tg.sum()),
                      p_trend_q=tuple(float(v) for v in tq / tq.sum()), nu=nu_f, nu_ll=nu_ll,
                      robust_trend=True)  # fmt: skip
    weights = {}
    for m in MODELS:
        b = base.weights[m]
        if len(ws[m]) >= 3:
            w = np.array(ws[m])
            mean = w.mean(axis=0)
            sd = np.maximum(2.0 * w.std(axis=0, ddof=1), np.asarray(b.sd) / 4.0)
            # wear rates: keep the prior centred at or above zero and wide enough for the tail
            sd = np.maximum(sd, np.abs(mean))
            weights[m] = ModelPrior(tuple(float(v) for v in mean), tuple(float(v) for v in sd))
        else:
            weights[m] = b
    sigma = float(np.median(sig)) if sig else base.sigma
    return FleetPrior(
        p_model={m: counts[m] / tot for m in counts},
        weights=weights,
        sigma=max(sigma, 1e-3),
        sigma_strength=base.sigma_strength,
        units=used,
        t_scale=base.t_scale,
        q2_rel=float(np.median(q2s)) if q2s else base.q2_rel,
        cv2=float(np.median(cv2s)) if cv2s else base.cv2,
        sigma_m2=s2m_f if s2m_f is not None else base.sigma_m2,
        **robust,
        kappa=hindcast(histories, replace(base, units=used), min_points=2 * min_points),
    )


def hindcast(
    histories: Sequence[tuple[NDArray, NDArray]], prior: FleetPrior, min_points: int = 10
) -> float:
    """How much wider the predictions must be to hold what the fleet did next: each history
    of ``min_points`` or more is fitted on all but its last quarter (at least 2 points), its
    posterior-predictive paths (parameter draws plus sigma) are compared with the held-back
    points, and kappa^2 = mean(z^2) over the standardised errors z of every unit (the ratio
    of the errors' variance to the predicted one), floored at 1."""
    z2: list[float] = []
    rng = np.random.default_rng(0)
    for t, y in histories:
        t, y = np.asarray(t, float), np.asarray(y, float)
        ok = np.isfinite(t) & np.isfinite(y)
        t, y = t[ok], y[ok]
        n = len(t)
        if n < min_points:
            continue
        m = max(2, n // 4)
        f = fit_history(t[: n - m], y[: n - m], prior)
        paths = sample_paths(f, t[n - m :], 300, rng)
        sd = np.sqrt(paths.var(axis=0) + f.sigma**2)
        z2.extend((((y[n - m :] - paths.mean(axis=0)) / sd) ** 2).tolist())
    if len(z2) < 6:
        return 1.0
    return max(1.0, math.sqrt(float(np.mean(z2))))


def sample_paths(
    fit: Fit, t: NDArray, n: int = 500, rng: np.random.Generator | None = None
) -> NDArray:
    """Draws (n, len(t)) of the noise-free indicator path at times ``t`` from the
    model-averaged posterior (for the RUL fan plot)."""
    rng = rng or np.random.default_rng(0)
    t = np.asarray(t, float)
    keys, probs = [], []
    for m in MODELS:
        for g, pw in enumerate(fit.post[m]):
            if pw > 1e-12:
                keys.append((m, g))
                probs.append(pw)
    p_tr = fit.p_model.get("trend", 0.0) if fit.trend is not None else 0.0
    if p_tr > 1e-12:
        keys.append(("trend", -1))
        probs.append(p_tr)
    counts = rng.multinomial(n, np.asarray(probs) / np.sum(probs))
    out = []
    for (m, g), c in zip(keys, counts, strict=True):
        if c and m == "trend":
            assert fit.trend is not None
            out.append(_trend_paths(fit.trend, t / fit.t_scale, int(c), rng))
        elif c:
            w = rng.multivariate_normal(fit.means[m][g], fit.covs[m][g], size=int(c))
            out.append(w @ basis(m, t / fit.t_scale, float(fit.grids[m][g])).T)
    return np.concatenate(out)


def _trend_paths(tf: TrendFit, u: NDArray, n: int, rng: np.random.Generator) -> NDArray:
    """Draws (n, len(u)) of the trend model's level at ``u``: simulated after its last
    reading, its smoothed level (of the drawn cell) before."""
    cells, x = tf.draw_states(n, rng)
    ahead = u > tf.u[-1]
    out = np.empty((n, len(u)))
    if ahead.any():
        out[:, ahead] = tf.paths_from(cells, x, u[ahead], rng)[0]
    for j in np.flatnonzero(~ahead):
        out[:, j] = np.array([np.interp(u[j], tf.u, tf.level[c]) for c in range(len(tf.w))])[cells]
    return out
