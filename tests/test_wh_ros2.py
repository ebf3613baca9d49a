"""WH's chamber mode integrated in one step per 1 ms sample (models/eha_reduced_wh.py, ROS2;
docs/models.md section 7, decisions/0012): stable at both stroke ends and mid stroke, second
order against a fine-step reference, and at rest on the analytic equilibrium."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import fsolve

from models import eha_reduced_wh as erw
from service.monitor import Baseline

BASE = Baseline.default("WH")
RP = BASE.reduced_params()._replace(x_0=0.0, skew=0.0)
V0, BETA, AREA = BASE.v_c, BASE.beta, BASE.area  # 7e-5 m^3, 1.4e9 Pa, 1e-3 m^2
END = 0.048  # 48 mm of the 50 mm half stroke: the small chamber is 2.2e-5 m^3 = 0.31 V0


def _prm(rp=RP) -> np.ndarray:
    return erw.param_vector(rp, V0, BETA)


def _run(x, i, n, prm, n_sub=1) -> np.ndarray:
    """n samples of 1 ms with the compiled step: the states after each, (n, 10)."""
    out, xs = np.empty(10), np.empty((n, 10))
    for k in range(n):
        erw.step_nb(x, i, 1e-3, n_sub, prm, out)
        x = xs[k] = out
    return xs


def _open_into_small_chamber(x_j: float) -> tuple[np.ndarray, float]:
    """Spool at full stroke into the smaller chamber (chamber 1 when x_J <= 0), that chamber
    starting 19 MPa below the supply: its pressure rises into the laminar band of land 1 (or
    3), where the chamber mode is stiffest. State and current."""
    s = 1.0 if x_j <= 0 else -1.0
    p_lo, p_hi = 1.0e6, 20.0e6
    x = np.array([s * RP.x_sm, 0.0, x_j, 0.0, 0.0, 20e6, 2e-13, 0.0, 0.0, 0.0])
    x[8], x[9] = (p_lo, p_hi) if s > 0 else (p_hi, p_lo)
    return x, s * 0.02  # 1 mA past the spool's 0.5 mm stroke


def test_the_chamber_mode_at_1_ms_is_beyond_rk4_and_inside_ros2():
    """The Jacobian's eigenvalues at the stiffest point (the filling chamber's land in its
    laminar band), by hand: lambda = beta / V_k (K_o (x_SS + x_SM) / sqrt(dp_lam) + C_Lk +
    c_land): 3.2e3 1/s at V0, 1.03e4 1/s at 0.31 V0 (|lambda h| = 10). Classic RK4 in one
    step amplifies it (|R| > 1 beyond 2.785); ROS2 damps every eigenvalue (|R| < 1, and
    R(-inf) = 0)."""
    k_o = erw.k_orifice(RP)
    dp_lam = 5e-3 * RP.p_sr_rated
    for x_j, v_k in ((0.0, V0), (-END, V0 - AREA * END), (END, V0 - AREA * END)):
        x, _ = _open_into_small_chamber(x_j)
        k = 8 if x_j <= 0 else 9
        x[k] = RP.p_r + 20e6 - 0.5 * dp_lam  # the filling land inside its laminar band
        jm = erw.jacobian(x[0], x[2], 0.0, x[8], x[9], 0.0, 20e6, 2e-13, RP, BETA, V0)
        lam = np.linalg.eigvals(jm)
        by_hand = BETA / v_k * (k_o * (RP.x_ss + RP.x_sm) / math.sqrt(dp_lam) + 2e-13 + RP.c_land)
        assert np.min(lam.real) == pytest.approx(-by_hand, rel=0.02)
        z = lam * 1e-3
        rk4 = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
        assert np.max(np.abs(rk4)) > 1.0  # explicit RK4 in one step: unstable
        assert np.all(np.abs(erw.ros2_amplification(z)) < 1.0)
    assert by_hand * 1e-3 > 10.0
    assert abs(erw.ros2_amplification(-1e9)) < 1e-8
    assert erw.ros2_amplification(0.0) == 1.0


@pytest.mark.parametrize("x_j", [-END, 0.0, END])
def test_one_step_per_sample_is_stable_in_the_laminar_band(x_j):
    """The jack held (mass 1e9 kg), the spool wide open into the smaller chamber: at one step
    per 1 ms the filling chamber's pressure rises 19.5 MPa into the laminar band and settles
    there, overshooting its final value by under 0.2 % of the rise, its error shrinking window
    by window (no oscillation growth); after 30 ms it is within 2 kPa of a 100-substep RK4
    reference. One explicit RK4 step per sample instead is off by more than 20 kPa (by
    0.8 MPa at the ends)."""
    rp = RP._replace(mass=1e9)
    x, i = _open_into_small_chamber(x_j)
    k = 8 if x_j <= 0 else 9
    xs = _run(x, i, 200, _prm(rp))
    assert np.all(np.isfinite(xs))
    final = xs[-1, k]
    assert abs(final - (RP.p_r + 20e6)) < 2e5  # close to the supply (no flow out)
    assert np.max(xs[:, k]) - final < 0.002 * 19.5e6
    env = np.max(np.abs(xs[:, k] - final).reshape(20, 10), axis=1)
    assert np.all(np.diff(env) <= 1.0)  # 1 Pa of round-off
    ref, bad = x.copy(), x.copy()
    with np.errstate(all="ignore"):
        for _ in range(30):
            ref = erw.step_rk4(ref, i, 1e-3, rp, 100, V0, BETA)
            bad = erw.step_rk4(bad, i, 1e-3, rp, 1, V0, BETA)
    assert abs(xs[29, k] - ref[k]) < 2e3
    assert not abs(bad[k] - ref[k]) < 2e4


def _ringing(x_j: float) -> np.ndarray:
    """A loaded jack at rest at x_J, its chambers 6 MPa apart against 4 kN: released, the
    hydraulic mode (632 rad/s at V0) rings."""
    return np.array([0.0, 0.0, x_j, 0.0, 4000.0, 19.5e6, 3e-13, 0.0, 13.0e6, 7.0e6])


@pytest.mark.parametrize("x_j", [-END, 0.0, END])
def test_a_ringing_jack_decays_at_both_ends_and_mid_stroke(x_j):
    """0.4 s of the released jack at one step per sample: the ringing of P12 decays (its
    peak-to-peak over each 20 ms window never grows) and the state stays bounded."""
    xs = _run(_ringing(x_j), 0.0, 400, _prm())
    assert np.all(np.isfinite(xs))
    p12 = xs[:, 8] - xs[:, 9]
    span = np.ptp(p12.reshape(20, 20), axis=1)
    assert np.all(np.diff(span) <= 1e3)
    assert span[-1] < 0.05 * span[0]
    assert np.max(np.abs(xs[:, 2] - x_j)) < 5e-3


def test_one_step_agrees_with_a_fine_step_reference_to_second_order():
    """The released jack at mid stroke for 50 ms against 100-substep RK4. Hand-checked
    tolerance: at the hydraulic mode's |lambda h| = 0.63 one ROS2 step turns the ringing by
    0.0099 rad less than the exact 0.63 rad (arg R(0.63 i), ``ros2_amplification``): 0.1 rad
    per 10 ms cycle, and on the ringing's 1.2 MPa amplitude after its first half cycle
    about 120 kPa. The largest P12 error stays under 180 kPa (3 % of the initial 6 MPa) and
    the x_J error under 2 % of the jack's swing. The method converges: a quarter of the step
    divides both errors by more than 6 (first order would give 4)."""
    x0 = _ringing(0.0)
    ref = np.empty((50, 10))
    y = x0.copy()
    for k in range(50):
        y = ref[k] = erw.step_rk4(y, 0.0, 1e-3, RP, 100, V0, BETA)
    one, four = _run(x0, 0.0, 50, _prm()), _run(x0, 0.0, 50, _prm(), n_sub=4)
    e_p = [np.max(np.abs((r[:, 8] - r[:, 9]) - (ref[:, 8] - ref[:, 9]))) for r in (one, four)]
    e_x = [np.max(np.abs(r[:, 2] - ref[:, 2])) for r in (one, four)]
    phase = np.angle(erw.ros2_amplification(0.63j)) - 0.63
    assert phase == pytest.approx(-0.0099, abs=2e-4)
    assert e_p[0] < 0.03 * 6e6 and e_x[0] < 0.02 * np.ptp(ref[:, 2])
    assert e_p[0] / e_p[1] > 6.0 and e_x[0] / e_x[1] > 6.0


def test_the_steady_state_is_the_analytic_equilibrium():
    """The spool held 60 um open, a 3 kN opposing load, no stiction: the jack settles at the
    speed and chamber pressures where both chamber balances and the jack's forces vanish
    (models.md eqs. 1-5, solved by fsolve on the lands' flows), to 1e-6 of P_SR and of the
    speed; the compiled one-step run and the numpy reference agree."""
    rp = RP._replace(f_s=0.0)
    x_l, f_r, c_lk, p_sr = 60e-6, 3000.0, 2e-13, 20e6

    def eqs(u):
        v, p1, p2 = u[0] * 1e-3, u[1] * 1e6, u[2] * 1e6
        q1, q2, q3, q4 = erw.land_flows(x_l, p1, p2, p_sr, rp)
        p12 = p1 - p2
        f = rp.area * p12 - f_r - rp.c_v * v - rp.f_d * math.tanh(v / rp.v_f)
        return [
            1e6 * (q1 - q2 - c_lk * p12 - rp.area * v),
            1e6 * (q3 - q4 + c_lk * p12 + rp.area * v),
            f * 1e-3,
        ]

    sol, _, ier, msg = fsolve(eqs, [20.0, 13.0, 8.0], xtol=1e-12, full_output=True)
    assert np.max(np.abs(eqs(sol))) < 1e-9, msg  # flows within 1e-15 m^3/s, force 1e-6 N
    v_eq, p1_eq, p2_eq = sol[0] * 1e-3, sol[1] * 1e6, sol[2] * 1e6
    assert 1e-3 < v_eq < 0.1  # moving, out of the friction's band
    x = np.array([x_l, 0.0, 0.0, 0.0, f_r, p_sr, c_lk, 0.0, 10e6, 10e6])
    i = x_l / rp.k_sv
    xs = _run(x, i, 1000, _prm(rp))
    assert xs[-1, 3] == pytest.approx(v_eq, rel=1e-6)
    assert abs(xs[-1, 8] - p1_eq) < 1e-6 * p_sr and abs(xs[-1, 9] - p2_eq) < 1e-6 * p_sr
    np.testing.assert_allclose(
        erw.step(xs[-2], i, 1e-3, rp, 1, V0, BETA), xs[-1], rtol=1e-11, atol=1e-12
    )


def test_compiled_step_equals_numpy_at_the_stroke_ends():
    rng = np.random.default_rng(7)
    prm = erw.param_vector(BASE.reduced_params(), V0, BETA)
    out = np.empty(10)
    for x_j in (-END, END, -0.09):
        for _ in range(10):
            x = _ringing(x_j) * (1.0 + 0.2 * rng.standard_normal(10))
            x[0] = rng.uniform(-6e-4, 6e-4)  # past the spool's stroke too
            erw.step_nb(x, 1e-3, 1e-3, 1, prm, out)
            ref = erw.step(x, 1e-3, 1e-3, BASE.reduced_params(), 1, V0, BETA)
            np.testing.assert_allclose(out, ref, rtol=1e-10, atol=1e-9)
