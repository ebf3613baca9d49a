"""The specialised RK4 loops of ``models.compiled.integrate`` against plain RK4 on the array
right-hand side ``compiled.rhs`` and against values recorded before the loops were
specialised (physics.md sections 3 and 5): the speed-up must not change the results beyond
round-off (rtol 1e-9)."""

from __future__ import annotations

import numpy as np
import pytest

from models import compiled as kern
from models.eha import VALVE_MODELS, EHAStepper, initial_state, n_substeps, simulate
from models.params import DEFAULT_PARAMS
from service.sim.scenarios import load_scenario

RTOL = 1e-9
# absolute floors where a signal crosses zero: 1e-9 of its range on paper_bench
SCALE = {"i": 1e-2, "x_j": 5e-2, "v_j": 1.0, "p12": 2e7, "p": 2e7}

# Recorded with the generic loop (commit 07093f7: array stages, model branch in the rhs) on
# paper_bench at step 1e-4 s: (step k, I [A], x_J [m], v_J [m/s], P12 [Pa]) at t = k * 1e-4 s.
RECORDED = {
    "HF": [
        (1000, 0.009001906347442535, 0.015578305162523292, 0.15793010954772485, 510046.76302290335),
        (3200, 0.0007430383065967874, 0.019641919013197204, 0.01808918232522023, 10236244.471355706),
        (4000, 0.0029553129491557933, 0.018510339342960622, -0.02410464002336833, 11535100.91753249),
        (6000, 0.009999999999999997, 0.009523285567897987, -0.05340063132471767, 11493216.839504978),
        (8000, 0.009999999999999997, 0.014368289913502532, 0.18187657488828368, -11311893.582889572),
        (10000, -0.008905622699072389, 0.02447647858422667, 0.0475183079088209, -11468071.184654886),
    ],
    "A": [
        (1000, 0.009999999999999997, 0.01310961984331013, 0.13409852673327083, 668197.0534665374),
        (3200, 0.000619178243335163, 0.019685307690030917, -0.010060173221444932, 11608701.358058907),
        (4000, 0.001842442784145178, 0.019075930411149637, -0.005656865940688296, 11596536.934194759),
        (6000, 0.0026122081634007417, 0.018693718445476102, -0.0003524826580237464, 11599784.214324195),
        (8000, 1.6441184768588637e-05, 0.020001077057795427, 0.018466266460434724, -11588695.172097031),
        (10000, -0.002496380005337592, 0.021248769344743203, 0.0011506439703526672, -11599295.589496106),
    ],
    "B": [
        (1000, 0.009999999999999997, 0.0026058478526038665, 0.02632480843221572, 452649.61686443206),
        (3200, 0.009999999999999997, 0.008029003212752468, 0.007766174140774033, 12415532.34828155),
        (4000, 0.009999999999999997, 0.008040280058435628, -0.00446829836076174, 11591063.403278476),
        (6000, 0.009999999999999997, 0.007146620386283581, -0.00446829836076174, 11591063.403278476),
        (8000, 0.009999999999999997, 0.008041433613955377, 0.031411727936025514, -11537176.544127945),
        (10000, 0.009999999999999997, 0.014323779201159879, 0.031411727936025514, -11537176.544127945),
    ],
    "C1": [
        (1000, 0.009999999999999997, 0.01310961984331013, 0.13409852673327083, 668197.0534665374),
        (3200, 0.000619178243335163, 0.019685307690030917, -0.010060173221444932, 11608701.358058907),
        (4000, 0.009999999999999997, -0.007238984443204451, -0.9149057537672651, 8710801.393728225),
        (6000, 0.009999999999999997, -0.050030160838218554, -1.5037279759896639e-69, 8710801.393728225),
        (8000, 0.009999999999999997, -0.021398454778687955, 0.9372777443381625, -8710801.393728225),
        (10000, -0.009999999999999997, 0.05003013164279628, 3.8583346108646827e-60, -8710801.393728225),
    ],
    # WH: recorded when the model was added (its loop was written in the specialised form)
    "WH": [
        (1000, 0.009115489025742649, 0.01552137816700881, 0.15799580676432107, 568007.4658718295),
        (3200, 0.0007052177248224889, 0.01966245209081658, 0.020466178840522854, 10043941.968827605),
        (4000, 0.0029400969419534884, 0.018518339547492622, -0.02330034490853371, 11536221.442350937),
        (6000, 0.009999999999999997, 0.00956024181588808, -0.05342841665231685, 11493143.16669534),
        (8000, 0.009999999999999997, 0.013735215579454398, 0.17773646069083746, -10684695.341188973),
        (10000, -0.008400288231433723, 0.024222830021664938, 0.04554947217505548, -11473246.904366713),
    ],
    "C3": [
        (1000, 0.009999999999999997, 0.013121439232698486, 0.13420514158439112, 668410.283168785),
        (3200, 0.0006190736131845264, 0.0196853592557081, -0.010061650547905102, 11608702.635859795),
        (4000, 0.009999999999999997, -0.001549371392582808, -0.6496024323331985, 9712509.712509712),
        (6000, 0.009999999999999997, -0.050020248268730645, -1.4111038330202322e-59, 9712509.712509712),
        (8000, 0.009999999999999997, -0.030437880211187714, 0.6225907760604251, -9712509.712509712),
        (10000, -0.009999999999999997, 0.05002022718349185, 4.810878777679426e-44, -9712509.712509712),
    ],
    "C5": [
        (1000, 0.009999999999999997, 0.01310961984331013, 0.13409852673327083, 668197.0534665266),
        (3200, 0.000619178243335163, 0.019685307690030917, -0.010060173221444932, 11608701.358058907),
        (4000, 0.009999999999999997, 0.003443659054196692, -0.5308800590169543, 9966691.516271345),
        (6000, 0.009999999999999997, -0.0500195764587534, -4.225729640154913e-52, 9712509.712509712),
        (8000, 0.009999999999999997, -0.03176322483380423, 0.5590726816825483, -9959473.5709358),
        (10000, -0.009999999999999997, 0.05001958963978615, 7.285687465583407e-37, -9712509.712509712),
    ],
}  # fmt: skip


