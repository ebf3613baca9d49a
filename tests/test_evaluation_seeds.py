"""``evaluation/seeds.py``: two process models compared over sensor-noise seeds, paired
(issue 11), with its Student-t interval checked by hand."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from evaluation.seeds import RUNS, compare, paired

ROOT = Path(__file__).resolve().parents[1]


def test_paired_interval_by_hand():
    # d = 1, 1.1, 0.9: mean 1, sd 0.1; t(0.975, 2) = 4.3027 -> half width 4.3027 * 0.1 / sqrt 3
    a = [1.0, 2.0, 3.0]
    b = [2.0, 3.1, 3.9]
    r = paired(a, b, lower_better=True)
    half = 4.302653 * 0.1 / math.sqrt(3.0)
    assert r["n"] == 3 and r["one_only"] == 0
    assert r["mean_a"] == pytest.approx(2.0) and r["mean_b"] == pytest.approx(3.0)
    assert r["diff"] == pytest.approx(1.0)
    assert r["lo"] == pytest.approx(1.0 - half, rel=1e-5)
    assert r["hi"] == pytest.approx(1.0 + half, rel=1e-5)
    assert r["verdict"] == "B worse"  # lower is better and B is higher on every pair
    assert paired(a, b, lower_better=False)["verdict"] == "B better"


def test_paired_no_difference_and_missing_values():
    # d = 1, 1, 2 -> mean 4/3, sd 0.577: half width 1.434 spans zero
    r = paired([1.0, 2.0, 3.0], [2.0, 3.0, 5.0], lower_better=True)
    assert r["lo"] < 0 < r["hi"] and r["verdict"] == "-"
    # an alarm raised by one model only is counted, not paired
    r = paired([0.15, None, 0.16, None], [0.17, 0.2, 0.18, None], lower_better=True)
    assert r["n"] == 2 and r["one_only"] == 1
    assert r["diff"] == pytest.approx(0.02)
    # one pair: a mean but no interval
    r = paired([1.0], [2.0], lower_better=True)
    assert r["diff"] == 1.0 and r["lo"] is None and r["verdict"] == "-"
    assert paired([None], [None], True)["n"] == 0


def test_compare_rows_by_scenario_and_figure():
    def fig(v):
        return {"c_lk_rms": v, "c_lk_1s_abs": None, "p_sr_rms": 0.1, "p_sr_settle": None,
                "delay": None, "false": 0.0, "nis_in": 95.0, "reinit": 0.0}  # fmt: skip

    rows = [{"row": "x", "seed": s, "A": fig(10.0 + s), "B": fig(11.0 + s)} for s in (1, 2, 3)]
    cmp = compare(rows, "A", "B")
    by = {c["figure"]: c for c in cmp}
    assert "|C_Lk 1s|%" not in by and "delay s" not in by  # defined on no seed
    assert by["C_Lk rms%"]["diff"] == pytest.approx(1.0)
    # zero spread: the interval is the point, above zero -> B worse
    assert by["C_Lk rms%"]["verdict"] == "B worse"
    assert by["NIS in%"]["verdict"] == "-" and by["NIS in%"]["diff"] == 0.0


def _run(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "evaluation.seeds", *argv],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=ROOT,
    )


@pytest.mark.parametrize(
    "argv,msg",
    [
        (("--models", "C5"), "two different models"),
        (("--seeds", "1"), "at least 2"),
        (("--only", "nope"), "--only: unknown nope"),
        (("--set", "process.c_lk=1e-13"), "MODEL:FIELD=VALUE"),
        (("--set", "WH:nope=1"), "--model/--set"),
        (("--plant", "c_r"), "--plant 'c_r': expected FIELD=VALUE"),
        (("--plant", "c_r=wide"), "--plant 'c_r=wide': VALUE must be a number"),
        (("--plant", "c_rr=1e-6"), "c_rr"),
        (("--plant", "c_r=-1"), "c_r"),
    ],
)
def test_bad_arguments_are_named(argv, msg):
    r = _run(*argv)
    assert r.returncode == 2 and msg in r.stderr


@pytest.mark.slow
def test_two_seeds_end_to_end(tmp_path):
    out = tmp_path / "s.json"
    r = _run("--seeds", "2", "--only", "leak_step", "--workers", "1", "--json", str(out))
    assert r.returncode == 0, r.stderr
    assert "C5 (A) against WH (B), 2 sensor-noise seeds" in r.stdout
    d = json.loads(out.read_text())
    runs = d["runs"]
    assert [(x["row"], x["seed"]) for x in runs] == [("leak_step", 1), ("leak_step", 2)]
    # different noise seeds: different figures; the leak alarm raised on every run
    assert runs[0]["C5"]["c_lk_rms"] != runs[1]["C5"]["c_lk_rms"]
    for x in runs:
        for m in ("C5", "WH"):
            assert 0.0 < x[m]["delay"] < 1.0 and x[m]["false"] == 0.0
    rms = next(c for c in d["compare"] if c["figure"] == "C_Lk rms%")
    mean_b = (runs[0]["WH"]["c_lk_rms"] + runs[1]["WH"]["c_lk_rms"]) / 2
    assert rms["n"] == 2 and rms["mean_b"] == pytest.approx(mean_b)
    assert {r[0] for r in RUNS} >= {"leak_step_2x", "est_overload", "healthy_noise"}


def test_plant_overrides_join_the_scenario_params():
    """--plant adds EHAParams overrides to every scenario (its own kept) and, when set,
    calibrates each model on healthy_noise with that plant."""
    from evaluation.scenarios import bundled_scenario
    from evaluation.seeds import plant_baselines, plant_scenario
    from service.monitor import Baseline

    sc = plant_scenario("leak_step", {"c_r": 2.5e-7}, leak=4e-13)
    assert sc.params["c_r"] == 2.5e-7 and sc.leak.events[0].value == 4e-13
    assert "c_r" not in plant_scenario("leak_step", {}).params
    assert plant_scenario("leak_step", {}) == bundled_scenario("leak_step")
    base = plant_baselines(("C5", "WH"), {}, {})
    assert base["WH"] == Baseline.default("WH") and base["C5"] == Baseline.default("C5")
