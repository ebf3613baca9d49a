"""The live Foxglove feed under the fleet page's rules (issue 43, item 1): the guard of
``service.edge.foxglove_guard`` in front of the SDK's server refuses a foreign ``Host``, a
cross-origin ``Origin`` and connections beyond the cap before the upgrade; cuts an unfinished
or oversized client message; drops a client that does not read; bounds and reports its memory
and its listener. Raw sockets on loopback, against a real ``FoxgloveFeed``."""

from __future__ import annotations

import base64
import os
import re
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from _foxglove_ws import OFFER, FoxgloveClient, client_frame

from service.edge.foxglove_feed import LEAVES, FoxgloveFeed
from service.edge.foxglove_guard import FrameCheck, GuardLimits
from service.monitor import EST_KEYS
from service.wire import messages as m

AC, ACT = "AC001", "elevator_L"
TOPIC = {leaf: m.mcap_topic(AC, ACT, leaf) for leaf in LEAVES}
ROOT = Path(__file__).resolve().parents[1]


def _handshake(
    port: int, headers: dict[str, str] | list[tuple[str, str]], s: socket.socket | None = None
) -> tuple[str, socket.socket]:
    """Send an upgrade request with ``headers`` (besides the WebSocket ones) on ``s`` (None:
    a new connection); (status line, socket)."""
    if s is None:
        s = socket.create_connection(("127.0.0.1", port), timeout=10)
    key = base64.b64encode(os.urandom(16)).decode()
    items = headers.items() if isinstance(headers, dict) else headers
    extra = "".join(f"{k}: {v}\r\n" for k, v in items)
    s.sendall(
        (f"GET / HTTP/1.1\r\n{extra}Upgrade: websocket\r\nConnection: Upgrade\r\n"
         f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
         f"Sec-WebSocket-Protocol: {OFFER}\r\n\r\n").encode()
    )  # fmt: skip
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = s.recv(4096)
        if not chunk:
            break
        head += chunk
    return head.split(b"\r\n", 1)[0].decode("latin-1"), s


def _closed(s: socket.socket, timeout: float) -> float | None:
    """Seconds until the peer closed ``s`` (reading and discarding), None if it did not."""
    t0 = time.monotonic()
    s.settimeout(0.2)
    while time.monotonic() - t0 < timeout:
        try:
            if not s.recv(65536):
                return time.monotonic() - t0
        except TimeoutError:
            continue
        except ConnectionError:
            return time.monotonic() - t0
    return None


@pytest.fixture
def feed():
    f = FoxgloveFeed(
        "127.0.0.1", 0,
        limits=GuardLimits(max_connections=3, max_per_address=3, message_s=1.0,
                           max_message_bytes=4096,
                           max_backlog_bytes=64 * 1024,
                           allowed_origins=("https://app.foxglove.dev",)),
    )  # fmt: skip
    try:
        yield f
    finally:
        f.close()


def test_a_foreign_host_or_origin_is_refused_before_the_upgrade(feed):
    p = feed.port
    ok = {"Host": f"127.0.0.1:{p}"}
    for headers, status in [
        ({"Host": f"evil.example:{p}"}, 421),  # DNS rebinding
        ([("Host", f"127.0.0.1:{p}"), ("Host", "evil.example")], 400),
        ({**ok, "Origin": "https://evil.example"}, 403),  # a cross-site page
        ({**ok, "Origin": "null"}, 403),  # a sandboxed frame of any site
        ({**ok, "Origin": f"http://evil.example:{p}"}, 403),
        ([*ok.items(), ("Origin", f"http://127.0.0.1:{p}"), ("Origin", "https://x.example")], 400),
    ]:
        line, s = _handshake(p, headers)
        s.close()
        assert f" {status} " in line + " ", (headers, line)
    for headers in [
        ok,  # no Origin: not a browser
        {"Host": f"localhost:{p}"},
        {**ok, "Origin": f"http://localhost:{p}"},  # the server's own origin
        {**ok, "Origin": "https://app.foxglove.dev"},  # listed in allowed_origins
    ]:
        line, s = _handshake(p, headers)
        s.close()
        assert " 101 " in line, (headers, line)
    st = feed.status()["guard"]
    assert st["refused"] == {"host": 2, "origin": 4}, st
    assert st["listener"] == "ok"


def test_connections_are_capped(feed):
    clients = [FoxgloveClient("127.0.0.1", feed.port).connect() for _ in range(3)]
    try:
        line, s = _handshake(feed.port, {"Host": f"127.0.0.1:{feed.port}"})
        s.close()
        assert " 503 " in line, line
        assert feed.status()["guard"]["connections"] == 3
        clients.pop().close()
        time.sleep(0.3)
        clients.append(FoxgloveClient("127.0.0.1", feed.port).connect())  # a slot is free again
    finally:
        for c in clients:
            c.close()
    st = feed.status()["guard"]
    assert st["refused"] == {"busy": 1} and st["max_connections"] == 3


