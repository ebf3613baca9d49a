"""``servowatch fleet``'s table: each unit's life and trend on the axis its history supports
(flights, or operating hours), and the ranking by RUL."""

from __future__ import annotations

import pytest

from service.cli.commands.fleet import format_fleet
from service.edge.fleet import life_and_trend, rank_fleet


def _row(
    name: str, rul: dict | None, slope_per_h: float | None, op_s: float, flights: int | None = None
) -> dict:
    """A ``fleet_summary`` row; ``flights``: its history counts that many (life axis)."""
    row = {"actuator": name, "commissioned": True, "periods": 10, "op_time_s": op_s,
           "last": {"c_lk_ratio": 1.5, "p_sr_min": 19.8e6}, "last_ratio": 1.5, "alarms": 0,
           "alarm_events": 0, "trend": {"slope_per_h": slope_per_h, "label": "rising"},
           "rul": rul, "life_axis": "hours"}  # fmt: skip
    if flights:
        row.update(life_axis="flights", first_flight=0, flights=flights)
        row["last"]["flight"] = flights - 1
    return row


def test_a_flight_history_shows_flights_and_a_trend_per_ten_flights():
    # 6 s logs: 1/600 h per flight; a ratio rising 0.02 per flight is 12 per operating hour
    rul = {"axis": "flights", "t_now": 39.0, "hours_per_flight": 1 / 600, "median_flights": 5.0}
    life, rate = life_and_trend(_row("AC1/a", rul, 12.0, 39 * 6.0, flights=39))
    assert life == {"value": 39.0, "unit": "flights"}
    assert rate["unit"] == "per 10 flights" and rate["value"] == pytest.approx(0.2)


def test_an_hour_history_shows_operating_hours_and_a_trend_per_hundred_hours():
    life, rate = life_and_trend(_row("AC1/b", {"axis": "hours", "t_now": 7.2}, 0.004, 7.2 * 3600))
    assert life == {"value": pytest.approx(7.2), "unit": "h"}
    assert rate == {"value": pytest.approx(0.4), "unit": "per 100 h"}
    assert life_and_trend(_row("AC1/c", None, None, 0.0))[1] is None


def test_the_table_ranks_by_rul_and_prints_each_units_axis():
    fl = {"axis": "flights", "t_now": 20.0, "hours_per_flight": 0.5, "median_flights": 4.0,
          "lo_flights": 3.0, "hi_flights": 6.0}  # fmt: skip
    hr = {"axis": "hours", "t_now": 100.0, "median_h": 50.0, "lo_h": 40.0, "hi_h": 70.0}
    ranked = rank_fleet([_row("AC1/hours", hr, 0.001, 100 * 3600.0),
                         _row("AC1/flights", fl, 0.01, 10 * 3600.0, flights=20)])  # fmt: skip
    assert [r["actuator"] for r in ranked] == ["AC1/flights", "AC1/hours"]
    text = format_fleet(ranked).splitlines()
    assert "20 fl" in text[2] and "+0.05/10 fl" in text[2] and "4 [3-6] flights" in text[2]
    assert "100.0 h" in text[3] and "+0.10/100 h" in text[3] and "50 [40-70] h" in text[3]


def test_the_default_table_fits_100_columns_and_wide_has_every_column():
    fl = {"axis": "flights", "t_now": 20.0, "hours_per_flight": 0.5, "median_flights": 1.0,
          "lo_flights": 1.0, "hi_flights": 6.0, "median_days": 12.0, "p_horizon": 0.4}  # fmt: skip
    rows = [_row(f"AC{k:03d}/aileron_R", fl, 0.01, 10 * 3600.0) for k in range(3)]
    for r in rows:
        r["usage"] = {"travel_m_per_h": 12.5, "load_travel_j_per_h": 3.2e4}
    ranked = rank_fleet(rows)
    narrow = format_fleet(ranked).splitlines()
    assert max(len(ln) for ln in narrow) <= 100, max(len(ln) for ln in narrow)
    assert "1 [1-6] flight ~12 d" in narrow[2]  # one flight, not "1 flights"
    wide = format_fleet(ranked, wide=True).splitlines()
    assert max(len(ln) for ln in wide) > 100
    for h in ("P_SR min MPa", "P(horizon)", "travel m/h", "load x travel kJ/h"):
        assert h in wide[0] and h not in narrow[0]
    assert "|F|trav" not in wide[0]
    assert "12.50" in wide[2] and "32.0" in wide[2]


def test_fleet_png_draws_the_trends_against_the_threshold(store_url, tmp_path, capsys):
    """``servowatch fleet --png``: a panel per unit with its C_Lk ratio per period and the
    threshold its RUL used; the table says which store it read."""
    import matplotlib.image as mpimg

    from service.cli import main
    from service.store import open_store
    from tests.test_store import make_period

    with open_store(store_url) as s:
        for name, slope in (("AC1/a", 0.05), ("AC1/b", 0.01)):
            s.add_periods([make_period(name, k, ratio=1.0 + slope * k) for k in range(1, 30)])
        s.put_rul("AC1/a", {"axis": "flights", "threshold_ratio": 2.5, "t_now": 29.0,
                            "median_flights": 3.0, "lo_flights": 1.0, "hi_flights": 8.0,
                            "periods": 29})  # fmt: skip
    png = tmp_path / "trends.png"
    assert main(["fleet", "--store", store_url, "--png", str(png)]) == 0
    out, err = capsys.readouterr()
    assert f"wrote {png} (2 units)" in err
    assert out.startswith("2 actuators in ") and "AC1/a" in out
    img = mpimg.imread(png)
    assert img.shape[0] > 200 and img.shape[1] > 1000  # two panels side by side
    # the threshold line is drawn in red: some pixels are red-dominant
    red = (img[..., 0] > 0.8) & (img[..., 1] < 0.4) & (img[..., 2] < 0.4)
    assert red.sum() > 200


def test_fleet_png_draws_each_history_in_its_life_order(store_url, tmp_path, monkeypatch):
    """Periods stored out of order (logs ingested newest first, as fleet-sim's workers may)
    are drawn in the unit's life order, flights 1..N left to right, as the page draws them
    (the panel took the store's row order, log-relative time then the log's name: flights
    1, 10, 11, ..., 19, 2, 20, ...)."""
    from dataclasses import replace

    import numpy as np

    import service.plots
    from service.edge.fleet_plot import plot_trends
    from service.store import open_store
    from tests.test_store import make_period

    with open_store(store_url) as s:
        for k in range(29, 0, -1):  # newest first, one log per flight, each from its own t=0
            p = make_period("AC1/a", k, source=f"log-{k}", ratio=1.0 + 0.05 * k)
            s.add_periods([replace(p, start_t=0.0, end_t=90.0, start_unix=1.79e9 + 86400.0 * k)])
    drawn: list = []
    save = service.plots._save

    def keep(fig, path):
        drawn.extend((ln.get_xdata(), ln.get_ydata()) for ln in fig.axes[0].lines[:1])
        save(fig, path)

    monkeypatch.setattr(service.plots, "_save", keep)
    with open_store(store_url, read_only=True) as s:
        assert plot_trends(s, [{"actuator": "AC1/a", "rank": 1}], tmp_path / "t.png") == 1
    ((x, y),) = drawn
    assert list(x) == list(np.arange(1.0, 30.0))  # flight - first + 1, the page's life axis
    assert np.allclose(y, 1.0 + 0.05 * np.arange(1, 30))
