"""FROZEN COPY of service/ukf.py as of commit 67172e0 (before the kernel speed-up), kept so
that bench/kernel.py can time the old and new ``ukf_one`` side by side. Do not edit; the
service does not import it.

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

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from _eha_reduced_ref import measure_nb, spool_coef_nb, step_core_nb
from filterpy.kalman import MerweScaledSigmaPoints
from numba import njit
from numpy.typing import NDArray

__all__ = [
    "SigmaWeights",
    "merwe_weights",
    "BatchUKF",
    "UpdateResult",
    "nearest_spd",
    "ukf_step_batch",
    "ukf_one",
    "workspace",
]


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
        """Propagate sigma points through ``fx`` ((B, K, n) -> (B, K, n)); return the sigma
        points redrawn from the prior (as filterpy's predict does), x_prior and P_prior."""
        sig = self.sigma_points(x, P)
        sig_f = fx(sig)
        xp, Pp, _ = self.unscented_transform(sig_f, Q)
        return self.sigma_points(xp, Pp), xp, Pp

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
        """Measurement update with the sigma points returned by ``predict`` (filterpy algebra)."""
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


# -- compiled kernel: one UKF step (predict + masked update) for each of B actuators --------
# The model is models.eha_reduced (step_nb / measure_nb). tests/test_ukf.py holds this kernel
# to BatchUKF with the numpy model, and BatchUKF to filterpy.


@njit(cache=True)
def _chol(A, L):
    """Lower Cholesky factor of A into L; False when A is not positive definite."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not (s > 0.0):
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = A[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
        for i in range(j):
            L[i, j] = 0.0
    return True


@njit(cache=True)
def _chol_solve(L, b, out):
    """Solve (L L^T) out = b."""
    n = L.shape[0]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * out[k]
        out[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s -= L[k, i] * out[k]
        out[i] = s / L[i, i]


@njit(cache=True)
def _sigma_points(x, P, c, A, L, sig):
    """Van der Merwe sigma points of (x, P) into sig (2n+1, n): x, x + columns of the
    Cholesky factor of c P, x - ...; jitter c 1e-9 on the diagonal if the factor fails.
    Returns 0 ok, 1 jittered, 2 failed (A, L: workspace)."""
    n = x.shape[0]
    st = 0
    for r in range(n):
        for s_ in range(n):
            A[r, s_] = c * P[r, s_]
    if not _chol(A, L):
        for r in range(n):
            A[r, r] += c * 1e-9
        if not _chol(A, L):
            return 2
        st = 1
    for r in range(n):
        sig[0, r] = x[r]
    for k in range(n):
        for r in range(n):
            sig[1 + k, r] = x[r] + L[r, k]
            sig[1 + n + k, r] = x[r] - L[r, k]
    return st


@njit(cache=True)
def ukf_one(xb, Pb, zb, mb, i_in, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm, yb, ws):
    """One filter step in place (state xb (n,), covariance Pb (n, n), measurement zb (m,)
    with mask mb); ``ws`` is the workspace of ``workspace(n, m)``. Returns (NIS, status)."""
    A, L, sig, sig_f, zs, xs, xo, zo, xm, zm, S, LS, Pxz, Kg, col, sol, yv, coef = ws
    n = xb.shape[0]
    m = zb.shape[0]
    K = 2 * n + 1
    st = _sigma_points(xb, Pb, c, A, L, sig)
    if st == 2:
        return 0.0, 2
    # propagate through the model (SI units)
    h = dt / n_sub
    spool_coef_nb(h, prm, coef)
    for k in range(K):
        for r in range(n):
            xs[r] = sig[k, r] * scale[r]
        step_core_nb(xs, i_in, h, n_sub, prm, coef, xo)
        for r in range(n):
            sig_f[k, r] = xo[r] / scale[r]
    # unscented transform
    for r in range(n):
        acc = 0.0
        for k in range(K):
            acc += Wm[k] * sig_f[k, r]
        xm[r] = acc
    for r in range(n):
        for s_ in range(n):
            acc = 0.0
            for k in range(K):
                acc += Wc[k] * (sig_f[k, r] - xm[r]) * (sig_f[k, s_] - xm[s_])
            Pb[r, s_] = acc
        Pb[r, r] += q[r] * dt
    # redraw the sigma points from the prior (as filterpy's predict does)
    st2 = _sigma_points(xm, Pb, c, A, L, sig_f)
    if st2 == 2:
        return 0.0, 2
    if st2 == 1:
        st = 1
    for k in range(K):
        for r in range(n):
            xs[r] = sig_f[k, r] * scale[r]
        measure_nb(xs, prm, zo)
        for r in range(m):
            zs[k, r] = zo[r] / zscale[r]
    for r in range(m):
        acc = 0.0
        for k in range(K):
            acc += Wm[k] * zs[k, r]
        zm[r] = acc
    for r in range(m):
        for s_ in range(m):
            acc = 0.0
            for k in range(K):
                acc += Wc[k] * (zs[k, r] - zm[r]) * (zs[k, s_] - zm[s_])
            S[r, s_] = acc + R[r, s_]
    for r in range(n):
        for s_ in range(m):
            acc = 0.0
            for k in range(K):
                acc += Wc[k] * (sig_f[k, r] - xm[r]) * (zs[k, s_] - zm[s_])
            Pxz[r, s_] = acc
    # masked channels: no innovation, no cross-covariance, unit diagonal
    for r in range(m):
        if mb[r]:
            yv[r] = zb[r] - zm[r]
        else:
            yv[r] = 0.0
            for s_ in range(m):
                S[r, s_] = 0.0
                S[s_, r] = 0.0
            S[r, r] = 1.0
            for s_ in range(n):
                Pxz[s_, r] = 0.0
    if not _chol(S, LS):
        return 0.0, 2
    # K = Pxz S^-1 (row by row: S k_r = Pxz[r])
    for r in range(n):
        for s_ in range(m):
            col[s_] = Pxz[r, s_]
        _chol_solve(LS, col, sol)
        for s_ in range(m):
            Kg[r, s_] = sol[s_]
    _chol_solve(LS, yv, sol)
    nis = 0.0
    for r in range(m):
        nis += yv[r] * sol[r]
    for r in range(m):
        yb[r] = yv[r]
    for r in range(n):
        acc = 0.0
        for s_ in range(m):
            acc += Kg[r, s_] * yv[s_]
        xb[r] = xm[r] + acc
    # P -= K S K^T = K Pxz^T, symmetrised
    for r in range(n):
        for s_ in range(n):
            acc = 0.0
            for k in range(m):
                acc += Kg[r, k] * Pxz[s_, k]
            A[r, s_] = Pb[r, s_] - acc
    for r in range(n):
        for s_ in range(n):
            Pb[r, s_] = 0.5 * (A[r, s_] + A[s_, r])
    # flush subnormal results to zero: their arithmetic depends on the CPU's FTZ/DAZ mode,
    # which other libraries in the process may change; keeps Monitor and MonitorBank bit-equal
    for r in range(n):
        if abs(xb[r]) < 1e-290:
            xb[r] = 0.0
        for s_ in range(n):
            if abs(Pb[r, s_]) < 1e-290:
                Pb[r, s_] = 0.0
    return nis, st


@njit(cache=True)
def workspace(n, m):
    """Scratch arrays of ``ukf_one``."""
    K = 2 * n + 1
    return (
        np.empty((n, n)), np.empty((n, n)), np.empty((K, n)), np.empty((K, n)),
        np.empty((K, m)), np.empty(n), np.empty(n), np.empty(m), np.empty(n), np.empty(m),
        np.empty((m, m)), np.empty((m, m)), np.empty((n, m)), np.empty((n, m)), np.empty(m),
        np.empty(m), np.empty(m), np.empty(4),
    )  # fmt: skip


@njit(cache=True)
def ukf_step_batch(
    x, P, z, mask, i_in, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm, y_out, nis_out, status
):
    """Advance B filters in place. Scaled state x (B, n), P (B, n, n); measurements z (B, m)
    in scaled units with mask (B, m); inputs i_in (B,), dt (B,); process noise intensities
    q (n,) (Q = diag(q) dt); R (m, m). Writes innovations y_out (B, m), NIS nis_out (B,) and
    status (B,): 0 ok, 1 covariance repaired with jitter, 2 failed (caller re-initialises)."""
    B, n = x.shape
    m = z.shape[1]
    ws = workspace(n, m)
    for b in range(B):
        nis, st = ukf_one(
            x[b], P[b], z[b], mask[b], i_in[b], dt[b], n_sub[b], q, R, scale, zscale, Wm, Wc,
            c, prm, y_out[b], ws,
        )  # fmt: skip
        nis_out[b] = nis
        status[b] = st
