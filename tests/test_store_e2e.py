"""The daemon's health store through real Zenoh on loopback, every piece in its own process:
kill -9 mid-stream leaves a consistent store with whole periods only; SIGTERM flushes the
open period."""

from __future__ import annotations

import math
import os
import signal
import time

import pytest

from service.store import open_store
from tests.test_service_e2e import AC, ACT, RATE, Net

pytestmark = pytest.mark.slow

zenoh = pytest.importorskip("zenoh")

NAME = f"{AC}/{ACT}"


def _start(net: Net, tmp_path, store, window_s: float, **kw):
    cfg = tmp_path / "servowatch.toml"
    cfg.write_text(f"[prognostics]\nperiod_window_s = {window_s}\n")
    d = net.start("run", "--config", str(cfg), "--log", str(tmp_path / "d.mcap"),
                  "--no-rotate", "--store", str(store), "--json", **kw)  # fmt: skip
    net.wait(lambda st: True, what="the daemon's status queryable")
    return d


def _act(st: dict) -> dict:
    return st["actuators"].get(f"fleet/{AC}/{ACT}/meas") or {}


def _whole(p) -> bool:
    fin = [p.start_t, p.end_t, p.op_time_s]
    return all(math.isfinite(v) for v in fin) and p.end_t >= p.start_t and p.samples > 0


def test_kill_9_mid_stream_leaves_a_consistent_store(net, tmp_path):
    store = tmp_path / "health.sqlite"
    d = _start(net, tmp_path, store, window_s=0.5, start_new_session=True)
    net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "30")
    st = net.wait(lambda st: _act(st).get("periods", 0) >= 4, what="4 periods stored")
    assert _act(st)["commissioned"] is False and _act(st)["baseline_version"] is None
    os.killpg(d.pid, signal.SIGKILL)  # the daemon and its log process, mid-stream
    d.wait(10)
    with open_store(store, create=False) as s:
        assert s.check() == []
        ps = s.periods(NAME)
        assert len(ps) >= 4 and all(_whole(p) for p in ps)
        # 0.5 s windows at RATE Hz: every stored period is complete, none half-written
        assert all(p.samples <= 0.5 * RATE + 1 for p in ps)
        assert len({p.start_t for p in ps}) == len(ps)


def test_sigterm_flushes_the_open_period(net, tmp_path):
    store = tmp_path / "health.sqlite"
    d = _start(net, tmp_path, store, window_s=600.0)
    net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "30")
    st = net.wait(lambda st: _act(st).get("samples", 0) > 2 * RATE, what="2 s of data")
    assert _act(st)["periods"] == 0  # the 600 s window is still open
    d.send_signal(signal.SIGTERM)
    d.wait(30)
    time.sleep(0.1)
    with open_store(store, create=False) as s:
        assert s.check() == []
        ps = s.periods(NAME)
        assert (
            len(ps) == 1
            and ps[0].samples >= 2 * RATE
            and ps[0].source.startswith("live:ground1/0@")
        )
