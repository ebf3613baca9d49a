"""Recovery and linked routers on the secure station (issue 33, item 4): the shipped
``deploy/secure/router.json5``, the PKI of ``deploy/pki/make-certs.sh``, every piece in its
own process, loopback only.

- the secure router killed (``kill -9``) and restarted mid-stream: the daemon loses no
  sample the virtual actuator's cache held (zenoh.ext history replies pass the rules);
- two linked secure routers (two stations, each on its own 127.0.0.1 port, B connecting to
  A with the ``router`` identity): the meas of an actuator on station A reach station B's
  daemon, and the link carries nothing else (no status query of A's daemon from B).
"""

from __future__ import annotations

import json
import shutil
import signal
import time
from pathlib import Path

import pytest

from service.zenoh_util import free_port

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed for the PKI"),
]

from loglines import find_in  # noqa: E402
from test_security import AC, ACT, SECURE, Station, top_level  # noqa: E402

KEY = f"fleet/{AC}/{ACT}/meas"


def _router(st: Station, tag: str, port: int, *connect: str):
    """``servowatch router --config deploy/secure/router.json5`` on tls/127.0.0.1:port."""
    args = [
        "router",
        "--config",
        str(SECURE / "router.json5"),
        "--listen",
        f"tls/127.0.0.1:{port}",
        "--tls-root-ca",
        str(st.pki / "ca.pem"),
        "--tls-cert",
        str(st.pki / "router.pem"),
        "--tls-key",
        str(st.pki / "router.key"),
    ]
    for c in connect:
        args += ["--connect", c]
    p = st.popen(
        args, tag, env={"RUST_LOG": "error,zenoh::net::routing::interceptor::access_control=trace"}
    )
    deadline = time.monotonic() + 60
    while find_in(st.tmp / f"{tag}.err", "servowatch.router", "listen") is None:
        assert p.poll() is None, (st.tmp / f"{tag}.err").read_text()[-2000:]
        assert time.monotonic() < deadline, f"router {tag} did not start"
        time.sleep(0.05)
    return p


def _daemon_config(st: Station, station: str, shard: str = "0") -> Path:
    cfg = st.tmp / f"{station}-{shard}.toml"
    text = (SECURE / "monitor.toml").read_text()
    text = text.replace('station = "ground1"', f'station = "{station}"')
    text = text.replace('shard = "0"', f'shard = "{shard}"')
    text = text.replace('log_dir = "/var/lib/servowatch/logs"', f'log_dir = "{st.tmp}"')
    cfg.write_text(top_level(text, 'store = "off"'))
    return cfg


def _status(st: Station, ep: str, tag: str = "status", timeout: float = 2.0) -> dict | None:
    res = st.run(["status", "--json", "--timeout", str(timeout), "--connect", ep,
                  "--tls-root-ca", str(st.pki / "ca.pem"), "--tls-cert", str(st.pki / "operator.pem"),
                  "--tls-key", str(st.pki / "operator.key")], tag)  # fmt: skip
    return res["json"] if res["rc"] == 0 else None


def _samples(status: dict | None) -> int:
    if not status:
        return 0
    return sum(d["actuators"].get(KEY, {}).get("samples", 0) for d in status["daemons"].values())


def _denied(log: str, cn: str, what: str, key: str) -> list[str]:
    """The router's refusals, to identity ``cn``, of ``what`` (e.g. "Reply (ingress)") on
    exactly ``key`` (the router also traces, at each declaration, what a key is not allowed
    for every other message type: those lines name other identities or directions)."""
    import re

    pat = re.compile(
        re.escape(f"CertCommonName({cn})")
        + r".*unauthorized to "
        + re.escape(what)
        + r" on "
        + re.escape(key)
        + r"(\s|\x1b|$)"
    )
    return [ln for ln in log.splitlines() if pat.search(ln)]


