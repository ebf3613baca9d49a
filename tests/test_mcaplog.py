"""MCAP logging: schemas, log_time, flush, rotation, thread safety, truncated files."""

from __future__ import annotations

import json
import math
import shutil
import threading
import warnings
from pathlib import Path

import pytest
from mcap.reader import make_reader

from service.log import (
    CorruptChunkWarning,
    LogReadStats,
    McapLogger,
    TruncatedLogWarning,
    read_log,
    read_log_files,
    rotated_files,
)
from service.zenoh_util import wait_until

MEAS = "/fleet/AC001/elevator_L/meas"
RES = "/fleet/AC001/elevator_L/residual"


def _meas(k: int) -> dict:
    return {"seq": k, "t": 100.0 + k * 1e-3, "x_j": 1e-5 * k, "p1": 1.2e7 + k, "x_s": None}


def _write(path: Path, n: int, **kw) -> McapLogger:
    lg = McapLogger(path, **kw)
    for k in range(n):
        m = _meas(k)
        lg.log(MEAS, m["t"], m)
        if k % 10 == 0:
            lg.log(RES, m["t"], {"r_p12": 0.5 * k, "nis": 1.0, "alarm": k > 500})
    return lg


def test_round_trip_with_mcap_reader(tmp_path):
    p = tmp_path / "a.mcap"
    with _write(p, 1000) as lg:
        pass
    assert lg.paths == [p]
    with open(p, "rb") as f:
        r = make_reader(f)
        summary = r.get_summary()
        assert summary.statistics.message_count == 1100
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == {"meas", "residual"}
        assert all(s.encoding == "jsonschema" for s in schemas.values())
        sch = json.loads(schemas["meas"].data)
        assert sch["properties"]["seq"] == {"type": "integer"}
        assert sch["properties"]["p1"]["type"] == ["number", "null"]
        assert json.loads(schemas["residual"].data)["properties"]["alarm"] == {"type": "boolean"}
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        msgs = [(c.topic, m.log_time, json.loads(m.data)) for _, c, m in r.iter_messages()]
    meas = [m for m in msgs if m[0] == MEAS]
    assert len(meas) == 1000
    assert meas[7][1] == round((100.0 + 7e-3) * 1e9)  # log_time = sample time [ns]
    assert meas[7][2] == _meas(7)
    ours = list(read_log(p))
    assert [(t, m) for t, _, m in ours] == [(t, m) for t, _, m in msgs]
    assert ours[0][1] == pytest.approx(100.0, abs=1e-9)
    assert [m for _, _, m in read_log(p, topics=[RES])] == [m for t, _, m in msgs if t == RES]


def test_non_finite_written_as_null(tmp_path):
    p = tmp_path / "nan.mcap"
    with McapLogger(p) as lg:
        lg.log(RES, 1.0, {"a": float("nan"), "b": float("inf"), "c": 2.0})
    assert list(read_log(p)) == [(RES, 1.0, {"a": None, "b": None, "c": 2.0})]


def test_close_idempotent_and_log_after_close_refused(tmp_path):
    lg = _write(tmp_path / "c.mcap", 10)
    lg.close()
    lg.close()
    assert lg.closed
    with pytest.raises(ValueError):
        lg.log(MEAS, 1.0, {"x": 1})


def test_flush_makes_data_readable_before_close(tmp_path):
    p = tmp_path / "f.mcap"
    lg = _write(p, 300, background_flush=False)
    lg.flush()
    cp = tmp_path / "copy.mcap"
    shutil.copyfile(p, cp)
    with pytest.warns(TruncatedLogWarning):
        got = [m for t, _, m in read_log(cp) if t == MEAS]
    assert got == [_meas(k) for k in range(300)]
    lg.close()


def test_background_flush_without_further_logging(tmp_path):
    p = tmp_path / "bg.mcap"
    lg = _write(p, 200, flush_s=0.2)
    cp = tmp_path / "copy.mcap"

    def readable() -> bool:
        shutil.copyfile(p, cp)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TruncatedLogWarning)
            return sum(1 for t, _, _ in read_log(cp) if t == MEAS) == 200

    assert wait_until(readable, timeout=10, interval=0.05)
    assert lg.flush_count >= 1
    lg.close()


def test_rotation_by_size(tmp_path):
    base = tmp_path / "rot.mcap"
    lg = _write(base, 6000, rotate_bytes=20_000, chunk_size=4096, background_flush=False)
    lg.close()
    assert len(lg.paths) >= 3
    assert all(p.name.startswith("rot-") and p.suffix == ".mcap" for p in lg.paths)
    assert rotated_files(base) == sorted(lg.paths)
    got = [m for t, _, m in read_log_files(lg.paths) if t == MEAS]
    assert got == [_meas(k) for k in range(6000)]
    for p in lg.paths:  # every file is complete and carries its own schemas
        with open(p, "rb") as f:
            s = make_reader(f).get_summary()
            assert s is not None and s.schemas


