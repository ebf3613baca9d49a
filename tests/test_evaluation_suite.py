"""``python -m evaluation.suite`` (issue 10): the randomized duty-cycle suite, its figures,
recap and plot."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
FIGURES = {"inc%", "ind%", "bias%", "psr%", "psr_all%", "nis%", "reinit", "false", "delay", "obs"}


def _run(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "evaluation.suite", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )


def test_suite_writes_every_figure_and_its_summary(tmp_path):
    out = tmp_path / "suite.json"
    argv = ("--suite", "2", "--seed", "1", "--only", "0,1", "--workers", "1", "--json")
    r = _run(*argv, str(out))
    assert r.returncode == 0, r.stderr
    assert "suite seed 1, 2 duty cycles" in r.stdout
    assert "figure   n   median    worst   target" in r.stdout
    d = json.loads(out.read_text())
    rows, s = d["rows"], d["summary"]
    assert [row["name"] for row in rows] == ["dc1_000", "dc1_001"]
    for row in rows:
        assert set(row) >= FIGURES
        assert 0.0 <= row["nis%"] <= 100.0
        assert isinstance(row["reinit"], int) and row["reinit"] >= 0
        assert isinstance(row["false"], int) and row["false"] >= 0
        for k in ("inc%", "ind%", "bias%", "psr%", "delay"):
            assert row[k] is None or math.isfinite(row[k]) or row[k] == math.inf
    # summary: distribution (median) and worst case over the 2 duty cycles
    assert s["nis%"]["n"] == 2 and s["reinit"]["n"] == 2 and s["false"]["n"] == 2
    assert s["nis%"]["worst"] == min(row["nis%"] for row in rows)
    assert s["reinit"]["worst"] == max(row["reinit"] for row in rows)
    assert s["false"]["median"] == sum(row["false"] for row in rows) / 2
    assert "failing" in s and "reinit_healthy" in s


def test_first_observable_window_by_hand():
    """The end of the first run of gate-open samples at least hold_s long, from t0."""
    from evaluation.suite import failures, first_observable

    t = [round(0.01 * j, 2) for j in range(100)]  # 0 .. 0.99 s, 10 ms apart
    v = [0.02 if j < 30 or 40 <= j < 45 else 0.0 for j in range(100)]  # moving before 0.3 s
    x_s = [0.0] * 100
    p12 = [3e6 if j != 33 else 0.5e6 for j in range(100)]  # one low sample at 0.33 s
    args = dict(v_max=0.01, x_s_max=1e-4, p12_min=1e6, hold_s=0.05)
    arr = [np.asarray(a, float) for a in (t, v, x_s, p12)]
    # from 0.1 s: the run 0.30-0.32 is too short (0.33 fails |P12|), 0.34-0.39 lasts 0.05 s
    assert first_observable(*arr, t0=0.1, **args) == pytest.approx(0.34 + 0.05 - 0.1)
    assert first_observable(*arr, t0=0.36, **args) == pytest.approx(0.45 + 0.05 - 0.36)
    assert math.isinf(first_observable(*arr, t0=0.98, **args))
    # a late alarm is marked when even the first observable window came after the target
    row = {"inc%": None, "psr%": None, "false": 0, "nis%": 95.0, "reinit": 0, "kind": "leak"}
    assert failures({**row, "delay": 1.2, "obs": 1.1}) == ["delay(obs)"]
    assert failures({**row, "delay": 1.2, "obs": 0.4}) == ["delay"]
    assert failures({**row, "delay": 0.9, "obs": 0.4}) == []


def test_monitor_run_on_a_nominal_plant_and_the_datasheet_baseline():
    """nominal_plant takes the member's plant without tolerances (and, frictionless, without
    Coulomb or breakaway friction); monitor_run's datasheet_baseline runs the monitor on
    Baseline.nominal, not calibrated, and plant_friction gives it the plant's F_d = F_s = 0."""
    from evaluation.dutycycle import duty_cycle, nominal_plant
    from evaluation.suite import monitor_run
    from service.monitor import Baseline

    dc = nominal_plant(duty_cycle(6, 0))
    assert dc.params == {} and dc.test.params == {} != duty_cycle(6, 0).params
    _, _, base, _, _ = monitor_run(dc, model="WH", datasheet_baseline=True)
    assert base == Baseline.nominal("WH")
    dc = nominal_plant(duty_cycle(6, 0), frictionless=True)
    assert (dc.params["f_d"], dc.params["f_s"]) == (0.0, 0.0)
    _, _, base, _, _ = monitor_run(dc, plant_friction=True, datasheet_baseline=True)
    assert (base.f_d, base.f_s) == (0.0, 0.0)


