"""Monitoring daemon logic without Zenoh: validation, counters, ordering, logging, status."""

from __future__ import annotations

import json
import logging
import math
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from service.config import ServiceConfig
from service.daemon import Daemon, RateLimitedLog, percentiles, sd_notify, watchdog_interval
from service.log import McapLogger
from service.monitor import AlarmEvent, MonitorBank, RowEvents
from service.wire import messages as m

ROOT = Path(__file__).resolve().parents[1]

KEY = "fleet/AC001/elevator_L/meas"
KEY2 = "fleet/AC002/rudder/meas"


class SpyBank(MonitorBank):
    """The real MonitorBank; records the samples fed to it and adds a 'leak' alarm event to
    the output row of a sample whose p1 rises above 1e7 (raised) or falls back (cleared), so
    the daemon's event path runs with known events."""

    def __init__(self):
        super().__init__()
        self.fed: dict[int, list[float]] = {}
        self.on: dict[int, bool] = {}

    def seen(self, key: str) -> list[float]:
        return self.fed.get(self.index_of(key), [])

    def update_arrays(self, ks, t, channels):
        for k, tk in zip(ks.tolist(), t.tolist(), strict=True):
            self.fed.setdefault(k, []).append(tk)
        rows = super().update_arrays(ks, t, channels)
        at = {r: list(rows.events[r]) for r in rows.events.rows()}
        p1 = channels[:, m.CHANNELS.index("p1")]
        for r, i in enumerate(rows.index.tolist()):
            k, high = int(ks[i]), bool(p1[i] > 1e7)
            if high != self.on.get(k, False):
                self.on[k] = high
                state = "raised" if high else "cleared"
                at.setdefault(r, []).append(AlarmEvent(float(t[i]), "leak", state, float(p1[i])))
        rows.events = RowEvents(len(rows.t), at)
        return rows


class BlockLogger:
    """The daemon's logger interface (log_block, log, commit, close, paths, failure), keeping
    every message as (topic, t, dict)."""

    def __init__(self):
        self.rows: list[tuple[str, float, dict]] = []
        self.closed = False
        self.paths = []
        self.failure = None
        self.commits = 0

    def log(self, topic, t, msg):
        assert math.isfinite(t)
        self.rows.append((topic, t, dict(msg)))

    def log_block(self, topic, t, names, values, *, int_fields=()):
        assert values.shape == (len(t), len(names))
        for tk, row in zip(np.asarray(t).tolist(), np.asarray(values).tolist(), strict=True):
            d = {k: (int(v) if k in int_fields else v) for k, v in zip(names, row, strict=True)}
            self.log(topic, tk, d)

    def commit(self):
        self.commits += 1

    def close(self):
        self.closed = True

    def topic(self, suffix):
        return [r for r in self.rows if r[0].endswith(suffix)]


def sample(seq, t=None, **kw):
    d = {
        "seq": seq,
        "t": 1000.0 + seq * 1e-3 if t is None else t,
        "x_cmd": 0.0,
        "i": 0.0,
        "x_s": 0.0,
        "x_j": seq * 1e-6,
        "p1": 5e6,
        "p2": 5e6,
        "p_sr": 20e6,
    }
    d.update(kw)
    return d


def make(**cfg):
    bank = SpyBank()
    lg = BlockLogger()
    d = Daemon(ServiceConfig(**cfg), logger=lg, bank=bank)
    return d, lg, bank


def test_good_samples_are_all_logged_and_fed_in_order():
    d, lg, bank = make()
    for j in range(0, 100, 10):
        assert d.submit(KEY, m.encode_meas([sample(k) for k in range(j, j + 10)]))
    d.submit(KEY2, m.encode_meas([sample(k) for k in range(5)], fmt="json"))
    assert d.process_pending() == 105
    assert bank.seen(KEY) == [1000.0 + k * 1e-3 for k in range(100)]
    meas = lg.topic("/AC001/elevator_L/meas")
    assert [r[2]["seq"] for r in meas] == list(range(100))
    assert set(meas[0][2]) == {"t", "seq", "x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr"}
    assert meas[7][1] == meas[7][2]["t"]  # log time = sample time
    st = d.status()
    a, b = st["actuators"][KEY], st["actuators"][KEY2]
    assert a["outputs"] == a["monitor"]["accepted"] == 100  # every sample gives an output
    assert len(lg.topic("/AC001/elevator_L/est")) == 100
    assert len(lg.topic("/AC001/elevator_L/health")) == 100
    assert len(lg.topic("/AC002/rudder/residual")) == b["outputs"] == 5
    assert (a["samples"], a["messages"], a["gaps"], a["bad_total"]) == (100, 10, 0, 0)
    assert st["samples"] == 105 and st["dropped"] == 0
    assert st["state"] == "ok" and st["log_failure"] is None
    assert lg.commits == 1
    json.dumps(st)  # JSON-ready