def test_rotation_by_time(tmp_path):
    base = tmp_path / "rt.mcap"
    lg = McapLogger(base, rotate_s=0.2, flush_s=0.1)
    k = 0
    while len(lg.paths) < 2 and k < 10_000_000:
        lg.log(MEAS, 1.0 + k * 1e-3, _meas(k))
        k += 1
        if k % 1000 == 0:
            wait_until(lambda: False, timeout=0.01)
    lg.close()
    assert len(lg.paths) >= 2
    assert sum(1 for _ in read_log_files(lg.paths)) == k


def test_thread_safe_log(tmp_path):
    p = tmp_path / "th.mcap"
    lg = McapLogger(p, chunk_size=8192, flush_s=0.05)

    def work(j: int) -> None:
        for k in range(2000):
            lg.log(f"/fleet/AC00{j}/a/meas", k * 1e-3, {"seq": k, "j": j})

    ths = [threading.Thread(target=work, args=(j,)) for j in range(4)]
    for t in ths:
        t.start()
    for t in ths:
        t.join()
    lg.close()
    per: dict[str, list[int]] = {}
    for topic, _, m in read_log(p):
        per.setdefault(topic, []).append(m["seq"])
    assert len(per) == 4
    assert all(v == list(range(2000)) for v in per.values())


