"""Batched UKF against filterpy, the compiled kernel against the numpy path, and the
simplified process model (models.eha_reduced) against hand-computed physics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from scipy.linalg import expm

from models import eha_reduced as er
from service.monitor import Baseline
from service.monitor.ukf import BatchUKF, merwe_weights, nearest_spd, ukf_step_batch

# -- a small nonlinear problem for the filterpy comparison ---------------------------------
DT = 0.05


def fx1(x, dt=DT):
    """Damped pendulum with a drifting bias (one state vector)."""
    return np.array([x[0] + dt * x[1], x[1] - dt * (9.81 * math.sin(x[0]) + 0.3 * x[1]), x[2]])


def hx1(x):
    return np.array([math.sin(x[0]) + x[2], x[1] ** 2 * 0.1 + x[0]])


def fx_b(s):
    x0, x1, x2 = s[..., 0], s[..., 1], s[..., 2]
    return np.stack([x0 + DT * x1, x1 - DT * (9.81 * np.sin(x0) + 0.3 * x1), x2], axis=-1)


def hx_b(s):
    return np.stack([np.sin(s[..., 0]) + s[..., 2], s[..., 1] ** 2 * 0.1 + s[..., 0]], axis=-1)


def test_weights_are_filterpys():
    w = merwe_weights(7, alpha=0.5, beta=2.0, kappa=0.0)
    pts = MerweScaledSigmaPoints(7, alpha=0.5, beta=2.0, kappa=0.0)
    assert np.array_equal(w.Wm, pts.Wm) and np.array_equal(w.Wc, pts.Wc)
    assert w.Wm.sum() == pytest.approx(1.0, abs=1e-12)
    assert w.c == pytest.approx(0.25 * 7)  # n + lambda = alpha^2 (n + kappa)


def test_batch_ukf_equals_filterpy_step_for_step():
    rng = np.random.default_rng(0)
    x0s = [np.array([0.5, 0.0, 0.1]), np.array([-0.3, 0.4, -0.2])]
    Q = np.diag([1e-4, 1e-3, 1e-5])
    R = np.diag([0.02**2, 0.05**2])
    refs = []
    for x0 in x0s:
        pts = MerweScaledSigmaPoints(3, alpha=0.3, beta=2.0, kappa=0.0)
        f = UnscentedKalmanFilter(dim_x=3, dim_z=2, dt=DT, hx=hx1, fx=fx1, points=pts)
        f.x, f.P, f.Q, f.R = x0.copy(), np.diag([0.1, 0.1, 0.05]), Q, R
        refs.append(f)
    ukf = BatchUKF(3, alpha=0.3, beta=2.0, kappa=0.0)
    x = np.stack(x0s)
    P = np.stack([np.diag([0.1, 0.1, 0.05])] * 2)
    truth = np.stack(x0s) + 0.1
    for _ in range(40):
        truth = fx_b(truth)
        z = hx_b(truth) + rng.normal(0, [0.02, 0.05], size=(2, 2))
        sig_f, xp, Pp = ukf.predict(x, P, fx_b, Q)
        r = ukf.update(sig_f, xp, Pp, hx_b, z, R)
        x, P = r.x, r.P
        for b, f in enumerate(refs):
            f.predict()
            f.update(z[b])
            np.testing.assert_allclose(x[b], f.x, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(P[b], f.P, rtol=1e-8, atol=1e-14)
            # NIS = y^T S^-1 y with filterpy's y and S
            assert r.nis[b] == pytest.approx(float(f.y @ np.linalg.solve(f.S, f.y)), rel=1e-8)


def test_masked_channel_equals_dropping_it():
    ukf = BatchUKF(3, alpha=0.3)
    x = np.array([[0.4, 0.1, 0.0]])
    P = np.diag([0.1, 0.1, 0.05])[None]
    Q = np.eye(3) * 1e-4
    R = np.diag([0.02**2, 0.05**2])
    z = np.array([[0.5, 0.3]])
    sig_f, xp, Pp = ukf.predict(x, P, fx_b, Q)
    masked = ukf.update(sig_f, xp, Pp, hx_b, z, R, mask=np.array([[True, False]]))
    only = ukf.update(sig_f, xp, Pp, lambda s: hx_b(s)[..., :1], z[:, :1], R[:1, :1])
    np.testing.assert_allclose(masked.x, only.x, rtol=1e-12)
    np.testing.assert_allclose(masked.P, only.P, rtol=1e-10, atol=1e-16)
    assert masked.y[0, 1] == 0.0 and masked.dof[0] == 1
    assert masked.nis[0] == pytest.approx(only.nis[0], rel=1e-12)


def test_nearest_spd_repairs_an_indefinite_matrix():
    P = np.array([[[1.0, 2.0], [2.0, 1.0]]])  # eigenvalues 3, -1
    Q = nearest_spd(P, 1e-9)
    assert np.all(np.linalg.eigvalsh(Q) > 0)
    np.testing.assert_allclose(Q, np.swapaxes(Q, 1, 2))


# -- the simplified EHA model --------------------------------------------------------------
RP = Baseline.default("C5").reduced_params()


def test_spool_step_is_the_exact_zero_order_hold():
    w, z, h, i = RP.omega_n, RP.zeta, 3e-4, 2e-3
    A = np.array([[0.0, 1.0], [-(w**2), -2 * z * w]])
    Bv = np.array([0.0, w**2 * RP.k_sv * i])
    M = expm(np.block([[A, Bv[:, None]], [np.zeros((1, 3))]]) * h)
    x0 = np.array([1e-5, 0.01])
    ref = M[:2, :2] @ x0 + M[:2, 2]
    x1, v1 = er.spool_step(x0[0], x0[1], i, h, RP)
    assert x1 == pytest.approx(ref[0], rel=1e-10)
    assert v1 == pytest.approx(ref[1], rel=1e-9)


def test_step_reaches_the_law_equilibrium_and_is_stable_at_large_steps():
    """Constant current and load: x_S -> K_sv i and v_J -> the velocity where
    A P12(x_S, A v, P_SR) = F_R + c_v v + F_d tanh(v / v_f) (physics.md sections 1-3)."""
    i, f_r = 2e-4, 3000.0
    x = np.array([0.0, 0.0, 0.0, 0.0, f_r, 20e6, 2e-13, 0.0])
    for dt in (1e-3, 1e-2):  # 10 ms is far beyond the explicit limit 2/7400 s
        y = x.copy()
        for _ in range(int(0.5 / dt)):
            y = er.step(y, i, dt, RP, 1)
        assert np.all(np.isfinite(y))
        assert y[0] == pytest.approx(RP.k_sv * i, rel=1e-6)
        p12 = float(er.p12_state(y[0], y[3], 20e6, 2e-13, RP))
        force = RP.area * p12 - f_r - RP.c_v * y[3] - RP.f_d * math.tanh(y[3] / RP.v_f)
        assert abs(force) < 1.0  # N
        assert y[3] > 0.0  # 10 um of spool beats a 3 kN load: the jack extends


def test_compiled_model_equals_numpy_model():
    rng = np.random.default_rng(1)
    prm = er.param_vector(RP)
    for _ in range(20):
        x = np.array(
            [
                rng.normal(0, 3e-5),
                rng.normal(0, 0.01),
                rng.normal(0, 1e-3),
                rng.normal(0, 0.01),
                rng.normal(3000, 2000),
                rng.uniform(10e6, 20e6),
                rng.uniform(0, 2e-12),
                rng.normal(0, 1e-4),
            ]
        )
        i = rng.normal(0, 1e-3)
        out = np.empty(8)
        er.step_nb(x, i, 1e-3, 2, prm, out)
        np.testing.assert_allclose(out, er.step(x, i, 1e-3, RP, 2), rtol=1e-9, atol=1e-18)
        zo = np.empty(5)
        er.measure_nb(x, prm, zo)
        np.testing.assert_allclose(zo, er.measure(x, RP), rtol=1e-12)


def test_supply_scaling_of_g_pq_follows_sqrt():
    """G_PQ = sqrt(P_SR rho)/(Cd w x_SS) (physics.md section 3): at 14 MPa it is sqrt(0.7) x."""
    assert er.g_pq_at(14e6, RP) == pytest.approx(RP.g_pq * math.sqrt(0.7), rel=1e-12)
    assert er.g_pq_at(14e6, RP._replace(g_pq_exp=0.0)) == RP.g_pq


def test_compiled_kernel_equals_batch_ukf_on_the_eha_model():
    """One kernel step (with a masked channel) against BatchUKF + the numpy model."""
    n, m = 8, 5
    scale = np.array([RP.x_ss, RP.x_ss * RP.omega_n, 1e-3, 1e-2, 1e3, 1e6, 1e-13, 1e-4])
    zscale = np.array([RP.x_ss, 1e-3, 1e6, 1e6, 1e6])
    x_si = np.array([[1.1e-5, 0.0, 1e-3, 2e-3, 4000.0, 19.5e6, 3e-13, 5e-5]])
    x = x_si / scale
    P = np.diag((np.array([2e-6, 1e-3, 1e-4, 5e-3, 5e3, 2e6, 2e-13, 2e-4]) / scale) ** 2)[None]
    q = (np.array([2e-5, 2e-2, 2e-5, 5e-3, 2e3, 2e6, 1e-13, 2e-6]) / scale) ** 2
    R = np.diag((np.array([0.5e-6, 50e-6, 55e3, 55e3, 55e3]) / zscale) ** 2)
    z_si = np.array([[1.2e-5, 1.01e-3, 12.6e6, 8.3e6, 0.0]])
    mask = np.array([[True, True, True, True, False]])
    z = np.where(mask, z_si / zscale, 0.0)
    dt, i = 1e-3, 2.3e-4
    ukf = BatchUKF(n, alpha=0.5)

    def fx(s):
        ev = s * scale
        ev[..., 6] = np.maximum(ev[..., 6], 0.0)
        ev[..., 5] = np.maximum(ev[..., 5], RP.p_vap)
        out = er.step(ev, i, dt, RP, 1)
        out[..., 5:] = (s * scale)[..., 5:]
        return out / scale

    sig_f, xp, Pp = ukf.predict(x, P, fx, np.diag(q) * dt)
    ref = ukf.update(sig_f, xp, Pp, lambda s: er.measure(s * scale, RP) / zscale, z, R, mask)
    xk, Pk = x.copy(), P.copy()
    y, nis, st = np.zeros((1, m)), np.zeros(1), np.zeros(1, np.int64)
    w = ukf.w
    ukf_step_batch(
        xk, Pk, z, mask, np.array([i]), np.array([dt]), np.array([1]), q, R, scale, zscale,
        w.Wm, w.Wc, w.c, er.param_vector(RP), y, nis, st,
    )  # fmt: skip
    assert st[0] == 0
    np.testing.assert_allclose(xk, ref.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Pk, 0.5 * (ref.P + np.swapaxes(ref.P, 1, 2)), rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(y, ref.y, rtol=1e-9, atol=1e-12)
    assert nis[0] == pytest.approx(ref.nis[0], rel=1e-9)
    assert np.all(np.linalg.eigvalsh(Pk[0]) > 0)


def test_kernel_flags_a_broken_covariance():
    n = 8
    x = np.zeros((1, n))
    x[0, 5], x[0, 6] = 20.0, 2.0
    P = -np.eye(n)[None]  # not positive definite
    st = np.zeros(1, np.int64)
    w = merwe_weights(n, 0.5)
    ukf_step_batch(
        x, P, np.zeros((1, 5)), np.ones((1, 5), bool), np.zeros(1), np.array([1e-3]),
        np.array([1]), np.ones(n), np.eye(5), np.ones(n), np.ones(5), w.Wm, w.Wc, w.c,
        er.param_vector(RP), np.zeros((1, 5)), np.zeros(1), st,
    )  # fmt: skip
    assert st[0] == 2


# -- the compiled kernel: determinism, non-finite inputs, the batched model ----------------
def _eha_problem():
    """Scaled state, covariance and noise of the EHA filter (as in the test above)."""
    scale = np.array([RP.x_ss, RP.x_ss * RP.omega_n, 1e-3, 1e-2, 1e3, 1e6, 1e-13, 1e-4])
    zscale = np.array([RP.x_ss, 1e-3, 1e6, 1e6, 1e6])
    x = np.array([1.1e-5, 0.0, 1e-3, 2e-3, 4000.0, 19.5e6, 3e-13, 5e-5]) / scale
    P = np.diag((np.array([2e-6, 1e-3, 1e-4, 5e-3, 5e3, 2e6, 2e-13, 2e-4]) / scale) ** 2)
    q = (np.array([2e-5, 2e-2, 2e-5, 5e-3, 2e3, 2e6, 1e-13, 2e-6]) / scale) ** 2
    R = np.diag((np.array([0.5e-6, 50e-6, 55e3, 55e3, 55e3]) / zscale) ** 2)
    z = np.array([1.2e-5, 1.01e-3, 12.6e6, 8.3e6, 0.0]) / zscale
    return scale, zscale, x, P, q, R, z


def _kernel_step(x, P, z, mask, i, q, R, scale, zscale, alpha=0.5):
    """One ukf_step_batch call on copies; returns (x, P, y, nis, status) of the one filter."""
    w = merwe_weights(8, alpha)
    xk, Pk = x[None].copy(), P[None].copy()
    y, nis, st = np.zeros((1, 5)), np.zeros(1), np.zeros(1, np.int64)
    ukf_step_batch(
        xk, Pk, z[None], mask[None], np.array([i]), np.array([1e-3]), np.array([1]), q, R,
        scale, zscale, w.Wm, w.Wc, w.c, er.param_vector(RP), y, nis, st,
    )  # fmt: skip
    return xk[0], Pk[0], y[0], nis[0], st[0]


def test_kernel_is_deterministic_bit_for_bit():
    """Same inputs, same bits (live and replay runs compare results exactly): a 200-step run
    repeated, including a fresh workspace, gives identical states, covariances and NIS."""
    scale, zscale, x0, P0, q, R, z0 = _eha_problem()
    rng = np.random.default_rng(5)
    zs = z0 + rng.normal(0, 0.02, size=(200, 5))
    masks = rng.random((200, 5)) > 0.15
    currents = rng.normal(2e-4, 1e-4, 200)

    def run():
        x, P, out = x0.copy(), P0.copy(), []
        for j in range(200):
            x, P, y, nis, st = _kernel_step(x, P, zs[j], masks[j], currents[j], q, R, scale, zscale)
            out.append(np.concatenate([x, P.ravel(), y, [nis, st]]))
        return np.array(out)

    a, b = run(), run()
    assert np.all(np.isfinite(a))
    assert np.array_equal(a.view(np.int64), b.view(np.int64))


def test_kernel_matches_batch_ukf_over_random_states_and_masks():
    """The kernel's algebra (triangles, transposed gain, masked channels) against BatchUKF
    with the numpy model, one step from each of 25 random states and channel masks."""
    scale, zscale, x0, P0, q, R, z0 = _eha_problem()
    rng = np.random.default_rng(7)
    ukf = BatchUKF(8, alpha=0.5)
    for _ in range(25):
        x = x0 * (1 + rng.normal(0, 0.05, 8))
        A = rng.normal(size=(8, 8)) * 0.3
        P = np.sqrt(P0) @ (np.eye(8) + A @ A.T) @ np.sqrt(P0)
        mask = rng.random(5) > 0.3
        z = np.where(mask, z0 * (1 + rng.normal(0, 0.01, 5)), 0.0)
        i = rng.normal(2e-4, 1e-4)

        def fx(s, i=i):
            ev = s * scale
            ev[..., 6] = np.maximum(ev[..., 6], 0.0)
            ev[..., 5] = np.maximum(ev[..., 5], RP.p_vap)
            out = er.step(ev, i, 1e-3, RP, 1)
            out[..., 5:] = (s * scale)[..., 5:]
            return out / scale

        sig_f, xp, Pp = ukf.predict(x[None], P[None], fx, np.diag(q) * 1e-3)
        ref = ukf.update(
            sig_f, xp, Pp, lambda s: er.measure(s * scale, RP) / zscale, z[None], R, mask[None]
        )
        xk, Pk, y, nis, st = _kernel_step(x, P, z, mask, i, q, R, scale, zscale)
        assert st == 0
        np.testing.assert_allclose(xk, ref.x[0], rtol=1e-9, atol=1e-12)
        Pr = 0.5 * (ref.P[0] + ref.P[0].T)
        np.testing.assert_allclose(Pk, Pr, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(y, ref.y[0], rtol=1e-9, atol=1e-12)
        assert nis == pytest.approx(ref.nis[0], rel=1e-9)
        assert np.array_equal(Pk, Pk.T)


@pytest.mark.parametrize(
    ("what", "index", "value", "status"),
    [
        ("z", 2, np.nan, 0),  # innovation NaN: non-finite state for the caller's check
        ("z", 3, np.inf, 0),
        ("P", (3, 3), np.nan, 2),
        ("P", (5, 2), np.nan, 2),
        ("P", (1, 1), np.inf, 2),
        ("x", 3, np.nan, 2),
        ("x", 5, np.nan, 2),
    ],
)
def test_kernel_non_finite_inputs_fail_or_stay_visible(what, index, value, status):
    """No fastmath assumption hides a NaN/inf: a bad covariance or state fails the Cholesky
    factors (status 2); a bad measurement leaves a non-finite state and NIS, which the
    monitor's isfinite check turns into a re-initialisation."""
    scale, zscale, x, P, q, R, z = _eha_problem()
    x, P, z = x.copy(), P.copy(), z.copy()
    if what == "P":
        P[index] = value
        P[index[::-1]] = value
    else:
        {"x": x, "z": z}[what][index] = value
    mask = np.array([True, True, True, True, False])
    xk, Pk, y, nis, st = _kernel_step(x, P, z, mask, 2.3e-4, q, R, scale, zscale)
    assert st == status
    if status == 0:
        assert not np.all(np.isfinite(xk)) and not math.isfinite(nis)
    else:
        assert nis == 0.0


