"""The ECU closing its position loop on the noisy jack LVDT (``SensorNoise.ecu_noisy_x_j``):
the bench, the measured run and the virtual actuator."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.dutycycle import duty_cycle, ecu_noisy_x_j
from models.eha import simulate
from models.scenario import Event, Profile, Scenario, SensorNoise
from service.monitor.calibration import measured_run
from service.sim.actuator import VirtualActuator


def _scenario(**sensors) -> Scenario:
    return Scenario(
        name="loop",
        duration_s=0.5,
        command=Profile(initial=0.0, events=[Event(t=0.1, value=2e-3)]),
        load=Profile(initial=1e3),
        sensors=SensorNoise(rate_hz=1000.0, **sensors),
    )


def test_a_feedback_error_is_a_command_offset():
    """I_c = K_p (x_cmd - x_J - n): a constant feedback error n runs the bench exactly as a
    command n lower, and the jack settles n short of the command."""
    sc = _scenario()
    n_out = sc.n_steps() // 10 + 1
    off = 0.5e-3
    a = simulate(sc, "HF", out_every=10, x_fb_noise=np.full(n_out, off))
    shifted = sc.model_copy(
        update={"command": Profile(initial=-off, events=[Event(t=0.1, value=2e-3 - off)])}
    )
    b = simulate(shifted, "HF", out_every=10)
    np.testing.assert_allclose(a.x_j, b.x_j, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.i, b.i, rtol=0, atol=1e-12)
    assert a.x_j[-1] == pytest.approx(2e-3 - off, abs=0.05e-3)
    np.testing.assert_array_equal(a.x_cmd, simulate(sc, "HF", out_every=10).x_cmd)


def test_a_feedback_noise_of_the_wrong_length_is_refused():
    with pytest.raises(ValueError, match="x_fb_noise"):
        simulate(_scenario(), "HF", out_every=10, x_fb_noise=np.zeros(3))
    with pytest.raises(ValueError, match="x_fb_noise"):
        simulate(_scenario(), "HF", out_every=10, x_fb_noise=np.full(501, np.nan))


def test_the_measured_run_keeps_its_draws_and_the_loop_feels_them():
    """Same seed, loop on the truth or on the reading: every channel's noise is the same
    draw; with the loop on the reading the current moves with K_p times the x_J noise, and
    without x_J noise the option changes nothing."""
    noisy = dict(x_j_m=50e-6, x_s_m=0.5e-6, p_pa=5e4, current_a=1e-5, seed=7)
    sim0, m0 = measured_run(_scenario(**noisy))
    sim1, m1 = measured_run(_scenario(**noisy, ecu_noisy_x_j=True))
    for ch in ("i", "x_s", "x_j", "p1", "p2"):
        np.testing.assert_allclose(m1[ch] - getattr(sim1, ch), m0[ch] - getattr(sim0, ch))
    n_xj = m0["x_j"] - sim0.x_j
    di = sim1.i - sim0.i
    assert np.std(di) > 0.5 * 2.0 * np.std(n_xj)  # K_p = 2 A/m (datasheet)
    assert np.corrcoef(di[1:], -n_xj[:-1])[0, 1] > 0.5
    quiet = dict(noisy, x_j_m=0.0)
    s0, q0 = measured_run(_scenario(**quiet))
    s1, q1 = measured_run(_scenario(**quiet, ecu_noisy_x_j=True))
    np.testing.assert_array_equal(s0.x_j, s1.x_j)
    np.testing.assert_array_equal(q0["i"], q1["i"])


def test_the_virtual_actuator_closes_its_loop_on_its_reading():
    def run(flag: bool):
        sc = _scenario(x_j_m=50e-6, seed=3, ecu_noisy_x_j=flag)
        va = VirtualActuator(sc, rate_hz=1000)
        return va.produce(300)

    a, b = run(False), run(True)
    ia = np.array([s["i"] for s in a])
    ib = np.array([s["i"] for s in b])
    assert not np.allclose(ia, ib)
    assert a[0]["i"] == b[0]["i"]  # the first sample is taken before any step


def test_the_suite_option_reaches_both_segments():
    dc = ecu_noisy_x_j(duty_cycle(1, 1))
    assert dc.calibration.sensors.ecu_noisy_x_j and dc.test.sensors.ecu_noisy_x_j
    assert dc.test.sensors.x_j_m == duty_cycle(1, 1).test.sensors.x_j_m
    assert not duty_cycle(1, 1).test.sensors.ecu_noisy_x_j


def test_the_measured_run_draws_in_the_published_order():
    """Every published figure is reproducible from a scenario's seed: the noise is the seed's
    standard normal draws, one array per channel in the order i, x_S, x_J, P1, P2, then P_SR
    (a channel without noise draws nothing), times the channel's sigma."""
    sn = dict(x_j_m=50e-6, x_s_m=0.0, p_pa=5e4, p_sr_pa=2e4, current_a=1e-5, seed=11)
    sim, m = measured_run(_scenario(**sn), with_supply_sensor=True)
    n = len(sim.t)
    z = np.random.default_rng(11).standard_normal((5, n))  # i, x_J, P1, P2, P_SR (no x_S)
    np.testing.assert_array_equal(m["i"], sim.i + 1e-5 * z[0])
    np.testing.assert_array_equal(m["x_s"], sim.x_s)
    np.testing.assert_array_equal(m["x_j"], sim.x_j + 50e-6 * z[1])
    np.testing.assert_array_equal(m["p1"], sim.p1 + 5e4 * z[2])
    np.testing.assert_array_equal(m["p2"], sim.p2 + 5e4 * z[3])
    np.testing.assert_array_equal(m["p_sr"], sim.p_sr + 2e4 * z[4])
