"""The daemon's OpenMetrics endpoint (``service.edge.metrics``): the values are the status
snapshot's, read at scrape time; the fleet page's loopback and Host rules; ``[metrics]`` and
``--metrics`` validated; series bounded by the units."""

from __future__ import annotations

import http.client
import subprocess
import sys
import time
import urllib.request

import pytest
from prometheus_client.parser import text_string_to_metric_families

from service.config import ConfigError, MetricsSettings, ServiceConfig, load_config
from service.daemon import Daemon
from service.edge.metrics import METRICS, collect_status
from service.store import open_store
from tests.test_status_text import KEY, NAME, _feed, _flights_rul, _leak_run


def _scrape(port: int, host: str | None = None, method: str = "GET", path: str = "/metrics"):
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    c.putrequest(method, path, skip_host=host is not None)
    if host is not None:
        c.putheader("Host", host)
    c.endheaders()
    r = c.getresponse()
    body = r.read().decode()
    c.close()
    return r.status, body


def _samples(text: str) -> dict[tuple[str, frozenset], float]:
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out[(s.name, frozenset(s.labels.items()))] = s.value
    return out


@pytest.fixture(scope="module")
def leaking(tmp_path_factory):
    """An in-process daemon with the endpoint on a free port, fed 3 s of a unit leaking at
    4x nominal (baseline v1 and a RUL on flights in its store); scraped, then stopped."""
    tmp = tmp_path_factory.mktemp("metrics")
    store = tmp / "h.sqlite"
    from service.monitor import Baseline

    with open_store(store) as s:
        s.add_baseline(NAME, Baseline.default("WH").model_dump(), "test")
        s.put_rul(NAME, _flights_rul())
    cfg = ServiceConfig(store=str(store), metrics=MetricsSettings(listen="127.0.0.1:0"))
    d = Daemon(cfg, log_path=tmp / "d.mcap", log_process=False, gather_s=0)
    d.metrics.start()
    try:
        _feed(d, _leak_run(4.0, 3.0))
        port = d.metrics.address[1]
        st = d.status()
        code, text = _scrape(port)
        yield {"daemon": d, "port": port, "status": st, "code": code, "text": text}
    finally:
        d.stop()


def test_scrape_is_the_status_snapshot(leaking):
    assert leaking["code"] == 200
    got = _samples(leaking["text"])
    st = leaking["status"]
    a = st["actuators"][KEY]
    base = {("station", "ground1"), ("shard", "0")}
    unit = frozenset(base | {("aircraft", "AC7"), ("actuator", "rudder")})

    def v(name: str, labels=unit) -> float:
        return got[(name, frozenset(labels))]

    assert v("servowatch_unit_leak_ratio") == pytest.approx(a["health"]["leak_ratio"], rel=1e-3)
    assert v("servowatch_unit_leak_ratio") > 2.5
    assert v("servowatch_unit_supply_ratio") == pytest.approx(a["health"]["supply_ratio"], 1e-3)
    assert v("servowatch_unit_c_lk") == pytest.approx(a["est"]["c_lk"], rel=1e-3)
    assert v("servowatch_unit_nis_in_band_ratio") == pytest.approx(a["nis_in_band"], abs=0.02)
    # the pooled C_Lk (issue 51, shown beside the indicator): the open period's, near 4x nominal
    pooled = a["c_lk_pooled"]
    assert v("servowatch_unit_c_lk_pooled") == pytest.approx(pooled["value"], rel=1e-3)
    assert v("servowatch_unit_c_lk_pooled_sigma") == pytest.approx(pooled["sigma"], rel=1e-3)
    assert 3.5 < pooled["value"] / 2e-13 < 4.5 and pooled["sigma"] < 0.5 * a["est"]["c_lk_sigma"]
    assert v("servowatch_unit_alarm", unit | {("kind", "leak")}) == 1.0
    assert v("servowatch_unit_alarm", unit | {("kind", "supply")}) == 0.0
    assert v("servowatch_unit_commissioned") == 1.0
    assert v("servowatch_unit_baseline_version") == 1.0
    rul = a["rul"]
    assert v("servowatch_unit_rul_median_flights") == pytest.approx(rul["median_flights"])
    assert v("servowatch_unit_rul_median_days") == pytest.approx(rul["median_days"])
    assert v("servowatch_unit_samples_total") == a["samples"] == 3001
    assert v("servowatch_samples_total", base) == st["samples"]
    assert v("servowatch_dropped_total", base) == 0.0
    assert v("servowatch_units", base) == 1.0
    assert got[("servowatch_info", frozenset(base | {("model", "WH"), ("state", "ok")}))] == 1
    # the histogram counts every output's latency, its +Inf bucket all of them
    n_out = a["outputs"]
    inf = frozenset(base | {("le", "+Inf")})
    assert got[("servowatch_latency_seconds_bucket", inf)] == n_out > 2900
    assert got[("servowatch_latency_seconds_count", frozenset(base))] == n_out
    les = sorted(
        (float(dict(k[1])["le"]), val)
        for k, val in got.items()
        if k[0] == "servowatch_latency_seconds_bucket"
    )
    assert [c for _, c in les] == sorted(c for _, c in les)  # cumulative
    assert v("servowatch_log_bytes", base) > 0  # the log file's size
    ret = st["log_retention"]  # the retention's: what it kept, what it deleted
    assert v("servowatch_log_kept_bytes", base) == ret["kept_bytes"] > 0
    assert v("servowatch_log_deleted_files_total", base) == ret["deleted_files"] == 0


