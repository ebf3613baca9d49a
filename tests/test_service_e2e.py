"""End to end through real Zenoh on loopback, every piece in its own process.

A router runs in the test process; ``servowatch run`` (daemon), ``servowatch actuator`` and
``servowatch inject`` run as child processes, exactly as a user starts them.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import pytest

from service.cli.commands.inject import send_fault
from service.wire import messages as m
from service.zenoh_util import free_port, loopback, make_config

pytestmark = pytest.mark.slow

zenoh = pytest.importorskip("zenoh")

AC, ACT = "AC001", "elevator_L"
MEAS = f"/fleet/{AC}/{ACT}/meas"
EST = f"/fleet/{AC}/{ACT}/est"
RATE = 250  # Hz: light enough to leave CPU to the rest of the suite on a 2-core machine


def cli(*args: str, env: dict | None = None, **kw) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "service.cli", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, **(env or {})}, **kw,
    )  # fmt: skip


class Net:
    """A router in this process and a client session to query through it."""

    def __init__(self):
        self.ep = loopback(free_port())
        self.router = zenoh.open(make_config("router", [self.ep]))
        self.session = zenoh.open(make_config("client", connect=[self.ep]))
        self.procs: list[subprocess.Popen] = []

    def start(self, *args: str, env: dict | None = None, **kw) -> subprocess.Popen:
        p = cli(*args, "--connect", self.ep, env=env, **kw)
        self.procs.append(p)
        return p

    def status(self, timeout: float = 1.0) -> dict | None:
        for reply in self.session.get("monitor/*/*/status", timeout=timeout):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def wait(self, pred, timeout: float = 60.0, what: str = "condition") -> dict:
        # generous: a cold numba cache (fresh clone, edited kernels) compiles for a while
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            st = self.status()
            if st is not None and pred(st):
                return st
            time.sleep(0.2)
        raise AssertionError(f"timed out waiting for {what}; last status {self.status()}")

    def close(self):
        for p in self.procs:
            if p.poll() is None:
                p.kill()
                p.wait(5)
            if p.stdout is not None:
                p.stdout.close()
            if p.stderr is not None:
                p.stderr.close()
        self.session.close()
        self.router.close()


def act_samples(st: dict) -> int:
    a = st["actuators"].get(f"fleet/{AC}/{ACT}/meas")
    return 0 if a is None else a["samples"]


def start_daemon(net: Net, log: Path, env: dict | None = None) -> subprocess.Popen:
    d = net.start("run", "--log", str(log), "--no-rotate", "--json", env=env)
    net.wait(lambda st: True, what="the daemon's status queryable")
    return d


def read(path: Path, topics=None):
    from service.log import read_log

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        rows = list(read_log(path, topics))
    return rows, [str(x.message) for x in w]


def _messages(path: Path, topics: list[str]) -> dict[str, list[tuple[int, bytes]]]:
    from mcap.reader import make_reader

    out: dict[str, list[tuple[int, bytes]]] = {tp: [] for tp in topics}
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages(topics=topics, log_time_order=False):
            out[ch.topic].append((msg.log_time, msg.data))
    return out


# --------------------------------------------------------------------------- leak + replay


@pytest.fixture(scope="module")
def leak_run(tmp_path_factory):
    """Daemon + actuator (16 s at 250 Hz); a leak injected through the @fault queryable,
    the actuator ends; then SIGTERM to the daemon."""
    tmp = tmp_path_factory.mktemp("leak")
    log = tmp / "live.mcap"
    n = Net()
    try:
        # a store of its own: a baseline another test recorded for this unit in the session's
        # store would be the daemon's, and the replay (no store) would not equal it
        d = start_daemon(n, log, env={"SERVOWATCH_STORE": str(tmp / "health.sqlite")})
        a = n.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "16",
                    "--json")  # fmt: skip
        n.wait(lambda st: act_samples(st) > RATE * 3, what="3 s of samples")
        # the acknowledged command straight through the queryable (CLI start-up takes seconds)
        ack = send_fault(n.session, AC, ACT, m.FaultCommand(kind="leak", value=8e-13))
        # both CLIs at once, while the actuator still runs
        refused = cli("inject", "--connect", n.ep, "--aircraft", AC, "--actuator", ACT,
                      "--fault", "leak", "--value", "1.0", "--json")  # fmt: skip
        status = cli("status", "--connect", n.ep, "--json")
        ref_out, ref_err = refused.communicate(timeout=30)
        status_out, _ = status.communicate(timeout=30)
        a_out, _ = a.communicate(timeout=60)
        n.wait(lambda st: st["queue"] == 0, what="the daemon to catch up")
        d.send_signal(signal.SIGTERM)
        d_out, d_err = d.communicate(timeout=60)
    finally:
        n.close()
    return {
        "log": log, "tmp": tmp, "inject": (0 if ack and ack.ok else 1, ack.model_dump()),
        "refused": (refused.returncode, ref_out, ref_err),
        "status": (status.returncode, status_out),
        "actuator": json.loads(a_out.strip().splitlines()[-1]),
        "daemon_rc": d.returncode, "final": json.loads(d_out.strip().splitlines()[-1]),
    }  # fmt: skip


def test_inject_acknowledged_and_refused(leak_run):
    rc, ack = leak_run["inject"]
    assert rc == 0 and ack["ok"] and "8e-13" in ack["message"]
    assert ack["active"][0]["kind"] == "leak" and ack["active"][0]["target"] == 8e-13
    rc, out, err = leak_run["refused"]
    assert rc == 1, err
    ans = json.loads(out)
    assert not ans["ok"] and "outside" in ans["message"] and "refused" in err
    assert ans["active"][0]["target"] == 8e-13  # the refusal changed nothing


def test_status_command_reports_the_daemon(leak_run):
    rc, out = leak_run["status"]
    assert rc == 0
    daemons = json.loads(out)["daemons"]
    st = daemons["monitor/ground1/0/status"]
    a = st["actuators"][f"fleet/{AC}/{ACT}/meas"]
    assert a["samples"] > 0 and a["dropped"] == 0 and a["bad_total"] == 0
    assert st["latency_ms"]["p50"] is not None
    assert st["alive_tokens"] == [f"fleet/{AC}/{ACT}/alive"]


def test_leak_detected_and_mcap_readable_with_the_mcap_reader(leak_run):
    """The daemon's log read by stock libraries only: mcap's reader with
    mcap-protobuf-support's decoder for every topic, the events too (decision 0043)."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    t_ack = leak_run["inject"][1]["active"][0]["t_ack"]
    counts: dict[str, int] = {}
    est: list[tuple[float, float]] = []
    events = []
    with open(leak_run["log"], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            leaf = channel.topic.rsplit("/", 1)[-1]
            assert channel.message_encoding == schema.encoding == "protobuf"
            if leaf in ("meas", "est", "residual", "health"):
                assert schema.name == "servowatch." + leaf.capitalize()
            else:
                assert schema.name == "servowatch.Event"
        f.seek(0)
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _message, row in reader.iter_decoded_messages():  # every topic decodes
            if channel.topic.endswith("/events"):
                events.append({"kind": row.kind, "state": row.state, "t": row.t})
        f.seek(0)
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, row in reader.iter_decoded_messages(topics=[MEAS, EST]):
            if channel.topic == MEAS:
                assert isinstance(row.seq, int)
                assert message.log_time == round(row.t * 1e9) or abs(
                    message.log_time - row.t * 1e9) < 1e3  # fmt: skip
            else:
                est.append((message.log_time * 1e-9, row.c_lk))
    n = leak_run["actuator"]["samples"]
    assert n == 16 * RATE
    assert counts[MEAS] == n
    assert counts[EST] == counts[f"/fleet/{AC}/{ACT}/residual"] == leak_run["final"]["samples"]
    assert len(est) == counts[EST]
    before = [c for t, c in est if t < t_ack]
    after = [c for t, c in est if t > t_ack + 1.0]
    # the leak (4x nominal) raises the estimated C_Lk and raises the leak alarm
    assert sum(after) / len(after) > 2 * sum(before) / len(before)
    raised = [e for e in events if e["kind"] == "leak" and e["state"] == "raised"]
    assert any(e["t"] >= t_ack for e in raised)


def test_sigterm_finishes_the_log_and_loses_nothing(leak_run):
    assert leak_run["daemon_rc"] == 0
    rows, warned = read(leak_run["log"], [MEAS])
    assert warned == []  # complete file: footer and summary written
    assert [r[2]["seq"] for r in rows] == list(range(leak_run["actuator"]["samples"]))
    fin = leak_run["final"]
    assert fin["dropped"] == 0 and fin["bad"] == 0 and fin["samples"] == len(rows)


def test_live_estimates_equal_replay(leak_run):
    from service.replay import replay

    out = leak_run["tmp"] / "replay.mcap"
    summary = replay(leak_run["log"], out=out)
    assert summary.samples == leak_run["actuator"]["samples"]
    live, _ = read(leak_run["log"], [EST])
    rep, _ = read(out, [EST])
    assert len(live) == len(rep) > 0
    for (_, t1, m1), (_, t2, m2) in zip(live, rep, strict=True):
        assert t1 == t2 and m1 == m2
    # bit for bit: the protobuf messages of every output topic are the same bytes
    topics = [f"/fleet/{AC}/{ACT}/{leaf}" for leaf in ("est", "residual", "health")]
    assert _messages(leak_run["log"], topics) == _messages(out, topics)


# --------------------------------------------------------------------------- crashes


def test_kill_9_loses_at_most_the_last_second_and_the_rest_replays(net, tmp_path):
    """Worst case: SIGKILL to the daemon and its MCAP log process at once (as systemd does
    to a whole cgroup); the file has no footer, everything older than ~1 s is readable."""
    from service.replay import replay

    log = tmp_path / "killed.mcap"
    d = net.start("run", "--log", str(log), "--no-rotate", "--json", start_new_session=True)
    net.wait(lambda st: True, what="the daemon's status queryable")
    net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "30")
    net.wait(lambda st: act_samples(st) > RATE * 4 and st["queue"] == 0, what="4 s of data")
    time.sleep(0.5)
    t_kill = time.time()
    os.killpg(d.pid, signal.SIGKILL)
    d.wait(10)
    rows, warned = read(log, [MEAS])
    assert warned and "truncated" in warned[0]
    seqs = [r[2]["seq"] for r in rows]
    assert seqs == list(range(len(seqs)))  # what is there is complete up to the cut
    last_t = rows[-1][2]["t"]
    assert t_kill - last_t <= 1.5, f"lost {t_kill - last_t:.2f} s"  # flush_s = 1 s
    s = replay(log)
    assert s.truncated and s.samples == len(rows) and s.outputs > 0