def test_bad_messages_are_counted_and_good_ones_kept():
    d, lg, bank = make()
    d.submit(KEY, m.encode_meas([sample(0), sample(1)]))
    d.submit(KEY, b"\x00garbage")
    d.submit(KEY, b'{"samples": [{"seq": 2, "t": 1000.002, "p1": NaN}]}')
    d.submit(KEY, b'{"seq": 2, "t": 1000.002, "p1": "high"}')
    d.submit(KEY, b'{"seq": 2, "t": 1000.002, "bogus": 1}')
    d.submit(KEY, b"{" + b" " * 70000 + b"}")
    nan_bin = bytearray(m.encode_meas([sample(2)]))
    nan_bin[-8:] = b"\x00\x00\x00\x00\x00\x00\xf8\x7f"  # p_sr = NaN in the binary form
    d.submit(KEY, bytes(nan_bin))
    d.submit(KEY, m.encode_meas([sample(2), sample(3)]))
    d.submit("fleet/AC001/bad key/meas", m.encode_meas([sample(0)]))
    d.submit("fleet/AC001/elevator_L/est", m.encode_meas([sample(0)]))
    d.submit(KEY2, b"\x00garbage only")  # an actuator that never reaches the monitor
    d.process_pending()
    assert d.status()["actuators"][KEY2]["monitor"] is None
    a = d.status()["actuators"][KEY]
    assert a["samples"] == 4
    assert bank.seen(KEY) == [1000.0, 1000.001, 1000.002, 1000.003]
    assert a["bad"] == {"malformed": 1, "non_finite": 2, "schema": 2, "oversize": 1}
    assert d.status()["unknown"] == {"invalid_key": 2}
    assert len(lg.topic("/meas")) == 4


def test_duplicates_out_of_order_gaps_and_restart():
    d, lg, bank = make()
    d.submit(KEY, m.encode_meas([sample(k) for k in range(10)]))
    d.submit(KEY, m.encode_meas([sample(k) for k in range(5, 10)]))  # duplicates
    d.submit(KEY, m.encode_meas([sample(9)]))  # exact repeat of the last
    d.submit(KEY, m.encode_meas([sample(k) for k in range(15, 20)]))  # gap of 5
    d.submit(KEY, m.encode_meas([sample(12)]))  # late: out of order
    # publisher restart: seq back to 0, time moves on
    d.submit(KEY, m.encode_meas([sample(k, t=2000.0 + k * 1e-3) for k in range(3)]))
    d.process_pending()
    a = d.status()["actuators"][KEY]
    assert a["samples"] == 18
    assert a["gaps"] == 5
    assert a["bad"] == {"out_of_order": 5, "duplicate": 2}  # seq 9 twice, 5-8 and 12 late
    assert a["restarts"] == 1
    ts = bank.seen(KEY)
    assert ts == sorted(ts) and len(set(ts)) == 18
    assert any(r[2]["kind"] == "restart" for r in lg.topic("/service"))


def test_full_queue_drops_are_counted_per_actuator():
    d, lg, bank = make(queue_size=3)
    ok = [d.submit(KEY, m.encode_meas([sample(k)])) for k in range(5)]
    assert ok == [True, True, True, False, False]
    d.process_pending()
    a = d.status()["actuators"][KEY]
    assert (a["dropped"], a["samples"], a["gaps"]) == (2, 3, 0)
    assert d.status()["dropped"] == 2


def test_alarm_events_are_logged_and_listed_while_active():
    d, lg, bank = make()
    d.submit(KEY, m.encode_meas([sample(0), sample(1, p1=2e7), sample(2, p1=2e7)]))
    d.process_pending()
    st = d.status()
    assert [(x["kind"], x["state"]) for x in st["alarms"]] == [("leak", "raised")]
    assert st["alarms"][0]["actuator"] == "AC001/elevator_L"
    d.submit(KEY, m.encode_meas([sample(3)]))
    d.process_pending()  # the real filter also re-initialises after the p1 jump: not a leak
    assert [x for x in d.status()["alarms"] if x["kind"] == "leak"] == []
    ev = [r for r in lg.topic("/AC001/elevator_L/events") if r[2]["kind"] == "leak"]
    assert [(r[2]["state"], r[1]) for r in ev] == [("raised", 1000.001), ("cleared", 1000.003)]
    ts = [r[1] for r in lg.topic("/AC001/elevator_L/est")]
    assert ts == [1000.0, 1000.001, 1000.002, 1000.003]  # the event rows among them


