"""Zenoh helpers, exercised through real sessions on loopback ports."""

from __future__ import annotations

import json
import socket
import threading

import pytest
import zenoh

from service.wire.messages import MeasSample, decode_meas, encode_meas
from service.zenoh_util import (
    BoundedQueue,
    EndpointError,
    check_endpoint,
    diagnose_link,
    free_port,
    loopback,
    make_config,
    wait_until,
)


@pytest.mark.parametrize(
    "ep",
    ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:0", "tls/127.0.0.1:7447", "unixsock-stream//tmp/sw.sock"],
)
def test_allowed_endpoints(ep):
    assert check_endpoint(ep) == ep


def test_unix_shorthand():
    assert check_endpoint("unix//tmp/a.sock") == "unixsock-stream//tmp/a.sock"


@pytest.mark.parametrize(
    "ep",
    [
        "tcp/0.0.0.0:7447",
        "tcp/[::]:7447",
        "tcp/localhost:7447",
        "tcp/10.0.0.5:7447",
        "udp/127.0.0.1:7447",
        "tcp/127.0.0.1:70000",
        "127.0.0.1:7447",
        "udp/224.0.0.224:7446",
    ],
)
def test_refused_endpoints(ep):
    with pytest.raises(EndpointError):
        check_endpoint(ep)


def test_allow_remote_is_explicit():
    assert check_endpoint("tcp/10.0.0.5:7447", allow_remote=True) == "tcp/10.0.0.5:7447"
    with pytest.raises(EndpointError):
        make_config("router", listen=["tcp/0.0.0.0:7447"])
    with pytest.raises(EndpointError, match="plain"):  # off loopback, tcp/ also needs its flag
        make_config("router", listen=["tcp/0.0.0.0:7447"], allow_remote=True)
    cfg = make_config(
        "router", listen=["tcp/0.0.0.0:7447"], allow_remote=True, allow_plain_listen=True
    )
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7447"]


def test_config_contents():
    cfg = make_config("client", connect=[loopback(7447)])
    assert json.loads(cfg.get_json("mode")) == "client"
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    assert json.loads(cfg.get_json("listen/endpoints")) == []  # not zenoh's [::] default
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]
    with pytest.raises(ValueError):
        make_config("client")
    with pytest.raises(ValueError):
        make_config("broker")  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        make_config("peer", connect="tcp/127.0.0.1:7447")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        make_config("peer", extra={"scouting/multicast/enabled": True})


def test_free_port_is_bindable():
    p = free_port()
    assert 1024 <= p <= 65535
    with socket.socket() as s:
        s.bind(("127.0.0.1", p))


def test_bounded_queue_drops_oldest_and_counts():
    q: BoundedQueue[int] = BoundedQueue(3)
    for k in range(5):
        q.put(k)
    assert q.dropped == 2 and q.put_count == 5 and q.high_water == 3
    assert q.get_batch(10, timeout=0) == [2, 3, 4]
    assert q.get_batch(10, timeout=0.01) == []
    got: list[list[int]] = []
    th = threading.Thread(target=lambda: got.append(q.get_batch(10, timeout=5)))
    th.start()
    q.put(9)
    th.join(5)
    assert got == [[9]]
    with pytest.raises(ValueError):
        BoundedQueue(0)


@pytest.fixture
def router():
    port = free_port()
    s = zenoh.open(make_config("router", listen=[loopback(port)]))
    yield port
    s.close()


