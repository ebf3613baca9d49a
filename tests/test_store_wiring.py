"""The health store in the daemon and the replay: per-actuator baselines (MonitorFleet),
commissioning flags, operating periods written idempotently, SIGTERM flush."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from models.scenario import Profile
from service.config import PrognosticsSettings, ServiceConfig
from service.daemon import Daemon
from service.log import McapLogger
from service.monitor import MonitorBank, MonitorFleet
from service.monitor.calibration import calibrate, measured_run
from service.replay import replay
from service.replay.fleetsim import C_LK_NOMINAL
from service.sim.scenarios import load_scenario
from service.store import open_store
from service.wire.messages import mcap_topic

CH = ("x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr")
ODD = "AC1/odd"  # the off-nominal unit
# the off-nominal unit: 30 % heavier, more friction, 20 % wider underlap, softer oil
OFF_NOMINAL = {"mass": 130.0, "c_v": 2600.0, "f_s": 700.0, "f_d": 560.0, "u1": 1.2e-4,
               "u2": 1.2e-4, "u3": 1.2e-4, "u4": 1.2e-4, "beta_l": 1.1e9}  # fmt: skip


def _run(leak_ratio: float, seed: int, duration_s: float = 5.0) -> dict:
    base = load_scenario("healthy_noise")
    sc = base.model_copy(
        update={
            "duration_s": duration_s,
            "params": dict(OFF_NOMINAL),
            "leak": Profile(initial=leak_ratio * C_LK_NOMINAL),
            "sensors": base.sensors.model_copy(update={"seed": seed}),
        }
    )
    return measured_run(sc)[1]


def _write_log(path: Path, runs: dict[str, dict]) -> Path:
    with McapLogger(path, background_flush=False) as lg:
        for name, meas in runs.items():
            ac, act = name.split("/")
            vals = np.column_stack([meas[c] if c in meas else np.full(len(meas["t"]), np.nan)
                                    for c in ("t", *CH)])  # fmt: skip
            lg.log_block(mcap_topic(ac, act, "meas"), meas["t"], ("t", *CH), vals)
    return path


@pytest.fixture(scope="module")
def odd(tmp_path_factory):
    """The off-nominal unit: its healthy run calibrated into a store, a 3.5x leak run logged
    for it and for an uncommissioned twin."""
    d = tmp_path_factory.mktemp("odd")
    healthy = _run(1.0, seed=11)
    leak = _run(3.5, seed=12)
    base = calibrate(healthy)
    store = str(d / "health.sqlite")
    with open_store(store) as s:
        s.add_baseline(ODD, base.model_dump(), "test: healthy run")
    log = _write_log(d / "leak.mcap", {ODD: leak, "AC1/twin": leak})
    return {"store": store, "log": log, "base": base, "dir": d}


def test_fleet_of_one_baseline_is_the_bank_bit_for_bit():
    meas = measured_run(load_scenario("healthy_noise").model_copy(update={"duration_s": 1.0}))[1]
    n = len(meas["t"])
    ch = np.column_stack([meas.get(c, np.full(n, np.nan)) for c in CH])
    bank, fleet = MonitorBank(), MonitorFleet()
    outs = []
    for b in (bank, fleet):
        k0, k1 = b.index_of("a"), b.index_of("b")
        ks = np.tile([k0, k1], n)
        t = np.repeat(meas["t"], 2)
        c2 = np.repeat(ch, 2, axis=0)
        outs.append([b.update_arrays(ks[a : a + 700], t[a : a + 700], c2[a : a + 700])
                     for a in range(0, 2 * n, 700)])  # fmt: skip
    for r0, r1 in zip(*outs, strict=True):
        for f in ("index", "t", "est", "res", "health"):
            assert np.array_equal(getattr(r0, f), getattr(r1, f))
        assert r0.events == r1.events
    assert fleet.bank.baseline_of("a") == fleet.baseline


def test_two_baselines_in_one_bank_equal_separate_banks(odd):
    """Actuators on different baselines in one bank (one batched update): each gets the
    numbers of a bank of its own baseline, bit for bit."""
    base = odd["base"]
    fleet = MonitorFleet(resolve=lambda k: (base, 1) if k == "own" else (fleet.baseline, None))
    meas = _run(1.0, seed=5, duration_s=0.6)
    n = len(meas["t"])
    ch = np.column_stack([meas.get(c, np.full(n, np.nan)) for c in CH])
    ks = np.tile([fleet.index_of("own"), fleet.index_of("dflt")], n)
    rows = fleet.update_arrays(ks, np.repeat(meas["t"], 2), np.repeat(ch, 2, axis=0))
    assert fleet.commissioned("own") and not fleet.commissioned("dflt")
    assert fleet.bank.baseline_of("own") == base
    for key, b in (("own", base), ("dflt", None)):
        rb = MonitorBank(baseline=b)
        ref = rb.update_arrays(np.full(n, rb.index_of(key)), meas["t"], ch)
        sel = ks[rows.index] == fleet.ids[key]
        for f in ("t", "est", "res", "health"):
            assert np.array_equal(getattr(rows, f)[sel], getattr(ref, f))


def test_own_baseline_reads_the_leak_the_default_misreads_and_periods_are_idempotent(odd):
    s1 = replay(odd["log"], store=odd["store"])
    assert s1.commissioned == {ODD: 1, "AC1/twin": None}
    assert s1.periods == 2 and s1.periods_new == 2
    assert s1.source is not None and s1.source.startswith("log:")  # its content, not its name
    assert s1.sources[ODD] != s1.sources["AC1/twin"]  # the same samples of two units
    with open_store(odd["store"]) as s:
        own = s.periods(ODD)[0].c_lk_ratio
        dflt = s.periods("AC1/twin")[0].c_lk_ratio
        assert s.check() == []
    assert abs(own / 3.5 - 1) < 0.1, own  # own baseline: the 3.5x leak within 10 %
    assert abs(dflt / 3.5 - 1) > 0.5, dflt  # default baseline: misread by more than half
    # the same log again, also from another path: nothing new
    copy = odd["dir"] / "sub" / "leak.mcap"
    copy.parent.mkdir(exist_ok=True)
    copy.write_bytes(Path(odd["log"]).read_bytes())
    for path in (odd["log"], copy):
        s2 = replay(path, store=odd["store"])
        assert s2.periods == 2 and s2.periods_new == 0
    with open_store(odd["store"]) as s:
        assert s.count_periods() == 2 and s.check() == []


class _Pub:
    def __init__(self, key: str, sink: list, encoding: str) -> None:
        self.key, self.sink, self.encoding = key, sink, encoding

    def put(self, payload: bytes) -> None:
        from service.wire.messages import decode_output

        self.sink.append((self.key, decode_output(self.key.rsplit("/", 1)[1], payload)))

    def undeclare(self) -> None:
        pass


class _Session:
    def __init__(self) -> None:
        self.puts: list = []

    def declare_publisher(self, key: str, *, encoding: str) -> _Pub:
        return _Pub(key, self.puts, encoding)


def _payloads(meas: dict, n0: int, n1: int, per: int = 50) -> list[bytes]:
    from service.wire.messages import encode_meas

    out = []
    for a in range(n0, n1, per):
        rows = [{"seq": j, "t": float(meas["t"][j]), **{c: float(meas[c][j]) for c in CH
                 if c in meas}} for j in range(a, min(a + per, n1))]  # fmt: skip
        out.append(encode_meas(rows))
    return out


def test_daemon_commissioned_flags_periods_and_flush_on_stop(odd, tmp_path):
    store = tmp_path / "d.sqlite"
    with open_store(store) as s:
        s.add_baseline(ODD, odd["base"].model_dump(), "test")
    cfg = ServiceConfig(
        store=str(store), publish_every=100,
        prognostics=PrognosticsSettings(period_window_s=1.0),
    )  # fmt: skip
    d = Daemon(cfg, log_path=tmp_path / "d.mcap", log_process=False, gather_s=0)
    sess = _Session()
    d.outputs.fanout.session = sess
    meas = _run(1.0, seed=13, duration_s=2.5)
    n = len(meas["t"])
    for key in ("fleet/AC1/odd/meas", "fleet/AC1/twin/meas"):
        for p in _payloads(meas, 0, n):
            d.submit(key, p)
    while d.queued:
        d.process_pending()
    st = d.status()["actuators"]
    assert st["fleet/AC1/odd/meas"]["commissioned"] is True
    assert st["fleet/AC1/odd/meas"]["baseline_version"] == 1
    assert st["fleet/AC1/twin/meas"]["commissioned"] is False
    assert st["fleet/AC1/twin/meas"]["baseline_version"] is None
    health = {k: v for k, v in sess.puts if k.endswith("/health")}
    assert health["fleet/AC1/odd/health"]["commissioned"] is True
    assert health["fleet/AC1/odd/health"]["baseline_version"] == 1
    assert health["fleet/AC1/twin/health"]["commissioned"] is False
    final = d.stop()  # flushes the open periods (2.5 s of data, 1 s windows: 3 each)
    with open_store(store) as s:
        assert s.count_periods(ODD) == 3 and s.count_periods("AC1/twin") == 3
        assert sum(p.samples for p in s.periods(ODD)) == n
        assert s.check() == []
        (src,) = {p.source for p in s.periods(ODD)}  # the id of the log written beside
        assert src.startswith("live:ground1/0@") and len(src) == len("live:ground1/0@") + 16
    assert final["actuators"]["fleet/AC1/odd/meas"]["periods"] == 3
    assert final["store"]["written"] == 6 and final["store"]["failure"] is None
    from service.cli.commands.status import format_status

    text = format_status({"monitor/ground1/0/status": final})
    assert "AC1/odd" in text and "baseline v1" in text and "3 periods, RUL -" in text
    assert "NOT COMMISSIONED" in text and "RUL - h" not in text


def test_auto_commissioning_from_healthy_looking_data(tmp_path):
    """A nominal unit is commissioned from its first 2 s; the off-nominal one, whose default
    baseline raises leak alarms, is not (each alarm restarts its collection)."""
    store = tmp_path / "a.sqlite"
    cfg = ServiceConfig(
        store=str(store),
        prognostics=PrognosticsSettings(auto_commission_s=2.0, period_window_s=1.0),
    )
    d = Daemon(cfg, log_path=tmp_path / "a.mcap", log_process=False, gather_s=0)
    runs = {
        "fleet/AC1/new/meas": measured_run(load_scenario("healthy_noise"))[1],
        "fleet/AC1/odd/meas": _run(1.0, seed=14, duration_s=4.0),
    }
    pays = {k: _payloads(v, 0, len(v["t"])) for k, v in runs.items()}
    half = {k: len(v) * 3 // 4 for k, v in pays.items()}
    for k, v in pays.items():
        for p in v[: half[k]]:
            d.submit(k, p)
    while d.queued:
        d.process_pending()
    for _ in range(600):  # the calibration runs in a background thread
        if d.monitor.commissioner._ready:
            break
        time.sleep(0.05)
    for k, v in pays.items():
        for p in v[half[k] :]:
            d.submit(k, p)
    while d.queued:
        d.process_pending()
    st = d.status()["actuators"]
    assert st["fleet/AC1/new/meas"]["commissioned"] is True
    assert st["fleet/AC1/new/meas"]["baseline_version"] == 1
    assert st["fleet/AC1/odd/meas"]["commissioned"] is False
    assert d.monitor.commissioner.rejected.get("fleet/AC1/odd/meas", 0) > 0
    d.stop()
    with open_store(store) as s:
        rec = s.latest_baseline("AC1/new")
        assert rec.source == "auto-commissioning" and rec.figures["duration_s"] >= 2.0
        assert s.latest_baseline("AC1/odd") is None
        ratios = [p.c_lk_ratio for p in s.periods("AC1/new") if np.isfinite(p.c_lk_ratio)]
        # the last period is judged against the unit's own baseline: a healthy ratio
        assert abs(ratios[-1] - 1.0) < 0.3, ratios
        assert s.check() == []