def test_suite_noise_scale_runs_the_member_with_its_noise_scaled(tmp_path):
    """evaluation/suite.py --noise-scale 0.1: the member's row is run_one on
    scale_noise(member, 0.1) (its printed noise scale a tenth of the member's), not the
    member as drawn; a negative factor exits 2, naming the option."""
    from evaluation.dutycycle import duty_cycle, scale_noise
    from evaluation.suite import run_one

    out = tmp_path / "s.json"
    r = _run("--seed", "1", "--only", "0", "--workers", "1",
             "--noise-scale", "0.1", "--json", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    (row,) = json.loads(out.read_text())["rows"]
    dc = duty_cycle(1, 0)
    assert row["noise_scale"] == pytest.approx(0.1 * dc.noise_scale)
    want = run_one(scale_noise(dc, 0.1), model="WH")
    assert row["bias%"] == pytest.approx(want["bias%"], rel=1e-9)
    assert row["bias%"] != pytest.approx(run_one(dc, model="WH")["bias%"], rel=1e-3)
    bad = _run("--noise-scale", "-1")
    assert bad.returncode == 2 and "--noise-scale" in bad.stderr


def test_suite_plant_friction_gives_the_baseline_the_plants_friction(tmp_path):
    """evaluation/suite.py --plant-friction (a diagnostic): the calibrated baseline
    takes the member's own F_d and F_s, the rest of the calibration unchanged, and the row is
    run_one with it; without the option the baseline keeps the datasheet's (400 / 600 N)."""
    from evaluation.dutycycle import duty_cycle
    from evaluation.suite import monitor_run, run_one

    dc = duty_cycle(1, 2)
    own = monitor_run(dc, model="WH", plant_friction=True)[2]
    sheet = monitor_run(dc, model="WH")[2]
    assert (own.f_d, own.f_s) == (dc.params["f_d"], dc.params["f_s"])
    assert (sheet.f_d, sheet.f_s) == (400.0, 600.0) != (own.f_d, own.f_s)
    assert own.model_copy(update={"f_d": 400.0, "f_s": 600.0}) == sheet
    out = tmp_path / "f.json"
    r = _run("--seed", "1", "--only", "2", "--workers", "1",
             "--plant-friction", "--json", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    (row,) = json.loads(out.read_text())["rows"]
    want = run_one(dc, model="WH", plant_friction=True)
    assert row["psr%"] == pytest.approx(want["psr%"], rel=1e-9)


def test_seed_list_and_recap_by_hand():
    """--seeds parses A-B and A,B,C; the recap counts a member once in all and once under
    each figure it misses, per seed as the single-seed summaries do."""
    import argparse

    from evaluation.suite import recap, seed_list

    assert seed_list("1-3") == [1, 2, 3]
    assert seed_list("8,2") == [8, 2]
    assert seed_list("5") == [5]
    for bad in ("1-x", "", "2,2", "3-1"):
        with pytest.raises(argparse.ArgumentTypeError):
            seed_list(bad)

    def row(name, inc=None, delay=None, obs=None, false=0, kind="leak", ind=None):
        return {"name": name, "kind": kind, "inc%": inc, "psr%": None, "delay": delay,
                "obs": obs, "false": false, "nis%": 95.0, "reinit": 0, "ind%": ind}  # fmt: skip

    by_seed = {
        1: [row("dc1_000", kind="healthy"), row("dc1_001", inc=12.0, delay=1.5, obs=1.2)],
        4: [row("dc4_000", false=1, kind="healthy"), row("dc4_001", inc=-3.0, delay=1.2,
                                                          obs=0.3, ind=-11.0),
            row("dc4_003", inc=20.0, ind=4.0)],
    }  # fmt: skip
    r = recap(by_seed)
    assert r["members"] == 5 and r["missing"] == 4
    assert r["per_seed"] == {1: 1, 4: 3}
    assert r["per_figure"] == {"delay": 1, "delay(obs)": 1, "false": 1, "inc%": 2}
    assert r["failing"]["dc1_001"] == ["inc%", "delay(obs)"]
    # three leak members, two of them off; the indicator reads two (one off), abstains on one
    assert r["indicator"] == {"leaks": 3, "inc_misses": 2, "read": 2, "read_misses": 1}


def test_indicator_increase_by_hand():
    """The health indicator of the last 2 s: the samples before the window and those whose
    sigma is above 0.25 x baseline are left out, the rest decimated to 20 Hz and their median
    taken. Here the window's second half reads 1.40, 1.41, ... 1.59 x baseline in its twenty
    50 ms bins: median 1.495 x, an increase of 0.495 against a true 0.5, -1 %."""
    from evaluation.suite import indicator_increase
    from service.monitor import EST_KEYS, HEALTH_KEYS

    c0 = 2e-13
    t = np.arange(3000) / 1000.0
    est = np.zeros((len(t), len(EST_KEYS)))
    c, cs = est[:, EST_KEYS.index("c_lk")], est[:, EST_KEYS.index("c_lk_sigma")]
    health = np.zeros((len(t), len(HEALTH_KEYS)))
    c[:], cs[:] = 10 * c0, 0.1 * c0  # before the window: sure, and far off
    mid = (t >= 1.0) & (t < 2.0)
    c[mid], cs[mid] = 3 * c0, 0.5 * c0  # in it, but not observable
    late = t >= 2.0
    k = np.floor(t[late] * 20.0) - 40.0  # the 50 ms bin, 0..19
    c[late], cs[late] = (1.4 + 0.01 * k) * c0, 0.1 * c0
    assert indicator_increase(t, est, health, c0, 0.5 * c0) == pytest.approx(-1.0, abs=1e-9)
    cs[late] = 0.3 * c0  # nothing observable left: the indicator abstains
    assert indicator_increase(t, est, health, c0, 0.5 * c0) is None


def test_estimation_suite_several_seeds_in_one_run(tmp_path):
    """--seeds 2,1: each seed's rows are the single-seed run's, and the recap is printed and
    written with them."""
    out, one = tmp_path / "two.json", tmp_path / "one.json"
    common = ("--suite", "1", "--workers", "1", "--json")
    png = tmp_path / "s.png"
    r = _run("--seeds", "2,1", *common, str(out), "--png", str(png))
    assert r.returncode == 0, r.stderr
    assert r.stdout.rstrip().endswith(f"wrote {png}") and png.read_bytes()[:4] == b"\x89PNG"
    assert "suite seed 2, 1 duty cycles" in r.stdout and "suite seed 1, 1 duty cycles" in r.stdout
    assert "all seeds: " in r.stdout and "of 2 members miss a target" in r.stdout
    d = json.loads(out.read_text())
    assert list(d["seeds"]) == ["2", "1"] and d["recap"]["members"] == 2
    r1 = _run("--seed", "1", *common, str(one))
    assert r1.returncode == 0, r1.stderr
    d1 = json.loads(one.read_text())

    def strip(rows):
        return [{k: v for k, v in x.items() if k != "wall_s"} for x in rows]

    assert strip(d["seeds"]["1"]["rows"]) == strip(d1["rows"])
    assert d["seeds"]["1"]["summary"] == d1["summary"]
    bad = _run("--seeds", "1,1")
    assert bad.returncode == 2 and "--seeds" in bad.stderr


def test_plot_suite_draws_every_member_where_it_belongs(tmp_path, monkeypatch):
    """--png of the suite: the left panel holds each leak member's increase error (red where
    off by more than 10 %, on the edge as a triangle past +-50 %) and a ring for each
    indicator reading; the right panel each alarm by kind, clipped at 4 s."""
    import evaluation.plots as plots

    def row(name, x, inc=None, ind=None, delay=None, obs=None):
        return {"name": name, "leak_ratio": x, "inc%": inc, "ind%": ind, "delay": delay,
                "obs": obs}  # fmt: skip

    rows = [
        row("h", 1.0),  # healthy: in neither panel
        row("a", 1.6, inc=3.0, ind=2.0),
        row("b", 1.8, inc=-14.0, ind=None),
        row("c", 3.5, inc=70.0, ind=8.0, delay=0.2, obs=0.05),
        row("d", 4.0, inc=1.0, delay=1.4, obs=0.3),
        row("e", 4.5, inc=-2.0, ind=-1.0, delay=6.2, obs=1.3),
    ]
    seen = {}

    def keep(fig, path, dpi=100):
        seen["axes"] = fig.axes
        return Path(path)

    monkeypatch.setattr(plots, "_save", keep)
    plots.plot_suite(rows, tmp_path / "s.png", "t")
    ax1, ax2 = seen["axes"]

    def points(ax):
        return {c.get_label(): c.get_offsets().data.tolist() for c in ax.collections}

    left = points(ax1)
    assert left["filter, last second"] == [[1.6, 3.0], [4.0, 1.0], [4.5, -2.0]]
    assert left["... missing"] == [[1.8, -14.0]]
    tri = [p for k, v in left.items() if k.startswith("_") for p in v]
    assert tri == [[3.5, 50.0]]  # 70 % drawn on the edge
    assert left["health indicator (3 of 5 read)"] == [[1.6, 2.0], [3.5, 8.0], [4.5, -1.0]]
    right = points(ax2)
    assert right["within (1)"] == [[0.05, 0.2]]
    assert right["late (1)"] == [[0.3, 1.4]]
    assert [p for k, v in right.items() if k.startswith("_") for p in v] == [[1.3, 4.0]]
    assert right["late, no window in time (1)"] == []  # 6.2 s: only its triangle, at 4 s
    # and the file itself, through the real _save
    monkeypatch.undo()
    png = plots.plot_suite(rows, tmp_path / "s.png", "t").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_indicator_window_by_hand():
    """``indicator_window``: over the last 2 s of a 4 s run at 1 kHz, the smallest C_Lk sigma
    / baseline there and the share of samples on which the estimate moved (C_Lk learnt);
    the smaller sigma before the window does not count."""
    from evaluation.suite import indicator_window

    t = np.arange(4001) * 1e-3
    c_lk = np.full(len(t), 2e-13)
    learnt = (t > 2.5) & (t <= 3.0)  # 500 of the window's 2001 samples move
    c_lk[learnt] += 1e-16 * np.arange(int(learnt.sum()))
    sigma = np.where(t < 1.0, 0.1, np.where(t < 3.2, 0.4, 0.3)) * 2e-13
    out = indicator_window(t, c_lk, sigma, 2e-13)
    assert out["ind_sd"] == pytest.approx(0.3)
    assert out["ind_learn%"] == pytest.approx(100.0 * 500 / 2001)
