"""The filter on large duty cycles with the WH process model (docs/estimation.md, "WH
process model"): the lands' hydraulic null, adaptive process noise, the |P12| gate, the
null refinement of the calibration, and suite members that meet every target of issue 10."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evaluation.dutycycle import duty_cycle
from models import eha_reduced_wh as erw
from service.monitor import EST_KEYS, Baseline, MonitorBank, MonitorConfig
from service.monitor.calibration import bank_rows, calibrate, identify_noise, measured_run
from service.sim.scenarios import load_scenario

ROOT = Path(__file__).resolve().parent.parent
C_LK = EST_KEYS.index("c_lk")


def _suite_module():
    from evaluation import suite

    return suite


def test_wh_lands_see_the_spool_from_its_hydraulic_null():
    """Compiled and numpy steps agree with x_0 != 0, and x_0 moves the chamber flows."""
    base = Baseline.default("WH").model_copy(update={"x_0": 2e-6, "skew": 0.02})
    rp = base.reduced_params()
    assert rp.x_0 == 2e-6 and rp.skew == 0.02
    prm = erw.param_vector(rp, base.v_c, base.beta)
    x = np.array([1.1e-5, 2e-4, 1e-3, 2e-3, 4000.0, 19.5e6, 3e-13, 5e-5, 12.6e6, 8.4e6])
    out = np.empty(10)
    erw.step_nb(x, 2.3e-4, 1e-3, 3, prm, out)
    ref = erw.step(x, 2.3e-4, 1e-3, rp, 3, base.v_c, base.beta)
    np.testing.assert_allclose(out, ref, rtol=1e-11, atol=1e-12)
    for rp0 in (rp._replace(x_0=0.0), rp._replace(skew=0.0)):
        ref0 = erw.step(x, 2.3e-4, 1e-3, rp0, 3, base.v_c, base.beta)
        assert abs(ref[8] - ref0[8]) > 1e4  # both move chamber 1 by tens of kPa in 1 ms


def test_land_skew_sets_the_chamber_pressures_at_null():
    """At null, with the jack held, each chamber sits at P_R + f P_SR, f = k^2 / (1 + k^2),
    k = (1 + skew) / (1 - skew) (docs/estimation.md, "WH's calibration: land skew"): run the
    numpy model to rest from mid-supply and compare, at two supplies (f does not move). The
    orifices only: the lands' clearance leak, the same on every open land, pulls towards
    mid-supply and is off here."""
    base = Baseline.default("WH").model_copy(update={"skew": 0.03, "c_lk": 0.0, "c_land": 0.0})
    rp = base.reduced_params()
    k = 1.03 / 0.97
    f = k * k / (1 + k * k)
    for p_sr in (20e6, 12e6):
        mid = rp.p_r + 0.5 * p_sr
        x = np.array([0.0, 0.0, 0.0, 0.0, 0.0, p_sr, 0.0, 0.0, mid, mid])
        for _ in range(200):
            x = erw.step(x, 0.0, 1e-3, rp._replace(mass=1e9), 3, base.v_c, base.beta)
            x[2:4] = 0.0  # jack held
        assert (x[8] - rp.p_r) / p_sr == pytest.approx(f, rel=2e-3)
        assert (x[9] - rp.p_r) / p_sr == pytest.approx(f, rel=2e-3)


def test_p_sr_after_a_drop_on_a_mismatched_plant():
    """Suite member 11 (seed 1): lands 88-92 um, supply drop with a 2.9x leak step. With the
    chamber-pressure offset read as a return-pressure offset, WH's P_SR read 2.0 % high over
    the last second and the C_Lk increase 22 % high; as a land skew, within 0.5 % and 15 %
    (+12 %: the lands' clearance leak, docs/estimation.md "Land clearance leak (WH)", moved it
    from +7 %; +20 % with the jack's stiction, "Stiction in the WH process model", which
    makes the suite's member dc1_011 miss its 10 %)."""
    dc = duty_cycle(1, 11)
    _, mc = measured_run(dc.calibration)
    cfg = MonitorConfig(model="WH").model_copy(update={"noise": identify_noise(mc)})
    base = calibrate(mc, config=cfg)
    assert base.p_r == Baseline.nominal("WH").p_r and base.skew != 0.0
    sim, meas = measured_run(dc.test)
    rows = bank_rows(meas, cfg, base)
    last = rows.t >= rows.t[-1] - 1.0
    p_sr = rows.est[last, EST_KEYS.index("p_sr")].mean()
    assert abs(p_sr / sim.p_sr[-1] - 1.0) < 0.005
    inc_true = sim.c_lk[-1] - sim.c_lk[0]
    inc = rows.est[last, C_LK].mean() - base.c_lk
    assert abs(inc / inc_true - 1.0) < 0.25


def test_gate_share_validated():
    with pytest.raises(ValueError, match="c_lk_gate_p12"):
        MonitorConfig(c_lk_gate_p12=1.5)


def _meas(name: str, duration: float | None = None):
    sc = load_scenario(name)
    if duration is not None:
        sc = sc.model_copy(update={"duration_s": duration})
    return measured_run(sc)[1]


def test_adaptive_process_noise_removes_the_reinitialisations_of_load_reversals():
    """est_load_reversal (+-12 kN every 0.5 s): the WH filter without adaptive process noise
    re-initialises at the load steps; with it (the WH default) it does not, and its NIS stays
    in band. A threshold no sample reaches is bit-for-bit the filter without it."""
    from service.monitor import RES_KEYS

    meas = _meas("est_load_reversal", 2.5)
    cfg_on = MonitorConfig(model="WH")
    base = Baseline.default("WH")
    bank_off = MonitorBank(MonitorConfig(model="WH", adapt_nis=0), base)
    bank_on = MonitorBank(cfg_on, base)
    from service.monitor.calibration import meas_channels

    ch, t = meas_channels(meas), np.asarray(meas["t"])
    r_off = bank_off.update_arrays(np.zeros(len(t), np.int64) + bank_off.index_of("a"), t, ch)
    r_on = bank_on.update_arrays(np.zeros(len(t), np.int64) + bank_on.index_of("a"), t, ch)
    assert bank_off.counters_of("a")["reinit"] >= 2
    assert bank_on.counters_of("a")["reinit"] == 0
    from scipy.stats import chi2

    nis, dof = r_on.res[:, RES_KEYS.index("nis")], r_on.res[:, RES_KEYS.index("nis_dof")]
    sel = (r_on.t > r_on.t[0] + 0.5) & (dof > 0)
    inb = (nis[sel] >= chi2.ppf(0.025, dof[sel])) & (nis[sel] <= chi2.ppf(0.975, dof[sel]))
    assert inb.mean() >= 0.9
    never = MonitorBank(MonitorConfig(model="WH", adapt_nis=1e12), base)
    r_never = never.update_arrays(np.zeros(len(t), np.int64) + never.index_of("a"), t, ch)
    np.testing.assert_array_equal(r_never.est, r_off.est)


def test_p12_gate_holds_c_lk_below_the_gate():
    """healthy_noise holds P12 near 4 MPa: a gate at 10 MPa (0.5 of rated) keeps C_Lk at its
    prior on every sample; without the gate C_Lk moves."""
    meas = _meas("healthy_noise", 1.0)
    base = Baseline.default("WH")
    held = bank_rows(meas, MonitorConfig(model="WH", c_lk_gate_p12=0.5), base).est[:, C_LK]
    free = bank_rows(meas, MonitorConfig(model="WH", c_lk_gate_p12=0.0), base).est[:, C_LK]
    np.testing.assert_array_equal(held, np.full_like(held, base.c_lk))
    assert np.ptp(free) > 0.05 * base.c_lk


def _hold_at(dc, p12: float, seed: int, duration_s: float = 4.0):
    """Measured run of ``dc``'s plant held at mid stroke under the load that gives ``p12``."""
    from models.params import EHAParams
    from models.scenario import Profile

    area = EHAParams().with_overrides(**dc.params).area
    scen = dc.calibration.model_copy(
        update={
            "name": "hold",
            "duration_s": duration_s,
            "command": Profile(initial=0.0),
            "load": Profile(initial=p12 * area),
            "sensors": dc.calibration.sensors.model_copy(update={"seed": seed}),
        }
    )
    return measured_run(scen)[1]


def test_p12_gate_on_a_low_pass_removes_the_selection_bias():
    """A hold at |P12| = 1.1 MPa, 10 % above the 1 MPa gate, on suite member dc3_012's plant
    (noise 1.23x the bundled, so the measured P1 - P2 has a 1-sigma of about 0.1 MPa). Gated on
    each sample's own measured P1 - P2, C_Lk is learnt only from the samples whose noise
    raised |P12|, and the filter drove it to 0.45-0.76x nominal over three noise seeds; gated on
    the 50 ms low-pass of the samples before (the default), within 15 % of nominal."""
    dc = duty_cycle(3, 12)
    _, mc = measured_run(dc.calibration)
    cfg = MonitorConfig(model="WH").model_copy(update={"noise": identify_noise(mc)})
    assert cfg.c_lk_gate_p12_tau_s == 0.05
    base = calibrate(mc, config=cfg)
    for seed in (1, 2, 3):
        meas = _hold_at(dc, 1.1e6, seed)
        per_sample = cfg.model_copy(update={"c_lk_gate_p12_tau_s": 0.0})
        c_sample = bank_rows(meas, per_sample, base).est[-2000:, C_LK] / base.c_lk
        c_low = bank_rows(meas, cfg, base).est[-2000:, C_LK] / base.c_lk
        assert float(np.mean(c_sample)) < 0.85, seed
        assert abs(float(np.mean(c_low)) - 1.0) < 0.15, seed


def test_null_refinement_reads_nominal_on_a_mismatched_plant():
    """Suite member 13 (seed 1): lands 106-110 um, calibration at +-2-5 kN. With the null fitted
    from rest points only, the WH monitor read C_Lk 0.37x nominal at rest at the start of the
    test run; with the refinement from its own C_Lk bias against 1/P12, within 15 %."""
    dc = duty_cycle(1, 13)
    _, mc = measured_run(dc.calibration)
    cfg = MonitorConfig(model="WH").model_copy(update={"noise": identify_noise(mc)})
    base = calibrate(mc, config=cfg)
    assert base.law == "WH" and base.x_0 != 0.0
    _, meas = measured_run(dc.test.model_copy(update={"duration_s": 1.0}))
    c = bank_rows(meas, cfg, base).est[:, C_LK]
    assert 0.85 < float(np.mean(c[200:])) / base.c_lk < 1.15


@pytest.mark.slow
def test_suite_members_meet_every_target_of_issue_10():
    """Four members of the seed-1 suite (healthy, leak step, supply drop, slow leak growth)
    meet every target with the default WH monitor (evaluation/suite.py)."""
    suite = _suite_module()
    for index in (0, 1, 10, 21):
        r = suite.run_one(duty_cycle(1, index), model="WH")
        assert suite.failures(r) == [], (index, r)
        assert r["reinit"] == 0


def test_p_sr_clip_above_rated_removes_the_wh_bias_at_rated_supply():
    """With the fast supply walk of the C-types (2 MPa/sqrt(s), chambers uncorrelated), WH
    read P_SR through its flows with a sigma of about 1 % of rated: clipped at rated, its mean
    read 0.27 % low on the healthy bench at rated supply; clipped at 1.05 x rated, within
    0.1 %. With the slow supply walk (3e5 Pa/sqrt(s)) the mean is within 0.1 % too."""
    meas = _meas("healthy_noise", 2.0)
    base = Baseline.default("WH")
    p_sr = EST_KEYS.index("p_sr")
    fast = {"process": {"p_sr": 2e6, "p_ch_common": 1e6}, "adapt_p_sr": 0.0}
    cases = ((1.0, fast, -0.005, -0.0015), (1.05, fast, -0.001, 0.001), (1.05, {}, -0.001, 0.001))
    for ratio, walk, lo, hi in cases:
        cfg = MonitorConfig(model="WH", p_sr_max_ratio=ratio, **walk)
        rows = bank_rows(meas, cfg, base)
        err = float(np.mean(rows.est[rows.t > 0.5, p_sr])) / base.p_sr_rated - 1.0
        assert lo < err < hi, (ratio, walk, err)
