"""The fleet page in a real headless Chromium, served by ``servowatch web`` in its own process
over SQLite and PostgreSQL stores: the table Chromium renders is the store's ranked fleet,
a unit's history chart is drawn to scale, store values stay text, and a lost store shows as a
banner, not a blank page.

Chromium is Debian's ``chromium`` (``.ci/run`` installs it); without it these tests skip, and
fail instead when ``SERVOWATCH_REQUIRE_CHROMIUM=1`` (as in CI).
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import urllib.request
from pathlib import Path
from urllib.parse import quote

import pytest
from webfleet import (
    CRITICAL,
    OK,
    RANKED,
    UNCOMMISSIONED,
    WATCH,
    fill_store,
    render,
    require_chromium,
    web_process,
)

from service.store import AlarmEvent, open_store

pytestmark = pytest.mark.slow

require_chromium()


def _fleet(url: str) -> dict:
    with urllib.request.urlopen(url + "/api/fleet", timeout=10) as r:
        return json.loads(r.read())


def test_table_is_the_ranked_store(store_url):
    fill_store(store_url)
    with web_process(store_url) as url:
        dom = render(url + "/")
        api = _fleet(url)
    body = dom.find("body")
    assert body.attrs.get("data-fleet-ready") == "1"
    rows = dom.find("table", id="fleet").find_all("tr")[1:]
    assert [r.attrs["data-actuator"] for r in rows] == RANKED
    assert [r.attrs["data-rank"] for r in rows] == ["1", "2", "3", "4"]
    by = {r.attrs["data-actuator"]: r for r in rows}
    api_by = {u["actuator"]: u for u in api["fleet"]}
    for a, r in by.items():
        assert r.find("td", class_="ratio").text() == f"{api_by[a]['last']['c_lk_ratio']:.3f}"
        assert r.attrs["data-status"] == api_by[a]["status"]
    assert by[CRITICAL].find("td", class_="rul").text() == "12 [8-20] h"  # an hours history
    assert by[CRITICAL].find("td", class_="flights").text() == "8 [5-13]"
    assert by[CRITICAL].find("span", class_="badge").text() == "critical"
    # the larger of the periods' alarm count (k % 3 over 8 periods) and the alarm events (1)
    assert by[WATCH].find("td", class_="alarms").text() == str(sum(k % 3 for k in range(8)))
    assert by[OK].find("td", class_="rul").text() == "none predicted"
    assert by[UNCOMMISSIONED].find("span", class_="badge").text() == "not commissioned"
    assert by[UNCOMMISSIONED].find("td", class_="rul").text() == "-"
    # the interval bar of the critical unit: 8-20 h on a 0-100 h axis of 218 px from x=1
    rect = by[CRITICAL].find("rect", class_="ivl")
    assert float(rect.attrs["x"]) == pytest.approx(1 + 8 / 100 * 218, abs=0.01)
    assert float(rect.attrs["width"]) == pytest.approx(12 / 100 * 218, abs=0.01)
    cards = {c.attrs["data-status"]: c.find("b").text() for c in dom.find_all("div", class_="card")}
    assert cards == {
        "all": "4",
        "critical": "1",
        "watch": "1",
        "ok": "1",
        "uncommissioned": "1",
        "rul": "2",
    }
    assert "hidden" in dom.find("div", id="banner").attrs


def test_unit_history_chart(tmp_path):
    db = str(tmp_path / "h.sqlite")
    fill_store(db)
    with open_store(db) as s:  # a kind that is markup: the page must show it as text
        s.add_alarms([AlarmEvent(CRITICAL, 650.0, "<b id=evil>x</b>", 1.0, "log-a")])
    with web_process(db) as url:
        dom = render(url + "/#unit=" + quote(CRITICAL, safe=""))
    assert dom.find("body").attrs.get("data-unit-ready") == CRITICAL
    assert dom.find("tr", **{"data-actuator": CRITICAL}).attrs["class"] == "selected"
    chart = dom.find("svg", id="history")
    pts = chart.find_all("circle", class_="pt")
    assert len(pts) == 8
    xs = [float(p.attrs["cx"]) for p in pts]
    ys = [float(p.attrs["cy"]) for p in pts]
    assert xs == sorted(xs) and ys == sorted(ys, reverse=True)  # hours on, ratio rising
    # equal periods: equal steps in x; ratio steps of 0.3: equal steps in y
    assert max(xs[i + 1] - xs[i] for i in range(7)) == pytest.approx(
        min(xs[i + 1] - xs[i] for i in range(7)), abs=0.01
    )
    assert max(ys[i] - ys[i + 1] for i in range(7)) == pytest.approx(
        min(ys[i] - ys[i + 1] for i in range(7)), abs=0.01
    )
    thr = chart.find("line", class_="threshold")
    base = chart.find("line", class_="baseline")
    # threshold 4.0 and baseline 1.0 on the same linear axis as the points (ratio 1.0 at k=0)
    y1, y4 = float(base.attrs["y1"]), float(thr.attrs["y1"])
    assert ys[0] == pytest.approx(y1, abs=0.01)
    assert ys[5] == pytest.approx(y1 + (y4 - y1) * (2.5 - 1.0) / 3.0, abs=0.01)
    band = chart.find("rect", class_="rul-band")
    med = chart.find("line", class_="rul-median")
    lo, hi = float(band.attrs["x"]), float(band.attrs["x"]) + float(band.attrs["width"])
    assert lo < float(med.attrs["x1"]) < hi
    assert xs[-1] < lo  # the crossing lies ahead of the last period
    # an hours history (no flight numbers): drawn against its operating hours
    label = chart.find("text", class_="x-label")
    assert label.text() == "operating hours" and label.attrs["data-axis"] == "hours"
    assert not dom.find_all("b", id="evil")
    facts = dom.find("dl", id="unit-facts").text()
    assert "<b id=evil>x</b>" in facts


def test_unit_chart_counts_flights(tmp_path):
    """A unit whose history counts flights (the store summary's life axis) is drawn against
    its flights, 1-8 since its first, and its RUL interval (80-600 flights from the 8th) on
    that same axis: x scales with the flight count from the chart's left edge."""
    db = str(tmp_path / "h.sqlite")
    fill_store(db)
    with web_process(db) as url:
        dom = render(url + "/#unit=" + quote(WATCH, safe=""))
    assert dom.find("body").attrs.get("data-unit-ready") == WATCH
    chart = dom.find("svg", id="history")
    label = chart.find("text", class_="x-label")
    assert label.text() == "flights" and label.attrs["data-axis"] == "flights"
    left = float(chart.find_all("line", class_="axis")[-1].attrs["x1"])  # the y axis
    xs = [float(p.attrs["cx"]) - left for p in chart.find_all("circle", class_="pt")]
    assert xs == pytest.approx([xs[0] * (k + 1) for k in range(8)], rel=1e-4)
    band = chart.find("rect", class_="rul-band")
    med = chart.find("line", class_="rul-median")
    per_flight = xs[0]
    assert float(band.attrs["x"]) - left == pytest.approx((8 + 80) * per_flight, rel=1e-4)
    assert float(band.attrs["width"]) == pytest.approx((600 - 80) * per_flight, rel=1e-4)
    assert float(med.attrs["x1"]) - left == pytest.approx((8 + 200) * per_flight, rel=1e-4)


def test_lost_store_shows_a_banner(tmp_path):
    db = tmp_path / "h.sqlite"
    fill_store(str(db))
    with web_process(str(db)) as url:
        db.rename(tmp_path / "away.sqlite")
        for side in ("-wal", "-shm"):
            Path(str(db) + side).unlink(missing_ok=True)
        dom = render(url + "/")
    banner = dom.find("div", id="banner")
    assert "hidden" not in banner.attrs
    assert banner.text().startswith("store not reachable") and "does not exist" in banner.text()
    assert dom.find("body").attrs.get("data-fleet-error")


def test_snapshot_writes_the_page(tmp_path):
    db = str(tmp_path / "h.sqlite")
    fill_store(db)
    out = tmp_path / "page.png"
    res = subprocess.run(
        [sys.executable, "-m", "service.cli", "web", "--store", db, "--snapshot", str(out),
         "--unit", CRITICAL],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    head = out.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert struct.unpack(">II", head[16:24]) == (1500, 1100)


def test_unit_view_shows_its_usage(tmp_path):
    """The unit's usage (issue 42): per operating hour and per flight in its facts; a unit
    whose periods predate usage says so."""
    from dataclasses import replace

    db = str(tmp_path / "h.sqlite")
    fill_store(db)
    with open_store(db) as s:
        s.add_periods([replace(p, start_t=p.start_t + 1e4, end_t=p.end_t + 1e4, flight=100 + k,
                               usage_travel_m=1.8,
                               usage_load_travel_j=7200.0, usage_load2_travel_n2m=1e7,
                               usage_reversals=36.0, usage_loaded_s=80.0,
                               usage_pressurised_s=90.0)
                       for k, p in enumerate(s.periods(OK)[:2])])  # fmt: skip
    with web_process(db) as url:
        dom = render(url + "/#unit=" + quote(OK, safe=""))
        old = render(url + "/#unit=" + quote(WATCH, safe=""))
    assert dom.find("body").attrs.get("data-unit-ready") == OK
    facts = dom.find("dl", id="unit-facts").text()
    # two 90 s periods with 1.8 m each: 72 m and 288 kJ per operating hour; 1.8 m per flight
    assert (
        "72.00 m travel, 288.0 kJ load-weighted travel, 1440 reversals per operating hour" in facts
    )
    assert "1.80 m, 7.2 kJ, 36 reversals per flight (2 flights)" in facts
    assert "not recorded" in old.find("dl", id="unit-facts").text()


# the page's width at a window of W px, the "monitored by" column shown with its longest text
# (as with `--connect`): [page scroll width, window width, table's right edge]
_WIDTH_JS = """(() => {
  document.body.classList.remove('live-off');
  for (const td of document.querySelectorAll('td.c-live')) td.textContent = 'UNMONITORED (owner ground2/1)';
  const d = document.documentElement;
  return [d.scrollWidth, d.clientWidth, document.getElementById('fleet').getBoundingClientRect().right];
})()"""


@pytest.mark.parametrize("unit", [None, CRITICAL])
def test_page_fits_1280_px_without_a_horizontal_scroll(tmp_path, unit):
    """At 1280 x 900 CSS px, the table with every column (the live one too) and, opened, a
    unit's chart lie inside the window: nothing to scroll sideways."""
    from service.edge.web.browser import evaluate

    db = str(tmp_path / "h.sqlite")
    fill_store(db)
    ready = "document.body.dataset.fleetReady === '1'"
    path = "/"
    if unit is not None:
        path += "#unit=" + quote(unit, safe="")
        ready += f" && document.body.dataset.unitReady === '{unit}'"
    with web_process(db) as url:
        scroll_w, client_w, right = evaluate(url + path, _WIDTH_JS, size=(1280, 900), ready=ready)
    assert client_w == 1280
    assert scroll_w <= client_w and right <= client_w
