"""``evaluation/bound.py``: the information bound on the duty-cycle suite's targets."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from evaluation import bound as sb
from models.scenario import SensorNoise

ROOT = Path(__file__).resolve().parents[1]


def _outputs(**ch):
    n = 2
    base = {c: np.zeros(n) for c, _ in sb.CHANNELS}
    return SimpleNamespace(t=np.arange(n) * 1e-3, **{**base, **ch})


def test_dprime_by_hand():
    """Two samples, x_J apart by 2 sigma and 1 sigma, P1 by 3 sigma on the second: d'^2 per
    sample 4 and 1 + 9; a channel without noise (current 0) carries nothing."""
    sn = SensorNoise(x_j_m=1e-4, p_pa=5e4, x_s_m=1e-6, current_a=0.0)
    y0 = _outputs()  # all zeros
    y1 = _outputs(x_j=np.array([2e-4, 1e-4]), p1=np.array([0.0, 1.5e5]), i=np.array([1.0, 1.0]))
    d2 = sb.dprime2_series(y0, y1, sn)
    np.testing.assert_allclose(d2, [4.0, 10.0])
    assert sb.first_reaching(y0.t, d2, 2.0) == 0.0  # 4 >= 2^2 at the first sample
    assert sb.first_reaching(y0.t, d2, 3.0) == pytest.approx(1e-3)  # 14 >= 9
    assert sb.first_reaching(y0.t, d2, 4.0) is None  # 14 < 16
    w = sb.whitened(y1, sn)
    assert w.shape == (2, 4)  # i dropped, x_s, x_j, p1, p2 kept
    np.testing.assert_allclose(w[:, 1], [2.0, 1.0])


def test_miss_probability_is_the_two_normal_tails():
    assert sb.miss_probability(1.959964, 1.959964) == pytest.approx(0.05, abs=1e-6)
    assert sb.miss_probability(0.0, 0.0) == pytest.approx(1.0)
    assert sb.miss_probability(1.0, 50.0) == pytest.approx(0.5 * math.erfc(1 / math.sqrt(2)))


def test_leak_profile_edits():
    """The cap keeps the ramp's slope; the crossing of a level on a ramp by hand."""
    assert sb.capped_ratio_ramp(3.0, 2.0, 2.0) == (2.0, 1.0)  # 1x -> 3x over 2 s: 2x at 1 s
    assert sb.capped_ratio_ramp(1.8, 2.0, 2.0) == (1.8, 2.0)  # never reaches the cap
    assert sb.capped_ratio_ramp(4.0, 0.0, 2.0) == (2.0, 0.0)  # a step stays a step
    assert sb.crossing_time(3.0, 2.0, 3.0, 2.5) == pytest.approx(4.5)
    assert sb.crossing_time(3.0, 0.0, 3.0, 2.5) == 3.0
    assert sb.crossing_time(3.0, 2.0, 2.4, 2.5) is None
    p = sb.leak_profile(2e-13, 3.0, 2.0, 3.0)
    np.testing.assert_allclose(p.sample([3.0, 4.0, 5.0, 9.0]), [2e-13, 4e-13, 6e-13, 6e-13])


def test_a_load_bump_adds_a_constant_on_its_piece_only():
    from evaluation.dutycycle import duty_cycle

    load = duty_cycle(1, 1).test.load
    t = np.array([1.99, 2.0, 2.1, 2.2499, 2.25, 2.3])
    np.testing.assert_allclose(
        sb.load_bump(load, 2.0, 2.25, 200.0).sample(t) - load.sample(t), [0, 200, 200, 200, 0, 0]
    )


def test_cramer_rao_with_a_nuisance_by_hand():
    """y = k a + theta b, whitened. a = (1, 0), b = (1, 1): F = [[1, 1], [1, 2]], so sigma_k
    is 1 with theta known and sqrt(2) with it unknown; a calibration that sees theta alone
    (c = (1)) makes F_thth 3 and sigma_k sqrt(3/2)."""
    j_k = np.array([[1.0], [0.0]])
    j_test = np.array([[[1.0]], [[1.0]]])
    no_cal = np.zeros((1, 1, 1))
    known, unknown = sb.crb_scale(j_k, j_test, no_cal)
    assert known == pytest.approx(1.0)
    assert unknown == pytest.approx(math.sqrt(2.0))
    _, with_cal = sb.crb_scale(j_k, j_test, np.ones((1, 1, 1)))
    assert with_cal == pytest.approx(math.sqrt(1.5))


