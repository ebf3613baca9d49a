"""The leak alarm keeps its state through a supply transient (AlarmConfig.leak_mask_*;
docs/estimation.md, "Leak alarm during a supply transient")."""

from __future__ import annotations

import pytest

from service.monitor import AlarmConfig, MonitorConfig
from service.monitor.calibration import measured_run, run_monitor
from service.sim.scenarios import load_scenario

T_DROP = 1.5  # supply_drop: P_SR 20 -> 14 MPa (0.7 rated) at 1.5 s


@pytest.fixture(scope="module")
def supply_drop():
    sc = load_scenario("supply_drop").model_copy(update={"duration_s": 2.4})
    return measured_run(sc)


def _raised(meas, **alarms) -> dict[str, float]:
    """First raise time per alarm kind, alarms armed 10 ms before the drop and the leak level
    set below the healthy ratio: the leak condition starts with the supply transient."""
    cfg = MonitorConfig(
        arm_s=T_DROP - 0.01, alarms=AlarmConfig(leak_raise=0.5, leak_clear=0.2, **alarms)
    )
    outs, _ = run_monitor(meas, cfg)
    out: dict[str, float] = {}
    for e in (e for o in outs if o is not None for e in o.events):
        if e.state == "raised":
            out.setdefault(e.kind, e.t)
    return out


def test_leak_alarm_waits_out_a_supply_transient(supply_drop):
    _, meas = supply_drop
    hold = AlarmConfig().hold_s
    off = _raised(meas, leak_mask_s=0.0)
    assert off["leak"] == pytest.approx(T_DROP - 0.01 + hold, abs=2e-3)  # no mask: at once
    on = _raised(meas)  # defaults: 5 % of rated against the 50 ms lag, then 0.2 s
    mask = AlarmConfig().leak_mask_s
    # the drop (30 % of rated) is seen within a few samples and lasts while the lagged
    # ratio follows (about 50 ms ln(0.3 / 0.05) = 90 ms): the raise comes mask_s + hold after
    assert T_DROP + mask + hold < on["leak"] < T_DROP + 0.15 + mask + hold
    # the supply alarm itself is not masked
    assert on["supply"] == pytest.approx(off["supply"], abs=1e-9)
    assert on["supply"] < T_DROP + 0.15


def test_mask_settings_are_validated():
    with pytest.raises(ValueError, match="leak_mask_tau_s"):
        AlarmConfig(leak_mask_tau_s=0.0)
    with pytest.raises(ValueError, match="leak_mask_supply"):
        AlarmConfig(leak_mask_supply=-0.1)
    with pytest.raises(ValueError, match="leak_mask_s"):
        AlarmConfig(leak_mask_s=-1.0)


def test_walks_the_filter_uses():
    """The C_Lk and chamber walks of the louder setting tried in docs/estimation.md reach the
    filter as set (q = (walk / state scale)^2; WH's louder C_Lk walk:
    docs/decisions/0002-wh-c-lk-walk.md)."""
    from service.monitor import MonitorBank

    s_c, s_p = 1e-13, 1e6  # filter units of C_Lk and of the chamber states
    for model in ("WH", "C5"):
        bank = MonitorBank(MonitorConfig(model=model, process={"c_lk": 1.7e-13}))
        assert bank._q[6] == pytest.approx((1.7e-13 / s_c) ** 2)
    loud = MonitorConfig(model="WH", process={"c_lk": 2e-13, "p_ch": 2e6})
    bank = MonitorBank(loud)
    assert bank._q[6] == pytest.approx((2e-13 / s_c) ** 2)
    assert bank._q[8:].tolist() == pytest.approx([(2e6 / s_p) ** 2, (1e5 / s_p) ** 2])


@pytest.mark.slow
def test_no_false_leak_alarm_at_a_supply_drop_during_a_hold():
    """Suite member dc1_007 (a 1.71x leak ramp, then the supply drops to 0.62 rated during a
    hold) on the louder C_Lk walk of docs/evaluation.md ("WH against C5 over noise seeds"):
    C_Lk read 2.7x for 70 ms before P_SR followed and, unmasked, raised a false leak alarm
    (the truth never passes the clear level)."""
    from evaluation.dutycycle import duty_cycle
    from evaluation.suite import run_one

    dc = duty_cycle(1, 7)
    loud = {"process": {"c_lk": 1.5e-13, "p_ch": 1.5e6, "p_ch_common": 7e4}}
    masked = run_one(dc, model="WH", overrides={**loud, "alarms": {"leak_z": 0.0}})
    assert masked["false"] == 0
    assert any(kind == "supply" for _, kind, _ in masked["alarms"])
    unmasked = run_one(
        dc, model="WH", overrides={**loud, "alarms": {"leak_mask_s": 0.0, "leak_z": 0.0}}
    )
    assert unmasked["false"] == 1