def test_silence_detection_and_resume():
    d, lg, bank = make(silence_s=2.0)
    d.submit(KEY, m.encode_meas([sample(0)]), t_recv=100.0)
    d.submit(KEY2, m.encode_meas([sample(0)]), t_recv=101.5)
    d.process_pending()
    assert d.check_silence(now=101.9) == []
    assert d.check_silence(now=102.1) == ["AC001/elevator_L"]
    assert d.check_silence(now=102.2) == []  # reported once
    assert d.status()["silent"] == ["AC001/elevator_L"]
    d.submit(KEY, m.encode_meas([sample(1)]), t_recv=102.5)
    d.process_pending()
    assert d.status()["silent"] == []
    kinds = [r[2]["kind"] for r in lg.topic("/AC001/elevator_L/service")]
    assert kinds == ["silent", "resumed"]


def test_monitor_exception_is_counted_not_fatal():
    d, lg, bank = make()
    d.submit(KEY, m.encode_meas([sample(0)]))
    d.process_pending()
    bank.update_arrays = lambda *a: 1 / 0
    d.submit(KEY, m.encode_meas([sample(1)]))
    d.process_pending()
    st = d.status()
    assert st["errors"] == 1 and st["actuators"][KEY]["samples"] == 2
    assert len(lg.topic("/meas")) == 2  # the sample itself is still logged


def test_stop_drains_the_queue_and_closes_the_log():
    d, lg, bank = make()
    d.start(None)
    for j in range(0, 1000, 10):
        d.submit(KEY, m.encode_meas([sample(k) for k in range(j, j + 10)]))
    final = d.stop()
    assert final["samples"] == 1000 and lg.closed
    assert len(lg.topic("/meas")) == 1000
    assert len(bank.seen(KEY)) == 1000
    assert d.stop()["samples"] == 1000  # idempotent


def test_real_monitor_and_mcap_log_round_trip(tmp_path):
    """The default path: MonitorBank + McapLogger; the log holds every sample and output."""
    from service.log import read_log

    cfg = ServiceConfig(rotate_bytes=None, rotate_s=None)
    path = tmp_path / "d.mcap"
    d = Daemon(cfg, log_path=path)
    for j in range(0, 60, 20):
        d.submit(
            KEY, m.encode_meas([sample(k, x_j=1e-3, p1=12e6, p2=8e6) for k in range(j, j + 20)])
        )
    d.process_pending()
    final = d.stop()
    rows = list(read_log(path))
    meas = [r for r in rows if r[0] == "/fleet/AC001/elevator_L/meas"]
    est = [r for r in rows if r[0] == "/fleet/AC001/elevator_L/est"]
    assert [r[2]["seq"] for r in meas] == list(range(60))
    assert len(est) == final["actuators"][KEY]["outputs"] > 0
    assert final["actuators"][KEY]["monitor"]["accepted"] == 60


# --------------------------------------------------------------------------- helpers


def test_percentiles_nearest_rank():
    assert percentiles([]) == [None, None]
    v = list(range(1, 101))  # 1..100
    assert percentiles(v, (50, 99, 100)) == [50, 99, 100]
    assert percentiles([3.0], (50, 99)) == [3.0, 3.0]


def test_rate_limited_log_suppresses_and_reports(caplog):
    rl = RateLimitedLog(logging.getLogger("t"), interval_s=3600)
    with caplog.at_level(logging.WARNING):
        assert rl.warning("a", "first %d", 1)
        assert not rl.warning("a", "second")
        assert not rl.warning("a", "third")
        assert rl.warning("b", "other key")
    assert [r.getMessage() for r in caplog.records] == ["first 1", "other key"]
    rl._last["a"] -= 7200
    with caplog.at_level(logging.WARNING):
        rl.warning("a", "later")
    assert caplog.records[-1].getMessage() == "later (2 similar suppressed)"


