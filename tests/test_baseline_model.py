"""A baseline records the process model it was identified for, and a monitor on another model
refuses it: the bank raises, the fleet monitors the actuator on its default baseline
(uncommissioned, logged), the commands exit with an error naming both models."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from service.cli import main
from service.monitor import (
    Baseline,
    BaselineModelError,
    MonitorBank,
    MonitorConfig,
    MonitorFleet,
)


def test_bank_refuses_a_baseline_of_another_model():
    with pytest.raises(BaselineModelError, match="C5.*WH"):
        MonitorBank(MonitorConfig(model="WH"), Baseline.default("C5"))
    bank = MonitorBank(MonitorConfig(model="C5"), Baseline.default("C5"))
    bank.index_of("a")
    with pytest.raises(BaselineModelError, match="WH.*C5"):
        bank.set_baseline("a", Baseline.default("WH"))
    assert bank.baseline_of("a").law == "C5"  # the row kept its own


def test_bank_without_a_baseline_takes_its_models_default():
    for model in ("C1", "C5", "WH"):
        assert MonitorBank(MonitorConfig(model=model)).baseline.law == model


def test_fleet_monitors_a_stored_baseline_of_another_model_on_the_default(caplog):
    stored = Baseline.default("C5").model_copy(update={"c_lk": 3e-13})
    fleet = MonitorFleet(MonitorConfig(model="WH"), resolve=lambda key: (stored, 4))
    with caplog.at_level(logging.ERROR, logger="service.monitor.fleet"):
        k = fleet.index_of("unit1")
    assert fleet.bank.baseline_of("unit1") == fleet.baseline
    assert fleet.versions["unit1"] is None and not fleet.commissioned("unit1")
    assert fleet.refused == {"unit1": "C5"}
    assert "C5" in caplog.text and "WH" in caplog.text
    t = np.arange(5) * 1e-3
    ch = np.tile([0.0, 0.0, 0.0, 0.0, 12e6, 9e6, np.nan], (5, 1))
    rows = fleet.update_arrays(np.full(5, k), t, ch)
    assert len(rows.t) == 5 and np.isfinite(rows.est).all()
    same = MonitorFleet(MonitorConfig(model="C5"), resolve=lambda key: (stored, 4))
    same.index_of("unit1")
    assert same.bank.baseline_of("unit1") == stored and same.versions["unit1"] == 4


def test_estimate_refuses_a_baseline_of_another_model(tmp_path, capsys):
    f = tmp_path / "c5.json"
    Baseline.default("C5").save(f)
    rc = main(["estimate", "--scenario", "healthy_noise", "--baseline", str(f), "--duration",
               "0.6"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2
    assert "C5" in err and "WH" in err and "calibrate" in err
    rc = main(["estimate", "--scenario", "healthy_noise", "--baseline", str(f), "--duration",
               "0.6", "--model", "C5", "--json"])  # fmt: skip
    assert rc == 0


def test_baseline_records_its_model(tmp_path):
    f = tmp_path / "b.json"
    Baseline.default("C3").save(f)
    assert Baseline.load(f).law == "C3"
    d = Baseline.default("C3").model_dump()
    del d["law"]
    with pytest.raises(ValueError, match="law"):
        Baseline.model_validate(d)
