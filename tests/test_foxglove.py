"""The live Foxglove view (service.edge.foxglove_feed): schemas and bytes of the MCAP log, only
subscribed topics encoded, a bounded queue, loopback by default; end to end, a WebSocket
client written from the protocol's specification (tests/_foxglove_ws.py) against
``servowatch run --foxglove`` with router, daemon and virtual actuator in their own processes.
"""

from __future__ import annotations

import base64
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from _foxglove_ws import FoxgloveClient, MessageData

from service.edge.foxglove_feed import LEAVES, FoxgloveFeed, encode_rows, topic_schemas
from service.log import McapLogger
from service.log.events import EventCodec, EventLayout, decode_event, encode_event
from service.log.proclog import MEAS_LOG_FIELDS
from service.log.rows import RowLayout
from service.monitor import EST_KEYS
from service.monitor.outputs import AlarmEvent
from service.wire import messages as m

AC, ACT = "AC001", "elevator_L"
TOPIC = {leaf: m.mcap_topic(AC, ACT, leaf) for leaf in LEAVES}


def _mcap(path: Path) -> tuple[dict[str, tuple], dict[str, dict[int, bytes]]]:
    """(topic -> (message encoding, schema name, schema encoding, schema), topic ->
    {log_time: message bytes}) of an MCAP file; a jsonschema parsed."""
    from mcap.reader import make_reader

    schemas: dict[str, tuple] = {}
    msgs: dict[str, dict[int, bytes]] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            data = json.loads(schema.data) if schema.encoding == "jsonschema" else schema.data
            schemas[channel.topic] = (channel.message_encoding, schema.name, schema.encoding, data)
            msgs.setdefault(channel.topic, {})[message.log_time] = message.data
    return schemas, msgs


def _advertised(schema) -> tuple:
    """What the feed advertises for a topic_schemas entry, as _mcap gives it."""
    if isinstance(schema, RowLayout | EventLayout):
        return ("protobuf", schema.message, "protobuf", schema.schema)
    return ("json", "events", "jsonschema", schema)


def _channel_schema(ch: dict) -> tuple:
    """An advertised channel as _mcap gives it (a binary schema is sent in base64)."""
    if ch["schemaEncoding"] == "protobuf":
        return (ch["encoding"], ch["schemaName"], "protobuf", base64.b64decode(ch["schema"]))
    return (ch["encoding"], ch["schemaName"], ch["schemaEncoding"], json.loads(ch["schema"]))