def test_scrape_reads_the_status_each_time(leaking):
    """A body is served at most ``max_age_s`` (1 s, issue 50): a scrape after that and more
    samples shows them."""
    d, port = leaking["daemon"], leaking["port"]
    key2 = "fleet/AC8/rudder/meas"
    _feed(d, _leak_run(1.0, 0.5), key=key2)
    time.sleep(d.metrics.exposition.max_age_s)
    _, text = _scrape(port)
    got = _samples(text)
    lab = frozenset({("station", "ground1"), ("shard", "0"), ("aircraft", "AC8"),
                     ("actuator", "rudder")})  # fmt: skip
    assert got[("servowatch_unit_samples_total", lab)] == 501
    assert got[("servowatch_units", frozenset({("station", "ground1"), ("shard", "0")}))] == 2
    # series bounded by the units: at most one per unit family (two alarm kinds) per unit
    bound = sum(1 for k in METRICS if k.startswith("unit_")) + 1
    per_unit = {}
    for _name, labels in got:
        ac = dict(labels).get("aircraft")
        if ac:
            per_unit[ac] = per_unit.get(ac, 0) + 1
    assert per_unit["AC7"] == bound and 10 <= per_unit["AC8"] <= bound
    assert len(got) - sum(per_unit.values()) < 60  # the daemon's own series


def test_host_check_methods_and_paths(leaking):
    port = leaking["port"]
    assert _scrape(port, host=f"localhost:{port}")[0] == 200
    assert _scrape(port, host=f"[::1]:{port}")[0] == 200
    assert _scrape(port, host="rebind.example:80")[0] == 421
    assert _scrape(port, host="")[0] == 421
    assert _scrape(port, method="POST")[0] == 405
    assert _scrape(port, path="/api")[0] == 404
    assert _scrape(port, method="HEAD")[0] == 200
    r = urllib.request.Request(
        f"http://127.0.0.1:{port}/metrics",
        headers={"Accept": "application/openmetrics-text; version=1.0.0"},
    )
    with urllib.request.urlopen(r) as ans:
        assert ans.headers["Content-Type"].startswith("application/openmetrics-text")
        assert ans.read().decode().rstrip().endswith("# EOF")


def test_two_host_headers_are_refused(leaking):
    port = leaking["port"]
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    c.putrequest("GET", "/metrics", skip_host=True)
    c.putheader("Host", "localhost")
    c.putheader("Host", "rebind.example")
    c.endheaders()
    assert c.getresponse().status == 400
    c.close()


def test_loopback_unless_allowed(tmp_path):
    with pytest.raises(ValueError, match="not a loopback address"):
        MetricsSettings(listen="0.0.0.0:9464")
    assert MetricsSettings(listen="0.0.0.0:9464", allow_remote=True).host_port()[0] == "0.0.0.0"
    p = tmp_path / "s.toml"
    p.write_text('[metrics]\nlisten = "10.1.2.3:9464"\n')
    with pytest.raises(ConfigError, match="metrics") as e:
        load_config(p, environ={})
    assert "allow_remote" in str(e.value)
    p.write_text('[metrics]\nlisten = "127.0.0.1:9464"\nextra = 1\n')
    with pytest.raises(ConfigError, match="extra"):
        load_config(p, environ={})
    p.write_text('[metrics]\nlisten = "127.0.0.1:99999"\n')
    with pytest.raises(ConfigError, match="port"):
        load_config(p, environ={})
    p.write_text("[metrics]\n")
    assert load_config(p, environ={}).metrics.listen == "127.0.0.1:9464"