def test_sd_notify_sends_a_datagram(tmp_path):
    path = str(tmp_path / "notify")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as srv:
        srv.bind(path)
        assert sd_notify("READY=1", {"NOTIFY_SOCKET": path})
        assert srv.recv(64) == b"READY=1"
    assert not sd_notify("READY=1", {})
    # abstract namespace: '@' stands for the leading NUL byte
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as srv:
        srv.bind("\0servowatch-test-notify")
        assert sd_notify("WATCHDOG=1", {"NOTIFY_SOCKET": "@servowatch-test-notify"})
        assert srv.recv(64) == b"WATCHDOG=1"


def test_watchdog_interval_is_half_the_systemd_period():
    assert watchdog_interval({"WATCHDOG_USEC": "4000000"}) == pytest.approx(2.0)
    assert watchdog_interval({}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "1"}) is None


def test_decimated_logging_keeps_counting_and_status_shows_the_latest_output(tmp_path):
    """log_every=7, publish_every=5: every sample is logged and processed, est/residual/health
    for 1 output in 7 (and at events); the status holds the last output, equal to a Monitor
    fed the same samples one by one."""
    from service.log import read_log
    from service.monitor import Monitor

    cfg = ServiceConfig(rotate_bytes=None, rotate_s=None, publish_every=5, log_every=7)
    path = tmp_path / "dec.mcap"
    d = Daemon(cfg, log_path=path)
    samples = [sample(k, x_j=1e-3, p1=12e6, p2=8e6) for k in range(53)]
    for j in range(0, 53, 10):
        d.submit(KEY, m.encode_meas(samples[j : j + 10]))
    d.process_pending()
    final = d.stop()
    a = final["actuators"][KEY]
    mon = Monitor()
    outs = [mon.update({k: s[k] for k in ("t", *m.CHANNELS)}) for s in samples]
    outs = [o for o in outs if o is not None]
    assert a["outputs"] == len(outs)
    assert a["est"] == outs[-1].est and a["health"] == outs[-1].health
    rows = list(read_log(path))
    topics = [r[0].rsplit("/", 1)[1] for r in rows]
    n_ev = topics.count("events")
    assert topics.count("meas") == 53
    assert len(outs) // 7 <= topics.count("est") <= len(outs) // 7 + n_ev
    assert topics.count("health") == topics.count("est")


def test_percentiles_match_numpy_nearest_rank_on_random_sets():
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 10, 101, 5000):
        v = rng.normal(size=n)
        s = np.sort(v)
        for q in (0, 1, 50, 99, 100):
            k = min(n - 1, max(0, int(np.ceil(q / 100 * n)) - 1))
            assert percentiles(v.tolist(), (q,)) == [s[k]]


# --------------------------------------------------------------------------- log failure


def test_a_logger_whose_stream_fails_keeps_the_failure_and_logs_it(caplog):
    """/dev/full accepts the open and fails every write with ENOSPC (a full disk)."""
    lg = McapLogger("/dev/full", background_flush=False)
    lg.log("/x", 1.0, {"a": 1.0})
    assert lg.failure is None
    with caplog.at_level(logging.ERROR, "servowatch.log"), pytest.raises(OSError):
        lg.flush()
    assert "No space left" in lg.failure and "/dev/full" in lg.failure
    assert any("No space left" in r.getMessage() for r in caplog.records)
    lg.log("/x", 2.0, {"a": 2.0})  # dropped and counted, not raised again
    lg.log_block("/x", np.array([3.0, 4.0]), ("a",), np.array([[3.0], [4.0]]))
    assert lg.dropped == 3
    first = lg.failure
    lg.close()
    assert lg.failure == first  # the first failure is the one kept


def _feed(d: Daemon, n: int = 40) -> None:
    for j in range(0, n, 10):
        d.submit(KEY, m.encode_meas([sample(k) for k in range(j, j + 10)]))
    d.process_pending()


def test_daemon_status_shows_a_failed_log_and_reports_degraded():
    lg = McapLogger("/dev/full", background_flush=False, flush_s=1e-6)
    d = Daemon(ServiceConfig(), logger=lg, bank=SpyBank())
    _feed(d)
    st = d.status()
    assert "No space left" in st["log_failure"] and st["state"] == "degraded"
    assert st["samples"] == 40 and st["actuators"][KEY]["outputs"] == 40  # monitoring goes on
    assert d.stop()["log_failure"] == st["log_failure"]