def test_kill_9_of_the_daemon_alone_loses_nothing_it_received(net, tmp_path):
    """SIGKILL to the daemon process only: its log process sees the pipe close and finishes
    the file with every sample the daemon had forwarded."""
    log = tmp_path / "killed1.mcap"
    d = start_daemon(net, log)
    net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "30")
    st = net.wait(lambda st: act_samples(st) > RATE * 3, what="3 s of data")
    # the status counts a tick's samples when they are accepted, and the tick forwards them
    # to the log process when it ends: let the tick the status saw end before the kill
    time.sleep(0.3)
    d.send_signal(signal.SIGKILL)
    d.wait(10)
    deadline = time.monotonic() + 20.0  # the log process writes its backlog, then the footer
    while True:
        rows, warned = read(log, [MEAS])
        if (rows and not warned) or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert warned == []
    seqs = [r[2]["seq"] for r in rows]
    assert seqs == list(range(len(seqs))) and len(seqs) >= act_samples(st)


def test_sigterm_mid_stream_finishes_a_contiguous_log(net, tmp_path):
    """Also: systemd notifications (READY, WATCHDOG, STOPPING) on NOTIFY_SOCKET."""
    import socket

    log = tmp_path / "mid.mcap"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify"))
    sock.settimeout(0.2)
    notes: list[str] = []
    reading = threading.Event()

    def reader():  # systemd reads continuously; so does this
        while not reading.is_set():
            try:
                notes.append(sock.recv(64).decode())
            except TimeoutError:
                continue

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    env = {"NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "400000"}
    d = start_daemon(net, log, env=env)
    net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "30")
    net.wait(lambda st: act_samples(st) > RATE * 2, what="2 s of data")
    d.send_signal(signal.SIGTERM)
    out, _ = d.communicate(timeout=30)
    final = json.loads(out.strip().splitlines()[-1])
    assert d.returncode == 0
    time.sleep(0.3)
    reading.set()
    th.join(2)
    sock.close()
    # the start extends systemd's timeout while it compiles/loads, then READY once started
    k = notes.index("READY=1")
    assert notes.count("READY=1") == 1 and notes[-1] == "STOPPING=1"
    assert all(n.startswith("EXTEND_TIMEOUT_USEC=") for n in notes[:k]) and k >= 1
    assert notes.count("WATCHDOG=1") >= 3  # every 0.2 s while running
    rows, warned = read(log, [MEAS])
    assert warned == []
    seqs = [r[2]["seq"] for r in rows]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    # every sample the daemon accepted is in the file
    assert len(rows) == final["samples"]


