"""``servowatch characteristic``: JSON contract, hand-computed values, usage errors."""

from __future__ import annotations

import json

import pytest

from service.cli import main


def run_json(capsys, *argv):
    rc = main(list(argv))
    out = capsys.readouterr().out
    assert rc == 0
    return json.loads(out)


def test_c5_json_matches_hand_computed(capsys):
    d = run_json(
        capsys,
        "characteristic",
        "--model",
        "C5",
        "--x-s",
        "-2e-4,0,1e-4",
        "--q-j",
        "0,1e-4",
        "--json",
    )
    assert d["model"] == "C5"
    assert d["x_s"] == [-2e-4, 0.0, 1e-4] and d["q_j"] == [0.0, 1e-4]
    assert len(d["p12"]) == 2 and all(len(r) == 3 for r in d["p12"])
    # x_S = x_SS, Q_J = 0: P12 = P_SR / (1 + C_Lk G_PQ) = 20e6 / 1.148
    assert d["p12"][0][2] == pytest.approx(20e6 / 1.148, rel=1e-12)
    # x_S = 0, Q_J = 1e-4: x_St = -1e-4 * 7.4e11 * 1e-4 / 20e6 = -3.7e-4
    #   P12 = -3.7e-4 * 20e6 / (3.7e-4 + 0.148e-4) = -19.2308 MPa
    assert d["p12"][1][1] == pytest.approx(-3.7e-4 * 20e6 / (3.7e-4 + 0.148e-4), rel=1e-12)
    assert d["params"]["g_pq"] == pytest.approx(7.4e11)
    assert d["params"]["x_ss"] == pytest.approx(1e-4)


def test_p_sr_and_c_lk_options(capsys):
    d = run_json(
        capsys,
        "characteristic",
        "--model",
        "C1",
        "--p-sr",
        "10e6",
        "--c-lk",
        "0",
        "--x-s",
        "1e-3",
        "--q-j",
        "0",
        "--json",
    )
    assert d["p12"][0][0] == pytest.approx(10e6)  # saturated, no leakage
    assert d["params"]["p_sr"] == 10e6 and d["params"]["c_lk"] == 0.0


def test_default_grid_and_png(capsys, tmp_path):
    png = tmp_path / "c3.png"
    d = run_json(capsys, "characteristic", "--model", "C3", "--json", "--png", str(png))
    assert len(d["x_s"]) == 201 and len(d["q_j"]) == 5
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize(
    "argv",
    [
        ["characteristic", "--model", "Z"],
        ["characteristic"],
        ["characteristic", "--model", "A", "--x-s", "1,abc"],
        ["characteristic", "--model", "A", "--p-sr", "nan"],
    ],
)
def test_bad_arguments_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as ei:
        main(argv)
    assert ei.value.code == 2
    assert "usage" in capsys.readouterr().err


def test_negative_p_sr_refused(capsys):
    assert main(["characteristic", "--model", "A", "--p-sr", "-5"]) == 2
    assert "--p-sr" in capsys.readouterr().err
