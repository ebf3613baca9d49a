"""A small health store with one unit of each page status, a ``servowatch web`` process
serving it, and the page's DOM as headless Chromium renders it (shared by the test_web*
modules)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from html.parser import HTMLParser

from loglines import find
from test_store import make_period

from service.edge.web.browser import dump_dom, find_chromium
from service.store import AlarmEvent, open_store

CRITICAL = "AC001/elevator_L"  # RUL warning: ranked first
WATCH = "AC001/aileron_R"  # alarms, a long RUL
OK = "AC002/rudder"  # stable, no crossing predicted
UNCOMMISSIONED = "AC002/spoiler_3"  # periods but no baseline
# the order `servowatch fleet` ranks them in: RUL median ascending, then no RUL
RANKED = [CRITICAL, WATCH, OK, UNCOMMISSIONED]


def _rul(
    actuator: str, median_h, lo_h, hi_h, p_horizon: float, warning: bool, flights: bool = False
) -> dict:
    """A RUL as ``rul`` stores it, 1.5 operating hours per flight; on the flights axis
    (``flights``) of a history of 8 flights, else on hours (no ``axis``: a RUL stored before
    the key was)."""
    axis = {"axis": "flights", "t_now": 8.0, "horizon": 20.0} if flights else {}
    return {
        "actuator": actuator, "status": "ok", "median_h": median_h, "lo_h": lo_h, "hi_h": hi_h,
        "median_flights": None if median_h is None else median_h / 1.5,
        "lo_flights": None if lo_h is None else lo_h / 1.5,
        "hi_flights": None if hi_h is None else hi_h / 1.5,
        "p_horizon": p_horizon, "warning": warning, "horizon_h": 50.0, "threshold_ratio": 4.0,
        "model": "linear", "t_now_h": 0.2, **axis,
    }  # fmt: skip


def fill_store(url: str) -> None:
    """Four units, one per status, with hand-set RULs: CRITICAL's history on operating hours
    (no flight numbers), WATCH's and OK's on flights (one flight a period)."""
    with open_store(url) as s:
        for a in (CRITICAL, WATCH, OK):
            s.add_baseline(a, {"c_lk": 1e-12}, "test")
        s.add_periods(
            [replace(make_period(CRITICAL, k, ratio=1.0 + 0.3 * k), flight=None) for k in range(8)]
        )
        s.add_periods([make_period(WATCH, k) for k in range(8)])
        s.add_periods([replace(make_period(OK, k, ratio=1.0), alarms=0) for k in range(8)])
        s.add_periods(
            [replace(make_period(UNCOMMISSIONED, k, ratio=1.0), alarms=0) for k in range(3)]
        )
        s.add_alarms([AlarmEvent(WATCH, 105.0, "leak", 3e-12, "log-a")])
        s.put_rul(CRITICAL, _rul(CRITICAL, 12.0, 8.0, 20.0, 0.93, True))
        s.put_rul(WATCH, _rul(WATCH, 300.0, 120.0, 900.0, 0.01, False, flights=True))
        s.put_rul(OK, _rul(OK, None, None, None, 0.0, False))


@contextmanager
def web_process(store: str, *extra: str) -> Iterator[str]:
    """``servowatch web --store STORE --listen 127.0.0.1:0`` in its own process; yields its
    base URL once it answers /healthz; SIGTERM at the end (it must exit 0)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli", "web", "--store", store,
         "--listen", "127.0.0.1:0", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True,
    )  # fmt: skip
    err: list[str] = []  # its log lines (stderr), read on a thread until it ends
    serving = threading.Event()

    def _read() -> None:
        for line in proc.stderr:
            err.append(line)
            if find(line, "servowatch.web", "url") is not None:
                serving.set()

    try:
        threading.Thread(target=_read, daemon=True).start()
        serving.wait(60)  # a cold start imports numpy and the store; a hang fails here
        rec = find("".join(err), "servowatch.web", "url")
        assert rec is not None and rec["url"].startswith("http://127.0.0.1:"), "".join(err)
        live = " (live status on)" if rec["live"] else ""
        assert rec["msg"] == f"serving {rec['url']} from {rec['store']}{live}", rec
        url = rec["url"].rstrip("/")
        deadline = time.monotonic() + 10
        while True:
            try:
                with urllib.request.urlopen(url + "/healthz", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)
        yield url
    finally:
        proc.terminate()
        try:
            rc = proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
        assert rc == 0, "".join(err)


def require_chromium() -> None:
    """Skip the calling test module without Chromium; fail it when
    ``SERVOWATCH_REQUIRE_CHROMIUM=1`` (CI)."""
    import pytest

    if find_chromium() is None:
        if os.environ.get("SERVOWATCH_REQUIRE_CHROMIUM") == "1":
            raise RuntimeError("Chromium required (SERVOWATCH_REQUIRE_CHROMIUM=1) but not found")
        pytest.skip("no Chromium (install Debian's chromium)", allow_module_level=True)


class Node:
    def __init__(self, tag: str, attrs: dict[str, str | None], parent: Node | None) -> None:
        self.tag, self.attrs, self.parent = tag, attrs, parent
        self.children: list[Node] = []
        self.text_parts: list[str] = []

    def text(self) -> str:
        return "".join(self.text_parts) + "".join(c.text() for c in self.children)

    def iter(self):
        yield self
        for c in self.children:
            yield from c.iter()

    def find_all(self, tag: str, **attrs: str) -> list[Node]:
        def ok(n: Node) -> bool:
            if n.tag != tag:
                return False
            for k, v in attrs.items():
                have = n.attrs.get(k.rstrip("_"))
                if k.rstrip("_") == "class":
                    if v not in (have or "").split():
                        return False
                elif have != v:
                    return False
            return True

        return [n for n in self.iter() if ok(n)]

    def find(self, tag: str, **attrs: str) -> Node:
        found = self.find_all(tag, **attrs)
        assert found, f"no <{tag} {attrs}>"
        return found[0]


_VOID = {"meta", "link", "input", "br", "img", "hr"}


class _Tree(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.root = Node("#root", {}, None)
        self.cur = self.root

    def handle_starttag(self, tag, attrs):
        n = Node(tag, dict(attrs), self.cur)
        self.cur.children.append(n)
        if tag not in _VOID:
            self.cur = n

    def handle_startendtag(self, tag, attrs):
        self.cur.children.append(Node(tag, dict(attrs), self.cur))

    def handle_endtag(self, tag):
        n = self.cur
        while n is not None and n.tag != tag:
            n = n.parent
        if n is not None and n.parent is not None:
            self.cur = n.parent

    def handle_data(self, data):
        self.cur.text_parts.append(data)


def render(url: str) -> Node:
    t = _Tree()
    t.feed(dump_dom(url))
    return t.root