def _wait(pred, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


def test_schemas_and_bytes_are_the_logs(tmp_path):
    """What the feed advertises and sends is what McapLogger writes, as the fan-out calls it."""
    rng = np.random.default_rng(3)
    t = 1000.0 + np.arange(5) * 1e-3
    est = rng.normal(size=(5, len(EST_KEYS))) * 1e-9
    est[2, 3] = np.nan  # written as NaN
    meas = rng.normal(size=(5, len(MEAS_LOG_FIELDS)))
    meas[:, MEAS_LOG_FIELDS.index("seq")] = np.arange(5) + 7
    event = {"t": 1000.002, "kind": "leak", "state": "raised", "value": 3.5}
    path = tmp_path / "a.mcap"
    with McapLogger(path, background_flush=False) as lg:
        lg.log_block(TOPIC["meas"], t, MEAS_LOG_FIELDS, meas, int_fields=("seq",))
        lg.log_block(TOPIC["est"], t, EST_KEYS, est)
        lg.log_event(TOPIC["events"], event["t"], event)
    schemas, msgs = _mcap(path)
    mine = topic_schemas(AC, ACT)
    for leaf in ("meas", "est", "events"):
        assert _advertised(mine[TOPIC[leaf]]) == schemas[TOPIC[leaf]], leaf
    assert schemas[TOPIC["est"]][:3] == ("protobuf", "servowatch.Est", "protobuf")
    assert set(mine) == set(TOPIC.values())
    assert set(AlarmEvent.__dataclass_fields__) <= set(EventCodec.names)  # every field carried
    assert msgs[TOPIC["events"]] == {round(event["t"] * 1e9): encode_event(event)}
    lts, datas = encode_rows(TOPIC["est"], t, EST_KEYS, est)
    assert dict(zip(lts.tolist(), datas, strict=True)) == msgs[TOPIC["est"]]
    lts, datas = encode_rows(TOPIC["meas"], t, MEAS_LOG_FIELDS, meas, ("seq",))
    assert dict(zip(lts.tolist(), datas, strict=True)) == msgs[TOPIC["meas"]]


def test_feed_encodes_only_subscribed_topics_and_counts_drops():
    feed = FoxgloveFeed("127.0.0.1", 0, queue_size=8)
    c = FoxgloveClient("127.0.0.1", feed.port).connect()
    try:
        feed.add_actuator(AC, ACT)
        c.wait_topics(set(TOPIC.values()), timeout=10)
        ch = c.channel_of(TOPIC["est"])
        assert c.topics() == set(TOPIC.values())
        enc = {x["topic"].rsplit("/", 1)[-1]: (x["encoding"], x["schemaEncoding"])
               for x in c.channels.values()}  # fmt: skip
        assert enc == {leaf: ("protobuf", "protobuf") for leaf in LEAVES}  # events too
        lay = topic_schemas(AC, ACT)[TOPIC["est"]]
        assert _channel_schema(ch) == _advertised(lay)
        t = np.array([1.0, 1.001, 1.002])
        est = np.arange(3 * len(EST_KEYS), dtype=float).reshape(3, -1)
        feed.log_block(TOPIC["est"], t, EST_KEYS, est)  # nobody subscribed: nothing queued
        assert feed.status()["sent"] == 0 and feed.status()["queued"] == 0
        c.subscribe({5: ch["id"]})
        _wait(lambda: feed.wants(TOPIC["est"]))
        feed.log_block(TOPIC["est"], t, EST_KEYS, est)
        got = []
        while len(got) < 3:
            r = c.recv(timeout=10)
            if isinstance(r, MessageData):
                got.append(r)
        assert [g.subscription for g in got] == [5, 5, 5]
        assert [g.timestamp_ns for g in got] == [1_000_000_000, 1_001_000_000, 1_002_000_000]
        assert [lay.decode_one(g.payload) for g in got] == est.tolist()
        feed.log_block(TOPIC["est"], np.arange(9.0), EST_KEYS, np.zeros((9, len(EST_KEYS))))
        st = feed.status()
        assert st["dropped"] == 9 and st["sent"] == 3  # 9 > queue_size 8: dropped, counted
        assert st["subscribed_topics"] == 1
        c.unsubscribe([5])
        _wait(lambda: not feed.wants(TOPIC["est"]))
        assert feed.status()["subscribed_topics"] == 0
    finally:
        c.close()
        feed.close()


def test_every_sends_one_row_in_n_per_topic_and_every_event():
    feed = FoxgloveFeed("127.0.0.1", 0, every=4)
    c = FoxgloveClient("127.0.0.1", feed.port).connect()
    try:
        feed.add_actuator(AC, ACT)
        c.wait_topics(set(TOPIC.values()), timeout=10)
        c.subscribe({1: c.channel_of(TOPIC["est"])["id"], 2: c.channel_of(TOPIC["events"])["id"]})
        _wait(lambda: feed.wants(TOPIC["est"]) and feed.wants(TOPIC["events"]))
        est = np.zeros((10, len(EST_KEYS)))
        for a, b in ((0, 3), (3, 8), (8, 10)):  # blocks of 3, 5 and 2 rows
            feed.log_block(TOPIC["est"], np.arange(a, b, dtype=float), EST_KEYS, est[a:b])
            feed.log_event(TOPIC["events"], a + 0.5,
                           {"t": a + 0.5, "kind": "leak", "state": "raised"})  # fmt: skip
        got, payloads = [], []
        while len(got) < 6:
            r = c.recv(timeout=10)
            if isinstance(r, MessageData):
                got.append((r.subscription, r.timestamp_ns / 1e9))
                if r.subscription == 2:
                    payloads.append(decode_event(r.payload))
        assert [(p["kind"], p["state"]) for p in payloads] == [("leak", "raised")] * 3
        assert sorted(x for s, x in got if s == 1) == [0.0, 4.0, 8.0]
        assert sorted(x for s, x in got if s == 2) == [0.5, 3.5, 8.5]
    finally:
        c.close()
        feed.close()


def test_non_loopback_refused_without_the_allow_flag(tmp_path):
    from service.cli.commands.run import foxglove_override
    from service.config import ServiceConfig

    cfg = ServiceConfig()
    with pytest.raises(ValueError, match="--foxglove: 10.1.2.3 is not a loopback address"):
        foxglove_override(cfg, "10.1.2.3:8765", False)
    assert foxglove_override(cfg, "10.1.2.3:8765", True).foxglove.listen == "10.1.2.3:8765"
    assert foxglove_override(cfg, "127.0.0.1:9", False).foxglove.host_port() == ("127.0.0.1", 9)
    with pytest.raises(ValueError, match="allow_remote = true"):
        ServiceConfig.model_validate({"foxglove": {"listen": "0.0.0.0:8765"}})
    assert ServiceConfig.model_validate({"foxglove": {}}).foxglove.listen == "127.0.0.1:8765"
    r = subprocess.run(
        [sys.executable, "-m", "service.cli", "run", "--foxglove", "192.168.1.2:8765"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 2 and "not a loopback address" in r.stderr


# --------------------------------------------------------------------------- end to end

# Hz: the stuck client of test_daemon_serves_foxglove_live must be sent more than the
# socket buffers hold (a 4 MB send buffer; the protobuf rows are about 470 bytes per sample
# for meas, est, residual and health: 24 s at 500 Hz is 5.6 MB)
RATE = 500


def _connect(port: int, timeout: float = 60.0) -> FoxgloveClient:
    end = time.monotonic() + timeout
    while True:
        try:
            return FoxgloveClient("127.0.0.1", port).connect()
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)


def _stuck_client(port: int) -> FoxgloveClient:
    """A client with a small receive buffer (it will stop reading after the handshake)."""
    return FoxgloveClient("127.0.0.1", port).connect(rcvbuf=4096)


@pytest.mark.slow
def test_daemon_serves_foxglove_live(net, tmp_path):
    from service.cli.commands.inject import send_fault
    from service.zenoh_util import free_port

    log = tmp_path / "live.mcap"
    port = free_port()
    d = net.start("run", "--log", str(log), "--no-rotate", "--json", "--store", "off",
                  "--foxglove", f"127.0.0.1:{port}",
                  env={"SERVOWATCH_FOXGLOVE__BACKLOG": "64",
                       "SERVOWATCH_FOXGLOVE__EVERY": "1"})  # fmt: skip
    net.wait(lambda st: True, what="the daemon's status queryable")
    a = net.start("actuator", "--scenario", "demo", "--rate", str(RATE), "--duration", "24")
    c = _connect(port)
    stuck = None
    try:
        assert c.subprotocol in ("foxglove.websocket.v1", "foxglove.sdk.v1")
        c.wait_topics(set(TOPIC.values()), timeout=60)  # advertised with the first sample
        ch_est = c.channel_of(TOPIC["est"])
        for topic, schema in topic_schemas(AC, ACT).items():
            assert _channel_schema(c.channel_of(topic)) == _advertised(schema), topic
        ch_ev = c.channel_of(TOPIC["events"])
        # a client that subscribes to everything but meas and events, then stops reading
        stuck = _stuck_client(port)
        stuck.wait_topics(set(TOPIC.values()), timeout=10)
        stuck.subscribe({i: stuck.channel_of(TOPIC[leaf])["id"]
                         for i, leaf in enumerate(("meas", "est", "residual", "health"), 1)})  # fmt: skip
        net.wait(lambda st: st["foxglove"]["subscribed_topics"] == 4, what="the stuck one's")
        net.wait(lambda st: st["samples"] > RATE * 2, what="2 s of samples")
        c.subscribe({1: ch_est["id"], 2: ch_ev["id"]})
        net.wait(lambda st: st["foxglove"]["subscribed_topics"] == 5, what="est and events")
        ack = send_fault(net.session, AC, ACT, m.FaultCommand(kind="leak", value=8e-13))
        assert ack is not None and ack.ok
        est: list[MessageData] = []
        events: list[MessageData] = []
        end = time.monotonic() + 30
        while (len(est) < 2 * RATE or not events) and time.monotonic() < end:
            r = c.recv(timeout=10)
            if isinstance(r, MessageData):
                (est if r.subscription == 1 else events).append(r)
        assert len(est) >= 2 * RATE
        ev = [decode_event(x.payload) for x in events]
        assert any(e["kind"] == "leak" and e["state"] == "raised" for e in ev), ev
        ts = [x.timestamp_ns for x in est]
        assert ts == sorted(ts) and len(set(ts)) == len(ts)
        c.unsubscribe([1, 2])
        net.wait(lambda st: st["foxglove"]["subscribed_topics"] == 4, what="the unsubscription")
        late = []  # what was in flight at the unsubscribe, then nothing
        c.sock.settimeout(1.0)
        try:
            while True:
                r = c.recv(timeout=1.0)
                if isinstance(r, MessageData):
                    late.append(r)
        except TimeoutError:
            pass
        assert not [x for x in late if x.timestamp_ns > est[-1].timestamp_ns + 2e9]

        # the stuck client: the monitor keeps its pace, the feed its bound
        s0 = net.status()
        time.sleep(4.0)
        s1 = net.status()
        rate = (s1["samples"] - s0["samples"]) / (s1["uptime_s"] - s0["uptime_s"])
        assert rate > 0.8 * RATE, (s0["samples"], s1["samples"])
        assert s1["queue"] < RATE  # the daemon's receive queue does not grow
        fx = s1["foxglove"]
        assert fx["sent"] - s0["foxglove"]["sent"] > 3 * 4 * 0.8 * RATE  # still fed to the SDK
        assert fx["queued"] <= fx["queue_size"]
        assert s1["dropped"] == 0  # no sample lost by the monitor
        a.communicate(timeout=60)
        net.wait(lambda st: st["queue"] == 0, what="the daemon to catch up")
        t_term = time.monotonic()
        d.send_signal(signal.SIGTERM)
        out, err = d.communicate(timeout=60)
        assert d.returncode == 0, err[-2000:]
        assert time.monotonic() - t_term < 30  # the stuck client does not hold the shutdown
        # it was stuck: what it reads now is its bounded backlog and the socket buffers, with
        # the oldest messages dropped for it (the SDK's per-client backlog, 64 here)
        got = []
        try:
            while True:
                r = stuck.recv(timeout=2.0)
                if isinstance(r, MessageData) and r.subscription == 2:
                    got.append(r.timestamp_ns)
        except (TimeoutError, ConnectionError):
            pass
    finally:
        c.close()
        if stuck is not None:
            stuck.close()
    final = json.loads(out.strip().splitlines()[-1])
    n_est = final["actuators"][f"fleet/{AC}/{ACT}/meas"]["outputs"]
    # it read some but far from all: the rest was dropped for it (where in its stream depends on
    # the SDK's per-client policy: its oldest backlog, or the client cut off)
    assert 0 < len(got) < 0.8 * n_est, (len(got), n_est)
    assert final["foxglove"]["errors"] == 0
    # the live est messages are the log's: same time stamps, same bytes
    schemas, msgs = _mcap(log)
    for topic, schema in topic_schemas(AC, ACT).items():
        assert schemas[topic] == _advertised(schema), topic
    logged = msgs[TOPIC["est"]]
    for x in est + late:
        assert logged[x.timestamp_ns] == x.payload
    ev_logged = msgs[TOPIC["events"]]
    for x in events:
        assert ev_logged[x.timestamp_ns] == x.payload


@pytest.mark.slow
def test_replay_serves_foxglove_paced(tmp_path):
    """``servowatch replay LOG --foxglove`` (a separate process) serves the replay's est at
    the pace of ``--speed``, the same bytes as its ``--out`` log."""
    import re

    from models.eha import simulate
    from service.sim.scenarios import load_scenario

    n, speed = 3000, 1.0
    r = simulate(load_scenario("leak_step"), "HF", out_every=10)  # 1 kHz samples
    log, out = tmp_path / "run.mcap", tmp_path / "replayed.mcap"
    with McapLogger(log, background_flush=False) as lg:
        for k in range(n):
            d = {"seq": k, "t": float(r.t[k])}
            d.update({c: float(getattr(r, c)[k]) for c in m.CHANNELS})
            lg.log(TOPIC["meas"], d["t"], d)
    p = subprocess.Popen(
        [sys.executable, "-m", "service.cli", "replay", str(log), "--out", str(out),
         "--foxglove", "127.0.0.1:0", "--foxglove-every", "1", "--foxglove-wait", "60",
         "--speed", str(speed), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        line = p.stderr.readline()
        port = int(re.search(r"ws://127\.0\.0\.1:(\d+)", line).group(1))
        c = _connect(port)
        c.wait_topics(set(TOPIC.values()), timeout=60)  # advertised before the first sample
        c.subscribe({1: c.channel_of(TOPIC["est"])["id"]})
        got: list[tuple[float, MessageData]] = []
        try:
            while True:
                x = c.recv(timeout=60 if not got else 5)
                if isinstance(x, MessageData):
                    got.append((time.monotonic(), x))
        except (TimeoutError, ConnectionError):
            pass
        c.close()
        stdout, _ = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0
    summary = json.loads(stdout)
    assert summary["samples"] == n
    _, msgs = _mcap(out)
    logged = msgs[TOPIC["est"]]
    assert len(got) >= 0.9 * len(logged)
    for _, x in got:
        assert logged[x.timestamp_ns] == x.payload
    half = got[len(got) // 2 :]  # past the monitor's warm-up lag, which the replay catches up
    span_t = (half[-1][1].timestamp_ns - half[0][1].timestamp_ns) / 1e9
    span_wall = half[-1][0] - half[0][0]
    # paced: as fast as possible, 3000 samples take well under 0.3 s
    assert span_t > 1.2 and span_wall >= 0.7 * span_t / speed, (span_t, span_wall)


def test_the_shipped_layout_names_fields_of_the_row_schemas():
    """Every ``topic.field`` path and every ``event.message.field`` of the layout's user
    scripts is a field of that topic's protobuf row (the schemas the log and the feed carry)."""
    import re

    text = (Path(__file__).parents[1] / "deploy/foxglove/servowatch-layout.json").read_text()
    schemas = topic_schemas(AC, ACT)
    paths = set(re.findall(r"(/fleet/AC001/elevator_L/[a-z]+)\.([a-z_0-9]+)", text))
    assert len(paths) >= 8
    for topic, fld in paths:
        assert fld in schemas[topic].names, (topic, fld)
    rows = [schemas[TOPIC[leaf]].names for leaf in ("est", "residual", "health")]
    used = set(re.findall(r"message\.([a-z_0-9]+)", text))
    assert used >= {"c_lk", "leak_ratio", "nis", "nis_dof"}
    for fld in used:
        assert any(fld in names for names in rows), fld
