"""MCAP log I/O speed: per-message ``McapLogger.log`` vs ``log_block``, ``read_log`` vs
``read_blocks`` (numba kernels of service.log.codec; timed warm, after one call compiled them
or loaded their cache).

Writes a 1 kHz meas log (9 fields: seq, t, x_cmd, i, x_s, x_j, p1, p2, p_sr; about 5 % nulls)
and an 18-field est log, each with ``log`` (dict per sample) and with ``log_block`` (one
array), checks the files are byte-identical, then reads the meas log both ways and checks
the values are bit-identical. Prints microseconds per message (best of ``--repeat``), all-in
(logger open, writes, close). The zstd compression of the chunks (level 3, as the mcap writer
does) is the same work for both write paths; it is timed on its own and the writes are also
timed with ``compression="none"`` to show the rest.

Beside the compiled codec (``service.log.codec``), the libraries one would take instead (the
``bench`` extra installs them): msgspec and orjson encoding the same rows (from dicts; neither
writes ``float.__repr__`` text exactly, e.g. ``1e16`` for Python's ``1e+16``, so their files
would not be byte-identical with ``log``) and parsing the same messages (to dicts; the codec
parses to the (N, F) array the replay uses), and a whole log path built from msgspec and the
stock ``mcap.writer.Writer`` (arrays -> dicts -> msgspec -> ``add_message``) beside
``log_block``.

    .venv/bin/python bench/logio.py [--samples 4000] [--repeat 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zstandard
from mcap.records import Chunk
from mcap.stream_reader import StreamReader

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import service.log.reader as log_reader  # noqa: E402
from service.log import McapLogger, codec, read_blocks, read_log  # noqa: E402

MEAS = "/fleet/AC001/elevator_L/meas"
EST = "/fleet/AC001/elevator_L/est"
MEAS_NAMES = ("seq", "t", "x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr")
EST_NAMES = (
    ("seq", "t")
    + tuple(f"x{k}" for k in range(7))
    + ("nis", "beta", "leak", "fric", "r_p12", "r_x", "sd_p1", "sd_p2", "sd_x")
)


def signals(n: int, names: tuple[str, ...], seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Sample times (1 kHz from t=1000 s) and a (n, F) array of smooth noisy signals with
    the magnitudes of the service's fields (full 17-digit doubles); ~5 % nulls (NaN)."""
    rng = np.random.default_rng(seed)
    t = 1000.0 + np.arange(n) * 1e-3
    scale = 10.0 ** rng.integers(-5, 8, size=len(names))
    phase = rng.uniform(0, 2 * np.pi, size=len(names))
    v = scale * (np.sin(2 * np.pi * 3.0 * t[:, None] + phase) + 0.01 * rng.normal(size=(n, 1)))
    v[:, 0] = np.arange(n)
    v[:, 1] = t
    nulls = rng.random((n, len(names))) < 0.05
    nulls[:, :2] = False
    v[nulls] = np.nan
    return t, v


def _dicts(names: tuple[str, ...], v: np.ndarray) -> list[dict]:
    return [
        {
            k: (None if not math.isfinite(x) else int(x) if k == "seq" else x)
            for k, x in zip(names, row, strict=True)
        }
        for row in v.tolist()
    ]


