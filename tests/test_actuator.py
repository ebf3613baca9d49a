"""Virtual actuator: fault state machine, sample generation, sensor noise (no Zenoh)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.scenario import Scenario, SensorNoise
from service.sim.actuator import FaultRefused, FaultState, VirtualActuator
from service.sim.scenarios import load_scenario
from service.wire.messages import FaultCommand

C0 = 2e-13  # nominal leakage [m^3/s/Pa]
P0 = 20e6  # nominal supply [Pa]


def cmd(**kw) -> FaultCommand:
    return FaultCommand(**kw)


# --------------------------------------------------------------------------- FaultState


def test_leak_step_then_clear():
    f = FaultState()
    assert f.c_lk(0.0, C0) == C0
    f.apply(cmd(kind="leak", value=6e-13), 1.0, C0, P0)
    assert f.c_lk(1.0, C0) == 6e-13
    assert f.c_lk(50.0, C0) == 6e-13
    msg = f.apply(cmd(kind="clear"), 2.0, C0, P0)
    assert "leak" in msg
    assert f.c_lk(2.0, C0) == C0


def test_leak_ramp_is_linear_from_the_value_in_force():
    f = FaultState()
    f.apply(cmd(kind="leak", value=6e-13, ramp_s=2.0), 1.0, C0, P0)
    # halfway: 2e-13 + 0.5 * (6e-13 - 2e-13) = 4e-13
    assert f.c_lk(2.0, C0) == pytest.approx(4e-13, rel=1e-12)
    assert f.c_lk(3.0, C0) == pytest.approx(6e-13, rel=1e-12)
    # a second ramp starts from where the first one is: 4e-13 at t = 2 -> 8e-13 over 4 s
    f = FaultState()
    f.apply(cmd(kind="leak", value=6e-13, ramp_s=2.0), 1.0, C0, P0)
    f.apply(cmd(kind="leak", value=8e-13, ramp_s=4.0), 2.0, C0, P0)
    assert f.c_lk(2.0, C0) == pytest.approx(4e-13, rel=1e-12)
    assert f.c_lk(4.0, C0) == pytest.approx(6e-13, rel=1e-12)


def test_clear_with_ramp_returns_to_nominal():
    f = FaultState()
    f.apply(cmd(kind="leak", value=1e-12), 0.0, C0, P0)
    f.apply(cmd(kind="clear", channel="leak", ramp_s=1.0), 5.0, C0, P0)
    assert f.c_lk(5.5, C0) == pytest.approx(0.5 * (1e-12 + C0), rel=1e-12)
    assert f.c_lk(6.0, C0) == C0
    assert f.leak is None  # auto-removed at the end of the clearing ramp


def test_duration_clears_itself():
    f = FaultState()
    f.apply(cmd(kind="supply", value=10e6, duration_s=1.5), 2.0, C0, P0)
    assert f.p_sr(3.0, P0) == 10e6
    assert f.p_sr(3.5, P0) == P0
    assert f.supply is None


@pytest.mark.parametrize(
    "kw, why",
    [
        ({"kind": "leak", "value": 1.0}, "outside"),
        ({"kind": "leak"}, "finite value"),
        ({"kind": "supply", "value": 100e6}, "outside"),
        ({"kind": "sensor_bias", "value": 1e-3, "channel": "nope"}, "channel"),
        ({"kind": "sensor_bias", "value": 1.0, "channel": "x_j"}, "limit"),
        ({"kind": "dropout", "channel": "nope"}, "dropout channel"),
        ({"kind": "clear", "channel": "nope"}, "clear channel"),
    ],
)
def test_refusals_change_nothing(kw, why):
    f = FaultState()
    f.apply(cmd(kind="leak", value=5e-13), 0.0, C0, P0)
    before = f.active(1.0, C0, P0)
    with pytest.raises(FaultRefused, match=why):
        f.apply(cmd(**kw), 1.0, C0, P0)
    assert f.active(1.0, C0, P0) == before


def test_sensor_bias_and_dropout():
    f = FaultState()
    f.apply(cmd(kind="sensor_bias", value=1e-3, channel="x_j"), 0.0, C0, P0)
    f.apply(cmd(kind="dropout", channel="p2", duration_s=1.0), 0.0, C0, P0)
    meas = {"x_j": 0.01, "p1": 5e6, "p2": 6e6}
    f.corrupt(0.5, meas)
    assert meas == {"x_j": pytest.approx(0.011, rel=1e-12), "p1": 5e6, "p2": None}
    meas = {"x_j": 0.01, "p1": 5e6, "p2": 6e6}
    f.corrupt(1.0, meas)  # the dropout has ended
    assert meas["p2"] == 6e6
    assert not f.silent(1.0)
    f.apply(cmd(kind="dropout"), 2.0, C0, P0)
    assert f.silent(2.0)
    f.apply(cmd(kind="clear"), 3.0, C0, P0)
    assert not f.silent(3.0)
    assert f.bias == {}


# --------------------------------------------------------------------------- generator


class FakeStepper:
    """Records the inputs; signals are a simple function of the step count."""

    def __init__(self, params, step_s):
        self.step_s = step_s
        self.calls: list[tuple] = []
        self.k = 0

    def advance(self, n, x_cmd, f_r, p_sr, c_lk):
        self.calls.append((n, x_cmd, f_r, p_sr, c_lk))
        self.k += n

    def signals(self):
        n, x_cmd, f_r, p_sr, c_lk = self.calls[-1]
        return {
            "x_cmd": x_cmd,
            "i": 1e-3,
            "x_s": 1e-5,
            "x_j": self.k * 1e-6,
            "p1": 10e6,
            "p2": 9e6,
            "p_sr": p_sr,
            "c_lk": c_lk,
        }


def _scenario(**kw) -> Scenario:
    base = dict(
        name="t",
        duration_s=2.0,
        step_s=1e-4,
        command={"initial": 0.0, "events": [{"t": 0.5, "value": 0.01}]},
    )
    base.update(kw)
    return Scenario.model_validate(base)


def test_samples_times_and_inputs_without_noise():
    va = VirtualActuator(_scenario(), rate_hz=1000, t_origin=100.0, stepper_factory=FakeStepper)
    assert va.steps_per_sample == 10
    s = va.produce(600)
    assert [r["seq"] for r in s] == list(range(600))
    assert s[0]["t"] == 100.0 and s[599]["t"] == pytest.approx(100.599, abs=1e-9)
    assert s[9]["x_j"] == pytest.approx(90e-6)  # sample k is taken after 10 k steps
    assert s[400]["x_cmd"] == 0.0 and s[550]["x_cmd"] == 0.01  # step at 0.5 s
    st = va.stepper
    assert st.calls[0][0] == 0  # initialisation at rest
    assert len(st.calls) == 6001 and all(c[0] == 1 for c in st.calls[1:])
    assert st.calls[0][3] == 20e6 and st.calls[0][4] == va.params.c_lk


def test_leak_fault_reaches_the_plant_and_profiles_repeat():
    va = VirtualActuator(_scenario(), rate_hz=1000, stepper_factory=FakeStepper)
    va.produce(100)
    ok, msg, active = va.apply_fault(cmd(kind="leak", value=6e-13, ramp_s=0.1))
    assert ok and active[0]["kind"] == "leak"
    va.produce(200)
    c = [call[4] for call in va.stepper.calls[1:]]  # c[j]: leakage during step j
    assert c[999] == va.params.c_lk  # before the command (t < 0.1 s)
    assert c[1500] == pytest.approx(va.params.c_lk + 0.5 * (6e-13 - va.params.c_lk))
    assert c[-1] == 6e-13
    ok, msg, _ = va.apply_fault(cmd(kind="leak", value=-1e-13))
    assert not ok and msg.startswith("refused")
    # profiles repeat with the scenario period (2 s): x_cmd back to 0 after the wrap
    s = va.produce(2000)
    assert s[-1]["t"] == pytest.approx(2.299) and s[-1]["x_cmd"] == 0.0


def test_whole_actuator_dropout_consumes_sequence_numbers():
    va = VirtualActuator(_scenario(), rate_hz=1000, stepper_factory=FakeStepper)
    va.produce(10)
    va.apply_fault(cmd(kind="dropout", duration_s=0.05))
    s = va.produce(100)
    assert len(s) == 50
    assert s[0]["seq"] == 60  # samples 10..59 were not sent


def test_sensor_noise_matches_the_scenario_sigma():
    sc = load_scenario("paper_bench")
    noisy = sc.model_copy(update={"sensors": SensorNoise(p_pa=1e4, x_j_m=2e-6, seed=3)})
    a = VirtualActuator(sc, rate_hz=1000).produce(3000)
    b = VirtualActuator(noisy, rate_hz=1000).produce(3000)
    dp = np.array([y["p1"] - x["p1"] for x, y in zip(a, b, strict=True)])
    dx = np.array([y["x_j"] - x["x_j"] for x, y in zip(a, b, strict=True)])
    # 3000 samples: the standard deviation is within a few % of sigma, the mean near 0
    assert np.std(dp) == pytest.approx(1e4, rel=0.06)
    assert np.std(dx) == pytest.approx(2e-6, rel=0.06)
    assert abs(np.mean(dp)) < 4 * 1e4 / math.sqrt(3000)
    # the command is not a sensor: no noise
    assert all(x["x_cmd"] == y["x_cmd"] for x, y in zip(a, b, strict=True))


def test_real_plant_follows_the_step_and_leak_costs_pressure():
    """HF bench (paper bench, unloaded run): the jack moves toward 20 mm; a larger leakage
    lowers the holding |P12| that the spool can build at a given opening."""
    sc = load_scenario("paper_bench")
    va = VirtualActuator(sc, rate_hz=1000)
    s = va.produce(250)  # 0.25 s, before the load at 0.30 s
    assert 0.0 < s[-1]["x_j"] <= 0.0205
    assert s[-1]["x_j"] > s[100]["x_j"] > s[10]["x_j"]