def _close(a, b, scale: float) -> None:
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * scale)


def _rk4_reference(y, h, n_sub, u, prm, model, n_steps):
    """Classic RK4 on the array rhs, inputs row min(k, n_u - 1) over step k; all states."""
    y = np.array(y, float)
    ns = 7 if model in (0, 6) else 5  # HF and WH carry the two chamber states
    hs = h / n_sub
    out = np.empty((n_steps + 1, 7))
    out[0] = y
    k1, k2, k3, k4 = (np.empty(7) for _ in range(4))
    for k in range(n_steps):
        x_cmd, f_r, p_sr, c_lk = u[min(k, len(u) - 1)]
        for _ in range(n_sub):
            kern.rhs(y, x_cmd, f_r, p_sr, c_lk, prm, model, k1)
            kern.rhs(y + 0.5 * hs * k1, x_cmd, f_r, p_sr, c_lk, prm, model, k2)
            kern.rhs(y + 0.5 * hs * k2, x_cmd, f_r, p_sr, c_lk, prm, model, k3)
            kern.rhs(y + hs * k3, x_cmd, f_r, p_sr, c_lk, prm, model, k4)
            y[:ns] += hs / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)[:ns]
        out[k + 1] = y
    return out


@pytest.fixture(scope="module")
def paper():
    return load_scenario("paper_bench")


@pytest.mark.parametrize("valve", VALVE_MODELS)
def test_simulate_equals_recorded_generic_loop(valve: str, paper) -> None:
    r = simulate(paper, valve)
    rows = [v[0] for v in RECORDED[valve]]
    rec = np.array([v[1:] for v in RECORDED[valve]])
    _close(r.i[rows], rec[:, 0], SCALE["i"])
    _close(r.x_j[rows], rec[:, 1], SCALE["x_j"])
    _close(r.v_j[rows], rec[:, 2], SCALE["v_j"])
    _close(r.p12[rows], rec[:, 3], SCALE["p12"])


