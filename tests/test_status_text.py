"""``servowatch status``'s text of a unit: the fields an operator acts on, chosen by name
(C_Lk and its sigma, the leak and supply ratios, NIS in band, alarms, commissioning and
baseline version, RUL on the history's own axis), for the WH model and a C-type."""

from __future__ import annotations

import re

import numpy as np
import pytest

from models.scenario import Profile
from service.cli.commands.status import format_rul, format_status
from service.config import PrognosticsSettings, ServiceConfig
from service.daemon import Daemon
from service.monitor import EST_KEYS
from service.monitor.calibration import measured_run
from service.prognostics.rul import History, rul_of_history
from service.replay.fleetsim import C_LK_NOMINAL
from service.sim.scenarios import load_scenario
from service.store import open_store
from service.wire.messages import encode_meas
from tests._c_type import c_type_config

CH = ("x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr")
KEY = "fleet/AC7/rudder/meas"
NAME = "AC7/rudder"


def _leak_run(ratio: float, duration_s: float) -> dict:
    sc = load_scenario("healthy_noise")
    sc = sc.model_copy(
        update={"duration_s": duration_s, "leak": Profile(initial=ratio * C_LK_NOMINAL)}
    )
    return measured_run(sc)[1]


def _feed(d: Daemon, meas: dict, key: str = KEY, per: int = 50) -> None:
    """``meas`` into ``d`` as meas messages on ``key`` of ``per`` rows each, all processed."""
    n = len(meas["t"])
    for a in range(0, n, per):
        rows = [{"seq": j, "t": float(meas["t"][j]), **{c: float(meas[c][j]) for c in CH
                 if c in meas}} for j in range(a, min(a + per, n))]  # fmt: skip
        d.submit(key, encode_meas(rows))
    while d.queued:
        d.process_pending()


def _flights_rul() -> dict:
    """A RUL on a history that counts flights (one period per flight, a rising ratio)."""
    t_h = np.cumsum(np.full(12, 2.0))
    y = 1.0 + 0.08 * np.arange(12)
    h = History(NAME, t_h, y, 2.0, np.arange(1.0, 13.0), 1.7e9 + 86400.0 * np.arange(12))
    return rul_of_history(h)


@pytest.fixture(scope="module")
def leak_meas():
    return _leak_run(4.0, 3.0)