def test_a_port_in_use_is_named(tmp_path):
    import socket

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        cfg = ServiceConfig(store="off", metrics=MetricsSettings(listen=f"127.0.0.1:{port}"))
        with pytest.raises(OSError, match=f"metrics endpoint 127.0.0.1:{port}"):
            Daemon(cfg, log_path=tmp_path / "d.mcap", log_process=False)


def test_run_refuses_a_remote_metrics_address():
    r = subprocess.run(
        [sys.executable, "-m", "service.cli", "run", "--metrics", "0.0.0.0:9464", "--connect",
         "tcp/127.0.0.1:9"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 2
    assert "--metrics" in r.stderr and "--metrics-allow-remote" in r.stderr


def full_status() -> dict:
    """A status with every part: a group, a live feed, a store, a unit with a RUL."""
    return {
        "station": "s", "shard": "0", "model": "WH", "state": "ok", "uptime_s": 1.0,
        "samples": 1, "dropped": 0, "bad": 0, "missed": 0, "errors": 0, "queue": 0,
        "queue_high": 0, "queue_size": 10, "busy_fraction": 0.1, "log": [], "log_failure": None,
        "log_retention": {"kept_bytes": 7, "kept_files": 1, "deleted_bytes": 9,
                          "deleted_files": 2},
        "latency_hist": {"le_s": [0.01], "counts": [1, 0], "sum_s": 0.001},
        "store": {"written": 1, "errors": 0, "pending": 0, "failure": None},
        "group": {"members": ["a", "b"], "takeovers": 1, "released": 0, "held_units": 0,
                  "unmonitored": {}},
        "foxglove": {"subscribed_topics": 2, "sent": 5, "dropped": 0,
                     "guard": {"listener": "ok", "connections": 3, "buffered_bytes": 10}},
        "silent": [],
        "actuators": {"k": {
            "aircraft": "A", "actuator": "b", "samples": 1, "dropped": 0, "gaps": 0,
            "bad_total": 0, "silent": False, "est": {"c_lk": 2e-13, "c_lk_sigma": 1e-14},
            "health": {"leak_ratio": 1.0, "supply_ratio": 1.0}, "nis_in_band": 0.95,
            "c_lk_pooled": {"value": 3e-13, "sigma": 1e-14},
            "alarms": [], "commissioned": True, "baseline_version": 2,
            "rul": {"median_flights": 10.0, "median_days": 5.0, "median_h": 20.0},
        }},
    }  # fmt: skip


def test_every_family_is_declared():
    """A status with a group, a live feed and a store: every family served is in METRICS and
    every METRICS family is served."""
    served = {f.name.removeprefix("servowatch_") for f in collect_status(full_status())}
    assert served == set(METRICS)


def test_the_feeds_viewers_come_from_its_guard():
    """The live feed's viewers, buffered bytes and listener state are its guard's (issue 43's
    guard counts the connections the SDK does not)."""
    st = full_status()
    fams = {f.name.removeprefix("servowatch_"): f for f in collect_status(st)}
    assert fams["foxglove_clients"].samples[0].value == 3
    assert fams["foxglove_buffered_bytes"].samples[0].value == 10
    assert fams["foxglove_listener_ok"].samples[0].value == 1
    st["foxglove"]["guard"]["listener"] = "dead"
    fams = {f.name.removeprefix("servowatch_"): f for f in collect_status(st)}
    assert fams["foxglove_listener_ok"].samples[0].value == 0


def test_a_trickling_request_is_cut_at_the_request_deadline():
    """The endpoint gives a request ``request_s`` in total however slowly it trickles in (the
    fleet page's rule, service.edge.httpguard): a client sending a header byte now and then does not
    hold its connection and thread for ever."""
    import socket
    import time

    from service.edge.metrics import MetricsServer

    srv = MetricsServer(lambda: {"station": "s", "shard": "0"}, port=0)
    srv._srv.RequestHandlerClass.request_s = 1.0
    srv.start()
    try:
        c = socket.create_connection(srv.address, timeout=10)
        c.sendall(b"GET /metrics HTTP/1.1\r\n")
        t0 = time.monotonic()
        cut = None
        while time.monotonic() - t0 < 8.0:
            try:
                c.sendall(b"X")
            except OSError:
                cut = time.monotonic() - t0
                break
            c.settimeout(0.25)
            try:
                if c.recv(1024) == b"":
                    cut = time.monotonic() - t0
                    break
            except TimeoutError:
                pass
        c.close()
        assert cut is not None and cut < 4.0, cut
    finally:
        srv.close()