@pytest.mark.parametrize("valve", VALVE_MODELS)
def test_simulate_equals_rk4_on_rhs_over_paper_bench(valve: str, paper) -> None:
    """Every step of the 1 s bench (three input changes, end stops, stick and slip)."""
    params = paper.eha_params()
    h = paper.step_s
    n = paper.n_steps()
    u = paper.inputs((np.arange(n) + 0.5) * h, params)
    u = np.stack([u["x_cmd"], u["f_r"], u["p_sr"], u["c_lk"]], axis=1)
    y0 = initial_state(params, valve, u[0, 2], u[0, 3])
    model = kern.MODEL_IDS[valve]
    ref = _rk4_reference(y0, h, 1, u, kern.param_array(params), model, n)
    r = simulate(paper, valve)
    _close(r.i, ref[:, 0], SCALE["i"])
    _close(r.x_j, ref[:, 3], SCALE["x_j"])
    _close(r.v_j, ref[:, 4], SCALE["v_j"])
    if valve in ("HF", "WH"):
        # WH reports P_k = max(p~_k, P_vap) of its volume-balance states (docs/models.md eq. 6)
        floor = params.p_vap if valve == "WH" else -np.inf
        _close(r.p1, np.maximum(ref[:, 5], floor), SCALE["p"])
        _close(r.p2, np.maximum(ref[:, 6], floor), SCALE["p"])
    # the output stride skips rows without changing them (segments start at 0.3/0.35/0.75 s)
    r7 = simulate(paper, valve, out_every=7)
    assert np.array_equal(r7.x_j, r.x_j[::7]) and np.array_equal(r7.v_j, r.v_j[::7])


@pytest.mark.parametrize("valve", ["HF", "A", "C3", "C5", "WH"])
def test_integrate_per_step_inputs_substeps_and_offset(valve: str) -> None:
    """Inputs varying every step then held (row min(k, n_u - 1)), 3 substeps, k0 > 0."""
    params = DEFAULT_PARAMS
    h = 1e-3
    n_sub = n_substeps(params, valve, h)
    assert n_sub > 1
    n, n_u = 120, 80
    t = (np.arange(n_u) + 0.5) * h
    u = np.stack(
        [0.02 * np.sin(40 * t), 3e3 * np.cos(25 * t), 20e6 - 5e7 * t, 2e-13 * (1 + 10 * t)],
        axis=1,
    )
    model = kern.MODEL_IDS[valve]
    prm = kern.param_array(params)
    y0 = initial_state(params, valve, u[0, 2], u[0, 3])
    ref = _rk4_reference(y0, h, n_sub, u, prm, model, n)
    y = y0.copy()
    k0, every = 5, 4  # global steps 5..124: rows (g + 1) / 4 for g + 1 = 8, 12, ..., 124
    out = np.full((32, 7), np.nan)
    kern.integrate(y, h, n_sub, k0, n, u, prm, model, every, out)
    for s in range(7):
        _close(y[s], ref[-1, s], max(abs(ref[:, s]).max(), 1e-30))
    g1 = np.arange(k0 + 1, k0 + n + 1)
    stored = g1 % every == 0
    got = out[g1[stored] // every]
    for s in range(7):
        _close(got[:, s], ref[1:][stored][:, s], max(abs(ref[:, s]).max(), 1e-30))
    assert np.isnan(out[:2]).all()  # rows before the first stored step are untouched


@pytest.mark.parametrize("valve", ["HF", "C1", "WH"])
def test_stepper_equals_rk4_on_rhs(valve: str) -> None:
    st = EHAStepper(DEFAULT_PARAMS, valve, step_s=1e-4)
    st.advance(0, 0.0, 0.0, 20e6, 2e-13)
    y0 = st.state
    st.advance(150, 0.01, 2e3, 20e6, 2e-13)
    st.advance(150, 0.01, 2e3, 20e6, 2e-13)
    u = np.array([[0.01, 2e3, 20e6, 2e-13]])
    ref = _rk4_reference(y0, 1e-4, 1, u, kern.param_array(DEFAULT_PARAMS), st.model, 300)
    for s in range(7):
        _close(st.state[s], ref[-1, s], max(abs(ref[:, s]).max(), 1e-30))


@pytest.mark.parametrize("valve", ["A", "B", "C1", "C3", "C5"])
def test_fast_law_equals_law_p12(valve: str) -> None:
    """The loop's rearranged law (step factors, no division on the v_J path) against
    law_p12, over both sides of every clip and of C5's |x_S*| = x_SS corner."""
    p = DEFAULT_PARAMS
    prm = kern.param_array(p)
    g_pq, x_ss, p_vap, area = prm[kern.I_G_PQ], prm[kern.I_X_SS], p.p_vap, p.area
    rng = np.random.default_rng(11)
    model = kern.MODEL_IDS[valve]
    got, ref, x_st, clipped = [], [], [], []
    for _ in range(3000):
        x_s = rng.uniform(-2.5, 2.5) * x_ss
        v_j = rng.uniform(-0.06, 0.06)  # G_PQ A v_J up to about 2 P_SR at 20 MPa
        p_sr = rng.choice([0.0, rng.uniform(1e5, 25e6)])
        c_lk = rng.uniform(0.0, 5e-12)
        f0, f1, f2 = kern._law_fast_consts(model, p_sr, c_lk, area, g_pq, x_ss, p_vap)
        got.append(kern._law_fast(model, x_s, v_j, p_sr, x_ss, f0, f1, f2))
        ref.append(kern.law_p12(model, x_s, area * v_j, p_sr, g_pq, x_ss, c_lk, p_vap))
        x_st.append(x_s - area * v_j * g_pq * x_ss / max(p_sr, p_vap))
        y = p_sr / x_ss * x_s - (0.0 if valve == "B" else g_pq * area * v_j)
        clipped.append(abs(y) > p_sr)
    got, ref = np.array(got), np.array(ref)
    assert np.isfinite(ref).all()
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * 25e6)
    # both sides of the clip at +-P_SR and of C5's corner |x_S*| = x_SS are reached
    assert 100 < sum(clipped) < len(clipped) - 100
    inside = np.abs(x_st) <= x_ss
    assert 100 < inside.sum() < inside.size - 100