# --------------------------------------------------------------------------- bad input


def _junk(good_seq: int) -> list[tuple[str, bytes]]:
    k = f"fleet/{AC}/{ACT}/meas"
    big = b'{"samples": [' + b",".join([b'{"seq": 1, "t": 1.0}'] * 5000) + b"]}"
    return [
        (k, b"\x00\x01garbage"),
        (k, b'{"seq": 1, "t": NaN}'),
        (k, b'{"seq": "one", "t": 1.0}'),
        (k, b'{"seq": 1, "t": 1.0, "volts": 3}'),
        (k, big),  # oversize
        (k, m.encode_meas([{"seq": good_seq, "t": 1.0, "p1": 5e6}])),  # clock far back
        (k, b"SW\x01M\x05\x00\x00\x00short"),
        ("fleet/AC001/x y/meas", b"{}"),
        (f"fleet/{AC}/other/meas", b"[1, 2, 3]"),
    ]


def test_flood_of_malformed_messages_beside_good_ones(net, tmp_path):
    log = tmp_path / "flood.mcap"
    d = start_daemon(net, log)
    a = net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "6",
                  "--json")  # fmt: skip
    net.wait(lambda st: act_samples(st) > 0, what="the first samples")
    sent = 0
    pubs: dict[str, object] = {}
    t_end = time.monotonic() + 3.0
    while time.monotonic() < t_end:
        for key, payload in _junk(5):
            pub = pubs.get(key) or pubs.setdefault(
                key,
                net.session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK
                ),
            )
            pub.put(payload)
            sent += 1
        time.sleep(0.005)
    a_out, _ = a.communicate(timeout=60)
    a_counts = json.loads(a_out.strip().splitlines()[-1])
    n_good = a_counts["samples"]
    st = net.wait(lambda st: st["queue"] == 0 and act_samples(st) == n_good, timeout=30,
                  what="all good samples")  # fmt: skip
    acts = st["actuators"]
    main = acts[f"fleet/{AC}/{ACT}/meas"]
    assert main["samples"] == n_good and main["dropped"] == 0
    per_round = 7  # junk messages per round on the good actuator's key
    # every junk message that arrived is counted bad, none of the good ones
    junk_received = main["messages"] - a_counts["messages"]
    assert main["bad_total"] == junk_received
    assert 0.95 * sent // 9 * per_round <= junk_received <= sent // 9 * per_round
    assert set(main["bad"]) >= {"malformed", "non_finite", "schema", "oversize", "clock"}
    other = acts[f"fleet/{AC}/other/meas"]
    assert other["bad"] == {"malformed": other["messages"]} and other["messages"] > 0
    assert 0 < st["unknown"]["invalid_key"] <= sent // 9
    assert st["errors"] == 0
    d.send_signal(signal.SIGTERM)
    d.communicate(timeout=30)
    rows, warned = read(log, [MEAS])
    assert [r[2]["seq"] for r in rows] == list(range(n_good)) and warned == []