def test_truncated_file_yields_complete_chunks_and_warns(tmp_path):
    p = tmp_path / "full.mcap"
    with _write(p, 5000, chunk_size=8192, background_flush=False):
        pass
    full = list(read_log(p))
    size = p.stat().st_size
    prev = -1
    for cut in (0, 7, 100, size // 4, size // 2, (3 * size) // 4, size - 40, size - 1):
        q = tmp_path / f"cut{cut}.mcap"
        shutil.copyfile(p, q)
        with open(q, "r+b") as f:
            f.truncate(cut)
        st = LogReadStats()
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            got = list(read_log(q, stats=st))
        assert len([x for x in w if issubclass(x.category, TruncatedLogWarning)]) == 1
        assert st.truncated
        assert got == full[: len(got)]  # a prefix, in order, nothing invented
        assert len(got) >= prev
        prev = len(got)
        if cut >= size // 2:
            assert len(got) >= len(full) // 3
    # the data section is complete before the summary: a cut inside the summary loses nothing
    assert prev == len(full)


def test_corrupt_chunk_is_skipped_and_the_chunks_after_it_read(tmp_path):
    p = tmp_path / "x.mcap"
    with _write(p, 3000, chunk_size=8192, background_flush=False, compression="none"):
        pass
    full = list(read_log(p))
    with open(p, "rb") as f:
        idx = sorted(make_reader(f).get_summary().chunk_indexes,
                     key=lambda c: c.chunk_start_offset)  # fmt: skip
    ci = idx[len(idx) // 2]
    data = bytearray(p.read_bytes())
    data[ci.chunk_start_offset + ci.chunk_length // 2] ^= 0xFF  # a byte of its data: bad CRC
    q = tmp_path / "y.mcap"
    q.write_bytes(bytes(data))
    st = LogReadStats()
    with pytest.warns(CorruptChunkWarning, match="skipped 1 corrupt chunk"):
        got = list(read_log(q, stats=st))
    assert st.corrupt == 1 and st.chunks == len(idx) - 1 and not st.truncated
    # every message but those of the one chunk, in order: the log's end is read
    assert 0 < len(full) - len(got) < len(full) // 3 and got[-1] == full[-1]
    k = next(i for i, (a, b) in enumerate(zip(got, full, strict=False)) if a != b)
    assert got[k:] == full[len(full) - len(got) + k :] and got[:k] == full[:k]


_WRITER = """
import sys, time
sys.path.insert(0, {root!r})
from service.log import McapLogger
lg = McapLogger({path!r}, flush_s=0.5)
k = 0
t0 = time.time()
while True:
    t = time.time()
    lg.log("/fleet/AC001/elevator_L/meas", t, {{"seq": k, "t": t}})
    k += 1
    if k % 50 == 0:
        print(k, t, flush=True)
    time.sleep(0.001)
"""


@pytest.mark.slow
def test_kill_9_loses_at_most_about_one_flush_period(tmp_path):
    """A writer killed with SIGKILL leaves every chunk flushed up to ~flush_s before."""
    import subprocess
    import sys

    root = str(Path(__file__).resolve().parent.parent)
    p = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", _WRITER.format(root=root, path=str(p))],
        stdout=subprocess.PIPE,
        text=True,
    )
    last = None
    try:
        assert proc.stdout is not None
        t_end = None
        for line in proc.stdout:
            k, t = line.split()
            last = (int(k), float(t))
            if t_end is None:
                t_end = float(t) + 2.5
            if float(t) >= t_end:
                break
    finally:
        proc.kill()
        proc.wait(10)
    assert last is not None
    st = LogReadStats()
    with pytest.warns(TruncatedLogWarning):
        got = list(read_log(p, stats=st))
    seqs = [m["seq"] for _, _, m in got]
    assert seqs == list(range(len(seqs)))  # a gapless prefix
    assert len(seqs) > 0
    lost_s = last[1] - got[-1][2]["t"]
    assert lost_s <= 0.5 + 1.0  # flush_s plus scheduling slack


def test_block_writer_writes_the_same_bytes_as_mcap_writer():
    import io
    import random

    from mcap.writer import CompressionType, Writer

    from service.compat.mcap import BlockWriter

    def run(cls) -> bytes:
        b = io.BytesIO()
        w = cls(b, chunk_size=4000, compression=CompressionType.ZSTD)
        w.start()
        s = w.register_schema("a", "jsonschema", b"{}")
        c1 = w.register_channel("x", "json", s)
        c2 = w.register_channel("y", "json", s)
        r = random.Random(1)
        for k in range(3000):  # out-of-order times, two channels, explicit flushes
            w.add_message(c1 if k % 3 else c2, 10**9 + r.randrange(10**6), b"{}" * k, 7, k)
            if k % 700 == 0:
                w.flush()
        w.finish()
        return b.getvalue()

    assert run(BlockWriter) == run(Writer)


def test_log_many_equals_log(tmp_path):
    recs = [(MEAS, _meas(k)["t"], _meas(k)) for k in range(100)]
    with McapLogger(tmp_path / "a.mcap", background_flush=False) as a:
        for r in recs:
            a.log(*r)
    with McapLogger(tmp_path / "b.mcap", background_flush=False) as b:
        b.log_many(recs)
    assert list(read_log(tmp_path / "a.mcap")) == list(read_log(tmp_path / "b.mcap"))


def test_non_json_values_made_safe(tmp_path):
    import numpy as np

    p = tmp_path / "np.mcap"
    with McapLogger(p) as lg:
        lg.log(
            RES,
            1.0,
            {"a": np.float32(1.5), "b": np.int64(3), "c": [1.0, float("nan")], "d": {"x": 1},
             "e": object, "f": np.float64("inf")},
        )  # fmt: skip
    ((_, _, m),) = list(read_log(p))
    assert m["a"] == 1.5 and m["b"] == 3 and m["f"] is None
    assert json.loads(m["c"]) == [1.0, None] and json.loads(m["d"]) == {"x": 1}
    assert isinstance(m["e"], str)


def test_random_corruption_never_raises_and_yields_a_prefix(tmp_path):
    import random

    p = tmp_path / "src.mcap"
    with _write(p, 600, chunk_size=2048, background_flush=False):
        pass
    full = list(read_log(p))
    data = p.read_bytes()
    rng = random.Random(5)
    q = tmp_path / "fuzz.mcap"
    for _ in range(150):
        b = bytearray(data)
        for _ in range(rng.randint(1, 3)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        if rng.random() < 0.3:
            b = b[: rng.randrange(len(b))]
        q.write_bytes(bytes(b))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TruncatedLogWarning)
            warnings.simplefilter("ignore", CorruptChunkWarning)
            got = list(read_log(q))
        it = iter(full)  # what is read is the log's messages in order, a corrupt chunk's left out
        assert all(any(g == f for f in it) for g in got)


def test_read_log_match_filters_topics(tmp_path):
    p = tmp_path / "m.mcap"
    with _write(p, 50):
        pass
    got = list(read_log(p, match=lambda t: t.endswith("/residual")))
    assert len(got) == 5 and {t for t, _, _ in got} == {RES}
    assert list(read_log(p, topics=[MEAS], match=lambda t: t.endswith("/residual"))) == []


def test_zstd_level_is_per_writer(tmp_path):
    """McapLogger compresses its chunks at ``zstd_level`` (default 1, about twice as fast as
    zstd's default 3 on these logs); a plain mcap Writer in the same process keeps zstd's
    default level; both read back the same messages."""
    import zstandard
    from mcap.reader import make_reader
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    msgs = [{"a": k * 1e-3, "b": math.sin(k * 0.01), "seq": k} for k in range(3000)]

    def chunks(p):
        with open(p, "rb") as fh:
            return [r for r in StreamReader(fh, emit_chunks=True).records if isinstance(r, Chunk)]

    sizes = {}
    for lvl in (1, 3):
        p = tmp_path / f"l{lvl}.mcap"
        with McapLogger(p, zstd_level=lvl, background_flush=False) as lg:
            for d in msgs:
                lg.log("/t", d["a"], d)
        (c,) = chunks(p)
        raw = zstandard.ZstdDecompressor().decompress(c.data, max_output_size=c.uncompressed_size)
        assert c.data == zstandard.compress(raw, lvl)
        sizes[lvl] = p.stat().st_size
        assert [m for _, _, m in read_log(p)] == msgs
    assert sizes[1] != sizes[3]
    plain = tmp_path / "plain.mcap"
    with open(plain, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start()
        sid = w.register_schema("s", "jsonschema", b"{}")
        cid = w.register_channel("/t", "json", sid)
        w.add_message(cid, 1, b'{"a":1}', 1)
        w.finish()
    (c,) = chunks(plain)
    raw = zstandard.ZstdDecompressor().decompress(c.data, max_output_size=c.uncompressed_size)
    assert c.data == zstandard.compress(raw)  # the library's default level
    with open(plain, "rb") as fh:
        assert len(list(make_reader(fh).iter_messages())) == 1
