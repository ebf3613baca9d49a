"""The fleet page's HTTP server (``servowatch web``) against SQLite and PostgreSQL stores:
the JSON it serves is the store's, ranked as ``servowatch fleet``; read only; loopback by
default; clear errors."""

from __future__ import annotations

import http.client
import json
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from webfleet import CRITICAL, OK, RANKED, UNCOMMISSIONED, WATCH, fill_store, web_process

from service.cli import main
from service.web.server import SECURITY_HEADERS, check_listen
from service.web.view import unit_status


def _get(url: str) -> tuple[int, dict, dict]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, dict(r.headers), json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, dict(e.headers), json.loads(e.read())


def _request(url: str, method: str, body: bytes = b"") -> tuple[int, dict, bytes]:
    u = urllib.parse.urlsplit(url)
    c = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    c.request(method, u.path + (f"?{u.query}" if u.query else ""), body=body)
    r = c.getresponse()
    out = r.status, dict(r.getheaders()), r.read()
    c.close()
    return out


@pytest.fixture
def filled(store_url) -> str:
    fill_store(store_url)
    return store_url


def test_fleet_json_is_the_ranked_store(filled, capsys):
    assert main(["fleet", "--store", filled, "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    with web_process(filled) as url:
        status, headers, page = _get(url + "/api/fleet")
    assert status == 200 and headers["Content-Type"] == "application/json"
    assert [u["actuator"] for u in page["fleet"]] == RANKED
    assert [u["actuator"] for u in cli["fleet"]] == RANKED  # the same order as the CLI
    for a, b in zip(page["fleet"], cli["fleet"], strict=True):
        assert a["rank"] == b["rank"] and a["rul_interval"] == b["rul_interval"]
        assert a["last"]["c_lk_ratio"] == pytest.approx(b["last"]["c_lk_ratio"], rel=1e-12)
    by = {u["actuator"]: u for u in page["fleet"]}
    assert [by[a]["status"] for a in RANKED] == ["critical", "watch", "ok", "uncommissioned"]
    assert page["counts"] == {"critical": 1, "watch": 1, "ok": 1, "uncommissioned": 1}
    assert page["with_rul"] == 2 and page["horizon_h"] == 50.0
    assert by[CRITICAL]["last"]["c_lk_ratio"] == pytest.approx(1.0 + 0.3 * 7)
    for k, v in SECURITY_HEADERS.items():
        assert headers[k] == v


def test_unit_history(filled):
    with web_process(filled) as url:
        status, _, unit = _get(url + "/api/unit?name=" + urllib.parse.quote(CRITICAL, safe=""))
        assert status == 200
        assert unit["actuator"] == CRITICAL and len(unit["periods"]) == 8
        # cumulative operating hours at each period's end: 90 s each
        assert [p["t_h"] for p in unit["periods"]] == pytest.approx(
            [90 * (k + 1) / 3600 for k in range(8)]
        )
        assert [p["c_lk_ratio"] for p in unit["periods"]] == pytest.approx(
            [1 + 0.3 * k for k in range(8)]
        )
        # sigma of the ratio: c_lk_sigma over the baseline C_Lk (1e-14 / 1e-12)
        assert unit["periods"][3]["c_lk_ratio_sigma"] == pytest.approx(0.01)
        assert unit["rul"]["median_h"] == 12.0 and [b["version"] for b in unit["baselines"]] == [1]
        status, _, watch = _get(url + "/api/unit?name=" + urllib.parse.quote(WATCH, safe=""))
        assert [(e["kind"], e["t"]) for e in watch["alarms"]] == [("leak", 105.0)]


def test_live_is_off_without_zenoh(filled):
    with web_process(filled) as url:
        status, _, live = _get(url + "/api/live")
    assert status == 200 and live == {"enabled": False}


def test_live_session_that_does_not_open_exits_3(filled, capsys):
    from service.zenoh_util import free_port, loopback

    rc = main(["web", "--store", filled, "--listen", "127.0.0.1:0",
               "--connect", loopback(free_port())])  # fmt: skip
    assert rc == 3
    assert capsys.readouterr().err.startswith("servowatch: error:")


def test_errors_name_the_field(filled):
    with web_process(filled) as url:
        status, _, body = _get(url + "/api/unit?name=not-a-unit")
        assert status == 400 and body["error"].startswith("actuator: expected 'AIRCRAFT/ACTUATOR'")
        status, _, body = _get(url + "/api/unit?name=AC9/none")
        assert status == 404 and "AC9/none" in body["error"]
        status, _, body = _get(url + "/api/unit")
        assert status == 400 and body["error"].startswith("name:")
        status, _, body = _get(url + "/api/unit?name=" + urllib.parse.quote("<script>/x", safe=""))
        assert status == 400
        status, _, body = _get(url + "/etc/passwd")
        assert status == 404
        status, _, body = _get(url + "/static/../server.py")
        assert status == 404


def test_read_only(filled):
    with web_process(filled) as url:
        for method in ("POST", "PUT", "DELETE", "PATCH"):
            status, headers, body = _request(url + "/api/fleet", method, b'{"x": 1}')
            assert status == 405 and headers["Allow"] == "GET, HEAD"
            assert json.loads(body)["error"] == f"{method}: the page is read only"
        status, headers, body = _request(url + "/api/fleet", "HEAD")
        assert status == 200 and body == b"" and int(headers["Content-Length"]) > 100
        # the connection still serves after a refused write
        status, _, page = _get(url + "/api/fleet")
        assert status == 200 and len(page["fleet"]) == 4


def test_page_and_assets(filled):
    with web_process(filled, "--refresh", "2.5") as url:
        status, headers, body = _request(url + "/", "GET")
        assert status == 200 and headers["Content-Type"].startswith("text/html")
        html = body.decode()
        assert '<meta name="servowatch-refresh-s" content="2.5">' in html
        assert '<script src="/static/fleet.js">' in html and "http" not in html.split("<body")[1]
        for asset, ctype in (("fleet.js", "text/javascript"), ("fleet.css", "text/css")):
            status, headers, body = _request(url + f"/static/{asset}", "GET")
            assert status == 200 and headers["Content-Type"].startswith(ctype) and body


def test_store_gone_is_503_then_back(tmp_path):
    db = tmp_path / "h.sqlite"
    fill_store(str(db))
    with web_process(str(db)) as url:
        moved = tmp_path / "away.sqlite"
        db.rename(moved)
        for side in ("-wal", "-shm"):
            Path(str(db) + side).unlink(missing_ok=True)
        status, _, body = _get(url + "/api/fleet")
        assert status == 503 and "does not exist" in body["error"]
        status, _, _ = _get(url + "/healthz")
        assert status == 503
        moved.rename(db)
        status, _, page = _get(url + "/api/fleet")
        assert status == 200 and len(page["fleet"]) == 4


def test_listen_is_loopback_unless_allowed():
    assert check_listen("127.0.0.1:8080") == ("127.0.0.1", 8080)
    assert check_listen("localhost:0") == ("127.0.0.1", 0)
    assert check_listen("[::1]:9000") == ("::1", 9000)
    with pytest.raises(ValueError, match="--listen: 0.0.0.0 is not a loopback address"):
        check_listen("0.0.0.0:8080")
    assert check_listen("0.0.0.0:8080", allow_remote=True) == ("0.0.0.0", 8080)
    for bad, msg in (("8080", "expected HOST:PORT"), ("127.0.0.1:x", "not a number"),
                     ("127.0.0.1:70000", "out of 0-65535"), ("example:80", "not an IP")):  # fmt: skip
        with pytest.raises(ValueError, match=msg):
            check_listen(bad)


def test_cli_refuses_bad_arguments(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    fill_store(str(db))
    assert main(["web", "--store", str(db), "--listen", "0.0.0.0:8080"]) == 2
    assert "not a loopback address" in capsys.readouterr().err
    assert main(["web", "--store", str(tmp_path / "none.sqlite")]) == 2
    assert "--store:" in capsys.readouterr().err and True
    assert main(["web", "--store", str(db), "--refresh", "-1"]) == 2
    assert main(["web", "--store", str(db), "--unit", OK]) == 2
    assert "--unit: only with --snapshot" in capsys.readouterr().err


def test_status_rules():
    base = {"commissioned": True, "alarms": 0, "alarm_events": 0, "trend": {"label": "stable"}}
    assert unit_status({**base, "commissioned": False})[0] == "uncommissioned"
    crit = {**base, "rul": {"warning": True, "p_horizon": 0.4, "horizon_h": 50.0}}
    assert unit_status(crit) == ("critical", "P(threshold within 50 h) = 0.40")
    assert unit_status({**base, "alarm_events": 2}) == ("watch", "2 alarms recorded")
    assert unit_status({**base, "trend": {"label": "rising"}}) == ("watch", "C_Lk ratio rising")
    assert unit_status({**base, "rul": {"warning": False}}) == ("ok", "")
    assert UNCOMMISSIONED not in (CRITICAL, WATCH, OK)
