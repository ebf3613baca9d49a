"""The fleet page's HTTP server (``servowatch web``) against SQLite and PostgreSQL stores:
the JSON it serves is the store's, ranked as ``servowatch fleet``; read only; loopback by
default; clear errors."""

from __future__ import annotations

import http.client
import json
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from webfleet import CRITICAL, OK, RANKED, WATCH, fill_store, web_process

from service.cli import main
from service.edge.web.server import SECURITY_HEADERS, check_listen
from service.edge.web.view import unit_status


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
        # an hours history: its life axis is the operating hours, the RUL counted from t_now_h
        assert unit["life_axis"] == "hours"
        assert [p["life"] for p in unit["periods"]] == [p["t_h"] for p in unit["periods"]]
        assert unit["rul_on_axis"] == pytest.approx({"now": 0.2, "median": 12.0, "lo": 8.0,
                                                     "hi": 20.0})  # fmt: skip
        status, _, watch = _get(url + "/api/unit?name=" + urllib.parse.quote(WATCH, safe=""))
        assert [(e["kind"], e["t"]) for e in watch["alarms"]] == [("leak", 105.0)]
        # a history of flights 0-7: flights 1-8 since its first, the RUL's interval in flights
        # from the 8th (the summary's life axis, as `fleet`'s life column and `rul` count)
        assert watch["life_axis"] == "flights"
        assert [p["life"] for p in watch["periods"]] == [1.0 + k for k in range(8)]
        assert watch["rul_on_axis"] == pytest.approx({"now": 8.0, "median": 200.0, "lo": 80.0,
                                                      "hi": 600.0})  # fmt: skip
        fleet = {u["actuator"]: u for u in _get(url + "/api/fleet")[2]["fleet"]}
        assert fleet[WATCH]["life"] == {"value": 8.0, "unit": "flights"}
        assert fleet[CRITICAL]["life"]["unit"] == "h"


def test_live_is_off_without_zenoh(filled):
    with web_process(filled) as url:
        status, _, live = _get(url + "/api/live")
    assert status == 200 and live == {"enabled": False}


def test_page_starts_before_its_router_and_picks_it_up(filled):
    import zenoh

    from service.zenoh_util import free_port, loopback, make_config

    ep = loopback(free_port())
    with web_process(filled, "--connect", ep, "--refresh", "1") as url:
        deadline = time.monotonic() + 20
        while "error" not in (live := _get(url + "/api/live")[2]) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert live["enabled"] and live["error"].startswith("no Zenoh session:")
        assert live["daemons"] == [] and live["units"] == {}
        status, _, page = _get(url + "/api/fleet")  # the page serves meanwhile
        assert status == 200 and len(page["fleet"]) == 4
        router = zenoh.open(make_config("router", [ep]))
        try:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                live = _get(url + "/api/live")[2]
                if "error" not in live and live["queried_s"] is not None:
                    break
                time.sleep(0.2)
            assert "error" not in live, live
            assert live["daemons"] == []  # a router, no daemon
        finally:
            router.close()


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
        u = urllib.parse.urlsplit(url)
        c = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
        for method in ("POST", "PUT", "DELETE", "PATCH", "TRACE", "BREW"):
            c.request(method, "/api/fleet", body=b'{"x": 1}')
            r = c.getresponse()
            body, headers = r.read(), dict(r.getheaders())
            assert r.status == 405 and headers["Allow"] == "GET, HEAD", method
            assert json.loads(body)["error"] == f"{method}: the page is read only"
            assert headers["Content-Security-Policy"] == SECURITY_HEADERS["Content-Security-Policy"]
            if method == "BREW":  # the base class's refusal closes the connection
                c.close()
                c = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
        # the same connection still serves after a refused write
        c.request("HEAD", "/api/fleet")
        r = c.getresponse()
        assert r.status == 200 and r.read() == b"" and int(r.getheader("Content-Length")) > 100
        c.request("GET", "/api/fleet")
        r = c.getresponse()
        assert r.status == 200 and len(json.loads(r.read())["fleet"]) == 4
        c.close()


def test_malformed_requests_are_answered_and_closed(filled):
    """Each gets one JSON answer with the security headers, then the server closes the
    connection: a body it did not read is never parsed as a next request."""
    import socket

    with web_process(filled) as url:
        u = urllib.parse.urlsplit(url)
        for raw, want in (
            (b"POST /api/fleet HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: abc\r\n\r\n", 405),
            (b"GET /api/fleet HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 5\r\n\r\nGET /", 200),
            (b"POST /x HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", 405),
            (b"NOT A REQUEST\r\n\r\n", 400),
        ):  # fmt: skip
            with socket.create_connection((u.hostname, u.port), timeout=10) as sock:
                sock.sendall(raw)
                got = b""
                while chunk := sock.recv(65536):  # ends when the server closes
                    got += chunk
            head, _, body = got.partition(b"\r\n\r\n")
            assert got.count(b"HTTP/1.") == 1, got  # one answer, no second
            assert int(head.split()[1]) == want, got
            assert b"Connection: close" in head and b"Content-Security-Policy" in head
            doc = json.loads(body)
            assert doc["fleet"] if want == 200 else doc["status"] == want


