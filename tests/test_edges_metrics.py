"""Metrics that cannot starve the monitor (issue 50, item 2): a scrape costs the daemon O(1)
(the exposition is built at most once per ``max_age_s`` by one builder, whatever the number
of scrapers), concurrent connections are capped and idle ones time out."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
import urllib.error
import urllib.request

from test_status_reply import GOOD

from service.edge.metrics import MetricsServer


class _Counting:
    def __init__(self, cost_s: float = 0.0) -> None:
        self.calls = 0
        self.cost_s = cost_s

    def __call__(self) -> dict:
        self.calls += 1
        time.sleep(self.cost_s)
        return dict(GOOD, samples=self.calls)


def _get(url: str, timeout: float = 10.0) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def test_concurrent_scrapes_share_one_build():
    status = _Counting(cost_s=0.05)
    srv = MetricsServer(
        status, "127.0.0.1", 0, max_age_s=1.0, max_connections=64, max_per_s=1e6
    ).start()
    try:
        url = f"http://127.0.0.1:{srv.address[1]}/metrics"
        codes: list[int] = []
        t0 = time.monotonic()

        def scrape() -> None:
            for _ in range(5):
                codes.append(_get(url)[0])

        ts = [threading.Thread(target=scrape) for _ in range(20)]
        for t in ts:
            t.start()
        for t in ts:
            t.join(30)
        took = time.monotonic() - t0
        assert codes.count(200) == 100, codes
        # 100 scrapes in about `took` seconds: at most one build per max_age_s (+1)
        assert status.calls <= int(took / 1.0) + 2, (status.calls, took)
        code, body = _get(url)
        assert b"servowatch_samples_total" in body and code == 200
    finally:
        srv.close()


def test_connections_are_capped_and_idle_ones_time_out():
    srv = MetricsServer(_Counting(), "127.0.0.1", 0, max_connections=4, idle_s=2.0).start()
    held = []
    try:
        port = srv.address[1]
        threads0 = threading.active_count()
        held = [socket.create_connection(("127.0.0.1", port), timeout=5) for _ in range(30)]
        time.sleep(0.5)
        assert threading.active_count() - threads0 <= 4 + 1, threading.active_count() - threads0
        # beyond the cap: answered 503 at once and closed, without a thread
        refused = 0
        for s in held:
            s.settimeout(0.1)
            with contextlib.suppress(TimeoutError):  # one of the 4 served: idle
                refused += s.recv(100).startswith(b"HTTP/1.1 503")
        assert refused >= 20, refused
        # the idle ones are closed after idle_s; a scrape then gets in
        time.sleep(2.5)
        code, _ = _get(f"http://127.0.0.1:{port}/metrics")
        assert code == 200
        st = srv.stats()
        assert st["refused"] >= 20 and st["max_connections"] == 4, st
    finally:
        for s in held:
            s.close()
        srv.close()


def test_scrapes_are_limited_per_second():
    """Beyond ``max_per_s`` a second, a scrape is answered 503 on the listening thread."""
    status = _Counting()
    srv = MetricsServer(status, "127.0.0.1", 0, max_per_s=5.0).start()
    try:
        url = f"http://127.0.0.1:{srv.address[1]}/metrics"
        t0 = time.monotonic()
        codes = [_get(url)[0] for _ in range(40)]
        took = time.monotonic() - t0
        assert set(codes) == {200, 503}, codes
        assert codes.count(200) <= 5 + 5 * took + 1, (codes.count(200), took)
        assert srv.stats()["refused"] == codes.count(503)
    finally:
        srv.close()
