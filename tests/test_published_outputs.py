"""The est, res and health the daemon and the replay publish on Zenoh: protobuf rows of the
log's fields (service.wire.messages.output_layout), the same numbers as the log, readable with the
stock protobuf library, printed by ``servowatch listen``."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from models.eha import simulate
from service.cli import main
from service.daemon.fanout import FanOut
from service.log import McapLogger
from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS, MonitorBank
from service.replay import replay
from service.sim.scenarios import load_scenario
from service.wire.messages import CHANNELS, MessageError, mcap_topic

N = 400
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def meas() -> dict:
    r = simulate(load_scenario("leak_step"), "HF", out_every=10)
    rng = np.random.default_rng(3)
    d = {"t": np.asarray(r.t[:N], float)}
    for c in CHANNELS:
        d[c] = np.asarray(getattr(r, c)[:N], float)
    d["x_j"] = d["x_j"] + rng.normal(0, 50e-6, N)
    d["p1"] = d["p1"] + rng.normal(0, 50e3, N)
    return d


class _Pub:
    def __init__(self, key: str, encoding: str, sink: list) -> None:
        self.key, self.encoding, self.sink = key, encoding, sink

    def put(self, payload: bytes) -> None:
        self.sink.append((self.key, self.encoding, bytes(payload)))

    def undeclare(self) -> None:
        pass


class _Session:
    """Records the puts (key, encoding, payload) as a Zenoh session would carry them."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, str, bytes]] = []

    def declare_publisher(self, key: str, *, encoding: str | None = None) -> _Pub:
        return _Pub(key, encoding, self.puts)


def _decode(leaf: str, payload: bytes, encoding: str | None = None) -> dict:
    from service.wire.messages import decode_output

    return decode_output(leaf, payload, encoding)


