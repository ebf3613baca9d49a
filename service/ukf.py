"""Batched unscented Kalman filter: many independent filters advanced in one vectorised call.

The algebra is filterpy's ``UnscentedKalmanFilter`` (additive noise, Van der Merwe scaled
sigma points, weights taken from ``filterpy.kalman.MerweScaledSigmaPoints``), written over a
leading batch axis so that every sigma point of every filter goes through the process model
in one call. ``tests/test_ukf.py`` holds it equal to filterpy step for step.

Shapes: B filters, n states, m measurement channels, K = 2 n + 1 sigma points.
``x`` (B, n), ``P`` (B, n, n), ``Q`` (B, n, n) or (n, n), ``R`` (B, m, m) or (m, m),
sigma points (B, K, n). Measurement channels can be masked per filter (missing samples):
a masked channel has zero innovation, no cross-covariance and a unit diagonal in S, so it
changes neither x nor P and adds nothing to the NIS.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints
from numpy.typing import NDArray

__all__ = ["SigmaWeights", "merwe_weights", "BatchUKF", "UpdateResult", "nearest_spd"]


@dataclass(frozen=True)
class SigmaWeights:
    """Van der Merwe scaled sigma-point weights (from filterpy) and the spread factor n + lambda."""

    n: int
    Wm: NDArray
    Wc: NDArray
    c: float  # n + lambda


def merwe_weights(
    n: int, alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0
) -> SigmaWeights:
    """Weights of filterpy's ``MerweScaledSigmaPoints(n, alpha, beta, kappa)``."""
    pts = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
    lam = alpha**2 * (n + kappa) - n
    return SigmaWeights(n=n, Wm=np.array(pts.Wm, float), Wc=np.array(pts.Wc, float), c=n + lam)


def nearest_spd(P: NDArray, jitter: float = 1e-12) -> NDArray:
    """Symmetrise and push eigenvalues up to ``jitter`` (batched repair of a broken covariance)."""
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    w, V = np.linalg.eigh(P)
    w = np.maximum(w, jitter)
    return (V * w[..., None, :]) @ np.swapaxes(V, -1, -2)


@dataclass
class UpdateResult:
    """Result of a batched measurement update."""

    x: NDArray  # (B, n) posterior
    P: NDArray  # (B, n, n) posterior
    y: NDArray  # (B, m) innovation (0 on masked channels)
    S: NDArray  # (B, m, m) innovation covariance (unit rows/cols on masked channels)
    zp: NDArray  # (B, m) predicted measurement
    nis: NDArray  # (B,) normalised innovation squared y^T S^-1 y
    dof: NDArray  # (B,) number of unmasked channels


class BatchUKF:
    """B independent additive-noise UKFs sharing the sigma-point weights (filterpy algebra)."""

    def __init__(self, n: int, alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0):
        self.w = merwe_weights(n, alpha, beta, kappa)
        self.n = n

    def sigma_points(self, x: NDArray, P: NDArray) -> NDArray:
        """Sigma points (B, 2n+1, n): x, x + rows of U, x - rows of U with U^T U = (n+lam) P.

        Raises ``numpy.linalg.LinAlgError`` when some P is not positive definite.
        """
        L = np.linalg.cholesky(self.w.c * P)  # lower; rows of U = L^T are columns of L
        Ut = np.swapaxes(L, -1, -2)
        xb = x[:, None, :]
        return np.concatenate([xb, xb + Ut, xb - Ut], axis=1)

    def unscented_transform(self, sig: NDArray, noise: NDArray | None):
        """Weighted mean (B, d) and covariance (B, d, d) (+ noise) of transformed points."""
        mean = np.einsum("k,bkd->bd", self.w.Wm, sig)
        d = sig - mean[:, None, :]
        cov = np.swapaxes(d * self.w.Wc[None, :, None], 1, 2) @ d
        if noise is not None:
            cov = cov + noise
        return mean, cov, d

    def predict(self, x: NDArray, P: NDArray, fx: Callable[[NDArray], NDArray], Q: NDArray):
        """Propagate sigma points through ``fx`` ((B, K, n) -> (B, K, n)), return
        (sigmas_f, x_prior, P_prior)."""
        sig = self.sigma_points(x, P)
        sig_f = fx(sig)
        xp, Pp, _ = self.unscented_transform(sig_f, Q)
        return sig_f, xp, Pp

    def update(
        self,
        sig_f: NDArray,
        x: NDArray,
        P: NDArray,
        hx: Callable[[NDArray], NDArray],
        z: NDArray,
        R: NDArray,
        mask: NDArray | None = None,
    ) -> UpdateResult:
        """Measurement update with the predicted sigma points (as filterpy does, no redraw)."""
        zh = hx(sig_f)  # (B, K, m)
        zp, S, dz = self.unscented_transform(zh, R)
        dx = sig_f - x[:, None, :]
        Pxz = np.swapaxes(dx * self.w.Wc[None, :, None], 1, 2) @ dz  # (B, n, m)
        y = z - zp
        m = zh.shape[-1]
        if mask is None:
            mask = np.ones(y.shape, bool)
        else:
            mask = np.asarray(mask, bool)
            y = np.where(mask, y, 0.0)
            both = mask[:, :, None] & mask[:, None, :]
            S = np.where(both, S, np.eye(m)[None])
            Pxz = np.where(mask[:, None, :], Pxz, 0.0)
        # K = Pxz S^-1 (S symmetric): solve S K^T = Pxz^T
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(Pxz, 1, 2)), 1, 2)
        xn = x + (K @ y[:, :, None])[:, :, 0]
        Pn = P - K @ S @ np.swapaxes(K, 1, 2)
        Siy = np.linalg.solve(S, y[:, :, None])[:, :, 0]
        nis = np.einsum("bm,bm->b", y, Siy)
        return UpdateResult(
            x=xn, P=Pn, y=y, S=S, zp=zp, nis=nis, dof=mask.sum(axis=1).astype(float)
        )
