"""The leak alarm is raised only with the clear level outside the estimate's 95 % band
(``AlarmConfig.leak_z``; docs/estimation.md, "Alarms")."""

from __future__ import annotations

import numpy as np
import pytest

from service.monitor import EST_KEYS, HEALTH_KEYS, Baseline, MonitorConfig
from service.monitor.calibration import bank_rows, measured_run
from service.sim.scenarios import load_scenario

C_LK_SIGMA = EST_KEYS.index("c_lk_sigma")
LR, ALARM = HEALTH_KEYS.index("leak_ratio"), HEALTH_KEYS.index("alarm_leak")


@pytest.fixture(scope="module")
def leak_step():
    return measured_run(load_scenario("leak_step").model_copy(update={"duration_s": 3.0}))


def _first_raise(meas, **alarms):
    base = Baseline.default("WH")
    rows = bank_rows(meas, MonitorConfig(model="WH", alarms=alarms), base)
    on = np.flatnonzero(rows.health[:, ALARM] > 0.5)
    lr = rows.health[:, LR]
    sd = rows.est[:, C_LK_SIGMA] / base.c_lk
    return (int(on[0]) if len(on) else None), rows.t, lr, sd


def test_the_band_holds_through_the_persistence_before_the_raise(leak_step):
    """leak_step (4x at 1.5 s): the alarm is raised, and over the 50 ms persistence before it
    every sample had the estimate at the raise level and 1.96 sigma above the clear level."""
    _, meas = leak_step
    j, t, lr, sd = _first_raise(meas)
    assert j is not None and 1.5 < t[j] < 2.0
    w = (t >= t[j] - 0.05) & (t <= t[j])
    assert np.all(lr[w] >= 2.5) and np.all(lr[w] - 1.96 * sd[w] >= 2.0)


def test_a_band_wider_than_the_estimate_keeps_the_alarm_down(leak_step):
    """The same run with a band of 20 sigma (the estimate never 20 sigma above 2x): no alarm,
    although the ratio passes 2.5x; without the band (leak_z = 0) the raise comes no later
    than with the default band."""
    _, meas = leak_step
    j20, _, lr, _ = _first_raise(meas, leak_z=20.0)
    assert j20 is None and lr.max() > 3.0
    j0, *_ = _first_raise(meas, leak_z=0.0)
    j196, *_ = _first_raise(meas)
    assert j0 is not None and j0 <= j196


def test_no_false_alarm_on_an_estimate_a_band_away_from_the_truth():
    """Suite member dc42_017 (a 1.82x leak ramp): after a hold at the variance cap the gate
    reopens at |P12| near its threshold and the estimate reads 2.55x with sigma 0.41x while
    the truth is 1.82x. Without the band (leak_z = 0, the rule before) that raised a false
    leak alarm; with the clear level inside the band (2.55 - 1.96 x 0.41 = 1.75) none."""
    from evaluation.dutycycle import duty_cycle
    from evaluation.suite import run_one

    dc = duty_cycle(42, 17)
    before = run_one(dc, model="WH", overrides={"alarms": {"leak_z": 0.0}})
    after = run_one(dc, model="WH")
    assert before["false"] == 1 and after["false"] == 0
    assert not any(kind == "leak" for _, kind, _ in after["alarms"])
