"""``evaluation/holds.py``: the C_Lk a law reads at the HF plant's static holds."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from evaluation import holds as hr
from models.eha_reduced import p12_state
from models.hf_valve import hf_static_hold
from models.params import EHAParams
from service.monitor import Baseline

ROOT = Path(__file__).resolve().parents[1]


def test_the_geometric_wh_law_reads_the_hf_holds():
    """WH with the valve's geometric values (``Baseline.nominal``) is the HF valve's own
    four-land law (turbulent lands, the laminar clearance apart): at every hold, rated and
    0.7 of rated supply, 1x to 5x leak, 2 and 4 kN, it reads C_Lk within 0.3 %; the hold
    carries the load (P12 = F_R / A)."""
    rows = hr.table({"WH": Baseline.nominal("WH")}, [1.0, 0.7], [1.0, 5.0], [4000.0, -2000.0])
    assert len(rows) == 8
    for r in rows:
        assert r["p12_mpa"] == pytest.approx(r["load_n"] / 1e3, rel=1e-6)  # A = 1e-3 m^2
        assert abs(r["WH"]) < 0.3, r


def test_a_c_type_reading_gives_the_holds_p12_back():
    """The C5 reading is the C_Lk at which the law, still jack, gives the hold's P12."""
    base = Baseline.default("C5")
    x_s, p1, p2 = hf_static_hold(4e6, 14e6, EHAParams(), 1e-12)
    c = hr.law_reading(base, x_s, p1, p2, 14e6)
    assert float(p12_state(x_s, 0.0, 14e6, c, base.reduced_params())) == pytest.approx(
        p1 - p2, rel=1e-9
    )


def test_cli_prints_the_table_and_refuses_a_zero_load():
    run = [sys.executable, "-m", "evaluation.holds"]
    out = subprocess.run([*run, "--supply", "1", "--leak", "5", "--load", "4000"],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)  # fmt: skip
    assert out.returncode == 0, out.stderr
    last = out.stdout.splitlines()[-1].split()
    assert [float(v) for v in last[:3]] == [1.0, 5.0, 4000.0] and len(last) == 7
    bad = subprocess.run(
        [*run, "--load", "0"], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert bad.returncode == 2 and "--load" in bad.stderr


def test_wh_default_is_the_datasheet_baseline():
    """WH's default baseline is its datasheet (geometric) values: no stored calibration."""
    assert Baseline.default("WH") == Baseline.nominal("WH")
    assert Baseline.default("C5").source.startswith("default calibration")


def test_cli_adds_one_column_per_calibration_seed():
    """``--calibrated-seeds 2``: WH calibrated on healthy_noise with sensor seeds 1 and 2, one
    column each, and the range over them; a calibration is not the datasheet (each seed's
    noise moves the law: its reading differs from the datasheet column)."""
    out = subprocess.run(
        [sys.executable, "-m", "evaluation.holds", "--calibrated-seeds", "2",
         "--supply", "1", "--leak", "1", "--load", "4000", "--models", "WH"],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    head = next(ln for ln in lines if ln.lstrip().startswith("supply")).split()
    assert head[-3:] == ["WH", "s1", "s2"]
    row = [float(v) for v in lines[-2].split()]
    assert abs(row[5]) < 0.3  # the datasheet values at 1x, rated supply
    assert row[6] != row[5] and row[7] != row[6]
    lo, hi = (float(v) for v in lines[-1].split(":")[1].replace("%", "").split(".."))
    assert lo == min(row[6:]) and hi == max(row[6:])