def test_an_unfinished_message_is_cut_after_message_s(feed):
    line, s = _handshake(feed.port, {"Host": f"127.0.0.1:{feed.port}"})
    assert " 101 " in line
    s.sendall(client_frame(0x1, b'{"op": "subscr', fin=False))  # a fragment, never finished
    t = _closed(s, 10.0)
    s.close()
    assert t is not None and 0.5 < t < 3.0, t
    assert feed.status()["guard"]["cut"] == {"message_timeout": 1}


def test_an_oversized_message_is_cut_at_its_header(feed):
    line, s = _handshake(feed.port, {"Host": f"127.0.0.1:{feed.port}"})
    assert " 101 " in line
    s.sendall(client_frame(0x1, b"x" * 100, fin=False, length=100))
    s.sendall(client_frame(0x0, b"", fin=False, length=4_000_000)[:14])  # 4 MB announced
    t = _closed(s, 5.0)
    s.close()
    assert t is not None and t < 1.0, t
    assert feed.status()["guard"]["cut"] == {"oversize": 1}


def test_a_client_that_does_not_read_is_dropped_and_memory_stays_bounded(feed):
    feed.add_actuator(AC, ACT)
    c = FoxgloveClient("127.0.0.1", feed.port).connect(rcvbuf=4096)
    c.wait_topics(set(TOPIC.values()), timeout=10)
    c.subscribe({1: c.channel_of(TOPIC["est"])["id"]})
    end = time.monotonic() + 10
    while not feed.wants(TOPIC["est"]):
        assert time.monotonic() < end
        time.sleep(0.01)
    est = np.zeros((500, len(EST_KEYS)))
    peak = 0
    end = time.monotonic() + 20
    while not feed.status()["guard"]["cut"] and time.monotonic() < end:
        feed.log_block(TOPIC["est"], np.arange(500.0), EST_KEYS, est)  # never read
        time.sleep(0.02)
        peak = max(peak, feed.status()["guard"]["buffered_bytes"])
    st = feed.status()["guard"]
    c.close()
    assert st["cut"] == {"slow_client": 1}, st
    assert st["connections"] == 0 and peak <= st["memory_bound_bytes"], (peak, st)
    assert st["memory_bound_bytes"] == 3 * (2 * (64 * 1024 + 256 * 1024) + 8192) + 64 * 8192


def test_a_dead_listener_is_reported_and_degrades_the_daemon(feed):
    from service.daemon.status import service_state

    fx = feed.status()
    assert fx["guard"]["listener"] == "ok" and service_state(None, fx) == "ok"
    feed.guard.loop.call_soon_threadsafe(feed.guard._server.close)
    time.sleep(0.3)
    fx = feed.status()
    assert fx["guard"]["listener"].startswith("dead"), fx["guard"]
    assert service_state(None, fx) == "degraded"
    with pytest.raises(OSError):
        FoxgloveClient("127.0.0.1", feed.port).connect(timeout=2)


def test_an_sdk_server_that_stops_accepting_is_reported(feed):
    from service.daemon.status import service_state

    feed.server.stop()  # the SDK's listener gone, the guard's still up
    line, s = _handshake(feed.port, {"Host": f"127.0.0.1:{feed.port}"})
    s.close()
    assert " 502 " in line, line
    fx = feed.status()
    assert fx["guard"]["listener"].startswith("upstream down"), fx["guard"]
    assert service_state(None, fx) == "degraded"


def test_frame_check_counts_fragments_and_control_frames():
    fc = FrameCheck(100)
    data = (
        client_frame(0x1, b"a" * 60, fin=False)
        + client_frame(0x9, b"p")
        + client_frame(0x0, b"b" * 30)
    )
    for i in range(len(data)):  # byte by byte: the same as at once
        assert fc.feed(data[i : i + 1], float(i)) is None
    assert fc.pending_since is None and fc.messages == 1  # the ping inside does not count
    assert (
        FrameCheck(100).feed(
            client_frame(0x1, b"a" * 60, fin=False) + client_frame(0x0, b"b" * 41), 0
        )
        == "oversize"
    )
    assert FrameCheck(100).feed(client_frame(0x0, b"x"), 0) == "protocol"  # no message open
    assert FrameCheck(100).feed(b"\x81\x05hello", 0) == "protocol"  # unmasked


def test_the_units_set_their_descriptor_limit():
    for unit in ("servowatch.service", "servowatch-router.service", "servowatch-web.service"):
        text = (ROOT / "deploy" / unit).read_text()
        got = re.findall(r"^LimitNOFILE=(\d+)$", text, re.M)
        assert got and int(got[0]) >= 4096, unit