def test_kernel_masked_nan_channel_is_ignored():
    scale, zscale, x, P, q, R, z = _eha_problem()
    mask = np.array([True, True, True, True, False])
    zn = z.copy()
    zn[4] = np.nan
    a = _kernel_step(x, P, z, mask, 2.3e-4, q, R, scale, zscale)
    b = _kernel_step(x, P, zn, mask, 2.3e-4, q, R, scale, zscale)
    for u, v in zip(a, b, strict=True):
        assert np.array_equal(u, v)


def test_step_points_equals_step_core_bit_for_bit():
    """The staged K-point model step (shared friction tanh) is step_core_nb row by row."""
    rng = np.random.default_rng(3)
    for law in ("C5", "A", "C3"):
        prm = er.param_vector(RP._replace(law=law))
        for trial in range(30):
            x = np.array([
                rng.normal(0, 3e-5), rng.normal(0, 0.01), rng.normal(0, 1e-3),
                rng.normal(0, 0.01), rng.normal(3000, 2000), rng.uniform(-1e6, 22e6),
                rng.uniform(-1e-12, 2e-12), rng.normal(0, 1e-4),
            ])  # fmt: skip
            sd = np.array([1e-6, 1e-3, 1e-5, 1e-3, 100, 1e5, 1e-13, 1e-5])
            L = np.tril(rng.normal(size=(8, 8))) * sd[:, None]
            X = np.vstack([x, x + L.T, x - L.T])  # sigma points: rows 5..8, 13..16 keep v_J
            if trial % 5 == 0:
                X[0, 3], X[2, 3] = 0.0, -0.0
            i, n_sub = rng.normal(0, 1e-3), int(rng.integers(1, 4))
            h = 1e-3 / n_sub
            coef = np.empty(4)
            er.spool_coef_nb(h, prm, coef)
            out, w = np.empty_like(X), np.empty((17, 6))
            er.step_points_nb(X, i, h, n_sub, prm, coef, out, w)
            for k in range(17):
                ref = np.empty(8)
                er.step_core_nb(X[k], i, h, n_sub, prm, coef, ref)
                assert np.array_equal(out[k].view(np.int64), ref.view(np.int64))