def test_fast_jack_equals_jack_accel() -> None:
    prm = kern.param_array(DEFAULT_PARAMS)
    jc = kern._jack_consts(prm)
    area, stroke, dv_k = jc[0], jc[1], jc[7]
    area_m = area * prm[kern.I_INV_MASS]
    rng = np.random.default_rng(5)
    n_stuck = n_stop = 0
    for _ in range(4000):
        x_j = rng.uniform(-1.2 * stroke, 1.2 * stroke)
        v_j = rng.choice([rng.uniform(-2 * dv_k, 2 * dv_k), rng.uniform(-0.3, 0.3)])
        p12 = rng.uniform(-2e7, 2e7) * rng.choice([1.0, 1e-3])
        f_r = rng.uniform(-2e4, 2e4) * rng.choice([1.0, 1e-3])
        ref = kern._jack_accel(x_j, v_j, p12, f_r, jc)
        got = kern._jack_accel_fast(x_j, v_j, p12, f_r, jc, area_m)
        scale = (abs(area * p12) + abs(f_r) + 1e6 * abs(v_j) + 1e3) * prm[kern.I_INV_MASS]
        assert got == pytest.approx(ref, rel=1e-12, abs=1e-13 * scale)
        n_stuck += ref == -v_j * prm[kern.I_INV_TAU_STICK]
        n_stop += abs(x_j) > stroke
    assert n_stuck > 100 and n_stop > 100  # stick band and end stops both exercised


def test_fast_orifice_root_equals_pow() -> None:
    """The HF loop's 4th root as two square roots: within 2 ulp of pow(., 0.25)."""
    p = DEFAULT_PARAMS
    rng = np.random.default_rng(3)
    args = (p.cd * p.w_eff, np.sqrt(2.0 / p.rho), p.dp_tr**2, p.w_eff * p.c_r**3, 12.0 * p.mu)
    for _ in range(2000):
        a = rng.uniform(-2e-4, 6e-4)
        dp = rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-2, 7.5)
        exact = kern._orifice(a, dp, *args, p.l_min, False)
        fast = kern._orifice(a, dp, *args, p.l_min, True)
        assert fast == pytest.approx(exact, rel=5e-16, abs=0.0)


@pytest.mark.parametrize("valve", ["HF", "A", "C5"])
def test_stuck_jack_velocity_reaches_zero_not_subnormal(valve: str) -> None:
    """Stuck, v_J relaxes by exp(-h / TAU_STICK) per step; without the V_J_ZERO flush it
    ends parked at a subnormal (~2.5e-323, every later step ~30x slower)."""
    st = EHAStepper(DEFAULT_PARAMS, valve, step_s=1e-4)
    st.advance(5000, 0.02, 0.0, 20e6, 2e-13)  # 0.5 s: settled and stuck, |v_J| ~ 1e-60
    x_j, v_mid = st.state[3], st.state[4]
    assert 0.0 < abs(v_mid) < 1e-40
    st.advance(10000, 0.02, 0.0, 20e6, 2e-13)
    y = st.state
    assert y[4] == 0.0
    assert y[3] == pytest.approx(x_j, abs=1e-40)  # held where it stuck
    tiny = np.finfo(float).tiny
    assert not np.any((y != 0.0) & (np.abs(y) < tiny))
