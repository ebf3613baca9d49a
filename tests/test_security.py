"""A secured station on loopback: mutual TLS and access control, every party in its own process.

The router is ``servowatch router --config deploy/secure/router.json5`` (the shipped config,
with the test's port and PKI), the PKI comes from ``deploy/pki/make-certs.sh`` in a temporary
directory, and every client is a separate process with one role's certificate. Each refused
case must fail, be logged (the router's access-control log) and change nothing; the
legitimate paths (acquisition -> daemon -> est/health -> dashboard, status, a fault command
from the operator) must still work.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from loglines import find_in

from service.config import EXIT_REFUSED
from service.zenoh_util import free_port

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed for the PKI"),
]

ROOT = Path(__file__).resolve().parents[1]
SECURE = ROOT / "deploy" / "secure"


def top_level(text: str, lines: str) -> str:
    """``text`` (a TOML config) with ``lines`` (top-level keys, then tables) put before its
    first table, wherever the shipped config's tables start."""
    at = re.search(r"^\[", text, flags=re.M)
    i = at.start() if at else len(text)
    return text[:i] + lines + "\n\n" + text[i:]


ROLE = str(Path(__file__).with_name("_zenoh_role.py"))
AC, ACT = "AC001", "elevator_L"
FORGED = "FORGED"


def make_pki(out: Path, *names: str) -> Path:
    subprocess.run(
        ["bash", str(ROOT / "deploy" / "pki" / "make-certs.sh"), str(out), *names],
        check=True, capture_output=True, timeout=60,
    )  # fmt: skip
    return out


