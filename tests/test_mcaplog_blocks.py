"""Block MCAP I/O: log_block writes protobuf rows that stock readers and read_blocks read back
bit for bit, read_blocks reads what read_log reads (protobuf and JSON), the compiled JSON
number parser matches float(), truncated files."""

from __future__ import annotations

import io
import json
import math
import random
import threading
import time
import warnings
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from service.compat.mcap import BlockWriter
from service.log import (
    CorruptChunkWarning,
    LogBlock,
    LogReadStats,
    McapLogger,
    TruncatedLogWarning,
    read_blocks,
    read_log,
)
from service.log import codec as logcodec

MEAS = "/fleet/AC001/elevator_L/meas"
EST = "/fleet/AC001/elevator_L/est"
RES = "/fleet/AC001/elevator_L/residual"
MEAS_NAMES = ("seq", "t", "x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr")
QUIET = {"background_flush": False, "flush_s": 1e9}  # no time-based flush: same chunks


def _bits(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, np.float64).view(np.uint64)


def assert_same_floats(a: np.ndarray, b: np.ndarray) -> None:
    """Equal bit for bit, except that any NaN equals any NaN."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    assert a.shape == b.shape
    na, nb = np.isnan(a), np.isnan(b)
    assert np.array_equal(na, nb)
    assert np.array_equal(_bits(np.where(na, 0.0, a)), _bits(np.where(nb, 0.0, b)))


def _as_float(v) -> float:
    if isinstance(v, bool | int | float):
        return float(v)
    return math.nan


def _hard_values(rng: np.random.Generator, n: int, f: int) -> np.ndarray:
    """Random doubles of all kinds: 17 significant digits, all exponents, subnormals, -0.0,
    1e-300, integers, non-finite."""
    v = rng.normal(size=(n, f)) * 10.0 ** rng.integers(-12, 12, size=(n, f))
    bits = rng.integers(0, 2**64, size=(n, f), dtype=np.uint64).view(np.float64)
    pick = rng.random((n, f))
    v = np.where(pick < 0.2, bits, v)
    with np.errstate(invalid="ignore"):
        v = np.where((pick > 0.2) & (pick < 0.3), np.round(v), v)
    specials = np.array(
        [0.0, -0.0, 1e-300, -1e-300, 5e-324, 2.2250738585072014e-308, 1.7976931348623157e308,
         1e16, 1e15, 9007199254740993.0, 0.1, 1 / 3, 123456789.12345678, 1e-5, 1e-4,
         np.nan, np.inf, -np.inf]
    )  # fmt: skip
    idx = rng.integers(0, specials.size, size=(n, f))
    v = np.where(pick > 0.9, specials[idx], v)
    return v


# --------------------------------------------------------------------- writing


def _stock_rows(path: Path, topics=None) -> dict[str, list[tuple[int, int, list]]]:
    """topic -> [(log_time, sequence, [field values])] as mcap-protobuf-support decodes the
    file (the stock reader; integer fields as int)."""
    from mcap_protobuf.decoder import DecoderFactory

    out: dict[str, list[tuple[int, int, list]]] = {}
    with open(path, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, ch, msg, row in r.iter_decoded_messages(topics=topics, log_time_order=False):
            vals = [getattr(row, fd.name) for fd in row.DESCRIPTOR.fields]
            out.setdefault(ch.topic, []).append((msg.log_time, msg.sequence, vals))
    return out


def _expected(vals: np.ndarray, ints: list[int]) -> list[list]:
    """What a row of ``vals`` decodes to: doubles as written, integer fields truncated."""
    rows = vals.tolist()
    for r in rows:
        for k in ints:
            r[k] = int(r[k])
    return rows


def _same_rows(got: list[list], exp: list[list]) -> None:
    assert len(got) == len(exp)
    for g, e in zip(got, exp, strict=True):
        assert [type(x) for x in g] == [type(x) for x in e]
        assert_same_floats([float(x) for x in g], [float(x) for x in e])
        assert [x for x in g if isinstance(x, int)] == [x for x in e if isinstance(x, int)]


def test_log_block_rows_read_back_bit_exact_by_stock_and_own_readers(tmp_path):
    rng = np.random.default_rng(1)
    n = 1500
    t = 100.0 + np.arange(n) * 1e-3
    meas = _hard_values(rng, n, len(MEAS_NAMES))
    meas[:, 0] = np.arange(n) * 3 - 7.9  # negative and fractional -> truncated like int()
    meas[:, 1] = t
    est_names = ("seq", "t", *(f"x{k}" for k in range(16)))  # tags of 2 bytes from field 16
    est = _hard_values(rng, n, len(est_names))
    est[:, 0] = rng.integers(-(2**62), 2**62, size=n).astype(np.float64)
    est[:, 1] = t
    p = tmp_path / "rows.mcap"
    cuts = [0, 1, 7, 300, 301, 999, n]  # blocks of several sizes, chunks of 16 kB
    with McapLogger(p, chunk_size=1 << 14, **QUIET) as lg:
        for k0, k1 in zip(cuts[:-1], cuts[1:], strict=True):
            lg.log_block(MEAS, t[k0:k1], MEAS_NAMES, meas[k0:k1], int_fields=("seq",))
            lg.log_block(EST, t[k0:k1], list(est_names), est[k0:k1], int_fields={"seq"})
        assert lg.message_count == 2 * n
    stock = _stock_rows(p)
    for topic, vals in ((MEAS, meas), (EST, est)):
        assert [x[1] for x in stock[topic]] == list(range(n))
        _same_rows([x[2] for x in stock[topic]], _expected(vals, [0]))
        blocks = [b for b in read_blocks(p, topics=[topic])]
        assert len(blocks) > 5 and {b.names for b in blocks} == {
            MEAS_NAMES if topic == MEAS else est_names
        }
        got = np.concatenate([b.values for b in blocks])
        exp = vals.copy()
        exp[:, 0] = np.trunc(exp[:, 0])
        assert_same_floats(got, exp)
    with open(p, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.chunk_count > 5
    assert {s.name for s in summary.schemas.values()} == {"servowatch.Meas", "servowatch.Est"}


def test_log_rows_of_many_topics_equal_log_block_per_topic(tmp_path):
    rng = np.random.default_rng(11)
    topics = [f"/fleet/AC{k:03d}/a/meas" for k in range(5)]
    a, b = tmp_path / "block.mcap", tmp_path / "rows.mcap"
    ticks = []
    for k in range(40):
        counts = rng.integers(0, 12, size=len(topics))
        t = 5.0 + k * 0.01 + np.arange(counts.sum()) * 1e-6
        v = _hard_values(rng, counts.sum(), len(MEAS_NAMES))
        v[:, 0] = rng.integers(0, 10**6, size=counts.sum())
        ticks.append((counts, t, v))
    with McapLogger(a, chunk_size=1 << 13, **QUIET) as lg:
        for counts, t, v in ticks:
            j = 0
            for tp, c in zip(topics, counts.tolist(), strict=True):
                lg.log_block(tp, t[j : j + c], MEAS_NAMES, v[j : j + c], int_fields=("seq",))
                j += c
    with McapLogger(b, chunk_size=1 << 13, **QUIET) as lg:
        for counts, t, v in ticks:
            lg.log_rows(topics, counts, t, MEAS_NAMES, v, int_fields=("seq",))
    ra, rb = _messages(a), _messages(b)
    assert set(ra) == set(topics) and ra == rb  # log times, sequences, bytes per topic


def _messages(path: Path) -> dict[str, list[tuple[int, int, int, bytes]]]:
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(ch.topic, []).append((m.log_time, m.publish_time, m.sequence, m.data))
    return out


def test_log_block_refuses_integer_fields_it_cannot_write_and_goes_on(tmp_path):
    names = ("seq", "a")
    p = tmp_path / "x.mcap"
    with McapLogger(p, **QUIET) as lg:
        for bad in (np.nan, np.inf, 2.0**63, -(2.0**64)):
            with pytest.raises(ValueError, match="seq"):
                lg.log_block(
                    MEAS, np.array([1.0]), names, np.array([[bad, 1.0]]), int_fields=["seq"]
                )
        with pytest.raises(ValueError, match="identifier"):
            lg.log_block(MEAS, np.array([1.0]), ("a-b",), np.ones((1, 1)))
        assert lg.failure is None and lg.message_count == 0
        lg.log_block(
            MEAS, np.array([1.0]), names, np.array([[-(2.0**63), np.nan]]), int_fields=["seq"]
        )
    assert list(read_log(p)) == [(MEAS, 1.0, {"seq": -(2**63), "a": None})]


def test_log_block_times_sequences_and_official_reader(tmp_path):
    rng = np.random.default_rng(2)
    n = 3000
    t = 1.7e9 + np.arange(n) * 1e-3 + rng.uniform(0, 1e-4, n)
    t[5] = -1.0  # negative times clamp to 0 like log()
    vals = _hard_values(rng, n, 9)
    vals[:, 0] = np.arange(n)
    p = tmp_path / "b.mcap"
    with McapLogger(p, **QUIET) as lg:
        lg.log_block(MEAS, t[:10], MEAS_NAMES, vals[:10], int_fields=("seq",))
        lg.log_block(MEAS, t[10:11], MEAS_NAMES, vals[10:11], int_fields=("seq",))
        lg.log_block(MEAS, t[11:], MEAS_NAMES, vals[11:], int_fields=("seq",))
    with open(p, "rb") as f:
        r = make_reader(f)
        summary = r.get_summary()
        assert summary.statistics.message_count == n
        (ch,) = summary.channels.values()
        assert ch.message_encoding == "protobuf" and ch.topic == MEAS
        sch = summary.schemas[ch.schema_id]
        assert (sch.name, sch.encoding) == ("servowatch.Meas", "protobuf")
        msgs = list(r.iter_messages(log_time_order=False))
    assert [m.sequence for _, _, m in msgs] == list(range(n))
    assert [m.log_time for _, _, m in msgs] == [max(0, int(round(x * 1e9))) for x in t.tolist()]
    assert all(m.publish_time == m.log_time for _, _, m in msgs)
    assert {len(m.data) for _, _, m in msgs} == {9 * 9}  # tag + 8 bytes per field, zeros too
    _same_rows([x[2] for x in _stock_rows(p)[MEAS]], _expected(vals, [0]))


def test_add_rows_same_bytes_as_add_message():
    rng = np.random.default_rng(3)
    size = 27
    datas = rng.integers(0, 256, size=(800, size), dtype=np.uint8)
    lts = np.array(sorted(rng.integers(0, 2**62, size=800).tolist()), np.int64)
    chans = rng.integers(0, 2, size=800)

    def write(bulk: bool) -> bytes:
        out = io.BytesIO()
        w = BlockWriter(out, chunk_size=4096, compression=CompressionType.ZSTD)
        w.start()
        sid = w.register_schema("s", "protobuf", b"")
        cid = [w.register_channel("/a", "protobuf", sid), w.register_channel("/b", "protobuf", sid)]
        for k0 in range(0, 800, 100):
            part = np.arange(k0, k0 + 100)
            c = np.array(cid)[chans[part]] if k0 % 200 else np.full(100, cid[0])
            if bulk:
                recs = np.empty((100, 31 + size), np.uint8)
                hdr = np.zeros(100, [("op", "u1"), ("len", "<u8"), ("cid", "<u2"),
                                     ("seq", "<u4"), ("lt", "<u8"), ("pt", "<u8")])  # fmt: skip
                hdr["op"], hdr["len"], hdr["cid"], hdr["seq"] = 5, 22 + size, c, part
                hdr["lt"] = hdr["pt"] = lts[part]
                recs[:, :31] = hdr.view(np.uint8).reshape(100, 31)
                recs[:, 31:] = datas[part]
                runs = np.flatnonzero(np.diff(c)) + 1  # runs of one channel
                a, b = [0, *runs.tolist()], [*runs.tolist(), 100]
                w.add_rows(c[a], np.subtract(b, a), lts[part], recs)
            else:
                for k, ck in zip(part.tolist(), c.tolist(), strict=True):
                    w.add_message(ck, int(lts[k]), datas[k].tobytes(), int(lts[k]), k)
        w.finish()
        return out.getvalue()

    ref = io.BytesIO()  # the plain mcap Writer
    w = Writer(ref, chunk_size=4096, compression=CompressionType.ZSTD)
    w.start()
    sid = w.register_schema("s", "protobuf", b"")
    cid = [w.register_channel("/a", "protobuf", sid), w.register_channel("/b", "protobuf", sid)]
    for k0 in range(0, 800, 100):
        for k in range(k0, k0 + 100):
            ck = cid[chans[k]] if k0 % 200 else cid[0]
            w.add_message(ck, int(lts[k]), datas[k].tobytes(), int(lts[k]), k)
    w.finish()
    expected = ref.getvalue()
    assert write(bulk=True) == expected
    assert write(bulk=False) == expected


def test_log_block_rejects_bad_input(tmp_path):
    with McapLogger(tmp_path / "x.mcap", **QUIET) as lg:
        with pytest.raises(ValueError):
            lg.log_block(MEAS, np.zeros(3), ("a", "b"), np.zeros((3, 3)))
        with pytest.raises(ValueError):
            lg.log_block(MEAS, np.zeros(2), ("a", "a"), np.zeros((2, 2)))
        with pytest.raises(ValueError):
            lg.log_block(MEAS, np.array([np.nan]), ("a",), np.zeros((1, 1)))
        lg.log_block(MEAS, np.zeros(0), ("a",), np.zeros((0, 1)))  # nothing to do
        assert lg.message_count == 0
    with pytest.raises(ValueError):
        lg.log_block(MEAS, np.zeros(1), ("a",), np.zeros((1, 1)))


def test_log_block_rotation_flush_and_threads(tmp_path):
    base = tmp_path / "rot.mcap"
    with McapLogger(base, rotate_bytes=20_000, chunk_size=4096, **QUIET) as lg:
        errors = []

        def worker(topic: str) -> None:
            try:
                for k in range(40):
                    t = 10.0 + (k * 25 + np.arange(25)) * 1e-3
                    v = np.column_stack([np.arange(25) + 25 * k, t, np.sin(t)])
                    lg.log_block(topic, t, ("seq", "t", "y"), v, int_fields=("seq",))
            except Exception as e:  # pragma: no cover
                errors.append(e)

        ths = [threading.Thread(target=worker, args=(tp,)) for tp in (MEAS, EST, RES)]
        for th in ths:
            th.start()
        for th in ths:
            th.join()
        assert not errors
    assert len(lg.paths) > 2
    for topic in (MEAS, EST, RES):
        seqs = [m["seq"] for p in lg.paths for tp, _, m in read_log(p) if tp == topic]
        assert seqs == list(range(1000))
    flushed = tmp_path / "flush.mcap"
    lg = McapLogger(flushed, flush_s=0.05, background_flush=False)
    lg.log_block(MEAS, np.array([1.0]), ("a",), np.ones((1, 1)))
    time.sleep(0.06)
    lg.log_block(MEAS, np.array([1.001]), ("a",), np.ones((1, 1)))  # flush due: chunk written
    assert lg.flush_count >= 1 and not lg._dirty
    with pytest.warns(TruncatedLogWarning):
        assert len(list(read_log(flushed))) == 2  # readable before close (no footer yet)
    lg.close()


# --------------------------------------------------------------------- codec


def _check_parse(texts: list[str]) -> int:
    """Texts the compiled parser takes must give exactly float(text); returns how many."""
    got = logcodec.parse_number(texts)
    # json reads "-0" as the int 0: texts without '.', 'e' are ints
    ref = np.array(
        [float(s) if ("." in s or "e" in s or "E" in s) else float(int(s)) for s in texts]
    )
    declined = np.isnan(got) & ~np.isnan(ref)
    for k in np.flatnonzero(declined).tolist():
        digits = texts[k].lstrip("-").replace(".", "").split("e")[0].split("E")[0]
        assert len(digits) > 19, texts[k]  # declined only for more than 19 digits
    taken = ~declined
    bad = np.flatnonzero(taken & (_bits(got) != _bits(ref)))
    assert bad.size == 0, [(texts[k], got[k], ref[k]) for k in bad[:5].tolist()]
    return int(taken.sum())


def test_warm_up_compiles_the_kernels():
    logcodec.warm_up()
    recs = logcodec.json_records([b'{"n":-3,"x":-0.0}', b'{"n":7,"x":null}'], channel_id=3)
    ops, starts, lens, cids, lts = logcodec.scan_records(recs)
    assert ops.tolist() == [5, 5] and cids.tolist() == [3, 3] and lts.tolist() == [0, 1]
    res = logcodec.parse_objects(recs, starts + 22, lens - 22)
    assert res is not None
    assert_same_floats(res[2], [[-3.0, -0.0], [7.0, np.nan]])
    with pytest.raises(ValueError):
        logcodec.scan_records(recs[:-1])


def test_parse_number_is_correctly_rounded():
    rng = np.random.default_rng(5)
    x = rng.integers(0, 2**64, size=1_000_000, dtype=np.uint64).view(np.float64)
    x = x[np.isfinite(x)]
    texts = [repr(v) for v in x.tolist()]
    y = rng.normal(size=200_000) * 10.0 ** rng.integers(-8, 10, size=200_000)
    texts += [repr(v) for v in y.tolist()]
    assert _check_parse(texts) == len(texts)  # every repr is taken (<= 17 digits)

    r = random.Random(6)
    dec = []
    for _ in range(200_000):
        nd = r.randint(1, 19)
        digs = str(r.randint(10 ** (nd - 1), 10**nd - 1))
        e = r.randint(-360, 320)
        k = r.randint(1, nd)
        dec.append(r.choice([f"{digs}e{e}", f"-{digs[:k]}.{digs[k:] or '0'}E{e:+d}", digs]))
    # exact halfway cases between two doubles (round half to even)
    for _ in range(20_000):
        m = r.randint(2**52, 2**53 - 1)
        s = format(Decimal(2 * m + 1) * Decimal(2) ** r.randint(-60, 12), "f")
        if len(s.replace(".", "").strip("0")) <= 19:
            dec.append(s)
    dec += [str(r.randint(0, 10**19 - 1)) for _ in range(100_000)]
    dec += [str(2**53 + 2 * r.randint(0, 2**40) + 1) for _ in range(20_000)]
    dec += ["0", "-0", "0.0", "-0.0", "0e10", "0.0e-999", "1e400", "-1e400", "1e-400",
            "2.2250738585072011e-308", "2.2250738585072012e-308", "4.9406564584124654e-324",
            "2.4703282292062327e-324", "2.4703282292062328e-324", "1.7976931348623158e308",
            "1.7976931348623159e308", "9007199254740993", "1e22", "1e23", "1E5", "1e+05",
            "0.000000000000000000000000000000000001234567890123456789", "1e0000000000000000001",
            "1e-99999999999999999999999", "12345678901234567890", "1.0000000000000000000001"]  # fmt: skip
    assert _check_parse(dec) > 0.99 * len(dec)  # declined: only > 19 digits
    declined = ["00", "1.", ".5", "-", "1e", "1e+", "+1", "NaN", "Infinity", "-Infinity", "01"]
    assert np.isnan(logcodec.parse_number(declined)).all()


# --------------------------------------------------------------------- reading


def _rows_by_topic(blocks: list[LogBlock]) -> dict[str, list[tuple[float, dict]]]:
    out: dict[str, list[tuple[float, dict]]] = {}
    for b in blocks:
        assert b.values.shape == (b.t.size, len(b.names)) and b.values.dtype == np.float64
        for k in range(b.t.size):
            out.setdefault(b.topic, []).append(
                (b.t[k], dict(zip(b.names, b.values[k].tolist(), strict=True)))
            )
    return out


def assert_blocks_equal_read_log(blocks: list[LogBlock], msgs: list[tuple[str, float, dict]]):
    ref: dict[str, list[tuple[float, dict]]] = {}
    for topic, t, m in msgs:
        if isinstance(m, dict):
            ref.setdefault(topic, []).append((t, {k: _as_float(v) for k, v in m.items()}))
    got = _rows_by_topic(blocks)
    assert set(got) == set(ref)
    for topic in ref:
        assert len(got[topic]) == len(ref[topic]), topic
        assert_same_floats([t for t, _ in got[topic]], [t for t, _ in ref[topic]])
        for (_, g), (_, r) in zip(got[topic], ref[topic], strict=True):
            assert list(g) == list(r)
            assert_same_floats(list(g.values()), list(r.values()))


def test_read_blocks_round_trip_bit_exact(tmp_path):
    rng = np.random.default_rng(7)
    n = 5000
    t = 1.7e9 + np.arange(n) * 1e-3 + rng.uniform(0, 1e-6, n)  # epoch times: ns > 2**53
    vals = _hard_values(rng, n, 12)
    vals[:, 0] = rng.integers(-(2**62), 2**62, size=n).astype(np.float64)
    vals[:, 1] = t
    names = ("seq", "t", *(f"v{k}" for k in range(10)))
    p = tmp_path / "rt.mcap"
    with McapLogger(p, chunk_size=1 << 16, **QUIET) as lg:
        lg.log_block(MEAS, t, names, vals, int_fields=("seq",))
    st = LogReadStats()
    blocks = list(read_blocks(p, stats=st))
    assert len(blocks) == st.chunks > 3 and st.messages == n and not st.truncated
    assert all(b.names == names and b.topic == MEAS for b in blocks)
    got = np.concatenate([b.values for b in blocks])
    expect = vals.copy()  # protobuf doubles as written, NaN and inf too
    expect[:, 0] = np.trunc(vals[:, 0])
    assert_same_floats(got, expect)
    assert_same_floats(np.concatenate([b.t for b in blocks]), [x for _, x, _ in read_log(p)])
    assert_blocks_equal_read_log(blocks, list(read_log(p)))


def _mixed_log(path: Path, n: int = 2000, **kw) -> None:
    """Interleaved topics written with log(): ints, bools, nulls, a string field, a topic
    whose keys change midway, nested values."""
    rng = np.random.default_rng(8)
    with McapLogger(path, **{**QUIET, **kw}) as lg:
        for k in range(n):
            t = 10.0 + k * 1e-3
            x = rng.normal(size=4) * 10.0 ** rng.integers(-9, 9, size=4)
            lg.log(
                MEAS,
                t,
                {"seq": k, "t": t, "p1": float(x[0]), "x_s": None if k % 13 == 0 else float(x[1])},
            )
            if k % 3 == 0:
                lg.log(RES, t, {"r": float(x[2]), "nis": 1e-300, "alarm": k > n // 2})
            if k % 5 == 0:
                st = {"state": "ok" if k % 2 else "degraded", "score": float(x[3]), "n": k}
                if k > n // 2:
                    st["extra"] = -0.0
                lg.log("/fleet/AC001/elevator_L/health", t, st)
            if k % 400 == 0:
                lg.log(
                    "/fleet/AC001/elevator_L/event",
                    t,
                    {"kind": "note", "data": [1, 2], "d": {"a": 1}},
                )
    # fmt: skip


def test_read_blocks_equals_read_log_mixed_topics(tmp_path):
    p = tmp_path / "mixed.mcap"
    _mixed_log(p, chunk_size=1 << 14)
    msgs = list(read_log(p))
    blocks = list(read_blocks(p))
    assert_blocks_equal_read_log(blocks, msgs)
    health = [b for b in blocks if b.topic.endswith("health")]
    assert {b.names for b in health} == {("state", "score", "n"), ("state", "score", "n", "extra")}
    assert all(np.isnan(b.values[:, 0]).all() for b in health)  # strings -> NaN
    res = [b for b in blocks if b.topic == RES]
    assert res[-1].values[-1, 2] == 1.0 and res[0].values[0, 2] == 0.0  # booleans -> 1/0
    # filters as read_log
    only = list(read_blocks(p, topics=[RES]))
    assert {b.topic for b in only} == {RES}
    assert_blocks_equal_read_log(only, [m for m in msgs if m[0] == RES])
    matched = list(read_blocks(p, match=lambda tp: tp.endswith("meas")))
    assert {b.topic for b in matched} == {MEAS}


def test_read_blocks_order_within_chunk(tmp_path):
    p = tmp_path / "order.mcap"
    with McapLogger(p, **QUIET) as lg:
        lg.log(RES, 1.0, {"a": 1.0})
        for k in range(10):
            lg.log(MEAS, 2.0 + k, {"k": k})
            lg.log(EST, 2.0 + k, {"k": k})
            lg.log(RES, 2.0 + k, {"a": float(k)})
    blocks = list(read_blocks(p))
    assert [b.topic for b in blocks] == [RES, MEAS, EST]  # order of first message
    assert blocks[0].values[:, 0].tolist() == [1.0, *map(float, range(10))]
    assert blocks[1].t.tolist() == [2.0 + k for k in range(10)]


def test_read_blocks_json_fallbacks(tmp_path):
    """Messages the compiled parser declines come out as json.loads reads them."""
    p = tmp_path / "odd.mcap"
    datas = [
        b'{"a": 1.5 , "b" :\n2}',  # whitespace: still the fast path
        b'{"a":1.5,"b":2}',
        b'{"a":123456789012345678901234567890,"b":1e999}',  # > 19 digits
        b'{"a":NaN,"b":-Infinity}',
        b'{"a":"x\\"y","b":true}',  # escape in a string
        b'{"a\\u0062":1,"b":2}',  # escape in a key
        b'{"a":{"n":1},"b":[1]}',
        b'{"a":1,"a":2}',  # duplicate key: json keeps the last
        b"[1,2]",  # not an object: skipped
        b'{"a":1,"b":2',  # not JSON: skipped
        b'{"a":-0,"b":-0.0}',
        b"{}",
        b'{"\xc3\xa9":1}',  # UTF-8 key
    ]
    with open(p, "wb") as f:
        w = Writer(f, chunk_size=1 << 20)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel("/odd", "json", sid)
        cid2 = w.register_channel("/ok", "json", sid)
        for k, d in enumerate(datas):
            w.add_message(cid, k * 1000, d, k * 1000, k)
            w.add_message(cid2, k * 1000, b'{"x":%d}' % k, k * 1000, k)
        w.finish()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        blocks = list(read_blocks(p))
        msgs = list(read_log(p))
    assert_blocks_equal_read_log(blocks, msgs)
    ok = [b for b in blocks if b.topic == "/ok"]
    assert len(ok) == 1 and ok[0].values[:, 0].tolist() == list(range(len(datas)))


def test_read_blocks_unchunked_file(tmp_path):
    p = tmp_path / "plain.mcap"
    with open(p, "wb") as f:
        w = Writer(f, use_chunking=False)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        ca = w.register_channel("/a", "json", sid)
        cb = w.register_channel("/b", "json", sid)
        for k in range(50):
            w.add_message(ca, k, json.dumps({"k": k, "v": k / 7}).encode(), k, k)
            if k % 2:
                w.add_message(cb, k, json.dumps({"z": None}).encode(), k, k)
        w.finish()
    blocks = list(read_blocks(p))
    assert [b.topic for b in blocks] == ["/a", "/b"]
    assert_blocks_equal_read_log(blocks, list(read_log(p)))


def test_read_blocks_truncated_file(tmp_path):
    full = tmp_path / "full.mcap"
    _mixed_log(full, n=3000, chunk_size=1 << 13)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    rng = np.random.default_rng(9)
    points = [0, 5, 8, 40, len(data) // 3, len(data) // 2, len(data) - 30, len(data) - 1]
    points += rng.integers(0, len(data), size=12).tolist()
    for n in points:
        cut.write_bytes(data[:n])
        st_log, st_blk = LogReadStats(), LogReadStats()
        with pytest.warns(TruncatedLogWarning):
            msgs = list(read_log(cut, stats=st_log))
        with pytest.warns(TruncatedLogWarning) as rec:
            blocks = list(read_blocks(cut, stats=st_blk))
        assert len(rec) == 1
        assert st_blk.truncated and st_blk.chunks == st_log.chunks, n
        assert st_blk.messages == st_log.messages - sum(
            1 for *_, m in msgs if not isinstance(m, dict)
        )
        assert_blocks_equal_read_log(blocks, msgs)
    # a corrupt byte inside a chunk: that chunk skipped, with a warning, the others read
    with open(full, "rb") as f:
        chunks = sorted(
            make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset
        )
    bad = bytearray(data)
    bad[chunks[len(chunks) // 2].chunk_start_offset + 200] ^= 0xFF  # inside the compressed data
    cut.write_bytes(bytes(bad))
    with pytest.warns(CorruptChunkWarning):
        msgs = list(read_log(cut))
    with pytest.warns(CorruptChunkWarning):
        blocks = list(read_blocks(cut))
    assert_blocks_equal_read_log(blocks, msgs)
    assert msgs[-1] == list(read_log(full))[-1]


def test_read_blocks_of_complete_file_does_not_warn(tmp_path):
    p = tmp_path / "ok.mcap"
    _mixed_log(p, n=300)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        st = LogReadStats()
        blocks = list(read_blocks(p, stats=st))
    assert st.footer and not st.truncated and st.messages == sum(b.t.size for b in blocks)


def test_read_blocks_reads_ahead_in_order_and_stops_its_helper(tmp_path):
    """Chunks are decompressed one ahead in a helper thread: the blocks still come in file
    order, and the helper stops when the reader is closed early or runs to the end."""
    p = tmp_path / "many.mcap"
    with McapLogger(p, background_flush=False) as lg:
        for c in range(12):  # 12 chunks of 50 messages
            for i in range(50):
                k = 50 * c + i
                lg.log("/a", 1.0 + k * 1e-3, {"k": k, "v": 0.5 * k})
            lg.flush()
    ks = np.concatenate([b.values[:, b.names.index("k")] for b in read_blocks(p)])
    assert ks.tolist() == list(range(600))

    def helpers() -> int:
        return sum(t.name.startswith("mcap-read") for t in threading.enumerate())

    def settle() -> int:  # a closed reader's helper exits asynchronously
        deadline = time.monotonic() + 5.0
        while helpers() and time.monotonic() < deadline:
            time.sleep(0.01)
        return helpers()

    assert settle() == 0  # no reader of the read above (nor of another test) left running
    it = read_blocks(p)
    next(it)
    assert helpers() == 1
    it.close()
    assert settle() == 0
