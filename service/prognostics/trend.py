"""The RUL's trend model (issue 55, decision record 0031): a local-linear-trend state-space
model whose rate diffuses, beside the parametric family (``paths``), and the Student-t
observation model's scales (decision record 0030).

State x = (level l, rate b) on the scaled life axis u (``degradation``). Between two readings
du apart the rate grows by exp(g du) and diffuses (an integrated random walk of diffusion q):

    l' = l + b (exp(g du) - 1) / g + n_l,    b' = exp(g du) b + n_b,
    Cov(n_l, n_b) = q [[du^3 / 3, du^2 / 2], [du^2 / 2, du]] + diag(v_k, 0),

y_k = l_k + e_k, e_k ~ N(0, r_k). g = 0 is the local linear trend (an integrated random walk
of the rate); q -> 0 gives the family's linear (g = 0) and exponential (g > 0) models, whose
weight prior is the initial state's; g < 0 is a rate that falls (a wear-in). v_k is the
wear's own spread per step (``degradation._refit_with_wear_spread``), r_k the measurement
noise of each reading (sigma^2 / lambda_k, below). (g, q) lie on a grid of cells
(``G_SPAN`` x ``Q_DEV``, relative to the history's span), with a prior over the cells learned
from the fleet (``FleetPrior.p_trend_g``, ``p_trend_q``); the Kalman filter gives each cell's
evidence p(y | g, q) exactly (the prediction-error decomposition) and the state at the last
reading; the model's evidence is the cells' prior-weighted mean.

Student-t readings as a scale mixture (``scale_weights``): e_k ~ N(0, sigma^2 / lambda_k),
lambda_k ~ Gamma(nu / 2, nu / 2) (a t with ``NU`` degrees of freedom). The scales are the EM
fixed point under this model, the family's most flexible member: lambda_k = (nu + 1) /
(nu + E[(y_k - l_k)^2] / sigma^2), E over the Rauch-Tung-Striebel smoother of each cell and
the cells' posterior. Every model of the family and this one is then fitted with the same per-reading noise,
so their evidences stay comparable (the scales' own prior is the same for all of them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["G_SPAN", "Q_DEV", "NU", "TrendFit", "fit_trend", "scale_weights", "cell_grid"]

G_SPAN = np.array([0.0, 1.0, 2.0, 3.0, 4.5, 6.0])
"""Rate growth g times the history's span u_now: the rate grows exp(g u_now) over it."""
Q_DEV = np.array([0.005, 0.03, 0.15, 0.6, 2.5])
"""Rate diffusion as the level's sd over the fleet's typical span (u = 1): q = 3 dev^2."""
NU = 4.0
"""Degrees of freedom of the Student-t reading noise without a fleet (``learn_nu``)."""
NU_GRID = np.array([2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 64.0, 128.0])
"""The degrees of freedom ``learn_nu`` chooses among (128: nearly Gaussian)."""


def cell_grid(u_now: float) -> tuple[NDArray, NDArray]:
    """(g, q) of every cell (``G_SPAN`` x ``Q_DEV``, g major) for a history spanning u_now:
    g relative to the history's own span (as the exponential's grid), q to the fleet's
    (u = 1), so that a short history is not given a diffusion that fills the horizon."""
    un = max(float(u_now), 1e-9)
    g = np.repeat(G_SPAN / un, len(Q_DEV))
    q = np.tile(3.0 * Q_DEV**2, len(G_SPAN))
    return g, q


@njit(cache=True)
def _transition(g, q, du, v):  # pragma: no cover - compiled
    e = math.exp(g * du)
    phi = du if abs(g * du) < 1e-8 else (e - 1.0) / g
    q00 = q * du**3 / 3.0 + v
    q01 = q * du * du / 2.0
    q11 = q * du
    return phi, e, q00, q01, q11