def test_a_difference_the_nuisance_can_mimic_is_not_detectable():
    j_test = np.array([[[1.0]], [[1.0]], [[0.0]]])
    cal = np.zeros((1, 1, 1))
    along = np.array([[2.0], [2.0], [0.0]])
    across = np.array([[1.0], [-1.0], [0.0]])
    assert sb.projected_dprime(along, j_test, cal) == pytest.approx(0.0, abs=1e-9)
    assert sb.projected_dprime(across, j_test, cal) == pytest.approx(math.sqrt(2.0))
    # a calibration that pins theta down gives the test the mimicked difference back
    pinned = sb.projected_dprime(along, j_test, np.full((1, 1, 1), 1e3))
    assert pinned == pytest.approx(np.linalg.norm(along), rel=1e-5)


@pytest.mark.slow
def test_a_member_bound_is_consistent():
    """dc1_001 (a 1.81x leak step): the +-10 % edges are as far from the truth on both sides,
    and the Cramer-Rao sigma with the plant known is 10 % over that distance; dc1_003 (a 3.4x
    leak with a supply change): the secant's 2 x 10 % / sigma is the distance between the
    edges, within the triangle of the truth and the two edges; with the tolerances unknown
    sigma can only grow and the alarm's d' only shrink."""
    r = sb.member_bound(1, 1, load_piece_s=0.0)
    assert r["leak_ratio"] == pytest.approx(1.81, abs=0.01) and "t_cross" not in r
    assert r["d_inc_plus"] == pytest.approx(r["d_inc_minus"], rel=0.1)
    assert r["sigma_known%"] == pytest.approx(100 * sb.INC_EDGE / r["d_inc"], rel=0.1)
    assert r["sigma%"] >= r["sigma_known%"]
    r = sb.member_bound(1, 3, load_piece_s=2.0)
    assert r["load_pieces"] == 6 + 4  # 12 s of test and 8 s of calibration, in 2 s pieces
    edges = 2 * 100 * sb.INC_EDGE / r["sigma_known%"]
    assert abs(r["d_inc_plus"] - r["d_inc_minus"]) <= edges <= r["d_inc_plus"] + r["d_inc_minus"]
    assert r["sigma%"] >= r["sigma_known%"]
    assert "supply drop" in r["nuisances"] and "u1" in r["nuisances"]
    assert 0 < r["d_alarm_1s_nuis"] <= r["d_alarm_1s"]
    assert r["t_ideal"] is not None and r["t_ideal"] < 1.0
    ch = r["d_alarm_1s_by_channel"]
    assert set(ch) == {"i", "x_s", "x_j", "p1", "p2"}
    assert math.hypot(*ch.values()) == pytest.approx(r["d_alarm_1s"], rel=1e-9)
    assert sb.member_bound(1, 0) == {"name": "dc1_000", "kind": "healthy", "leak_ratio": 1.0}


def test_judge_marks_misses_beyond_the_bound():
    rows = [
        {"name": "a", "d_inc": 30.0, "sigma%": 0.5, "t_ideal": 0.1, "d_alarm_1s_nuis": 50.0},
        {"name": "b", "d_inc": 1.5, "t_ideal": 1.4},
        {"name": "c", "d_inc": 30.0, "sigma%": 8.0, "t_ideal": 0.2, "d_alarm_1s_nuis": 2.0},
    ]
    monitor = {
        "a": {"inc%": 20.0, "delay": 1.5},
        "b": {"inc%": -15.0, "delay": 1.2},
        "c": {"inc%": 4.0, "delay": 2.0},
    }
    sb.judge(rows, monitor)
    assert [(r["inc_beyond"], r["alarm_beyond"]) for r in rows] == [
        (False, False),  # misses both, and the sensors had what it takes
        (True, True),
        (False, True),  # within 10 %: not a miss, whatever the bound
    ]
    assert rows[2]["misses"] == ["delay"]


