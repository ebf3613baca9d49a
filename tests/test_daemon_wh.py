"""The daemon on the WH process model (``[monitor] model = "WH"`` in its TOML): the status
names the model, and ``servowatch run --config`` on real Zenoh (loopback) estimates with it."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from service.config import ServiceConfig, load_config
from service.daemon import Daemon
from service.monitor import Baseline, MonitorBank, MonitorConfig
from service.wire import messages as m

AC, ACT = "ACWH1", "aileron_R"
KEY = f"fleet/{AC}/{ACT}/meas"


class NullLogger:
    """The daemon's logger interface, keeping nothing."""

    paths: list = []
    failure = None

    def log(self, topic, t, msg):
        pass

    def log_block(self, topic, t, names, values, *, int_fields=()):
        pass

    def commit(self):
        pass

    def close(self):
        pass


@pytest.fixture(scope="module")
def healthy():
    """3 s of the healthy HF bench with its sensor noise at 1 kHz, as meas samples."""
    from service.monitor.calibration import measured_run
    from service.sim.scenarios import load_scenario

    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 3.0})
    _, meas = measured_run(sc)
    n = len(meas["t"])
    samples = [
        {"seq": k, "t": 1000.0 + float(meas["t"][k])}
        | {c: float(meas[c][k]) for c in m.CHANNELS if c in meas}
        for k in range(n)
    ]
    return samples


def _reference(samples: list[dict], model: str) -> np.ndarray:
    """C_Lk of a MonitorBank on ``model`` fed the same samples (one per output)."""
    from service.monitor import EST_KEYS

    bank = MonitorBank(MonitorConfig(model=model))
    ch = np.array([[s.get(c, np.nan) for c in m.CHANNELS] for s in samples], float)
    t = np.array([s["t"] for s in samples])
    rows = bank.update_arrays(np.full(len(t), bank.index_of(KEY)), t, ch)
    return rows.t, rows.est[:, EST_KEYS.index("c_lk")]


@pytest.mark.parametrize("model", ["C5", "WH"])
def test_status_names_the_monitor_model(tmp_path, model):
    p = tmp_path / "svc.toml"
    p.write_text(f'store = "off"\n[monitor]\nmodel = "{model}"\n')
    cfg = load_config(p, environ={})
    d = Daemon(cfg, logger=NullLogger())
    assert d.monitor.bank.config.model == model
    assert d.monitor.bank.baseline == Baseline.default(model)
    assert d.status()["model"] == model
    d.stop()


def test_status_names_the_model_the_default_config_runs():
    d = Daemon(ServiceConfig(), logger=NullLogger())
    assert d.status()["model"] == d.monitor.bank.config.model == d.monitor.bank.baseline.law
    d.stop()


@pytest.mark.slow
def test_run_from_toml_on_the_wh_model_over_zenoh(tmp_path, healthy):
    """``servowatch run --config`` with ``model = "WH"``: 3 s of a simulated healthy actuator
    published over loopback Zenoh; the final status names WH, and the logged C_Lk is finite,
    within 10 % of the WH baseline's over the last second and the WH monitor's own (not the
    C5 one's) to 1e-9."""
    zenoh = pytest.importorskip("zenoh")
    from service.cli.commands.status import format_status
    from service.log import read_log
    from service.zenoh_util import free_port, loopback, make_config

    ep = loopback(free_port())
    cfg = tmp_path / "svc.toml"
    cfg.write_text(
        f'store = "off"\nstation = "whst"\n[zenoh]\nmode = "client"\nconnect = ["{ep}"]\n'
        '[monitor]\nmodel = "WH"\n'
    )
    log = tmp_path / "wh.mcap"
    router = zenoh.open(make_config("router", [ep]))
    session = zenoh.open(make_config("client", connect=[ep]))
    d = subprocess.Popen(
        [sys.executable, "-m", "service.cli", "run", "--config", str(cfg), "--log", str(log),
         "--no-rotate", "--json", "--plain-logs"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
    )  # fmt: skip

    def status() -> dict | None:
        for reply in session.get("monitor/whst/*/status", timeout=1.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def wait(pred, what: str, timeout: float = 60.0) -> dict:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            st = status()
            if st is not None and pred(st):
                return st
            time.sleep(0.1)
        raise AssertionError(f"timed out waiting for {what}; last status {status()}")

    try:
        st = wait(lambda st: True, "the daemon's status queryable")
        assert st["model"] == "WH"
        # BLOCK, as the virtual actuator publishes: the default (drop) lets a burst of puts
        # overflow the transmit queue on a loaded machine (600 of 3000 samples once)
        pub = session.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
        for j in range(0, len(healthy), 100):
            pub.put(m.encode_meas(healthy[j : j + 100]))
            time.sleep(0.002)
        n = len(healthy)
        st = wait(
            lambda st: st["actuators"].get(KEY, {}).get("samples") == n and st["queue"] == 0,
            f"{n} samples processed",
        )
        d.send_signal(signal.SIGTERM)
        out, err = d.communicate(timeout=60)
    finally:
        if d.poll() is None:
            d.kill()
            d.communicate(timeout=10)
        session.close()
        router.close()
    assert d.returncode == 0, err[-2000:]
    final = json.loads(out)
    assert final["model"] == "WH" and "model WH" in format_status({"k": final})
    a = final["actuators"][KEY]
    assert (a["samples"], a["bad_total"], a["gaps"], final["dropped"]) == (n, 0, 0, 0)
    assert a["monitor"]["reinit"] == 0
    assert a["monitor"]["c_lk_changes"] == 0  # a healthy run: the change detector is quiet
    est = [r for r in read_log(log) if r[0] == f"/{KEY[:-5]}/est"]
    t = np.array([r[1] for r in est])
    c = np.array([r[2]["c_lk"] for r in est])
    assert len(est) == a["outputs"] > 0.9 * n and np.all(np.isfinite(c))
    c0 = Baseline.default("WH").c_lk
    late = t >= t[-1] - 1.0
    assert float(np.mean(c[late])) == pytest.approx(c0, rel=0.10)
    t_ref, c_wh = _reference(healthy, "WH")
    np.testing.assert_allclose(t, t_ref)
    np.testing.assert_allclose(c, c_wh, rtol=1e-9, atol=0.0)
    _, c_c5 = _reference(healthy, "C5")
    assert np.max(np.abs(c - c_c5)) > 1e-3 * c0  # the C5 filter reads otherwise
    assert math.isfinite(a["est"]["c_lk"]) and a["est"]["c_lk"] == pytest.approx(c[-1])