def best(fn: Callable[[], object], repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=4000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    n = args.samples
    res: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as d:
        dd = Path(d)
        for label, topic, names in (("meas9", MEAS, MEAS_NAMES), ("est18", EST, EST_NAMES)):
            t, v = signals(n, names, seed=len(names))
            tl = t.tolist()
            rows = _dicts(names, v)  # built outside the timing: log's input is a dict
            for comp in ("zstd", "none"):
                kw = {"background_flush": False, "flush_s": 1e9, "compression": comp}
                pa, pb = dd / f"{label}-{comp}-log.mcap", dd / f"{label}-{comp}-block.mcap"

                def write_log(p=pa, topic=topic, tl=tl, rows=rows, kw=kw):
                    with McapLogger(p, **kw) as lg:
                        for tk, row in zip(tl, rows, strict=True):
                            lg.log(topic, tk, row)

                def write_block(p=pb, topic=topic, t=t, v=v, names=names, kw=kw):
                    with McapLogger(p, **kw) as lg:
                        lg.log_block(topic, t, names, v, int_fields=("seq",))

                write_block()  # compile / load the numba cache
                key = label if comp == "zstd" else f"{label}_nozstd"
                res[f"{key}_log_us_per_msg"] = best(write_log, args.repeat) / n * 1e6
                res[f"{key}_log_block_us_per_msg"] = best(write_block, args.repeat) / n * 1e6
                res[f"{key}_write_speedup"] = (
                    res[f"{key}_log_us_per_msg"] / res[f"{key}_log_block_us_per_msg"]
                )
                res[f"{key}_files_identical"] = float(pa.read_bytes() == pb.read_bytes())
            # the zstd level-3 compression both paths pay (the chunk text of the same messages)
            chunk = b"".join(_chunk_texts(dd / f"{label}-none-block.mcap"))
            res[f"{label}_zstd_us_per_msg"] = (
                best(lambda c=chunk: zstandard.compress(c), args.repeat) / n * 1e6
            )
            res[f"{label}_bytes_per_msg"] = len(chunk) / n

        p = dd / "meas9-zstd-log.mcap"
        list(read_blocks(p))  # compile / load the numba cache
        res["read_log_us_per_sample"] = (
            best(lambda: sum(1 for _ in read_log(p)), args.repeat) / n * 1e6
        )
        res["read_blocks_us_per_sample"] = best(lambda: list(read_blocks(p)), args.repeat) / n * 1e6
        res["read_speedup"] = res["read_log_us_per_sample"] / res["read_blocks_us_per_sample"]
        # read_log as it was before read_blocks: mcap's StreamReader parses every MessageIndex
        fast_reader = log_reader.SkipIndexStreamReader
        log_reader.SkipIndexStreamReader = StreamReader  # type: ignore[misc]
        try:
            res["read_log_before_us_per_sample"] = (
                best(lambda: sum(1 for _ in read_log(p)), args.repeat) / n * 1e6
            )
        finally:
            log_reader.SkipIndexStreamReader = fast_reader  # type: ignore[misc]
        res["read_speedup_vs_before"] = (
            res["read_log_before_us_per_sample"] / res["read_blocks_us_per_sample"]
        )
        ref = np.array(
            [
                [math.nan if m[k] is None else float(m[k]) for k in MEAS_NAMES]
                for _, _, m in read_log(p)
            ]
        )
        blocks = list(read_blocks(p))
        got = np.concatenate([b.values for b in blocks])
        same = (
            blocks[0].names == MEAS_NAMES
            and np.array_equal(np.isnan(got), np.isnan(ref))
            and np.array_equal(
                np.where(np.isnan(got), 0, got).view(np.uint64),
                np.where(np.isnan(ref), 0, ref).view(np.uint64),
            )
        )
        res["read_values_bit_identical"] = float(same)
        res.update(libraries(dd, n, args.repeat))
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(
        f"{n} samples at 1 kHz, best of {args.repeat}; numba kernels warm (compiled before timing)"
    )
    for label, f in (("meas9", 9), ("est18", 18)):
        r = {k[len(label) + 1 :]: v for k, v in res.items() if k.startswith(label + "_")}
        print(
            f"write {label} ({f} fields, {r['bytes_per_msg']:.0f} B/msg): "
            f"log {r['log_us_per_msg']:6.2f} us/msg   log_block {r['log_block_us_per_msg']:5.2f} "
            f"us/msg   x{r['write_speedup']:.1f}   identical files: {bool(r['files_identical'])}"
        )
        print(
            f"      of which zstd level 3 (same bytes, both paths): {r['zstd_us_per_msg']:.2f} us/msg;"
            f" compression='none': log {r['nozstd_log_us_per_msg']:5.2f}   log_block "
            f"{r['nozstd_log_block_us_per_msg']:4.2f}   x{r['nozstd_write_speedup']:.1f}"
        )
    print(
        f"read  meas9: read_log {res['read_log_us_per_sample']:6.2f} us/sample   read_blocks "
        f"{res['read_blocks_us_per_sample']:5.2f} us/sample   x{res['read_speedup']:.1f}   "
        f"bit-identical: {bool(res['read_values_bit_identical'])}"
    )
    print(
        f"      read_log before this change (parsing every MessageIndex): "
        f"{res['read_log_before_us_per_sample']:6.2f} us/sample -> "
        f"x{res['read_speedup_vs_before']:.1f}"
    )
    if "msgspec_encode_us_per_msg" in res:
        print(
            f"codec vs libraries, est18 rows: encode codec {res['codec_encode_us_per_msg']:.2f}"
            f"   msgspec {res['msgspec_encode_us_per_msg']:.2f}"
            f"   orjson {res['orjson_encode_us_per_msg']:.2f} us/msg"
            f" (codec from the array into records; the libraries from dicts, text only)"
        )
        print(
            f"      parse meas9 messages: codec {res['codec_parse_us_per_msg']:.2f} (to the array)"
            f"   msgspec {res['msgspec_parse_us_per_msg']:.2f}"
            f"   orjson {res['orjson_parse_us_per_msg']:.2f} us/msg (to dicts)"
        )
        print(
            f"      est18 log path: log_block {res['path_log_block_us_per_msg']:.2f}   msgspec + "
            f"stock mcap Writer {res['path_msgspec_stock_us_per_msg']:.2f} us/msg"
            f"   x{res['path_ratio']:.2f} (both zstd at their default level, 1 and 3;"
            f" compression none: {res['path_nozstd_log_block_us_per_msg']:.2f} vs "
            f"{res['path_nozstd_msgspec_stock_us_per_msg']:.2f})"
        )
    else:
        print("msgspec/orjson not installed (pip install -e '.[bench]'): library rows skipped")
    return 0


def libraries(dd: Path, n: int, repeat: int) -> dict[str, float]:
    """The codec against msgspec and orjson (encode, parse) and a log path built from msgspec
    and the stock mcap Writer against ``log_block``; {} without the libraries."""
    try:
        import msgspec
        import orjson
    except ImportError:
        return {}
    from mcap.writer import CompressionType, Writer

    res: dict[str, float] = {}
    t, v = signals(n, EST_NAMES, seed=len(EST_NAMES))
    rows = _dicts(EST_NAMES, v)
    fmt = codec.row_format(EST_NAMES, frozenset({"seq"}))
    lts = np.rint(t * 1e9).astype(np.int64)
    codec.encode_records(fmt, v, 1, 0, lts)  # warm
    enc = msgspec.json.Encoder()
    res["codec_encode_us_per_msg"] = (
        best(lambda: codec.encode_records(fmt, v, 1, 0, lts), repeat) / n * 1e6
    )
    res["msgspec_encode_us_per_msg"] = best(lambda: [enc.encode(r) for r in rows], repeat) / n * 1e6
    res["orjson_encode_us_per_msg"] = (
        best(lambda: [orjson.dumps(r) for r in rows], repeat) / n * 1e6
    )
    # parsing: the messages of the meas log's chunks
    text = b"".join(_chunk_texts(dd / "meas9-none-block.mcap"))
    buf = np.frombuffer(text, np.uint8)
    ops, starts, lens, _cids, _lts = codec.scan_records(buf)
    sel = ops == codec.MSG_OPCODE
    offs, ln = starts[sel] + 22, lens[sel] - 22
    datas = [text[o : o + k] for o, k in zip(offs.tolist(), ln.tolist(), strict=True)]
    m = len(datas)
    codec.parse_objects(buf, offs, ln)  # warm
    dec = msgspec.json.Decoder()
    res["codec_parse_us_per_msg"] = (
        best(lambda: codec.parse_objects(buf, offs, ln), repeat) / m * 1e6
    )
    res["msgspec_parse_us_per_msg"] = best(lambda: [dec.decode(x) for x in datas], repeat) / m * 1e6
    res["orjson_parse_us_per_msg"] = (
        best(lambda: [orjson.loads(x) for x in datas], repeat) / m * 1e6
    )

    # a log path from msgspec and stock parts: arrays -> dicts -> msgspec -> Writer.add_message
    for comp, key in (("zstd", "path"), ("none", "path_nozstd")):
        pb, ps = dd / f"path-{comp}-block.mcap", dd / f"path-{comp}-stock.mcap"
        ctype = CompressionType.ZSTD if comp == "zstd" else CompressionType.NONE

        def block(pb=pb, comp=comp):
            with McapLogger(pb, background_flush=False, flush_s=1e9, compression=comp) as lg:
                lg.log_block(EST, t, EST_NAMES, v, int_fields=("seq",))

        def stock(ps=ps, ctype=ctype):
            with open(ps, "wb") as fh:
                w = Writer(fh, chunk_size=1 << 20, compression=ctype)
                w.start()
                sid = w.register_schema("est", "jsonschema", b"{}")
                cid = w.register_channel(EST, "json", sid)
                for k, (lt, row) in enumerate(zip(lts.tolist(), _dicts(EST_NAMES, v), strict=True)):
                    w.add_message(cid, lt, enc.encode(row), lt, k)
                w.finish()

        res[f"{key}_log_block_us_per_msg"] = best(block, repeat) / n * 1e6
        res[f"{key}_msgspec_stock_us_per_msg"] = best(stock, repeat) / n * 1e6
    res["path_ratio"] = res["path_msgspec_stock_us_per_msg"] / res["path_log_block_us_per_msg"]
    return res


def _chunk_texts(path: Path) -> list[bytes]:
    """The uncompressed data of each chunk of ``path``."""
    with open(path, "rb") as f:
        return [r.data for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]


if __name__ == "__main__":
    raise SystemExit(main())