def test_pub_sub_query_liveliness_through_a_router(router):
    ep = [loopback(router)]
    with (
        zenoh.open(make_config("peer", connect=ep)) as daemon,
        zenoh.open(make_config("client", connect=ep)) as source,
    ):
        q: BoundedQueue[tuple[str, bytes]] = BoundedQueue(1000)
        sub = daemon.declare_subscriber(
            "fleet/**/meas", lambda s: q.put((str(s.key_expr), s.payload.to_bytes()))
        )
        qbl = daemon.declare_queryable(
            "monitor/g1/0/status",
            lambda query: query.reply("monitor/g1/0/status", b'{"actuators": 1}'),
        )
        tok = daemon.liveliness().declare_token("fleet/AC001/elevator_L/alive")
        samples = [MeasSample(seq=k, t=k * 1e-3, p1=1e7 + k) for k in range(5)]
        # wait until the subscription has propagated: a probe put arrives
        assert wait_until(
            lambda: source.put("fleet/probe/x/meas", b"probe") or len(q) > 0, timeout=10
        )
        q.get_batch(1000, timeout=0)
        source.put("fleet/AC001/elevator_L/meas", encode_meas(samples))
        source.put("fleet/AC001/elevator_L/@fault", b"{}")  # '@' chunk: not matched by **
        source.put("fleet/AC001/elevator_L/est", b"{}")
        got: list[tuple[str, bytes]] = []

        def arrived() -> bool:
            got.extend(x for x in q.get_batch(100, timeout=0) if "probe" not in x[0])
            return len(got) >= 1

        assert wait_until(arrived, timeout=10)
        wait_until(lambda: False, timeout=0.3)  # anything else (it must not come) arrives
        arrived()
        (key, payload), *rest = got
        assert rest == []
        assert key == "fleet/AC001/elevator_L/meas"
        assert decode_meas(payload) == samples
        replies = [r.ok for r in source.get("monitor/**/status", timeout=5) if r.ok]
        assert [json.loads(r.payload.to_bytes()) for r in replies] == [{"actuators": 1}]
        alive = [str(r.ok.key_expr) for r in source.liveliness().get("fleet/**/alive", timeout=5)]
        assert alive == ["fleet/AC001/elevator_L/alive"]
        tok.undeclare()
        assert wait_until(
            lambda: not list(source.liveliness().get("fleet/**/alive", timeout=1)), timeout=10
        )
        sub.undeclare()
        qbl.undeclare()


def test_router_command_routes_and_stops_on_sigterm():
    import signal
    import subprocess
    import sys

    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli", "router", "--listen", loopback(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stderr is not None
        first = proc.stderr.readline()  # its first log line: listening (a JSON record)
        rec = json.loads(first)
        assert rec["logger"] == "servowatch.router" and rec["listen"] == [loopback(port)], first
        assert f"listening on tcp/127.0.0.1:{port}" in rec["msg"] and rec["zid"] in rec["msg"]
        ep = [loopback(port)]
        with (
            zenoh.open(make_config("client", connect=ep)) as a,
            zenoh.open(make_config("client", connect=ep)) as b,
        ):
            q: BoundedQueue[bytes] = BoundedQueue(100)
            a.declare_subscriber("fleet/**", lambda s: q.put(s.payload.to_bytes()))
            assert wait_until(lambda: b.put("fleet/x/y/meas", b"hi") or len(q) > 0, timeout=10)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
        assert proc.returncode == 0, err
        assert out == "" and json.loads(err.splitlines()[-1])["msg"] == "router stopped", err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_router_command_refuses_remote_listen():
    from service.cli import main

    assert main(["router", "--listen", "tcp/0.0.0.0:7447"]) == 2


@pytest.mark.parametrize("ep", ["tls/10.0.0.1:7447", "tls/0.0.0.0:7447", "tls/127.0.0.1:70000"])
def test_tls_endpoints_loopback_only(ep):
    with pytest.raises(EndpointError):
        check_endpoint(ep)


def test_diagnose_link_tells_an_absent_router():
    kind, why = diagnose_link(f"tls/127.0.0.1:{free_port()}")
    assert kind == "unreachable" and "no router there" in why
    kind, _why = diagnose_link(f"tcp/127.0.0.1:{free_port()}")
    assert kind == "unreachable"


def test_diagnose_link_tells_a_plain_tcp_listener_from_tls():

    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        ep = f"127.0.0.1:{srv.getsockname()[1]}"
        srv.settimeout(5)

        def answer() -> None:  # a non-TLS server: replies with plain bytes, closes
            c, _ = srv.accept()
            with c:
                c.recv(1024)
                c.sendall(b"HTTP/1.0 400 nope\r\n\r\n")

        t = threading.Thread(target=answer)
        t.start()
        kind, why = diagnose_link("tls/" + ep, timeout=5)
        t.join(5)
    assert kind == "refused" and "TLS" in why
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        assert diagnose_link(f"tcp/127.0.0.1:{srv.getsockname()[1]}")[0] == "ok"