# --------------------------------------------------------------------------- restart


def test_publisher_that_stops_and_restarts(net, tmp_path):
    log = tmp_path / "restart.mcap"
    d = start_daemon(net, log, env={"SERVOWATCH_SILENCE_S": "1.0"})
    runs = []
    for _ in range(2):
        a = net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration",
                      "2", "--json")  # fmt: skip
        out, _ = a.communicate(timeout=60)
        runs.append(json.loads(out.strip().splitlines()[-1])["samples"])
        st = net.wait(lambda st: st["silent"] == [f"{AC}/{ACT}"], what="silence detection")
        # the actuator's liveliness token went with it
        assert st["lost_tokens"] == [f"fleet/{AC}/{ACT}/alive"] and st["alive_tokens"] == []
    total = sum(runs)
    st = net.wait(lambda st: act_samples(st) == total and st["queue"] == 0,
                  what="both runs")  # fmt: skip
    a = st["actuators"][f"fleet/{AC}/{ACT}/meas"]
    assert a["restarts"] == 1 and a["gaps"] == 0 and a["bad_total"] == 0
    kinds = [e["kind"] for e in a["events"] if e["kind"] in ("silent", "resumed", "restart")]
    assert kinds == ["silent", "resumed", "restart", "silent"], a["events"]
    d.send_signal(signal.SIGTERM)
    d.communicate(timeout=30)
    rows, _ = read(log, [MEAS])
    seqs = [r[2]["seq"] for r in rows]
    assert seqs == list(range(runs[0])) + list(range(runs[1]))
    ts = [r[2]["t"] for r in rows]
    assert all(b > a for a, b in zip(ts, ts[1:], strict=False)) and not any(
        math.isnan(t) for t in ts
    )