def _stock_classes(schema: bytes) -> dict:
    """Message classes of a FileDescriptorSet, by the stock protobuf library only."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema)
    for f in fds.file:
        pool.Add(f)
    return {
        m.full_name: message_factory.GetMessageClass(m)
        for f in fds.file
        for m in (pool.FindFileByName(f.name).message_types_by_name.values())
    }


def test_fanout_publishes_each_output_as_its_row(meas):
    """Every ``publish_every``-th output of each actuator, decoded, is the bank's row of that
    output (bit for bit), with t and the health's commissioning info; the encoding names the
    message."""
    bank = MonitorBank()
    ids = [bank.index_of(f"AC1/{a}") for a in ("a", "b", "c")]
    sess = _Session()
    fo = FanOut(None, publish_every=7, session=sess)
    fo.track(ids[0], "AC1", "a", info={"commissioned": True, "baseline_version": 4})
    fo.track(ids[1], "AC1", "b", info={"commissioned": False, "baseline_version": None})
    fo.track(ids[2], "AC1", "c")  # no store: no commissioning info
    ch = np.column_stack([meas[c] for c in CHANNELS])
    want: dict[str, list[dict]] = {}
    count = dict.fromkeys(ids, 0)
    for a0 in range(0, N, 37):  # interleaved blocks of the three actuators
        a1 = min(N, a0 + 37)
        ks = np.repeat(ids, a1 - a0)[np.argsort(np.tile(np.arange(a1 - a0), 3), kind="stable")]
        t = np.tile(meas["t"][a0:a1], 3)[np.argsort(np.tile(np.arange(a1 - a0), 3), kind="stable")]
        z = np.tile(ch[a0:a1], (3, 1))[np.argsort(np.tile(np.arange(a1 - a0), 3), kind="stable")]
        rows = bank.update_arrays(ks, t, z)
        fo.emit(rows, ks)
        for r, k in enumerate(ks[rows.index].tolist()):
            count[k] += 1
            if count[k] % 7 == 0:
                o, name = rows.output(r), "abc"[ids.index(k)]
                info = [{"commissioned": True, "baseline_version": 4},
                        {"commissioned": False, "baseline_version": None}, {}][ids.index(k)]  # fmt: skip
                for leaf, d in (("est", o.est), ("res", o.res), ("health", {**o.health, **info})):
                    want.setdefault(f"fleet/AC1/{name}/{leaf}", []).append({"t": o.t, **d})
    got: dict[str, list[dict]] = {}
    message = {"est": "EstOutput", "res": "ResidualOutput", "health": "HealthOutput"}
    for key, enc, payload in sess.puts:
        leaf = key.rsplit("/", 1)[1]
        assert enc == f"application/protobuf;servowatch.{message[leaf]}"
        got.setdefault(key, []).append(_decode(leaf, payload, enc))
    assert sum(len(v) for v in want.values()) == len(sess.puts) > 3 * 3 * 40
    assert got == want  # same keys, same order of keys per row, same floats


def test_published_rows_are_the_logged_rows_and_stock_protobuf_reads_them(meas, tmp_path):
    """A replay (the daemon's fan-out) logs every output and publishes every 10th: each
    published est/res/health, decoded by the stock protobuf library with the schema
    ``servowatch listen --write-schema`` writes, holds the numbers of the logged row of the
    same sample, read by the stock MCAP reader."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    log = tmp_path / "in.mcap"
    with McapLogger(log, background_flush=False) as lg:
        for k in range(N):
            d = {"seq": k, "t": float(meas["t"][k]), **{c: float(meas[c][k]) for c in CHANNELS}}
            lg.log(mcap_topic("AC001", "elevator_L", "meas"), d["t"], d)
    sess = _Session()
    s = replay(log, out=tmp_path / "out.mcap", publish=sess, publish_every=10)
    assert s.published == s.outputs // 10 > 30
    schema = tmp_path / "outputs.binpb"
    assert main(["listen", "--write-schema", str(schema)]) == 0
    classes = _stock_classes(schema.read_bytes())
    assert set(classes) == {"servowatch.EstOutput", "servowatch.ResidualOutput",
                            "servowatch.HealthOutput"}  # fmt: skip
    logged: dict[str, list] = {}
    with open(tmp_path / "out.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _sc, ch, msg, row in reader.iter_decoded_messages():
            leaf = ch.topic.rsplit("/", 1)[1]
            if leaf in ("est", "residual", "health"):
                logged.setdefault(leaf, []).append((msg.log_time, row))
    names = {"est": EST_KEYS, "res": RES_KEYS, "health": HEALTH_KEYS}
    seen = 0
    for leaf, log_leaf in (("est", "est"), ("res", "residual"), ("health", "health")):
        pubs = [(e, p) for k, e, p in sess.puts if k == f"fleet/AC001/elevator_L/{leaf}"]
        assert len(pubs) == s.published
        rows = logged[log_leaf]
        assert len(rows) == s.outputs
        for j, (enc, payload) in enumerate(pubs):
            msg = classes[enc.split(";", 1)[1]].FromString(payload)
            log_time, row = rows[10 * j + 9]  # the 10th, 20th, ... output
            assert round(msg.t * 1e9) == log_time
            for n in names[leaf]:
                a, b = getattr(msg, n), getattr(row, n)
                assert a == b or (math.isnan(a) and math.isnan(b)), (leaf, j, n, a, b)
            seen += 1
            if leaf == "health":
                assert msg.commissioned == -1 and msg.baseline_version == 0  # no store
    assert seen == 3 * s.published
    last = _decode("est", [p for k, _e, p in sess.puts if k.endswith("/est")][-1])
    assert last["c_lk"] == s.final["AC001/elevator_L"]["est"]["c_lk"]


def test_decode_output_formats_and_refusals():
    """Protobuf and the JSON of older daemons are both read; a malformed message is a
    MessageError naming its field, never another exception."""
    from service.wire.messages import (
        decode_output,
        encode_outputs,
        output_encoding,
        output_layout,
        output_schema,
    )

    v = np.arange(len(HEALTH_KEYS) + 3, dtype=float)
    v[-2:] = (1, 7)  # commissioned, baseline v7
    p = encode_outputs("health", v[None])[0].tobytes()
    d = decode_output("health", p)
    assert d["t"] == v[len(HEALTH_KEYS)] and d["commissioned"] is True
    assert d["baseline_version"] == 7 and list(d)[1:6] == list(HEALTH_KEYS)
    assert decode_output("health", p, output_encoding("health")) == d
    old = json.dumps({"t": 1.5, "leak_ratio": 2.0}).encode()
    assert decode_output("health", old) == {"t": 1.5, "leak_ratio": 2.0}
    assert decode_output("health", old, "zenoh/bytes") == {"t": 1.5, "leak_ratio": 2.0}
    bad = {
        "truncated": (p[:40], "payload"),
        "empty": (b"", "payload"),
        "json as protobuf": (old, "payload"),  # the encoding says protobuf
        "commissioned 5": (
            encode_outputs("health", np.r_[v[:-2], 5, 0][None])[0].tobytes(),
            "commissioned",
        ),  # fmt: skip
        "version -1": (
            encode_outputs("health", np.r_[v[:-2], 1, -1][None])[0].tobytes(),
            "baseline_version",
        ),  # fmt: skip
        "not json": (b"{nope", "payload"),
    }
    for why, (payload, field) in bad.items():
        enc = output_encoding("health") if why == "json as protobuf" else None
        with pytest.raises(MessageError) as e:
            decode_output("health", payload, enc)
        assert e.value.field == field, why
    # any valid protobuf encoding reads: zeros left out (field 1 = 0.0 omitted)
    lay = output_layout("est")
    full = encode_outputs("est", np.r_[0.0, np.arange(1.0, len(EST_KEYS) + 1)][None])[0]
    short = full[lay.value_offsets[1] - 1 :].tobytes()  # from field 2's tag on
    assert decode_output("est", short) == decode_output("est", full.tobytes())
    assert len(output_schema()) > 0


def _router(port: int):
    import zenoh

    from service.zenoh_util import loopback, make_config

    return zenoh.open(make_config("router", listen=[loopback(port)]))


@pytest.mark.slow
def test_listen_prints_outputs_old_json_too_and_counts_malformed(meas, tmp_path):
    """``servowatch listen`` (its own process) prints each published output as the log's
    numbers, reads an older daemon's JSON, and counts a malformed binary output (exit 0, no
    traceback)."""
    import zenoh

    from service.wire.messages import encode_outputs, output_encoding, output_layout
    from service.zenoh_util import free_port, loopback, make_config

    sess = _Session()
    bank = MonitorBank()
    k = bank.index_of("AC1/x")
    fo = FanOut(None, publish_every=10, session=sess)
    fo.track(k, "AC1", "x", info={"commissioned": True, "baseline_version": 2})
    ks = np.full(N, k)
    fo.emit(bank.update_arrays(ks, meas["t"], np.column_stack([meas[c] for c in CHANNELS])), ks)
    want = [(key, _decode(key.rsplit("/", 1)[1], p)) for key, _e, p in sess.puts]
    assert len(want) == 3 * N // 10
    port = free_port()
    est = output_layout("est")
    with _router(port), zenoh.open(make_config("client", connect=[loopback(port)])) as pub:
        proc = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "listen", "--connect", loopback(port),
             "--count", str(len(want) + 1), "--duration", "60"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            # a truncated est, on the wire until listen has subscribed and counted it
            bad = encode_outputs("est", np.ones((1, len(est.names))))[0].tobytes()[:50]
            enc = zenoh.Encoding(output_encoding("est"))
            t_end = time.monotonic() + 30
            malformed = 0
            while time.monotonic() < t_end:
                pub.put("fleet/AC1/x/est", bad, encoding=enc)
                malformed += 1
                line = proc.stderr.readline() if _readable(proc.stderr, 0.2) else ""
                if "malformed output on fleet/AC1/x/est" in line:
                    break
            else:
                pytest.fail("listen never saw the malformed output")
            pub.put("fleet/AC1/old/health", b'{"t": 2.5, "leak_ratio": 1.25}')  # older daemon
            pubs = {}
            for key, e, p in sess.puts:
                if key not in pubs:  # blocking: a loaded machine drops no put
                    pubs[key] = pub.declare_publisher(
                        key, encoding=zenoh.Encoding(e),
                        congestion_control=zenoh.CongestionControl.BLOCK,
                        reliability=zenoh.Reliability.RELIABLE,
                    )  # fmt: skip
                pubs[key].put(p)
                time.sleep(0.0005)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    lines = [ln.split(" ", 2) for ln in out.splitlines()]  # time, key, fields
    assert len(lines) == len(want) + 1  # --count N: exactly N lines
    got = [(key, json.loads(d)) for _when, key, d in lines]
    assert all(w == f"t={d['t']:.3f}s" for (w, _k, _d), (_, d) in zip(lines, got, strict=True))
    by_key: dict[str, list] = {}
    for key, d in got:
        by_key.setdefault(key, []).append(d)
    assert by_key.pop("fleet/AC1/old/health") == [{"t": 2.5, "leak_ratio": 1.25}]
    want_by_key: dict[str, list] = {}
    for key, d in want:
        want_by_key.setdefault(key, []).append(d)
    assert by_key == want_by_key  # each key's outputs in order (keys may interleave)
    assert [d["commissioned"] for d in by_key["fleet/AC1/x/health"]] == [True] * (N // 10)
    summary = err.strip().splitlines()[-1]
    n_bad = int(summary.split(", ")[1].split()[0])
    assert summary.startswith(f"listen: {len(want) + 1} outputs, ") and 1 <= n_bad <= malformed


def _readable(f, timeout: float) -> bool:
    import select

    return bool(select.select([f], [], [], timeout)[0])