def test_secure_router_restart_loses_no_cached_sample(tmp_path):
    st = Station(tmp_path)  # router "router" on st.ep
    try:
        port = int(st.ep.rsplit(":", 1)[1])
        log = tmp_path / "d.mcap"
        daemon = st.popen(
            ["run", "--config", str(_daemon_config(st, "ground1")), "--log", str(log),
             "--no-rotate", "--json", "--plain-logs"],
            "daemon", env=st.env("monitor.ground1.0"),
        )  # fmt: skip
        deadline = time.monotonic() + 120
        while _status(st, st.ep) is None:
            assert daemon.poll() is None, (tmp_path / "daemon.err").read_text()[-3000:]
            assert time.monotonic() < deadline, "no daemon status"
            time.sleep(0.5)
        act = st.actuator("--cache-s", "60")
        while _samples(_status(st, st.ep)) < 250:
            assert act.poll() is None, (tmp_path / "actuator.err").read_text()[-3000:]
            assert time.monotonic() < deadline, "no stream reached the daemon"
            time.sleep(0.3)
        st.router.send_signal(signal.SIGKILL)
        st.router.wait(10)
        time.sleep(1.0)
        _router(st, "router2", port)
        t_back = time.monotonic()
        before = 0
        while time.monotonic() - t_back < 60:  # the stream resumes after the restart
            n = _samples(_status(st, st.ep, "status2"))
            if before and n > before + 250:
                break
            before = before or n
            time.sleep(0.3)
        act.send_signal(signal.SIGTERM)
        assert act.wait(30) == 0
        time.sleep(1.5)
        final = _status(st, st.ep, "status3")
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(60) == 0, (tmp_path / "daemon.err").read_text()[-3000:]
        from service.log import read_log

        seqs = sorted(int(r[2]["seq"]) for r in read_log(log, [f"/{KEY}"]))
        a = json.loads((tmp_path / "actuator.out").read_text().strip().splitlines()[-1])
        lost = sorted(set(range(seqs[0], seqs[-1] + 1)) - set(seqs))
        assert seqs and lost == [] and len(seqs) > 500, (len(seqs), lost[:20])
        assert seqs[-1] + 1 >= a["samples"] * 0.95, (seqs[-1], a)
        (d,) = final["daemons"].values()
        print(f"secure restart: {a['samples']} published, {len(seqs)} logged (seq {seqs[0]}-"
              f"{seqs[-1]}), {len(lost)} lost, gaps {d['actuators'][KEY]['gaps']}, missed "
              f"{d['actuators'][KEY]['missed']}")  # fmt: skip
        assert d["actuators"][KEY]["gaps"] == 0 and d["actuators"][KEY]["missed"] == 0, d
        # the restarted router let the cache's history replies through
        log2 = (tmp_path / "router2.out").read_text() + (tmp_path / "router2.err").read_text()
        for cn, what in (("sim-AC001", "Reply (ingress)"), ("monitor.ground1.0", "Reply (egress)")):
            assert not _denied(log2, cn, what, KEY), _denied(log2, cn, what, KEY)[:5]
    finally:
        st.close()


def test_two_linked_secure_stations_carry_meas_to_the_other_daemon(tmp_path):
    st = Station(tmp_path)  # station A: router on st.ep, the actuator connects there
    try:
        pb = free_port()
        ep_b = f"tls/127.0.0.1:{pb}"
        _router(st, "router_b", pb, st.ep)  # station B's router links to A's
        log = tmp_path / "b.mcap"
        env_b = {**st.env("monitor.ground2.0"), "SERVOWATCH_ZENOH__CONNECT": ep_b}
        daemon = st.popen(
            ["run", "--config", str(_daemon_config(st, "ground2")), "--log", str(log),
             "--no-rotate", "--json", "--plain-logs"],
            "daemon_b", env=env_b,
        )  # fmt: skip
        deadline = time.monotonic() + 120
        while _status(st, ep_b, "status_b") is None:
            assert daemon.poll() is None, (tmp_path / "daemon_b.err").read_text()[-3000:]
            assert time.monotonic() < deadline, "no daemon status on B"
            time.sleep(0.5)
        act = st.actuator("--duration", "4")
        assert act.wait(120) == 0, (tmp_path / "actuator.err").read_text()[-3000:]
        a = json.loads((tmp_path / "actuator.out").read_text().strip().splitlines()[-1])
        time.sleep(1.5)
        on_b = _status(st, ep_b, "status_b2")
        on_a = _status(st, st.ep, "status_a")  # B's daemon is not A's to query
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(60) == 0, (tmp_path / "daemon_b.err").read_text()[-3000:]
        assert list(on_b["daemons"]) == ["monitor/ground2/0/status"], on_b
        got = _samples(on_b)
        print(f"linked stations: {a['samples']} published on A, {got} accepted by B's daemon")
        assert got >= a["samples"] * 0.95 and got > 500, (got, a["samples"])
        assert on_a is None, on_a
        log_b = (tmp_path / "router_b.out").read_text() + (tmp_path / "router_b.err").read_text()
        log_a = st.router_log()
        for lg, cn, what in (
            (log_a, "sim-AC001", "Put (ingress)"),
            (log_a, "router", "Put (egress)"),
            (log_b, "router", "Put (ingress)"),
            (log_b, "monitor.ground2.0", "Put (egress)"),
        ):
            assert not _denied(lg, cn, what, KEY), _denied(lg, cn, what, KEY)[:5]
        assert "CertCommonName(router)" in log_a and "CertCommonName(router)" in log_b
        # the link carries no status queryable: B's router keeps its daemon's to itself
        refused = _denied(
            log_b, "router", "Declare/Undeclare Queryable (egress)", "monitor/ground2/0/status"
        )
        assert refused, log_b[-3000:]
    finally:
        st.close()