@njit(cache=True)
def _kalman(u, y, rvar, lvar, m0, p0, gs, qs, smooth):  # pragma: no cover - compiled
    """Per cell c (gs[c], qs[c]): the log evidence, the filtered state and covariance at the
    last reading, and (``smooth``) the smoothed level and its variance at every reading."""
    n, nc = len(u), len(gs)
    logev = np.zeros(nc)
    m_end = np.zeros((nc, 2))
    p_end = np.zeros((nc, 3))
    lev = np.zeros((nc, n))
    lvr = np.zeros((nc, n))
    inn = np.zeros((nc, n))
    mp = np.zeros((n, 2))
    pp = np.zeros((n, 3))
    mf = np.zeros((n, 2))
    pf = np.zeros((n, 3))
    fs = np.zeros((n, 2))
    for c in range(nc):
        g, q = gs[c], qs[c]
        a, b = m0[0], m0[1]
        s00, s01, s11 = p0[0], p0[1], p0[2]
        prev = 0.0
        for k in range(n):
            du = max(u[k] - prev, 0.0)
            prev = u[k]
            phi, e, q00, q01, q11 = _transition(g, q, du, lvar[k])
            a, b = a + phi * b, e * b
            t00 = s00 + 2.0 * phi * s01 + phi * phi * s11 + q00
            t01 = e * (s01 + phi * s11) + q01
            t11 = e * e * s11 + q11
            s00, s01, s11 = t00, t01, t11
            mp[k, 0], mp[k, 1] = a, b
            pp[k, 0], pp[k, 1], pp[k, 2] = s00, s01, s11
            fs[k, 0], fs[k, 1] = phi, e
            sv = s00 + rvar[k]
            r = y[k] - a
            logev[c] += -0.5 * (math.log(2.0 * math.pi * sv) + r * r / sv)
            inn[c, k] = r * r / sv
            k0, k1 = s00 / sv, s01 / sv
            a, b = a + k0 * r, b + k1 * r
            s00, s01, s11 = s00 - k0 * k0 * sv, s01 - k0 * k1 * sv, s11 - k1 * k1 * sv
            mf[k, 0], mf[k, 1] = a, b
            pf[k, 0], pf[k, 1], pf[k, 2] = s00, s01, s11
        m_end[c, 0], m_end[c, 1] = a, b
        p_end[c, 0], p_end[c, 1], p_end[c, 2] = s00, s01, s11
        if not smooth:
            continue
        sa, sb = a, b
        z00, z01, z11 = s00, s01, s11
        lev[c, n - 1], lvr[c, n - 1] = sa, z00
        for k in range(n - 2, -1, -1):
            phi, e = fs[k + 1, 0], fs[k + 1, 1]
            # C = Pf F' Pp^-1 (2 x 2), F = [[1, phi], [0, e]]
            f00, f01, f11 = pf[k, 0], pf[k, 1], pf[k, 2]
            c00 = f00 + phi * f01
            c01 = e * f01
            c10 = f01 + phi * f11
            c11 = e * f11
            p00, p01, p11 = pp[k + 1, 0], pp[k + 1, 1], pp[k + 1, 2]
            det = p00 * p11 - p01 * p01
            if det <= 1e-300:
                lev[c, k], lvr[c, k] = mf[k, 0], f00
                continue
            i00, i01, i11 = p11 / det, -p01 / det, p00 / det
            g00 = c00 * i00 + c01 * i01
            g01 = c00 * i01 + c01 * i11
            g10 = c10 * i00 + c11 * i01
            g11 = c10 * i01 + c11 * i11
            da, db = sa - mp[k + 1, 0], sb - mp[k + 1, 1]
            sa = mf[k, 0] + g00 * da + g01 * db
            sb = mf[k, 1] + g10 * da + g11 * db
            d00, d01, d11 = z00 - p00, z01 - p01, z11 - p11
            # P_s = Pf + G (Ps' - Pp) G'
            h00 = g00 * d00 + g01 * d01
            h01 = g00 * d01 + g01 * d11
            h10 = g10 * d00 + g11 * d01
            h11 = g10 * d01 + g11 * d11
            z00 = f00 + h00 * g00 + h01 * g01
            z01 = f01 + h00 * g10 + h01 * g11
            z11 = f11 + h10 * g10 + h11 * g11
            lev[c, k], lvr[c, k] = sa, z00
    return logev, m_end, p_end, lev, lvr, inn


