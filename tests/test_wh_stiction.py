"""Stiction in the WH process model (models/eha_reduced_wh.py; docs/estimation.md,
"Stiction in the WH process model"): a jack under an applied force below F_s stays stuck, one
above it breaks away, a v_J that crosses zero under such a force is caught at 0, and the
compiled kernel equals the numpy reference around the stick band."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import fsolve

from models import eha_reduced_wh as erw
from service.monitor import Baseline

BASE = Baseline.default("WH")
RP = BASE.reduced_params()
PRM = erw.param_vector(RP, BASE.v_c, BASE.beta)
F_R = 4000.0  # external load [N]


def _held(f_a: float, v_j: float = 0.0) -> tuple[np.ndarray, float]:
    """(state, current [A]): a jack at mid stroke with A P12 - F_R = ``f_a`` [N], the spool
    where the WH lands hold that P12 with the jack still (both chamber balances met)."""
    p12 = (F_R + f_a) / RP.area
    c_lk = 2e-13

    def balance(v):
        q1, q2, q3, q4 = erw.land_flows(v[0] * 1e-6, v[1] * 1e6, v[1] * 1e6 - p12, 20e6, RP)
        return [1e6 * (q1 - q2 - c_lk * p12), 1e6 * (q3 - q4 + c_lk * p12)]

    (x_s, p1), _, ier, msg = fsolve(balance, [10.0, 10.5 + p12 / 2e6], xtol=1e-13, full_output=True)
    assert ier == 1 or np.max(np.abs(balance([x_s, p1]))) < 1e-6, msg  # flows within 1e-12 m^3/s
    x = np.array([x_s * 1e-6, 0.0, 0.0, v_j, F_R, 20e6, c_lk, 0.0, p1 * 1e6, p1 * 1e6 - p12])
    return x, x_s * 1e-6 / RP.k_sv


def _advance(held: tuple[np.ndarray, float], n: int, prm: np.ndarray = PRM) -> np.ndarray:
    x, i = held
    out = np.empty(10)
    for _ in range(n):
        erw.step_nb(x, i, 1e-3, 1, prm, out)
        x = out.copy()
    return x


def test_the_defaults_carry_the_datasheet_breakaway_friction():
    """WH's default and nominal baselines stick at the HF plant's F_s (600 N); the C-types have
    no stiction (their jack equation is models.eha_reduced's)."""
    assert BASE.f_s == Baseline.nominal("WH").f_s == 600.0
    assert Baseline.default("C5").f_s == 0.0
    assert PRM[erw.K_WH_F_S] == 600.0 and PRM[erw.K_WH_V_STICK] == 3e-4


def test_a_force_below_breakaway_holds_the_jack_still():
    """400 N applied, F_s = 600 N: after 0.1 s x_J has not moved and v_J is 0. Without
    stiction (F_s = 0) the same jack creeps: the smooth friction F_d tanh(v / v_f) needs
    v_J = v_f atanh(400 / F_d) > 0 to hold any force, so it moves by more than 50 um."""
    x = _advance(_held(400.0), 100)
    assert abs(x[2]) < 1e-12 and abs(x[3]) < 1e-9
    smooth = PRM.copy()
    smooth[erw.K_WH_F_S] = 0.0
    assert _advance(_held(400.0), 100, smooth)[2] > 50e-6


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_force_above_breakaway_moves_the_jack_its_way(sign):
    """800 N applied (above F_s = 600 N) in either direction: the jack moves that way, by
    more than 0.1 mm in 0.1 s."""
    x = _advance(_held(sign * 800.0), 100)
    assert sign * x[2] > 1e-4


def test_a_velocity_crossing_zero_under_a_small_force_is_caught():
    """Moving at -2 mm/s (outside the 0.3 mm/s band) against +300 N applied: v_J reaches zero
    within a few ms, where the zero crossing is caught, and the jack stays still after."""
    held = _held(300.0, v_j=-2e-3)
    x = _advance(held, 20)
    assert x[3] == 0.0
    x_j = x[2]
    x = _advance((x, held[1]), 50)
    assert x[3] == 0.0 and x[2] == x_j


def test_compiled_equals_numpy_around_the_stick_band():
    """States with v_J within and across the band and applied forces on both sides of F_s:
    the compiled step equals ``step`` (numpy), including the zero-crossing catch."""
    rng = np.random.default_rng(3)
    out = np.empty(10)
    caught = 0
    for _ in range(60):
        x, i = _held(float(rng.uniform(-900.0, 900.0)), v_j=float(rng.uniform(-3e-3, 3e-3)))
        x[8:10] += rng.normal(0.0, 2e4, 2)
        erw.step_nb(x, i, 1e-3, 1, PRM, out)
        ref = erw.step(x, i, 1e-3, RP, 1, BASE.v_c, BASE.beta)
        np.testing.assert_allclose(out, ref, rtol=1e-11, atol=1e-12)
        caught += out[3] == 0.0
    assert caught > 0  # some of them were caught at zero


def test_calibrate_cli_keeps_and_prints_the_breakaway_friction(tmp_path, capsys):
    """``servowatch calibrate --model WH``: the written baseline carries the datasheet's F_s
    (600 N) and the summary prints the friction it assumes."""
    from service.cli import main

    out = tmp_path / "wh.json"
    rc = main(["calibrate", "--scenario", "healthy_noise", "--model", "WH", "--passes", "0",
               "--out", str(out)])  # fmt: skip
    assert rc == 0
    assert "Coulomb F_d 400 N, breakaway F_s 600 N" in capsys.readouterr().out
    assert Baseline.load(out).f_s == 600.0
