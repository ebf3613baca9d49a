"""The speed gate relative to the leak flow (``MonitorConfig.c_lk_gate_flow``; on WH by
default within 0.3 s of a slew, off on the C-types; docs/estimation.md, "A speed gate
relative to the leak flow"): C_Lk is held while the jack's flow A |v_J| exceeds that many
times the baseline leak flow C_Lk |P12|."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.monitor import EST_KEYS, Baseline, MonitorConfig
from service.monitor.calibration import bank_rows, measured_run
from service.sim.scenarios import load_scenario

ROOT = Path(__file__).resolve().parent.parent
C_LK = EST_KEYS.index("c_lk")


def test_a_tiny_ratio_holds_c_lk_wherever_the_jack_moves():
    """healthy_noise (sines under 4 kN, |P12| about 4 MPa): with the ratio at 1e-6 the jack
    speed allowed is 1e-6 x 2e-13 x 4e6 / 1e-3 = 8e-10 m/s, so the estimated jack is never
    that still and C_Lk stays at the baseline on every sample; off, it is learnt."""
    _, meas = measured_run(load_scenario("healthy_noise").model_copy(update={"duration_s": 2.0}))
    base = Baseline.default("WH")
    always = MonitorConfig(model="WH", c_lk_gate_flow=1e-6, c_lk_gate_flow_s=0.0)
    held = bank_rows(meas, always, base)
    np.testing.assert_array_equal(held.est[:, C_LK], np.full(len(held.t), base.c_lk))
    free = bank_rows(meas, MonitorConfig(model="WH", c_lk_gate_flow=0.0), base)
    assert np.ptp(free.est[:, C_LK]) > 0.05 * base.c_lk
    # ... and only within c_lk_gate_flow_s of fast motion when that is set: here the
    # estimated jack passes 30 mm/s only in the first few ms (the filter's start; the sines
    # reach 3.8 mm/s), so C_Lk is held until 0.3 s after that and learnt from then on
    after_fast = MonitorConfig(
        model="WH", c_lk_gate_flow=1e-6, c_lk_gate_flow_s=0.3, c_lk_gate_flow_v_fast=0.03
    )
    rows = bank_rows(meas, after_fast, base)
    fast = rows.t[np.abs(rows.est[:, EST_KEYS.index("v_j")]) > 0.03]
    assert len(fast) > 0 and fast[-1] < 0.05
    c = rows.est[:, C_LK]
    t_learn = rows.t[np.flatnonzero(np.diff(c))[0] + 1]
    assert fast[-1] + 0.3 <= t_learn <= fast[-1] + 0.302
    assert np.all(c[rows.t < t_learn] == base.c_lk) and np.ptp(c) > 0.05 * base.c_lk


def test_it_removes_the_spike_after_a_slew_onto_a_low_load_hold():
    """Suite member dc7_008 (healthy): after a 230 mm/s slew onto a hold at 1.1 MPa the
    deceleration's tail reads as a leak. With the gate off, C_Lk peaks above the 2.5x raise
    level, and at WH's 1.2e-13 walk the alarm of the C-types (sigma(C_Lk) below 1x, no band) is
    raised: a false alarm. WH's alarm (sigma below 0.6x) does not raise on it, and with
    WH's default gate (5x the leak flow within 0.3 s of a slew) C_Lk stays under the 2x
    clear level (1.65x; 1.39x at the 1e-13 walk)."""
    from evaluation.dutycycle import duty_cycle
    from evaluation.suite import monitor_run

    runs = {
        "off, C-type alarm": {
            "c_lk_gate_flow": 0.0,
            "alarms": {"leak_max_sigma": 1.0, "leak_z": 0.0},
        },
        "off": {"c_lk_gate_flow": 0.0},
        "WH defaults": {},
    }
    peaks, raised = {}, {}
    for name, overrides in runs.items():
        _, rows, base, _, _ = monitor_run(duty_cycle(7, 8), overrides=overrides)
        w = (rows.t > 6.3) & (rows.t < 7.5)
        peaks[name] = float(np.max(rows.est[w, C_LK]) / base.c_lk)
        events = [e for evs in rows.events for e in evs]
        raised[name] = [e.t for e in events if e.kind == "leak" and e.state == "raised"]
    assert peaks["off, C-type alarm"] == peaks["off"] > 2.5
    assert len(raised["off, C-type alarm"]) == 1 and 6.3 < raised["off, C-type alarm"][0] < 7.5
    assert raised["off"] == [] and raised["WH defaults"] == []
    assert peaks["WH defaults"] < 2.0


def test_a_ramp_is_not_a_slew():
    """Suite member dc5_001: a 3.21x leak ramp crosses the raise level while the jack starts
    to follow a 30 mm/s position ramp. Counted as fast motion (c_lk_gate_flow_v_fast at
    30 mm/s, the setting before) the ramp keeps the post-slew gate shut and the alarm comes
    2.8 s after the crossing; at WH's default, 0.1 m/s, a slew to a step and not a commanded
    ramp, within 1 s. Both with the leak alarm before its band (leak_z = 0): the raise at
    0.9 s reads 2.53x at sigma 0.51x against a true 3.2x; with the band the alarm waits until
    the gate reopens 2.8 s after the crossing (docs/decisions/0020-leak-alarm-band.md)."""
    from evaluation.dutycycle import duty_cycle
    from evaluation.suite import run_one

    dc = duty_cycle(5, 1)
    no_band = {"alarms": {"leak_z": 0.0}}
    before = run_one(dc, model="WH", overrides={"c_lk_gate_flow_v_fast": 0.03, **no_band})
    now = run_one(dc, model="WH", overrides=no_band)
    assert before["delay"] > 2.0 and before["false"] == 0
    assert 0.0 < now["delay"] <= 1.0 and now["false"] == 0
