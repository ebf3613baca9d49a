"""Seeded random duty cycles (evaluation/dutycycle.py): determinism, bounds, validation."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.dutycycle import (
    MAX_LOAD_N,
    SETTLE_S,
    STROKE_FRACTION,
    duty_cycle,
    nominal_plant,
    scale_noise,
    suite,
)
from models.params import EHAParams
from models.scenario import Scenario

P = EHAParams()
SUITE = suite(12, seed=7)


def test_same_seed_and_index_give_the_same_scenarios():
    a, b = duty_cycle(7, 5), duty_cycle(7, 5)
    assert a.test == b.test and a.calibration == b.calibration and a.params == b.params
    assert a.test.model_dump() == SUITE[5].test.model_dump()
    assert duty_cycle(8, 5).test != a.test  # another seed, another duty cycle
    assert duty_cycle(7, 6).test != a.test


def test_every_scenario_validates_and_round_trips():
    for dc in SUITE:
        for sc in (dc.calibration, dc.test):
            assert Scenario.model_validate(sc.model_dump()) == sc
            sc.eha_params()  # the plant overrides validate as EHAParams


def test_kinds_cycle_with_the_index():
    assert [dc.kind for dc in SUITE[:4]] == ["healthy", "leak", "supply", "leak+supply"]
    assert all(dc.leak_shape is None for dc in SUITE if dc.kind in ("healthy", "supply"))
    assert all(dc.leak_shape in ("step", "ramp", "growth") for dc in SUITE if "leak" in dc.kind)


def test_command_load_and_faults_stay_in_bounds():
    lim = STROKE_FRACTION * P.stroke
    big = 0.0
    for dc in SUITE:
        sc = dc.test
        t = np.arange(0.0, sc.duration_s, 1e-3)
        u = sc.inputs(t)
        assert np.abs(u["x_cmd"]).max() <= lim + 1e-12
        assert np.abs(u["f_r"]).max() <= MAX_LOAD_N + 1e-6
        big = max(big, np.abs(u["x_cmd"]).max())
        r = u["p_sr"] / P.p_sr
        assert r.min() >= 0.55 - 1e-12 and r.max() <= 1.0 + 1e-12
        c = u["c_lk"] / P.c_lk
        assert c.min() == pytest.approx(1.0) and c[-1] == pytest.approx(dc.leak_ratio)
        assert 1.5 <= dc.leak_ratio <= 5.0 or dc.leak_ratio == 1.0
        assert not (1.9 < dc.leak_ratio < 2.75)  # clear of the alarm levels 2.0 / 2.5
        # no leak or supply change in the settle window at the end
        late = t >= sc.duration_s - SETTLE_S
        assert np.ptp(u["c_lk"][late]) == 0.0 and np.ptp(u["p_sr"][late]) == 0.0
    assert big > 0.5 * lim  # the suite does reach large positions


def test_plant_tolerances():
    for dc in SUITE:
        p = dc.params
        assert 0.8 * P.mass <= p["mass"] <= 1.2 * P.mass
        assert 0.8 * P.c_v <= p["c_v"] <= 1.2 * P.c_v
        assert 0.7 * P.f_d <= p["f_d"] <= 1.5 * P.f_d and p["f_s"] >= p["f_d"]
        for land in ("u1", "u2", "u3", "u4"):
            assert 0.9 * 0.97 * P.u1 <= p[land] <= 1.1 * 1.03 * P.u1
        assert 0.7 * P.beta_l <= p["beta_l"] <= 1.15 * P.beta_l
        assert 0.7 <= dc.noise_scale <= 1.5
        assert dc.test.sensors.x_j_m == pytest.approx(50e-6 * dc.noise_scale)
        assert dc.calibration.params == dc.test.params  # calibrated on the same plant
        assert dc.calibration.leak is None  # the calibration segment is healthy


def test_scale_noise_scales_every_sensor_and_keeps_the_rest():
    """scale_noise(dc, 0.1): each sensor's 1-sigma, calibration and test, is a tenth of the
    member's (x_S 0.5 um x the member's noise scale -> a tenth of that), the noise seeds,
    plant, commands and faults are the same; 0 gives noiseless sensors; a negative factor is
    refused, naming it."""
    dc = SUITE[3]
    q = scale_noise(dc, 0.1)
    for a, b in ((dc.calibration, q.calibration), (dc.test, q.test)):
        for key in ("x_s_m", "x_j_m", "p_pa", "p_sr_pa", "current_a"):
            assert getattr(b.sensors, key) == pytest.approx(0.1 * getattr(a.sensors, key))
        assert b.sensors.seed == a.sensors.seed and b.sensors.rate_hz == a.sensors.rate_hz
        assert b.model_copy(update={"sensors": a.sensors}) == a
    assert dc.calibration.sensors.x_s_m == pytest.approx(0.5e-6 * dc.noise_scale)
    assert q.noise_scale == pytest.approx(0.1 * dc.noise_scale)
    assert (q.params, q.leak_t, q.supply_changes) == (dc.params, dc.leak_t, dc.supply_changes)
    assert scale_noise(dc, 0.0).test.sensors.p_pa == 0.0
    with pytest.raises(ValueError, match="noise factor"):
        scale_noise(dc, -1.0)


def test_nominal_plant_drops_the_tolerances_and_keeps_the_rest():
    """nominal_plant(dc): both segments run on the datasheet plant (no parameter override:
    the HF plant is EHAParams()), while the commands, loads, faults, sensors and the truth of
    the events are the member's own."""
    dc = SUITE[5]
    assert dc.params  # a drawn plant has tolerances ...
    q = nominal_plant(dc)
    assert q.params == {} and q.calibration.params == {} and q.test.params == {}
    assert EHAParams().with_overrides(**q.test.params) == P  # ... the nominal one has none
    for a, b in ((dc.calibration, q.calibration), (dc.test, q.test)):
        assert b.model_copy(update={"params": a.params}) == a
    assert (q.kind, q.leak_t, q.leak_ratio, q.supply_changes, q.noise_scale) == (
        dc.kind, dc.leak_t, dc.leak_ratio, dc.supply_changes, dc.noise_scale
    )  # fmt: skip
    f = nominal_plant(dc, frictionless=True)  # ... and no Coulomb or breakaway friction
    assert f.params == f.test.params == f.calibration.params == {"f_d": 0.0, "f_s": 0.0}
    plant = EHAParams().with_overrides(**f.test.params)
    assert (plant.f_d, plant.f_s, plant.c_v) == (0.0, 0.0, P.c_v)
