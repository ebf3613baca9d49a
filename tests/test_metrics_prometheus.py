"""The daemon's metrics scraped by a real Prometheus server (Debian's ``prometheus``).

Router (in this process), ``servowatch run --metrics``, ``servowatch actuator`` and
``servowatch inject`` each in its own process on loopback; the test starts its own
``prometheus`` on a free loopback port with a scrape config of its own (1 s interval, a
temporary storage directory) and asks its HTTP API. Without the binary these tests skip, and
fail instead when ``SERVOWATCH_REQUIRE_PROMETHEUS=1`` (as in CI; ``.ci/run`` installs it).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from service.monitor import Baseline
from service.zenoh_util import free_port
from tests.test_grafana import DASH as DASHBOARD
from tests.test_grafana import _exprs
from tests.test_service_e2e import Net, act_samples, cli

pytestmark = pytest.mark.slow

AC, ACT = "AC001", "elevator_L"
LEAK = 8e-13  # injected C_Lk [m^3/(s Pa)]


def prometheus_binary() -> str:
    exe = shutil.which("prometheus")
    if exe is None:
        why = "no `prometheus` binary (Debian: apt-get install prometheus)"
        if os.environ.get("SERVOWATCH_REQUIRE_PROMETHEUS") == "1":
            pytest.fail(f"Prometheus required (SERVOWATCH_REQUIRE_PROMETHEUS=1): {why}")
        pytest.skip(why)
    return exe


class Prometheus:
    """A throwaway Prometheus server scraping ``targets`` every second."""

    def __init__(self, exe: str, tmp: Path, targets: list[str]) -> None:
        self.port = free_port()
        cfg = tmp / "prometheus.yml"
        cfg.write_text(
            "global:\n  scrape_interval: 1s\n  evaluation_interval: 1s\n"
            "scrape_configs:\n  - job_name: servowatch\n    scrape_interval: 1s\n"
            "    scrape_timeout: 1s\n    static_configs:\n"
            f"      - targets: {json.dumps(targets)}\n"
        )
        self.log = open(tmp / "prometheus.log", "w")  # noqa: SIM115 (closed in close)
        self.proc = subprocess.Popen(
            [exe, f"--config.file={cfg}", f"--storage.tsdb.path={tmp / 'tsdb'}",
             f"--web.listen-address=127.0.0.1:{self.port}", "--log.level=warn"],
            stdout=self.log, stderr=subprocess.STDOUT, cwd=tmp,
        )  # fmt: skip

    def api(self, path: str, **params: str) -> dict:
        q = urllib.parse.urlencode(params)
        url = f"http://127.0.0.1:{self.port}/api/v1/{path}" + (f"?{q}" if q else "")
        with urllib.request.urlopen(url, timeout=5) as r:
            return json.loads(r.read())

    def query(self, promql: str) -> list[dict]:
        ans = self.api("query", query=promql)
        assert ans["status"] == "success", ans
        return ans["data"]["result"]

    def wait(self, pred, what: str, timeout: float = 60.0):
        deadline = time.monotonic() + timeout
        last = None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise AssertionError(f"prometheus exited: {self.proc.returncode}")
            try:
                last = pred()
            except OSError as e:  # not listening yet
                last = e
            else:
                if last:
                    return last
            time.sleep(0.5)
        raise AssertionError(f"timed out waiting for {what}; last: {last}")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.log.close()


def test_prometheus_scrapes_the_injected_leak(tmp_path):
    """A leak of 8e-13 injected into a running virtual actuator: through Prometheus's HTTP
    API, ``servowatch_unit_alarm{kind="leak"}`` of the unit is 1 and its
    ``servowatch_unit_leak_ratio`` is within 15 % of 8e-13 over the baseline C_Lk; the target
    is up and the daemon's sample counter and latency histogram are there; every query of the
    Grafana dashboard runs on this server, those of the unit's ratios with data."""
    exe = prometheus_binary()
    mport = free_port()
    n = Net()
    prom = None
    try:
        d = n.start("run", "--metrics", f"127.0.0.1:{mport}", "--store",
                    str(tmp_path / "h.sqlite"), "--log", str(tmp_path / "d.mcap"),
                    "--no-rotate", "--json", "--plain-logs")  # fmt: skip
        n.wait(lambda st: True, what="the daemon's status queryable")
        prom = Prometheus(exe, tmp_path, [f"127.0.0.1:{mport}"])
        a = n.start("actuator", "--aircraft", AC, "--actuator", ACT, "--scenario", "healthy_noise",
                    "--rate", "250", "--duration", "60", "--json")  # fmt: skip
        n.wait(lambda st: act_samples(st) > 250 * 2, what="2 s of samples")
        sel = f'aircraft="{AC}",actuator="{ACT}"'
        before = prom.wait(
            lambda: prom.query(f"servowatch_unit_leak_ratio{{{sel}}}"), "a scraped leak ratio"
        )
        assert float(before[0]["value"][1]) < 1.5  # healthy before the leak
        inj = cli("inject", "--connect", n.ep, "--aircraft", AC, "--actuator", ACT,
                  "--fault", "leak", "--value", str(LEAK), "--json")  # fmt: skip
        out, err = inj.communicate(timeout=60)
        assert inj.returncode == 0, err
        alarm = prom.wait(
            lambda: [r for r in prom.query(f'servowatch_unit_alarm{{{sel},kind="leak"}} == 1')],
            "the leak alarm in Prometheus",
            timeout=90,
        )
        assert alarm[0]["metric"]["station"] == "ground1" and alarm[0]["metric"]["shard"] == "0"
        want = LEAK / Baseline.default("WH").c_lk
        # the ratio settles on the injected leak within a few seconds of the alarm
        ratio = prom.wait(
            lambda: [
                r
                for r in prom.query(f"servowatch_unit_leak_ratio{{{sel}}}")
                if abs(float(r["value"][1]) / want - 1.0) < 0.15
            ],
            f"a leak ratio near {want:.2f}",
            timeout=30,
        )
        assert float(ratio[0]["value"][1]) == pytest.approx(want, rel=0.15)
        up = prom.query('up{job="servowatch"}')
        assert [float(r["value"][1]) for r in up] == [1.0]
        samples = prom.query('servowatch_samples_total{station="ground1"}')
        assert float(samples[0]["value"][1]) > 500
        p99 = prom.query("histogram_quantile(0.99, servowatch_latency_seconds_bucket)")
        assert 0.0 < float(p99[0]["value"][1]) < 5.0
        # every query of the Grafana dashboard is valid PromQL to this server, and the unit
        # row's ratios have data for the unit
        dash = json.loads(DASHBOARD.read_text())
        sub = {"$station": ".*", "$aircraft": AC, "$actuator": ACT, "$__rate_interval": "1m"}
        empty = []
        for e in _exprs(dash):
            q = e
            for k, v in sub.items():
                q = q.replace(k, v)
            if e.startswith("label_values("):  # Grafana's own function: its selector inside
                q = q[len("label_values(") : q.rindex(",")]
            if not prom.query(q):
                empty.append(e)
        for want in ("unit_leak_ratio", "unit_supply_ratio", "unit_nis_in_band_ratio",
                     "unit_alarm", "samples_total", "latency_seconds_bucket"):  # fmt: skip
            assert not [e for e in empty if f"servowatch_{want}{{" in e], (want, empty)
        a.send_signal(signal.SIGTERM)
        a.communicate(timeout=30)
        d.send_signal(signal.SIGTERM)
        d.communicate(timeout=60)
        assert d.returncode == 0
    finally:
        if prom is not None:
            prom.close()
        n.close()