def test_daemon_status_shows_a_failure_in_the_log_process():
    from service.zenoh_util import wait_until

    cfg = ServiceConfig(rotate_bytes=None, rotate_s=None, flush_s=0.01)
    d = Daemon(cfg, log_path="/dev/full", bank=SpyBank())
    try:
        _feed(d)
        assert wait_until(lambda: (d.outputs.logger.commit(), d.status()["log_failure"])[1], 20)
        st = d.status()
        assert "No space left" in st["log_failure"] and st["state"] == "degraded"
    finally:
        final = d.stop()
    assert final["state"] == "degraded"


def test_daemon_log_and_its_replay_hold_the_same_outputs(tmp_path):
    """Live and replay share the fan-out: replaying the daemon's log (same log_every) writes
    the same est/residual/health rows, bit for bit, and the same events."""
    from service.log import read_blocks
    from service.replay import replay

    cfg = ServiceConfig(rotate_bytes=None, rotate_s=None, log_every=3, publish_every=5)
    live = tmp_path / "live.mcap"
    d = Daemon(cfg, log_path=live, log_process=False)
    for j in range(0, 300, 10):
        d.submit(
            KEY, m.encode_meas([sample(k, x_j=1e-3, p1=12e6, p2=8e6) for k in range(j, j + 10)])
        )
        d.submit(KEY2, m.encode_meas([sample(k, x_j=2e-3) for k in range(j, j + 10)]))
        if j % 50 == 0:
            d.process_pending()
    d.stop()
    out = tmp_path / "replay.mcap"
    s = replay(live, out=out, log_every=3)
    assert s.samples == 600

    def outputs(p):
        got: dict[str, list] = {}
        for b in read_blocks(p):
            if b.topic.rsplit("/", 1)[1] in ("est", "residual", "health", "events"):
                got.setdefault(b.topic, []).append(np.column_stack([b.t, b.values]))
        return {k: np.concatenate(v) for k, v in got.items()}

    a, b = outputs(live), outputs(out)
    assert sorted(a) == sorted(b) and len(a) >= 6
    for k in a:
        assert a[k].tobytes() == b[k].tobytes(), k
    n_out = d.status()["actuators"][KEY]["outputs"]
    assert len(a["/fleet/AC001/elevator_L/est"]) >= n_out // 3


def test_the_log_process_writes_what_the_in_process_log_writes(tmp_path):
    """The log process receives the accepted measurements as arrays (it decodes nothing):
    its file holds the same messages, byte for byte, as the in-process McapLogger's, for
    whole messages, partly accepted ones (duplicates cut off the start, a sample ahead of
    the stream the end), both payload formats and absent channels (NaN -> null)."""
    from mcap.reader import make_reader

    msgs = [
        m.encode_meas([sample(k, x_j=1e-3, p1=12e6, p2=8e6) for k in range(0, 10)]),
        m.encode_meas([sample(k) for k in range(5, 15)], fmt="json"),  # 5..9 duplicates
        m.encode_meas([sample(k) for k in range(15, 20)] + [sample(20, t=1e6)]),  # 20 ahead
        m.encode_meas([{k: v for k, v in sample(k).items() if k != "p_sr"} for k in range(21, 30)]),
    ]

    def run(process: bool) -> list[tuple]:
        path = tmp_path / f"p{int(process)}.mcap"
        cfg = ServiceConfig(rotate_bytes=None, rotate_s=None)
        d = Daemon(cfg, log_path=path, log_process=process)
        for p in msgs:
            d.submit(KEY, p)
        d.process_pending()
        st = d.stop()
        assert st["actuators"][KEY]["samples"] == 29
        with open(path, "rb") as f:
            r = make_reader(f)
            return [(c.topic, msg.log_time, msg.data) for _, c, msg in r.iter_messages()
                    if c.topic.endswith("/meas")]  # fmt: skip

    got, want = run(True), run(False)
    assert len(want) == 10 + 5 + 5 + 9
    assert got == want


def test_start_imports_what_the_first_period_needs(tmp_path):
    """The first period's NIS band imports scipy.stats (about a second under the GIL): the
    daemon's start does it, before any Zenoh entity exists, so a unit's first samples are
    not followed by a stall that reads as silence."""
    code = (
        "import sys\n"
        "from service.config import ServiceConfig\n"
        "from service.daemon import Daemon\n"
        f"d = Daemon(ServiceConfig(rotate_bytes=None, rotate_s=None), log_path={str(tmp_path / 'w.mcap')!r})\n"
        "assert 'scipy.stats' not in sys.modules\n"
        "d.start(None)\n"
        "print('scipy.stats' in sys.modules)\n"
        "d.stop()\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "True"