@dataclass
class TrendFit:
    """The trend model's posterior on one history (scaled axis u): per cell its g, q,
    posterior weight within the model ``w`` (sums to 1), state mean and covariance at the last
    reading, and the smoothed level at the readings; the model's log evidence."""

    u: NDArray
    g: NDArray
    q: NDArray
    w: NDArray
    m_end: NDArray
    p_end: NDArray  # (cells, 3): P00, P01, P11
    level: NDArray  # (cells, n)
    log_evidence: float

    def mean_path(self, u: NDArray) -> NDArray:
        """Posterior-mean level at ``u``: the smoothed level within the history (interpolated),
        the forecast mean beyond its last reading."""
        u = np.asarray(u, float)
        out = np.zeros_like(u)
        un = float(self.u[-1])
        for c in np.flatnonzero(self.w > 1e-9):
            inside = np.interp(u, self.u, self.level[c])
            s = np.maximum(u - un, 0.0)
            g = self.g[c]
            phi = s if abs(g) < 1e-12 else np.expm1(g * s) / g
            ahead = self.m_end[c, 0] + self.m_end[c, 1] * phi
            out += self.w[c] * np.where(u > un, ahead, inside)
        return out

    def draw_states(self, n: int, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
        """n draws of (cell index, state (l, b)) at the last reading."""
        cells = rng.choice(len(self.w), size=n, p=self.w / self.w.sum())
        m = self.m_end[cells]
        p = self.p_end[cells]
        l0 = np.sqrt(np.maximum(p[:, 0], 0.0))
        c1 = np.where(l0 > 0, p[:, 1] / np.where(l0 > 0, l0, 1.0), 0.0)
        l1 = np.sqrt(np.maximum(p[:, 2] - c1 * c1, 0.0))
        z = rng.standard_normal((n, 2))
        x = np.stack([m[:, 0] + l0 * z[:, 0], m[:, 1] + c1 * z[:, 0] + l1 * z[:, 1]], axis=1)
        return cells, x

    def crossing(self, thr: float, n: int, rng: np.random.Generator, reach: float):
        """Draws of the crossing time of ``thr`` on u (inf: none) and the rate there: the paths
        simulated over ``reach`` beyond the last reading (at most 200 steps), then each draw's
        last state extrapolated without diffusion (the exponential or linear crossing)."""
        un = float(self.u[-1])
        du = max(float(np.mean(np.diff(self.u))) if len(self.u) > 1 else reach / 50, reach / 200)
        ua = un + du * np.arange(1, int(math.ceil(reach / du)) + 1)
        cells, x = self.draw_states(n, rng)
        lv, rt = self.paths_from(cells, x, ua, rng)
        tc = np.full(n, np.inf)
        sl = np.zeros(n)
        now = x[:, 0] >= thr
        tc[now], sl[now] = un, np.maximum(x[now, 1], 0.0)
        above = lv >= thr
        hit = above.any(axis=1) & ~now
        j = np.argmax(above, axis=1)
        idx = np.flatnonzero(hit)
        if len(idx):
            jj = j[idx]
            l1 = lv[idx, jj]
            l0 = np.where(jj > 0, lv[idx, np.maximum(jj - 1, 0)], x[idx, 0])
            u0 = np.where(jj > 0, ua[np.maximum(jj - 1, 0)], un)
            f = np.where(l1 > l0, (thr - l0) / np.where(l1 > l0, l1 - l0, 1.0), 1.0)
            tc[idx] = u0 + f * (ua[jj] - u0)
            sl[idx] = rt[idx, jj]
        rest = np.flatnonzero(~hit & ~now)
        if len(rest):  # beyond the simulated reach: the last state's noise-free path
            a, b, g = lv[rest, -1], rt[rest, -1], self.g[cells[rest]]
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                lin = np.where(b > 0, (thr - a) / b, np.inf)
                arg = 1.0 + g * (thr - a) / b
                ex = np.where((b > 0) & (arg > 0), np.log(arg) / np.where(g != 0, g, 1.0), np.inf)
                s = np.where(np.abs(g) < 1e-12, lin, ex)
                s = np.where(np.isfinite(s) & (s >= 0), s, np.inf)
                tc[rest] = ua[-1] + s
                sl[rest] = np.where(np.isfinite(s), b * np.exp(np.where(np.isfinite(s), g * s, 0)),
                                    0.0)  # fmt: skip
        return tc, sl

    def paths_from(self, cells: NDArray, x: NDArray, ua: NDArray, rng: np.random.Generator):
        """From draws (``draw_states``) of the cell and the state at the last reading, the
        level and the rate at ``ua`` (increasing, after it): ((n, len), (n, len)). A leak
        does not heal: the forecast's rate is floored at zero (a draw whose rate diffuses
        below it stays level until the diffusion lifts it)."""
        n = len(cells)
        g, q = self.g[cells], self.q[cells]
        lv, rt = np.empty((n, len(ua))), np.empty((n, len(ua)))
        a, b = x[:, 0].copy(), x[:, 1].copy()
        prev = float(self.u[-1])
        for j, uj in enumerate(np.asarray(ua, float)):
            du = max(uj - prev, 0.0)
            prev = uj
            gd = g * du
            phi = np.where(np.abs(gd) < 1e-8, du, np.expm1(gd) / np.where(g != 0, g, 1.0))
            z0, z1 = rng.standard_normal(n), rng.standard_normal(n)
            s11 = np.sqrt(q * du)
            s01 = q * du * du / 2.0 / np.where(s11 > 0, s11, 1.0)
            s00 = np.sqrt(np.maximum(q * du**3 / 3.0 - s01 * s01, 0.0))
            b0 = np.maximum(b, 0.0)
            a = a + phi * b0 + s01 * z1 + s00 * z0
            b = np.maximum(np.exp(gd) * b0 + s11 * z1, 0.0)
            lv[:, j], rt[:, j] = a, b
        return lv, rt


def fit_trend(
    u: NDArray,
    y: NDArray,
    rvar: NDArray,
    lvar: NDArray | None,
    m0: NDArray,
    sd0: NDArray,
    p_g: NDArray | None = None,
    p_q: NDArray | None = None,
    smooth: bool = True,
) -> TrendFit:
    """The trend model's posterior (module docstring) on readings ``y`` at scaled times ``u``
    (increasing, > 0), reading variances ``rvar``, wear-spread variances per step ``lvar``
    (None: 0), initial state prior N(m0, diag(sd0^2)) at u = 0, and the cells' prior
    p(g) p(q) (None: uniform)."""
    u = np.ascontiguousarray(u, float)
    y = np.ascontiguousarray(y, float)
    g, q = cell_grid(float(u[-1]))
    pg = np.full(len(G_SPAN), 1.0 / len(G_SPAN)) if p_g is None else np.asarray(p_g, float)
    pq = np.full(len(Q_DEV), 1.0 / len(Q_DEV)) if p_q is None else np.asarray(p_q, float)
    prior = np.outer(pg / pg.sum(), pq / pq.sum()).ravel()
    lv = np.zeros(len(u)) if lvar is None else np.ascontiguousarray(lvar, float)
    p0 = np.array([sd0[0] ** 2, 0.0, sd0[1] ** 2])
    le, m_end, p_end, lev, _, _ = _kalman(u, y, np.ascontiguousarray(rvar, float), lv,
                                       np.asarray(m0, float), p0, g, q, smooth)  # fmt: skip
    z = le + np.log(np.maximum(prior, 1e-300))
    mx = float(z.max())
    w = np.exp(z - mx)
    tot = float(w.sum())
    return TrendFit(u, g, q, w / tot, m_end, p_end, lev, mx + math.log(tot))


def scale_weights(
    u: NDArray,
    y: NDArray,
    sigma: float,
    m0: NDArray,
    sd0: NDArray,
    iters: int = 4,
    lvar: NDArray | None = None,
    nu: float = NU,
    z2_out: list | None = None,
) -> NDArray:
    """The Student-t readings' scales lambda_k (module docstring): the EM fixed point under
    the trend model's most probable cell (its smoothed levels and their variances), of the
    larger objective from two starts (below); ``sigma`` the readings' noise scale, ``lvar``
    the wear spread per step (None: 0), ``nu`` the degrees of freedom; ``z2_out`` (a list)
    gets the squared standardised residuals E[(y_k - l_k)^2] / sigma^2 of the fixed point
    (``learn_nu``)."""
    u = np.ascontiguousarray(u, float)
    y = np.ascontiguousarray(y, float)
    s2 = sigma * sigma
    lam = np.ones(len(y))
    if len(y) < 5:
        return lam
    g, q = cell_grid(float(u[-1]))
    p0 = np.array([sd0[0] ** 2, 0.0, sd0[1] ** 2])
    lv = np.zeros(len(u)) if lvar is None else np.ascontiguousarray(lvar, float)
    m0 = np.asarray(m0, float)

    def em(lam):
        for _ in range(iters):
            le, _, _, lev, lvr, inn = _kalman(u, y, s2 / lam, lv, m0, p0, g, q, True)
            c = int(np.argmax(le))
            r2 = (y - lev[c]) ** 2 + lvr[c]
            lam = (nu + 1.0) / (nu + r2 / s2)
        le = _kalman(u, y, s2 / lam, lv, m0, p0, g, q, False)[0]
        # the EM's objective: the evidence at the scales times their Gamma(nu/2, nu/2) prior
        obj = float(le.max()) + float(np.sum((nu / 2 - 1) * np.log(lam) - nu / 2 * lam))
        return lam, r2, obj, inn[c]

    # two starts, the EM's fixed point of the larger objective: every reading trusted
    # (lambda = 1), and each reading judged by what the readings before it predicted (its
    # filter innovation): a jump the last readings cannot yet confirm or refute is then
    # either followed or discounted, whichever the evidence prefers
    lam_a, r2_a, obj_a, inn = em(np.ones(len(y)))
    lam_b, r2_b, obj_b, _ = em((nu + 1.0) / (nu + inn))
    lam, r2 = (lam_a, r2_a) if obj_a >= obj_b else (lam_b, r2_b)
    if z2_out is not None:
        z2_out.extend((r2 / s2).tolist())
    return lam


def nu_loglik(z2: NDArray) -> NDArray:
    """sum_k log t_nu(z_k) at each nu of ``NU_GRID`` for squared standardised residuals
    ``z2`` (``scale_weights``)."""
    from scipy.special import gammaln

    z2 = np.asarray(z2, float)
    z2 = z2[np.isfinite(z2)]
    nu = NU_GRID[:, None]
    return (gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * np.log(nu * math.pi)
            - (nu + 1) / 2 * np.log1p(z2[None, :] / nu)).sum(axis=1)  # fmt: skip


def learn_nu(z2: NDArray) -> tuple[float, tuple[float, ...] | None]:
    """The fleet's degrees of freedom of the readings' noise by maximum likelihood on its
    squared standardised residuals ``z2`` (argmax of ``nu_loglik`` over ``NU_GRID``; Lange,
    Little and Taylor 1989), and the log likelihood per residual on the grid (a unit's prior
    over nu, ``unit_nu``); ``NU`` and None with fewer than 20 residuals."""
    z2 = np.asarray(z2, float)
    z2 = z2[np.isfinite(z2)]
    if len(z2) < 20:
        return NU, None
    ll = nu_loglik(z2)
    return float(NU_GRID[int(np.argmax(ll))]), tuple(float(v) for v in ll / len(z2))


def unit_nu(z2: NDArray, fleet_ll: tuple[float, ...] | None, strength: float) -> float | None:
    """A unit's degrees of freedom: argmax over ``NU_GRID`` of its own residuals' log
    likelihood plus the fleet's per residual (``learn_nu``) times ``strength`` pseudo-readings
    (a unit whose leak read high for one flight has heavier tails than its fleet's);
    None without a fleet curve."""
    if fleet_ll is None:
        return None
    ll = nu_loglik(z2) + strength * np.asarray(fleet_ll, float)
    return float(NU_GRID[int(np.argmax(ll))])
