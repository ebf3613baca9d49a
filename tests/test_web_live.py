"""The fleet page's live column through real Zenoh on loopback, every piece in its own
process: router (this process), ``servowatch run``, ``servowatch actuator`` and ``servowatch
web --connect``, the page rendered by headless Chromium. The unit shows the daemon that
monitors it while it runs, and "not monitored" once it has stopped."""

from __future__ import annotations

import json
import signal
import time
import urllib.request

import pytest
from webfleet import render, require_chromium, web_process

from service.edge.web.live import slim
from tests.test_service_e2e import AC, ACT, RATE
from tests.test_store_e2e import _act, _start

pytestmark = pytest.mark.slow

zenoh = pytest.importorskip("zenoh")
require_chromium()

NAME = f"{AC}/{ACT}"


def _live(url: str) -> dict:
    with urllib.request.urlopen(url + "/api/live", timeout=10) as r:
        return json.loads(r.read())


def _wait_live(url: str, pred, what: str, timeout: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        lv = _live(url)
        if pred(lv):
            return lv
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}; last /api/live {_live(url)}")


def test_live_column_follows_the_daemon(net, tmp_path):
    store = tmp_path / "health.sqlite"
    d = _start(net, tmp_path, store, window_s=0.5)
    net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "120")
    net.wait(lambda st: _act(st).get("periods", 0) >= 1, what="a period stored")
    with web_process(str(store), "--connect", net.ep, "--refresh", "1") as url:
        lv = _wait_live(url, lambda lv: NAME in lv["units"], "the unit in the live status")
        assert lv["enabled"] and [x["name"] for x in lv["daemons"]] == ["ground1/0"]
        assert lv["units"][NAME]["daemon"] == "ground1/0" and lv["units"][NAME]["samples"] > 0
        dom = render(url + "/")
        cell = dom.find("tr", **{"data-actuator": NAME}).find("td", class_="c-live")
        assert cell.attrs["data-live"] == "receiving"
        assert cell.text() == "ground1/0 (receiving)"
        assert "live-off" not in (dom.find("body").attrs.get("class") or "")
        strip = dom.find("div", **{"data-daemon": "ground1/0"})
        assert "1 units" in strip.text()

        d.send_signal(signal.SIGTERM)
        assert d.wait(30) == 0
        _wait_live(url, lambda lv: not lv["daemons"], "no daemon to answer")
        dom = render(url + "/")
        cell = dom.find("tr", **{"data-actuator": NAME}).find("td", class_="c-live")
        assert cell.attrs["data-live"] == "none" and cell.text() == "not monitored"
        assert "no daemon answers" in dom.find("div", id="daemon-list").text()


def test_slim_maps_units_to_their_daemon():
    st = {
        "state": "ok", "station": "gA", "shard": "1", "model": "WH", "uptime_s": 5.0,
        "samples": 30, "dropped": 1, "bad": 2, "missed": 0, "latency_ms": {"p99": 1.5},
        "silent": ["AC2/rudder"], "log_failure": None,
        "actuators": {
            "fleet/AC1/ail/meas": {"aircraft": "AC1", "actuator": "ail", "samples": 20,
                                   "silent": False, "bad": 2, "dropped": 1, "missed": 0,
                                   "alarms": [{"kind": "leak"}, {"kind": "leak"}]},
            "fleet/AC2/rudder/meas": {"aircraft": "AC2", "actuator": "rudder", "samples": 10,
                                      "silent": True, "bad": 0, "dropped": 0, "missed": 0,
                                      "alarms": []},
        },
    }  # fmt: skip
    out = slim(
        {"monitor/gA/1/status": st, "monitor/gB/0/status": {"error": "unreadable status"}}, 7.0
    )
    assert out["queried_s"] == 7.0 and out["enabled"] is True
    assert [(x.get("name"), x["state"]) for x in out["daemons"]] == [
        ("gA/1", "ok"),
        (None, "malformed"),
    ]
    assert out["daemons"][0]["units"] == 2 and out["daemons"][0]["latency_p99_ms"] == 1.5
    assert out["units"]["AC1/ail"] == {"daemon": "gA/1", "samples": 20, "silent": False, "bad": 2,
                                       "dropped": 1, "missed": 0, "alarms": ["leak"]}  # fmt: skip
    assert out["units"]["AC2/rudder"]["silent"] is True