def test_g_pq_square_root_law_matches_numpy():
    """The compiled G_PQ(P_SR) takes math.sqrt for the exponent 0.5 (within an ulp of pow)."""
    prm = er.param_vector(RP)
    for p in np.linspace(1e3, 25e6, 50):
        x = np.array([1e-5, 0.0, 0.0, 0.0, 0.0, p, 2e-13, 0.0])
        zo = np.empty(5)
        er.measure_nb(x, prm, zo)
        np.testing.assert_allclose(zo, er.measure(x, RP), rtol=1e-14)


def test_sigma_points_helper_matches_batch_ukf():
    from service.monitor.ukf import _sigma_points

    rng = np.random.default_rng(11)
    for n in (3, 8):
        A = rng.normal(size=(n, n))
        P, x = A @ A.T + 0.1 * np.eye(n), rng.normal(size=n)
        w = merwe_weights(n, 0.5)
        sig = np.empty((2 * n + 1, n))
        st = _sigma_points(x, P, w.c, np.empty((n, n)), np.empty((n, n)), sig)
        assert st == 0
        ref = BatchUKF(n, alpha=0.5).sigma_points(x[None], P[None])[0]
        np.testing.assert_allclose(sig, ref, rtol=1e-12, atol=1e-14)
    sig = np.empty((7, 3))
    assert _sigma_points(np.zeros(3), -np.eye(3), 1.0, np.empty((3, 3)), np.empty((3, 3)), sig) == 2
