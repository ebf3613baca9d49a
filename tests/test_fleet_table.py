"""``servowatch fleet``'s table: each unit's life and trend on the axis its history supports
(flights, or operating hours), and the ranking by RUL."""

from __future__ import annotations

import pytest

from service.cli.commands.fleet import format_fleet
from service.edge.fleet import life_and_trend, rank_fleet


def _row(name: str, rul: dict | None, slope_per_h: float | None, op_s: float) -> dict:
    return {"actuator": name, "commissioned": True, "periods": 10, "op_time_s": op_s,
            "last": {"c_lk_ratio": 1.5, "p_sr_min": 19.8e6}, "alarms": 0, "alarm_events": 0,
            "trend": {"slope_per_h": slope_per_h, "label": "rising"}, "rul": rul}  # fmt: skip


def test_a_flight_history_shows_flights_and_a_trend_per_ten_flights():
    # 6 s logs: 1/600 h per flight; a ratio rising 0.02 per flight is 12 per operating hour
    rul = {"axis": "flights", "t_now": 39.0, "hours_per_flight": 1 / 600, "median_flights": 5.0}
    life, rate = life_and_trend(_row("AC1/a", rul, 12.0, 39 * 6.0))
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
                         _row("AC1/flights", fl, 0.01, 10 * 3600.0)])  # fmt: skip
    assert [r["actuator"] for r in ranked] == ["AC1/flights", "AC1/hours"]
    text = format_fleet(ranked).splitlines()
    assert "20 fl" in text[2] and "+0.05/10 fl" in text[2] and "4 [3-6] flights" in text[2]
    assert "100.0 h" in text[3] and "+0.10/100 h" in text[3] and "50 [40-70] h" in text[3]