@pytest.mark.parametrize("model", ["WH", "C5"])
def test_status_text_names_the_operators_fields(tmp_path, leak_meas, model):
    """A daemon on ``model`` fed 3 s of a unit leaking at 4x nominal, with a baseline (v1) and
    a RUL on flights in its store: the unit's text shows C_Lk +- sigma, the leak and supply
    ratios and the NIS in band of its status (by name, so never the spool's x_s, v_s), the
    active leak alarm, the baseline version and the RUL in flights with its days."""
    store = tmp_path / "h.sqlite"
    rul = _flights_rul()
    mc = c_type_config(model) if model != "WH" else None
    cfg = ServiceConfig(
        store=str(store),
        prognostics=PrognosticsSettings(period_window_s=1.0),
        **({"monitor": mc} if mc is not None else {}),
    )
    from service.monitor import Baseline

    with open_store(store) as s:
        s.add_baseline(NAME, Baseline.default(model).model_dump(), "test")
        s.put_rul(NAME, rul)
    d = Daemon(cfg, log_path=tmp_path / "d.mcap", log_process=False, gather_s=0)
    try:
        _feed(d, leak_meas)
        st = d.status()
    finally:
        d.stop()
    a = st["actuators"][KEY]
    assert st["model"] == model
    est, health = a["est"], a["health"]
    # the model's first estimate fields are the spool's (WH) or the jack's (C5), not C_Lk
    assert list(est)[:4] != ["c_lk", "c_lk_sigma"] and list(est) == list(EST_KEYS)
    text = format_status({"monitor/ground1/0/status": st})
    lines = text.splitlines()
    i = next(j for j, ln in enumerate(lines) if ln.strip().startswith(NAME + ":"))
    head, ind, flags = lines[i : i + 3]
    assert f"{a['samples']} samples" in head and a["samples"] == len(leak_meas["t"])
    m = re.fullmatch(
        r"\s+C_Lk (\S+) \+- (\S+) m\^3/\(s Pa\), leak ratio (\S+), supply ratio (\S+), "
        r"NIS in band (\d+) %, pooled (\S+) \+- (\S+)",
        ind,
    )
    assert m, ind
    assert float(m[6]) == pytest.approx(a["c_lk_pooled"]["value"], rel=1e-2)
    assert float(m[7]) == pytest.approx(a["c_lk_pooled"]["sigma"], rel=1e-1)
    assert float(m[7]) < 0.5 * est["c_lk_sigma"]  # the pool keeps what the walk forgets
    assert float(m[1]) == pytest.approx(est["c_lk"], rel=1e-2)
    assert float(m[2]) == pytest.approx(est["c_lk_sigma"], rel=1e-1)
    assert float(m[3]) == pytest.approx(health["leak_ratio"], rel=1e-2)
    assert float(m[3]) > 2.5  # 4x nominal read as a leak over the raise level
    assert float(m[4]) == pytest.approx(health["supply_ratio"], rel=1e-2)
    assert 0.0 < a["nis_in_band"] <= 1.0
    assert int(m[5]) == round(100 * a["nis_in_band"])
    for k in ("x_s", "v_s", "x_j", "v_j"):
        assert f"{k}=" not in text
    assert [al["kind"] for al in a["alarms"]] == ["leak"]
    assert f"ALARM leak ({a['alarms'][0]['value']:.3g})" in flags
    assert "commissioned, baseline v1" in flags
    assert rul["axis"] == "flights" and rul["median_flights"] is not None
    want = f"RUL {rul['median_flights']:.0f} flights [{rul['lo_flights']:.0f}-"
    assert want in flags and f"~{rul['median_days']:.0f} d" in flags
    assert " h " not in flags and "RUL - h" not in text


def test_rul_text_on_the_hours_axis_and_without_one():
    """A history without flight numbers counts operating hours; too short a history says
    so; none stored is a dash."""
    h = History(NAME, np.cumsum(np.full(12, 3.0)), 1.0 + 0.08 * np.arange(12), None)
    rul = rul_of_history(h)
    assert rul["axis"] == "hours" and rul["median_h"] is not None
    assert format_rul(rul).startswith(f"RUL {rul['median_h']:.0f} h [{rul['lo_h']:.0f}-")
    short = rul_of_history(History(NAME, np.array([1.0]), np.array([1.0]), None))
    assert format_rul(short) == "RUL - (insufficient history)"
    assert format_rul(None) == "RUL -"


def test_unit_text_survives_missing_fields():
    """A status from an older daemon (no nis_in_band, no health yet) prints dashes."""
    st = {"actuators": {"k": {"aircraft": "A", "actuator": "b", "samples": 0, "dropped": 0,
                              "gaps": 0, "bad_total": 0, "est": {}, "health": {},
                              "alarms": []}}}  # fmt: skip
    text = format_status({"monitor/x/0/status": st})
    assert "C_Lk - +- - m^3/(s Pa), leak ratio -, supply ratio -, NIS in band -" in text
    assert "pooled" not in text  # an older daemon: no pooled C_Lk in its status


def test_unit_text_shows_the_pooled_c_lk_or_its_abstention():
    unit = {"aircraft": "A", "actuator": "b", "samples": 9, "dropped": 0, "gaps": 0,
            "bad_total": 0, "est": {}, "health": {}, "alarms": []}  # fmt: skip
    read = format_status({"m": {"actuators": {"k": {**unit, "c_lk_pooled": {
        "value": 4.1e-13, "sigma": 1.2e-14}}}}})  # fmt: skip
    assert "pooled 4.1e-13 +- 1.2e-14" in read
    none = format_status({"m": {"actuators": {"k": {**unit, "c_lk_pooled": None}}}})
    assert "pooled abstains" in none
