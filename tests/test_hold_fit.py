"""The WH calibration's last step (docs/estimation.md, "Calibrating where the monitor
reads"): the holds of a healthy run, the C_Lk the WH law reads at a hold, and the fit of the
hydraulic null and the null pressure coefficient to the holds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import fsolve

from evaluation.dutycycle import CAL_HOLD_END_S, CAL_HOLD_SWAP_S, CAL_SINE_END_S, duty_cycle
from models.eha_reduced_wh import land_flows
from models.hf_valve import hf_static_hold
from models.params import EHAParams
from service.monitor import Baseline, MonitorConfig
from service.monitor.calibration import (
    calibrate,
    hold_reading,
    hold_windows,
    identify_noise,
    measured_run,
)


def test_hold_windows_by_hand():
    """3 s at 1 kHz: a sine command to 1 s, then held; P12 steps from 3 to -2 MPa at 2 s.
    Two holds: from 1.3 s (0.3 s after the command stops) to the step, and after it once
    P12 is steady again; their means are the signals' values there."""
    t = np.arange(3000) * 1e-3
    x_cmd = np.where(t < 1.0, 1e-3 * np.sin(2 * np.pi * t), 0.0)
    x_j = x_cmd.copy()
    p12 = np.where(t < 2.0, 3e6, -2e6)
    p1, p2 = 10e6 + 0.5 * p12, 10e6 - 0.5 * p12
    x_s = np.where(t < 2.0, 4e-6, -3e-6)
    meas = {"t": t, "x_cmd": x_cmd, "x_j": x_j, "x_s": x_s, "p1": p1, "p2": p2}
    holds = hold_windows(meas, 20e6)
    assert len(holds) == 2
    (xa, p1a, p2a), (xb, p1b, p2b) = holds
    assert (xa, p1a - p2a) == pytest.approx((4e-6, 3e6), rel=1e-9)
    assert (xb, p1b - p2b) == pytest.approx((-3e-6, -2e6), rel=1e-9)
    # a command that never stops has no hold
    assert hold_windows({**meas, "x_cmd": 1e-3 * np.sin(2 * np.pi * t)}, 20e6) == []


def test_hold_reading_inverts_the_wh_law():
    """Solve the WH law's two chamber balances for (P1, P2) at a given x_S and C_Lk with the
    jack still; ``hold_reading`` at that (x_S, P1, P2) gives that C_Lk back."""
    base = Baseline.default("WH").model_copy(update={"x_0": 0.4e-6, "skew": 0.01})
    rp = base.reduced_params()
    for x_s, c in ((15e-6, 2e-13), (-9e-6, 7e-13), (30e-6, 1e-12)):

        def balance(p, x_s=x_s, c=c):
            q1, q2, q3, q4 = land_flows(x_s - rp.x_0, p[0], p[1], 20e6, rp)
            return [1e6 * (q1 - q2 - c * (p[0] - p[1])), 1e6 * (q3 - q4 + c * (p[0] - p[1]))]

        p1, p2 = fsolve(balance, [10e6, 10e6], xtol=1e-13)
        assert abs(p1 - p2) > 1e6
        assert hold_reading(base, x_s, p1, p2, 20e6) == pytest.approx(c, rel=1e-6)


def test_the_calibration_segment_holds_under_both_loads():
    """The suite's calibration segment: its sines end at a zero crossing, then the jack holds
    under the second load and under the first one again; ``hold_windows`` finds both."""
    dc = duty_cycle(3, 17)
    cal = dc.calibration
    assert cal.duration_s == CAL_HOLD_END_S
    assert all(p.t_end == CAL_SINE_END_S for p in cal.command.periodic)
    assert [e.t for e in cal.load.events] == [2.5, CAL_HOLD_SWAP_S]
    assert cal.load.events[-1].value == cal.load.initial
    _, meas = measured_run(cal)
    p12 = [h[1] - h[2] for h in hold_windows(meas, 20e6)]
    assert len(p12) >= 2 and min(p12) < -1e6 and max(p12) > 1e6


@pytest.mark.parametrize(("seed", "index"), [(3, 17), (1, 29), (2, 0)])
def test_hold_fit_reads_nominal_at_the_plants_holds(seed, index):
    """On three suite plants, the C_Lk the calibrated WH law reads at the HF plant's static
    holds (rated supply, nominal leak, P12 from -6 to 6 MPa): 0.019 / 0.080 / 0.038 RMS of
    nominal C_Lk from the passes over the whole segment (``holds=False``), 0.006 / 0.018 /
    0.005 once fitted to the segment's holds (for (3, 17): 0.025 before WH's one ROS2 step
    per sample; before the WH model's stiction the passes left 0.040 / 0.072 / 0.047; with
    the C_Lk walk at 1e-13, 0.028 / 0.079 / 0.036)."""
    dc = duty_cycle(seed, index)
    plant = EHAParams().with_overrides(**dc.params)
    _, meas = measured_run(dc.calibration)
    cfg = MonitorConfig(model="WH").model_copy(update={"noise": identify_noise(meas)})
    before = calibrate(meas, config=cfg, holds=False)
    after = calibrate(meas, config=cfg)
    err = {id(before): [], id(after): []}
    for p12 in (-6e6, -4e6, -2e6, 2e6, 4e6, 6e6):
        x_s, p1, p2 = hf_static_hold(p12, plant.p_sr, plant)
        for b in (before, after):
            err[id(b)].append(hold_reading(b, x_s, p1, p2, plant.p_sr) / plant.c_lk - 1.0)
    rms_before = float(np.sqrt(np.mean(np.square(err[id(before)]))))
    rms_after = float(np.sqrt(np.mean(np.square(err[id(after)]))))
    assert rms_before > 0.015
    assert rms_after < 0.02 and rms_after < 0.5 * rms_before


def test_no_holds_no_fit():
    """The bundled healthy run (small sines, never still) has no hold: the baseline is the
    passes' one, whether or not the hold fit is asked for."""
    from service.sim.scenarios import load_scenario

    _, meas = measured_run(load_scenario("healthy_noise").model_copy(update={"duration_s": 3.0}))
    cfg = MonitorConfig(model="WH")
    assert hold_windows(meas, 20e6) == []
    a, b = calibrate(meas, config=cfg), calibrate(meas, config=cfg, holds=False)
    assert (a.x_0, a.x_ss, a.g_pq) == (b.x_0, b.x_ss, b.g_pq)


def test_a_fit_far_from_the_passes_baseline_is_not_taken():
    """Holds whose spool positions are 40 um off what the baseline law expects (a spool
    sensor offset, say) would need x_0 moved by 40 % of x_SS: the fit is refused and the
    passes' baseline kept; the same holds as measured are fitted."""
    from service.monitor.calibration import hold_fit

    dc = duty_cycle(3, 17)
    _, meas = measured_run(dc.calibration)
    cfg = MonitorConfig(model="WH").model_copy(update={"noise": identify_noise(meas)})
    base = calibrate(meas, config=cfg, holds=False)
    assert hold_fit(meas, base) != base
    shifted = {**meas, "x_s": np.asarray(meas["x_s"]) + 40e-6}
    assert hold_fit(shifted, base) == base
