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

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from models.eha_reduced import MEAS_NAMES, N_STATES, measure_nb, spool_coef_nb, step_points_nb
from models.eha_reduced_wh import N_STATES as N_STATES_WH
from models.eha_reduced_wh import measure_nb as measure_wh_nb
from models.eha_reduced_wh import step_points_nb as step_points_wh_nb
from service.compat.numba import borrowed_all

__all__ = [
    "SigmaWeights",
    "merwe_weights",
    "BatchUKF",
    "UpdateResult",
    "nearest_spd",
    "ukf_step_batch",
    "ukf_one",
    "ukf_one_wh",
    "process_covariance",
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
    """Weights of filterpy's ``MerweScaledSigmaPoints(n, alpha, beta, kappa)``, by its own
    formulas in its own order (bit for bit, ``tests/test_ukf.py``; filterpy imports scipy,
    a second of start-up, so it is not imported here)."""
    lam = alpha**2 * (n + kappa) - n
    c = 0.5 / (n + lam)
    Wc = np.full(2 * n + 1, c)
    Wm = np.full(2 * n + 1, c)
    Wc[0] = lam / (n + lam) + (1 - alpha**2 + beta)
    Wm[0] = lam / (n + lam)
    return SigmaWeights(n=n, Wm=Wm, Wc=Wc, c=n + lam)


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
# The model is models.eha_reduced (step_points_nb / measure_nb), so the sizes are the model's:
# n = 8 states, m = 5 channels, K = 17 sigma points. tests/test_ukf.py holds this kernel to
# BatchUKF with the numpy model, and BatchUKF to filterpy.
#
# Layout for speed:
# * the sizes are compile-time constants (_N, _M): the short loops are unrolled instead of
#   running the generic loop set-up hundreds of times per step;
# * sums over the sigma points keep the order k = 0, 1, ... and the products (Wc[k] d_r) d_s
#   of the plain formulas, on deviations D[k] = sig_f[k] - mean, Dw[k] = Wc[k] D[k] computed
#   once; covariances are computed on one triangle and mirrored; the loop over k is the
#   outer one, so the sums of all the elements advance together (independent additions
#   instead of one chain per element; the same order, the same bits);
# * scaling to and from filter units multiplies by reciprocals computed once per step, and
#   the parameter states the model copies through are not scaled back and forth;
# * the Cholesky factor is kept as U = L^T (its rows are the columns of L, i.e. the
#   sigma-point offsets); the gain is solved for all n rows at once on the transposed
#   cross-covariance C = Pxz^T (m, n);
# * the 17 model steps run in stages over the points (models.eha_reduced.step_points_nb);
# * no atomic reference counting (``service.compat.numba.borrowed_all``).
# No fastmath: every operation is the plain IEEE one written here (no reassociation, no FMA
# contraction), so the step is bitwise the same in every caller; NaN fails the "s > 0" test
# of the Cholesky factors (status 2).
_N = N_STATES
_N_WH = N_STATES_WH  # the WH process model (ukf_one_wh)
_M = len(MEAS_NAMES)
_KERNEL = {"cache": True, "error_model": "numpy", "boundscheck": False}


@njit(**_KERNEL)
def _chol_upper(P, c, jit, U, n):
    """U upper triangular with U^T U = c P + jit I (P (n, n) read from its lower triangle),
    strictly lower part zeroed; row k of U is column k of the lower factor L = U^T. False
    when the matrix is not positive definite (or not finite)."""
    ok = True
    for k in range(n):
        s = c * P[k, k] + jit
        for i in range(k):
            s -= U[i, k] * U[i, k]
        if not (s > 0.0):
            ok = False
            break
        d = math.sqrt(s)
        U[k, k] = d
        for r in range(k + 1, n):
            t = c * P[r, k]
            for i in range(k):
                t -= U[i, r] * U[i, k]
            U[k, r] = t / d
        for r in range(k):
            U[k, r] = 0.0
    return ok


@njit(**_KERNEL)
def _sigma_points_n(x, P, c, L, sig, n):
    """``_sigma_points`` for n states."""
    st = 0
    if not _chol_upper(P, c, 0.0, L, n):
        st = 1 if _chol_upper(P, c, c * 1e-9, L, n) else 2
    if st != 2:
        for r in range(n):
            sig[0, r] = x[r]
        for k in range(n):
            for r in range(n):
                sig[1 + k, r] = x[r] + L[k, r]
            for r in range(n):
                sig[1 + n + k, r] = x[r] - L[k, r]
    return st


@njit(**_KERNEL)
def _sigma_points(x, P, c, A, L, sig):
    """Van der Merwe sigma points of (x, P) into sig (2n+1, n): x, x + columns of the
    Cholesky factor of c P, x - ...; jitter c 1e-9 on the diagonal if the factor fails.
    Returns 0 ok, 1 jittered, 2 failed (L: workspace, gets the factor transposed; A unused)."""
    return _sigma_points_n(x, P, c, L, sig, x.shape[0])


@njit(**_KERNEL)
def _mean(X, W, mean, K, d):
    """mean = sum_k W[k] X[k] (rows of X (K, d))."""
    for r in range(d):
        mean[r] = 0.0
    for k in range(K):  # k outermost: d independent sums, each still in the order k = 0, 1, ..
        w = W[k]
        for r in range(d):
            mean[r] += w * X[k, r]


@njit(**_KERNEL)
def _dev(X, mean, Wc, D, Dw, K, d):
    """D[k] = X[k] - mean and Dw[k] = Wc[k] D[k] (rows of (K, d))."""
    for k in range(K):
        w = Wc[k]
        for r in range(d):
            v = X[k, r] - mean[r]
            D[k, r] = v
            Dw[k, r] = w * v


@njit(**_KERNEL)
def _cov(Dw, D, P, K, d):
    """P = sum_k Dw[k] D[k]^T, symmetric: the lower triangle P[r, s] = sum_k Dw[k, r] D[k, s]
    (s <= r, the terms of the plain formula in its order), mirrored."""
    for r in range(d):
        for s_ in range(r + 1):
            P[r, s_] = 0.0
    for k in range(K):  # k outermost: the sums are independent, each in the order k = 0, 1, ..
        for r in range(d):
            a = Dw[k, r]
            for s_ in range(r + 1):
                P[r, s_] += a * D[k, s_]
    for r in range(d):
        for s_ in range(r):
            P[s_, r] = P[r, s_]


@njit(**_KERNEL)
def ukf_one(xb, Pb, zb, mb, i_in, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm, yb, ws, again):
    """One filter step in place (state xb (n,), covariance Pb (n, n), measurement zb (m,)
    with mask mb); ``ws`` is the workspace of ``workspace(n, m)``. Returns (NIS, status).
    The prediction before the process noise is kept in ``ws``; ``again`` True redoes the
    last step from it with process noise ``q`` (its prediction, the propagated sigma points'
    mean and covariance, with q dt added, then the update; xb, Pb are overwritten, their
    values unused): the same bits as a step from that step's prior with ``q``, without
    propagating the sigma points again. ``again`` is an argument, not a compile-time
    constant: one compiled step serves both uses."""
    if xb.shape[0] != _N or zb.shape[0] != _M:
        raise ValueError("ukf_one: the model has 8 states and 5 measurement channels")
    return _ukf_core(
        xb, Pb, zb, mb, i_in, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm, yb, ws, _N, False,
        again,
    )  # fmt: skip


@njit(**_KERNEL)
def ukf_one_wh(xb, Pb, zb, mb, i_in, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm, yb, ws, again):
    """``ukf_one`` on the WH process model (``models.eha_reduced_wh``: 10 states, 21 sigma
    points; prm from its ``param_vector``)."""
    if xb.shape[0] != _N_WH or zb.shape[0] != _M:
        raise ValueError("ukf_one_wh: the model has 10 states and 5 measurement channels")
    return _ukf_core(
        xb, Pb, zb, mb, i_in, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm, yb, ws, _N_WH,
        True, again,
    )  # fmt: skip


@njit(**_KERNEL, inline="always")
def _ukf_core(
    xb, Pb, zb, mb, i_in, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm, yb, ws, n, wh, again
):  # fmt: skip
    """The step of ``ukf_one`` for n states (a constant of each caller): the C-type model
    (``models.eha_reduced``, wh False) or WH (``models.eha_reduced_wh``, wh True: its plant
    states are 0..3 and the chamber states 8..9; the parameter states 4..7 are copied
    through by both models). ``again``: redo the last step from the prediction kept in ``ws``."""
    m = _M
    # every array through borrowed_all: no atomic reference counting in the step
    xb, Pb, zb, mb, yb, q, R, scale, zscale, Wm, Wc, prm = borrowed_all(
        (xb, Pb, zb, mb, yb, q, R, scale, zscale, Wm, Wc, prm)
    )
    L, sig, sig_f, zs, xs, zo, xm, zm, S, LS, C, G, D, Dw, Dz, Dzw, yv, coef, W6, xm0, pc0 = (
        borrowed_all(ws)
    )
    K = 2 * n + 1
    nis = 0.0
    if again:  # the kept prediction: its status, mean and covariance before Q
        st = int(xm0[n])
        if st != 2:
            for r in range(n):
                xm[r] = xm0[r]
                for s_ in range(n):
                    Pb[r, s_] = pc0[r, s_]
    else:
        st = _sigma_points_n(xb, Pb, c, L, sig, n)
        xm0[n] = st
    if st != 2 and not again:
        # propagate through the model (SI units)
        h = dt / n_sub
        spool_coef_nb(h, prm, coef)
        for k in range(K):
            for r in range(n):
                D[k, r] = sig[k, r] * scale[r]
        if wh:
            step_points_wh_nb(D, i_in, h, n_sub, prm, coef, Dw, W6)
        else:
            step_points_nb(D, i_in, h, n_sub, prm, coef, Dw, W6)  # D, Dw: scratch here
        # back to filter units; the parameter states (4..7), which the model copies through,
        # are taken from the points themselves (exact: no (x scale) / scale round trip)
        for r in range(4):
            xs[r] = 1.0 / scale[r]
        if wh:
            for r in range(_N, n):  # WH chamber states
                xs[r] = 1.0 / scale[r]
        for k in range(K):
            for r in range(4):
                sig_f[k, r] = Dw[k, r] * xs[r]
            if wh:
                for r in range(4, _N):
                    sig_f[k, r] = sig[k, r]
                for r in range(_N, n):
                    sig_f[k, r] = Dw[k, r] * xs[r]
            else:
                for r in range(4, n):
                    sig_f[k, r] = sig[k, r]
        # unscented transform: P = sum_k Wc[k] D[k] D[k]^T + Q
        _mean(sig_f, Wm, xm, K, n)
        _dev(sig_f, xm, Wc, D, Dw, K, n)
        _cov(Dw, D, Pb, K, n)
        for r in range(n):  # kept for a step again
            xm0[r] = xm[r]
            for s_ in range(n):
                pc0[r, s_] = Pb[r, s_]
    if st != 2:
        if wh:  # q[8], q[9]: the chambers' differential and common modes (p~1 -+ p~2)/sqrt 2
            for r in range(_N):
                Pb[r, r] += q[r] * dt
            v, cv = 0.5 * (q[_N] + q[_N + 1]) * dt, 0.5 * (q[_N + 1] - q[_N]) * dt
            Pb[_N, _N] += v
            Pb[_N + 1, _N + 1] += v
            Pb[_N, _N + 1] += cv
            Pb[_N + 1, _N] += cv
        else:
            for r in range(n):
                Pb[r, r] += q[r] * dt
        # redraw the sigma points from the prior (as filterpy's predict does)
        st = max(st, _sigma_points_n(xm, Pb, c, L, sig_f, n))
    if st != 2:
        for r in range(m):
            zm[r] = 1.0 / zscale[r]  # zm: the reciprocal scales here, the mean below
        for k in range(K):
            for r in range(n):
                xs[r] = sig_f[k, r] * scale[r]
            if wh:
                measure_wh_nb(xs, prm, zo)
            else:
                measure_nb(xs, prm, zo)
            for r in range(m):
                zs[k, r] = zo[r] * zm[r]
        _mean(zs, Wm, zm, K, m)
        _dev(zs, zm, Wc, Dz, Dzw, K, m)
        _cov(Dzw, Dz, S, K, m)
        for r in range(m):
            for s_ in range(r + 1):
                v = S[r, s_] + R[r, s_]
                S[r, s_] = v
                S[s_, r] = v
        # C = Pxz^T (m, n) about the prior mean; the centre point is xm itself (D[0] = 0,
        # a zero term, left out)
        _dev(sig_f, xm, Wc, D, Dw, K, n)
        for s_ in range(m):
            for r in range(n):
                C[s_, r] = 0.0
        for k in range(1, K):
            for s_ in range(m):
                a = Dz[k, s_]
                for r in range(n):
                    C[s_, r] += Dw[k, r] * a
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
                    C[r, s_] = 0.0
        if not _chol_upper(S, 1.0, 0.0, LS, m):
            st = 2
    if st != 2:
        # S [K^T | S^-1 y] = [C | y] by forward and back substitution with LS = U (U^T U = S),
        # all n rows of the gain and the NIS solve at once; G[:, n] holds S^-1 y
        for i in range(m):
            for r in range(n):
                G[i, r] = C[i, r]
            G[i, n] = yv[i]
            for k in range(i):
                u = LS[k, i]
                for r in range(n + 1):
                    G[i, r] -= u * G[k, r]
            d = LS[i, i]
            for r in range(n + 1):
                G[i, r] /= d
        for i in range(m - 1, -1, -1):
            for k in range(i + 1, m):
                u = LS[i, k]
                for r in range(n + 1):
                    G[i, r] -= u * G[k, r]
            d = LS[i, i]
            for r in range(n + 1):
                G[i, r] /= d
        for r in range(m):
            nis += yv[r] * G[r, n]
            yb[r] = yv[r]
        # x = xm + K y; P = P - K S K^T = P - K Pxz^T on the upper triangle, mirrored;
        # subnormal results flushed to zero: their arithmetic depends on the CPU's FTZ/DAZ
        # mode, which other libraries in the process may change (keeps Monitor and
        # MonitorBank bit-equal)
        for r in range(n):
            acc = 0.0
            for k in range(m):
                acc += G[k, r] * yv[k]
            v = xm[r] + acc
            xb[r] = 0.0 if abs(v) < 1e-290 else v
            for s_ in range(r, n):
                acc = 0.0
                for k in range(m):
                    acc += G[k, r] * C[k, s_]
                v = Pb[r, s_] - acc
                if abs(v) < 1e-290:
                    v = 0.0
                Pb[r, s_] = v
                Pb[s_, r] = v
    return nis, st


def process_covariance(q: NDArray, n: int) -> NDArray:
    """The process noise rate Q (n, n) [per second] that a step adds as Q dt: diag(q) for a
    C-type model; for WH (n = 10) q[8], q[9] are the chambers' differential and common
    modes (p~1 -+ p~2)/sqrt 2, so Var p~k = (q[8] + q[9])/2 and Cov = (q[9] - q[8])/2."""
    Q = np.diag(np.asarray(q, float)[:n])
    if n == _N_WH:
        d, s = Q[_N, _N], Q[_N + 1, _N + 1]
        Q[_N, _N] = Q[_N + 1, _N + 1] = 0.5 * (d + s)
        Q[_N, _N + 1] = Q[_N + 1, _N] = 0.5 * (s - d)
    return Q


@njit(cache=True)
def workspace(n, m):
    """Scratch arrays of ``ukf_one``: factor U = L^T (n, n); sigma points, propagated and
    redrawn (K, n); their measurements (K, m); model in/out (n,), (m,); means (n,), (m,);
    S and its factor (m, m); Pxz^T (m, n); gain^T | S^-1 y (m, n + 1); deviations and
    weighted deviations (K, n), (K, m); innovation (m,); spool transition (4,); model
    stage scratch (K, 6); the prediction kept for a step again: mean and status (n + 1,),
    covariance before the process noise (n, n)."""
    K = 2 * n + 1
    return (
        np.empty((n, n)), np.empty((K, n)), np.empty((K, n)), np.empty((K, m)),
        np.empty(n), np.empty(m), np.empty(n), np.empty(m),
        np.empty((m, m)), np.empty((m, m)), np.empty((m, n)), np.empty((m, n + 1)),
        np.empty((K, n)), np.empty((K, n)), np.empty((K, m)), np.empty((K, m)),
        np.empty(m), np.empty(4), np.empty((K, 6)), np.empty(n + 1), np.empty((n, n)),
    )  # fmt: skip


@njit(cache=True)
def ukf_step_batch(
    x, P, z, mask, i_in, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm, y_out, nis_out, status
):
    """Advance B filters in place. Scaled state x (B, n), P (B, n, n); measurements z (B, m)
    in scaled units with mask (B, m); inputs i_in (B,), dt (B,); process noise intensities
    q (n,) (Q = diag(q) dt); R (m, m). Writes innovations y_out (B, m), NIS nis_out (B,) and
    status (B,): 0 ok, 1 covariance repaired with jitter, 2 failed (caller re-initialises).
    n = 10 runs the WH process model (``ukf_one_wh``), else the C-type one (``ukf_one``)."""
    B, n = x.shape
    m = z.shape[1]
    ws = workspace(n, m)
    again = bool(False)  # noqa: UP018 - a run-time flag, not a literal: the monitor's compiled step
    for b in range(B):
        if n == _N_WH:  # the WH process model
            nis, st = ukf_one_wh(
                x[b], P[b], z[b], mask[b], i_in[b], dt[b], n_sub[b], q, R, scale, zscale, Wm,
                Wc, c, prm, y_out[b], ws, again,
            )  # fmt: skip
        else:
            nis, st = ukf_one(
                x[b], P[b], z[b], mask[b], i_in[b], dt[b], n_sub[b], q, R, scale, zscale, Wm, Wc,
                c, prm, y_out[b], ws, again,
            )  # fmt: skip
        nis_out[b] = nis
        status[b] = st