class Station:
    """The secured router, and helpers starting clients of a given identity."""

    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.pki = make_pki(tmp / "pki")
        self.other = make_pki(tmp / "other", "operator", "acq-AC001")  # another CA
        self.ep = f"tls/127.0.0.1:{free_port()}"
        self.procs: list[subprocess.Popen] = []
        self.router_err = tmp / "router.err"
        self.router = self.popen(
            ["router", "--config", str(SECURE / "router.json5"), "--listen", self.ep,
             "--tls-root-ca", str(self.pki / "ca.pem"),
             "--tls-cert", str(self.pki / "router.pem"),
             "--tls-key", str(self.pki / "router.key")],
            "router",
            env={"RUST_LOG": "error,zenoh::net::routing::interceptor::access_control=trace"},
        )  # fmt: skip
        deadline = time.monotonic() + 30
        while find_in(tmp / "router.err", "servowatch.router", "listen") is None:
            assert self.router.poll() is None, self.router_err.read_text()[-2000:]
            assert time.monotonic() < deadline, "the router did not start"
            time.sleep(0.1)

    def env(self, name: str | None, pki: Path | None = None) -> dict[str, str]:
        """SERVOWATCH_ZENOH__* for identity ``name`` (None: no client certificate)."""
        pki = pki or self.pki
        env = {
            "SERVOWATCH_ZENOH__MODE": "client",
            "SERVOWATCH_ZENOH__CONNECT": self.ep,
            "SERVOWATCH_ZENOH__TLS__ROOT_CA": str(self.pki / "ca.pem"),
        }
        if name is not None:
            env["SERVOWATCH_ZENOH__TLS__CERT"] = str(pki / f"{name}.pem")
            env["SERVOWATCH_ZENOH__TLS__KEY"] = str(pki / f"{name}.key")
        return env

    def flags(self, name: str | None, pki: Path | None = None) -> list[str]:
        """The same identity as command-line flags (paths only)."""
        pki = pki or self.pki
        out = ["--connect", self.ep, "--tls-root-ca", str(self.pki / "ca.pem")]
        if name is not None:
            out += ["--tls-cert", str(pki / f"{name}.pem"), "--tls-key", str(pki / f"{name}.key")]
        return out

    def popen(self, args: list[str], tag: str, env: dict | None = None, role: bool = False):
        cmd = [sys.executable, ROLE] if role else [sys.executable, "-m", "service.cli"]
        with (self.tmp / f"{tag}.out").open("w") as out, (self.tmp / f"{tag}.err").open("w") as err:
            p = subprocess.Popen(
                cmd + args, stdout=out, stderr=err, cwd=ROOT,
                env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
            )  # fmt: skip
        self.procs.append(p)
        return p

    def web(self) -> subprocess.Popen:
        """The fleet page on an empty store, with live status through the secure router as
        the dashboard role (``deploy/secure/dashboard.toml``)."""
        from service.store import open_store

        open_store(self.tmp / "web.sqlite").close()
        return self.popen(
            ["web", "--store", str(self.tmp / "web.sqlite"), "--listen", "127.0.0.1:0",
             "--refresh", "1", "--config", str(SECURE / "dashboard.toml")],
            "web", env=self.env("dashboard"),
        )  # fmt: skip

    def actuator(self, *extra: str) -> subprocess.Popen:
        """The virtual actuator AC001's, on the healthy scenario at 250 Hz, as sim-AC001
        (``extra``: more of its flags)."""
        return self.popen(
            ["actuator", "--scenario", "healthy_noise", "--aircraft", AC, "--actuator", ACT,
             "--rate", "250", *extra, "--json", *self.flags("sim-AC001")],
            "actuator",
        )  # fmt: skip

    def monitor_config(self) -> Path:
        """``deploy/secure/monitor.toml`` logging to tmp, with no store, in group ``fleet``
        (join after 0.5 s, a unit unmonitored after 1.5 s): ``tmp/m0.toml``."""
        cfg = self.tmp / "m0.toml"
        text = (SECURE / "monitor.toml").read_text()
        text = text.replace('log_dir = "/var/lib/servowatch/logs"', f'log_dir = "{self.tmp}"')
        cfg.write_text(top_level(
            text, 'store = "off"\n\n[group]\nname = "fleet"\njoin_s = 0.5\nunmonitored_s = 1.5'
        ))  # fmt: skip
        return cfg

    def monitored(self) -> tuple[subprocess.Popen, subprocess.Popen, subprocess.Popen]:
        """(daemon, actuator, web): ``servowatch run`` on ``monitor_config()`` as
        monitor.ground1.0, started and answering ``servowatch status`` within 120 s; then the
        virtual actuator and the fleet page (``actuator()``, ``web()``)."""
        cmd = ["run", "--config", str(self.monitor_config()), "--no-rotate", "--json",
               "--plain-logs"]  # fmt: skip
        daemon = self.popen(cmd, "daemon", env=self.env("monitor.ground1.0"))
        deadline = time.monotonic() + 120
        while self.status()["rc"] != 0:
            assert daemon.poll() is None, (self.tmp / "daemon.err").read_text()[-3000:]
            assert time.monotonic() < deadline, "no daemon status"
            time.sleep(0.5)
        return daemon, self.actuator(), self.web()

    def run(self, args: list[str], tag: str, env=None, role=False, timeout=60.0) -> dict:
        """Run to the end: ``{"rc", "out", "err", "json"}``."""
        return self.result(self.popen(args, tag, env, role), tag, timeout)

    def result(self, p: subprocess.Popen, tag: str, timeout: float = 240.0) -> dict:
        """Wait for ``p``: ``{"rc", "out", "err", "json"}`` (last stdout line as JSON)."""
        rc = p.wait(timeout)
        out = (self.tmp / f"{tag}.out").read_text()
        last = out.strip().splitlines()[-1] if out.strip() else ""
        try:
            js = json.loads(last)
        except ValueError:
            js = None
        return {"rc": rc, "out": out, "err": (self.tmp / f"{tag}.err").read_text(), "json": js}

    def status(self, name: str = "operator", tag: str = "status") -> dict:
        return self.run(["status", "--json", "--timeout", "2", *self.flags(name)], tag)

    def router_log(self) -> str:
        """Zenoh's log of the router (it writes to stdout) and its stderr."""
        return (self.tmp / "router.out").read_text() + self.router_err.read_text()

    def close(self) -> None:
        for p in reversed(self.procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(5)


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    """Router, daemon (monitor), virtual actuator (sim-AC001), dashboard listener; then every
    refused attempt and the legitimate operator commands, while the actuator runs."""
    tmp = tmp_path_factory.mktemp("secure")
    st = Station(tmp)
    r: dict = {"station": st}
    try:
        daemon = st.popen(
            ["run", "--config", str(SECURE / "monitor.toml"), "--log", str(tmp / "d.mcap"),
             "--no-rotate", "--json", "--plain-logs"],
            "daemon", env=st.env("monitor.ground1.0"),
        )  # fmt: skip
        deadline = time.monotonic() + 90  # a cold numba cache compiles for a while
        while True:
            s = st.status()
            if s["rc"] == 0:
                break
            assert daemon.poll() is None, (tmp / "daemon.err").read_text()[-3000:]
            assert time.monotonic() < deadline, f"no daemon status: {s}"
            time.sleep(0.5)
        dash = st.popen(["listen", "fleet/**", FORGED], "dashboard", st.env("dashboard"), True)
        deadline = time.monotonic() + 30
        while '"ready"' not in (tmp / "dashboard.out").read_text():
            assert dash.poll() is None, (tmp / "dashboard.err").read_text()[-2000:]
            assert time.monotonic() < deadline
            time.sleep(0.1)
        # the fleet page with live status through the secure router, as the dashboard role
        web = st.web()
        act = st.actuator()
        time.sleep(3.0)
        # the refused cases and the legitimate commands, all at once while the actuator runs
        spoof = [
            "actuator",
            "--scenario",
            "healthy_noise",
            "--aircraft",
            "AC002",
            "--actuator",
            ACT,
            "--rate",
            "250",
            "--duration",
            "3",
            "--json",
            *st.flags("acq-AC001"),
        ]
        dash_inject = [
            "inject",
            "--aircraft",
            AC,
            "--actuator",
            ACT,
            "--fault",
            "leak",
            "--value",
            "6e-13",
            "--timeout",
            "3",
            "--json",
            *st.flags("dashboard"),
        ]
        op_inject = [
            "inject",
            "--aircraft",
            AC,
            "--actuator",
            ACT,
            "--fault",
            "clear",
            "--json",
            *st.flags("operator"),
        ]
        op_not_virtual = [
            "inject",
            "--aircraft",
            "AC002",
            "--actuator",
            ACT,
            "--fault",
            "clear",
            "--timeout",
            "3",
            *st.flags("operator"),
        ]
        fault = '{"kind": "leak", "value": 6e-13}'
        jobs = {
            "no_cert": (["status", "--json", *st.flags(None)], None, False),
            "other_ca": (["status", "--json", *st.flags("operator", st.other)], None, False),
            "spoof": (spoof, None, False),
            "forged_health": (["put", f"fleet/{AC}/{ACT}/health", FORGED, "25"],
                              st.env("acq-AC001"), True),
            "dash_inject": (dash_inject, None, False),
            "dash_query": (["get", f"fleet/{AC}/{ACT}/@fault", fault], st.env("dashboard"), True),
            "op_inject": (op_inject, None, False),
            "op_not_virtual": (op_not_virtual, None, False),
        }  # fmt: skip
        procs = {k: st.popen(a, k, env, role) for k, (a, env, role) in jobs.items()}
        for k, p in procs.items():
            r[k] = st.result(p, k)
        r["dash_status"] = st.status("dashboard", "dash_status")
        r["web_live"] = _web_live(tmp / "web.err", web)
        web.send_signal(signal.SIGTERM)
        r["web_rc"] = web.wait(15)
        r["status"] = st.status()
        assert act.poll() is None, "the actuator ended before the commands were done"
        act.send_signal(signal.SIGTERM)
        act.wait(30)
        r["actuator"] = json.loads((tmp / "actuator.out").read_text().strip().splitlines()[-1])
        time.sleep(1.0)
        dash.send_signal(signal.SIGTERM)
        dash.wait(15)
        r["dashboard"] = json.loads((tmp / "dashboard.out").read_text().strip().splitlines()[-1])
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(30) == 0, (tmp / "daemon.err").read_text()[-3000:]
        r["daemon"] = json.loads((tmp / "daemon.out").read_text().strip().splitlines()[-1])
        yield r
    finally:
        st.close()


def live_url(err: Path) -> str:
    """The /api/live address of the page whose ``serving http://...`` record is in ``err``
    (its ``url`` field)."""
    rec = find_in(err, "servowatch.web", "url")
    assert rec is not None and rec["url"].startswith("http://127.0.0.1:"), err.read_text()
    assert rec["msg"].startswith(f"serving {rec['url']} from "), rec
    return rec["url"].rstrip("/") + "/api/live"


def _web_live(err: Path, web: subprocess.Popen, timeout: float = 30.0) -> dict:
    """The page's /api/live once it lists the actuator (or the last answer at ``timeout``)."""
    import urllib.request

    deadline = time.monotonic() + timeout
    while find_in(err, "servowatch.web", "url") is None:
        assert web.poll() is None and time.monotonic() < deadline, "the page did not start"
        time.sleep(0.1)
    url = live_url(err)
    live: dict = {}
    while time.monotonic() < deadline:
        with urllib.request.urlopen(url, timeout=5) as resp:
            live = json.loads(resp.read())
        if f"{AC}/{ACT}" in live.get("units", {}):
            break
        time.sleep(0.3)
    return live


def _daemon_status(r: dict) -> dict:
    (st,) = r["status"]["json"]["daemons"].values()
    return st


def test_client_without_certificate_is_refused(station):
    res = station["no_cert"]
    assert res["rc"] == EXIT_REFUSED, res
    assert station["station"].ep in res["err"]
    assert "client certificate" in res["err"]


def test_certificate_of_another_ca_is_refused(station):
    res = station["other_ca"]
    assert res["rc"] == EXIT_REFUSED, res
    assert station["station"].ep in res["err"] and "refused" in res["err"]


def test_acquisition_cannot_publish_another_aircrafts_meas(station):
    assert station["spoof"]["rc"] == 0 and station["spoof"]["json"]["messages"] > 0
    assert "unauthorized to Put (ingress) on fleet/AC002/elevator_L/meas" in (
        station["station"].router_log()
    )
    for st in (_daemon_status(station), station["daemon"]):
        assert not any("AC002" in k for k in st["actuators"]), st["actuators"].keys()
    assert not any("AC002" in k for k in station["dashboard"]["counts"])


def test_acquisition_cannot_put_health(station):
    assert station["forged_health"]["json"] == {"opened": True, "sent": 25}
    assert "unauthorized to Put (ingress) on fleet/AC001/elevator_L/health" in (
        station["station"].router_log()
    )
    assert station["dashboard"]["marked"] == {}


def test_dashboard_cannot_send_a_fault_command(station):
    res = station["dash_inject"]
    assert res["rc"] == 1 and res["json"]["ok"] is False
    assert "not a virtual actuator" in res["json"]["message"]
    assert station["dash_query"]["json"] == {"opened": True, "replies": 0}
    assert "unauthorized to Query (ingress) on fleet/AC001/elevator_L/@fault" in (
        station["station"].router_log()
    )
    # only the operator's command reached the actuator
    assert station["actuator"]["faults_ok"] == 1
    assert station["actuator"]["faults_refused"] == 0


def test_fault_commands_go_to_virtual_actuators_only(station):
    res = station["op_not_virtual"]
    assert res["rc"] == 1 and "not a virtual actuator" in res["out"] + res["err"]


def test_legitimate_paths_end_to_end(station):
    # acquisition -> daemon
    st = _daemon_status(station)
    a = st["actuators"][f"fleet/{AC}/{ACT}/meas"]
    assert a["samples"] > 500 and not a["bad"]
    assert station["daemon"]["samples"] >= station["actuator"]["samples"] * 0.9
    # daemon -> est/health -> dashboard
    counts = station["dashboard"]["counts"]
    for kind in ("meas", "est", "health"):
        assert counts.get(f"fleet/{AC}/{ACT}/{kind}", 0) > 10, counts
    # status, for the operator and the dashboard; a fault command from the operator
    assert station["status"]["rc"] == 0 and station["dash_status"]["rc"] == 0
    assert station["op_inject"]["rc"] == 0 and station["op_inject"]["json"]["ok"] is True


def test_fleet_page_reads_live_status_as_the_dashboard(station):
    """``servowatch web --config deploy/secure/dashboard.toml`` with the dashboard's
    certificate: the read-only role is enough for the page's live status."""
    live = station["web_live"]
    assert live.get("enabled") and "error" not in live, live
    assert live["units"][f"{AC}/{ACT}"]["daemon"] == "ground1/0"
    assert live["units"][f"{AC}/{ACT}"]["samples"] > 0
    assert station["web_rc"] == 0


def test_monitor_group_forms_through_the_secure_router(tmp_path):
    """Two daemons of one monitor group, each with the monitor certificate, find each other
    through the secured router: its access control lets the group's liveliness tokens
    (``monitor/*/*/group/*``) through."""
    st = Station(tmp_path)
    try:
        base = (SECURE / "monitor.toml").read_text()
        for shard in ("0", "1"):
            cfg = tmp_path / f"m{shard}.toml"
            text = base.replace('shard = "0"', f'shard = "{shard}"').replace(
                'log_dir = "/var/lib/servowatch/logs"', f'log_dir = "{tmp_path}"'
            )
            # top-level keys before the first table
            cfg.write_text(top_level(text, 'store = "off"\n\n[group]\nname = "fleet"'))
            st.popen(["run", "--config", str(cfg), "--no-rotate", "--json", "--plain-logs"],
                     f"m{shard}", env=st.env(f"monitor.ground1.{shard}"))  # fmt: skip
        deadline = time.monotonic() + 90
        groups: dict = {}
        while time.monotonic() < deadline:
            s = st.status()
            if s["rc"] == 0:
                groups = {k: v.get("group") for k, v in s["json"]["daemons"].items()}
                if len(groups) == 2 and all(
                    g and g["members"] == ["ground1/0", "ground1/1"] and g["joined"]
                    for g in groups.values()
                ):
                    break
            time.sleep(0.5)
        assert len(groups) == 2 and all(
            g["members"] == ["ground1/0", "ground1/1"] and g["joined"] for g in groups.values()
        ), groups
        # the router traces what is not allowed per key at each declaration; none of it may
        # be what a member does with the group's tokens
        denied = [
            ln for ln in st.router_log().splitlines() if "unauthorized" in ln and "/group/" in ln
        ]
        for what in ("Liveliness Token", "Declare Liveliness Subscriber (ingress)"):
            assert not [ln for ln in denied if f"unauthorized to {what}" in ln], what
    finally:
        st.close()