def test_host_header_must_name_this_server(filled):
    with web_process(filled) as url:
        u = urllib.parse.urlsplit(url)
        for host, want in (("evil.example", 421), (f"evil.example:{u.port}", 421),
                           (f"localhost:{u.port}", 200), (f"127.0.0.1:{u.port}", 200)):  # fmt: skip
            c = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
            c.putrequest("GET", "/api/fleet", skip_host=True)
            c.putheader("Host", host)
            c.endheaders()
            r = c.getresponse()
            body = json.loads(r.read())
            assert r.status == want, (host, body)
            if want == 421:
                assert body["error"] == "Host: not this server's name"
            c.close()


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
    assert "--store:" in capsys.readouterr().err
    assert main(["web", "--store", str(db), "--refresh", "-1"]) == 2
    assert "--refresh: expected 0-3600 s, got -1" in capsys.readouterr().err
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


def _page_thread(store: str, **kw):
    """The page's server in a thread of this process (``make_server``), and its URL."""
    import threading

    from service.edge.web.server import make_server

    srv = make_server(store, "127.0.0.1", 0, **kw)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv, f"http://127.0.0.1:{srv.server_address[1]}"


def test_more_than_one_host_header_is_400(filled):
    import socket

    srv, url = _page_thread(filled)
    try:
        port = srv.server_address[1]
        for hosts in ((f"localhost:{port}", "evil.example"), ("evil.example", "localhost"),
                      (f"127.0.0.1:{port}", f"127.0.0.1:{port}")):  # fmt: skip
            raw = b"GET /api/fleet HTTP/1.1\r\n" + b"".join(
                f"Host: {h}\r\n".encode() for h in hosts
            )
            with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
                sock.sendall(raw + b"\r\n")
                got = b""
                while chunk := sock.recv(65536):  # the server closes after the 400
                    got += chunk
            head, _, body = got.partition(b"\r\n\r\n")
            assert int(head.split()[1]) == 400, (hosts, got)
            assert json.loads(body)["error"] == "Host: more than one Host header"
    finally:
        srv.shutdown()
        srv.server_close()


def test_idle_limit_is_on_the_whole_request_not_each_byte(filled):
    """A client sending one byte every 0.3 s never trips a per-read timeout; the request's
    own limit (here 1.5 s) closes the connection all the same."""
    import socket

    srv, _ = _page_thread(filled, request_s=1.5)
    try:
        sock = socket.create_connection(("127.0.0.1", srv.server_address[1]), timeout=10)
        t0 = time.monotonic()
        closed_at = None
        with sock:
            for b in b"GET /api/fleet HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 200:
                try:
                    sock.sendall(bytes([b]))
                    time.sleep(0.3)
                    sock.setblocking(False)
                    try:
                        if sock.recv(65536) == b"":
                            closed_at = time.monotonic() - t0
                            break
                    except BlockingIOError:
                        pass
                    finally:
                        sock.setblocking(True)
                except OSError:  # reset by the server
                    closed_at = time.monotonic() - t0
                    break
                assert time.monotonic() - t0 < 10, "still open after 10 s"
        assert closed_at is not None and 1.4 < closed_at < 3.0, closed_at
    finally:
        srv.shutdown()
        srv.server_close()


def test_listen_backlog_fits_the_expected_clients(filled):
    """64 clients connecting at once while the server accepts nothing all complete their
    handshake (socketserver's default backlog of 5 leaves the others waiting on SYN retries)."""
    import select
    import socket

    from service.edge.web.server import make_server

    srv = make_server(filled, "127.0.0.1", 0)  # bound and listening, not serving
    socks = []
    try:
        for _ in range(64):
            s = socket.socket()
            s.setblocking(False)
            s.connect_ex(("127.0.0.1", srv.server_address[1]))
            socks.append(s)
        deadline = time.monotonic() + 0.8  # the first SYN retry comes after 1 s
        done: set = set()
        while time.monotonic() < deadline and len(done) < len(socks):
            _, w, _ = select.select([], [s for s in socks if s not in done], [], 0.05)
            done.update(x for x in w if x.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) == 0)
        assert len(done) == 64, len(done)
    finally:
        for s in socks:
            s.close()
        srv.server_close()