def test_cli_runs_one_member_and_reports_errors(tmp_path, capsys):
    out = tmp_path / "b.json"
    argv = ["--seed", "1", "--only", "1", "--known-plant", "--channels", "--json", str(out)]
    assert sb.main(argv) == 0
    data = json.loads(out.read_text())
    (row,) = data["rows"]
    assert row["name"] == "dc1_001" and row["d_inc"] > 2.0 and "sigma%" not in row
    assert data["summary"]["leak_members"] == 1
    printed = capsys.readouterr().out
    assert "dc1_001" in printed and "d' per channel" in printed
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with pytest.raises(SystemExit):
        sb.main(["--seed", "1", "--only", "1", "--suite-json", str(bad)])
    assert "--suite-json" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        sb.main(["--seeds", "1-2", "--only", "1"])


def test_plot_bound_draws_the_monitor_over_the_bound(tmp_path, monkeypatch, capsys):
    """--png: left, each leak member's +-3 sigma bar and the monitor's increase error (red
    where it misses, on the edge past +-50 %); right, each alarm's delay against the ideal
    test's, clipped at 4 s."""
    import evaluation.plots as plots

    rows = [
        {"name": "a", "leak_ratio": 1.6, "d_inc": 30.0, "sigma%": 0.5, "inc%": 3.0},
        {"name": "b", "leak_ratio": 1.8, "d_inc": 20.0, "sigma_known%": 1.0, "inc%": -14.0},
        {"name": "c", "leak_ratio": 3.5, "d_inc": 90.0, "sigma%": 0.2, "inc%": 70.0,
         "t_ideal": -0.3, "delay": 0.2},
        {"name": "d", "leak_ratio": 4.0, "d_inc": 90.0, "sigma%": 0.1, "inc%": 1.0,
         "t_ideal": 0.02, "delay": 6.0},
        {"name": "h", "leak_ratio": 1.0},
    ]  # fmt: skip
    seen = {}

    def keep(fig, path, dpi=100):
        seen["axes"] = fig.axes
        return Path(path)

    monkeypatch.setattr(plots, "_save", keep)
    plots.plot_bound(rows, tmp_path / "b.png")
    ax1, ax2 = seen["axes"]
    left = {c.get_label(): c for c in ax1.collections}
    segs = np.array([s for s in left["ideal estimator, +-3 sigma"].get_segments()])
    np.testing.assert_allclose(segs[:, :, 0], [[1.6, 1.6], [1.8, 1.8], [3.5, 3.5], [4.0, 4.0]])
    np.testing.assert_allclose(segs[:, 1, 1], [1.5, 3.0, 0.6, 0.3])  # 3 sigma, or sigma known
    np.testing.assert_allclose(segs[:, 0, 1], -segs[:, 1, 1])
    assert left["monitor"].get_offsets().data.tolist() == [[1.6, 3.0], [4.0, 1.0]]
    assert left["... missing"].get_offsets().data.tolist() == [[1.8, -14.0]]
    edge = [p for k, c in left.items() if k.startswith("_") for p in c.get_offsets().data.tolist()]
    assert edge == [[3.5, 50.0]]
    right = {c.get_label(): c.get_offsets().data.tolist() for c in ax2.collections}
    assert right["within (1)"] == [[-0.3, 0.2]]
    assert [p for k, v in right.items() if k.startswith("_") for p in v] == [[0.02, 4.0]]
    with pytest.raises(SystemExit):
        sb.main(["--seed", "1", "--only", "1", "--png", str(tmp_path / "x.png")])
    assert "--suite-json" in capsys.readouterr().err


def test_dropped_channels_leave_the_bound():
    sn = SensorNoise(x_s_m=1e-6, x_j_m=1e-4, p_pa=5e4, current_a=1e-5)
    assert sb.measured_names(sb.without(sn, ("i", "x_s"))) == ["x_j", "p1", "p2"]
    assert sb.measured_names(sb.without(sn, ("p",))) == ["i", "x_s", "x_j"]
    with pytest.raises(ValueError, match="x_k"):
        sb.without(sn, ("x_k",))
    y0 = _outputs()
    y1 = _outputs(i=np.ones(2), x_j=np.array([1e-4, 0.0]))
    # the current's 1e5 sigma of difference is gone, x_J's 1 sigma stays
    assert sb.dprime2_series(y0, y1, sb.without(sn, ("i",))).sum() == pytest.approx(1.0)


def test_cli_rejects_an_unknown_channel(capsys):
    with pytest.raises(SystemExit):
        sb.main(["--seed", "1", "--only", "1", "--drop", "i,q"])
    assert "--drop" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        sb.main(["--seed", "1", "--only", "1", "--load-piece", "-1"])
    assert "--load-piece" in capsys.readouterr().err
