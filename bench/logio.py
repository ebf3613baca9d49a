"""MCAP log rows: protobuf (the log's encoding, decision 0011) against ROS 2 CDR and JSON.

All figures are CPU time of this process (the machine is shared: wall time would measure
the others' load), best of ``--repeat``.

For a 9-field meas row (the daemon's: seven channels, ``seq`` as a 64-bit integer, ``t``)
and an 18-field est row, N rows of smooth noisy signals with about 5 % NaN (absent channels):

* encode: numpy rows -> packed MCAP Message records, per row. Protobuf is
  ``service.log.rows.RowLayout.records`` (a fixed layout: tag + 8 bytes per field, zeros
  written); CDR is the same idea (4-byte encapsulation header + 8 bytes per field, every
  field 8-aligned, no tags) with the same numpy record packing; JSON is ``json.dumps`` per
  row (the text the log wrote before decision 0011; its compiled encoder is retired);
* decode: records -> (N, F) float64 by a numpy gather (protobuf, CDR) or ``json.loads``;
* bytes per row in the records and after zstd at level 1 (the log's chunk compression),
  and the zstd time per row;
* the stock readers: ``mcap-protobuf-support``'s and ``mcap-ros2-support``'s decoder on a
  file of each (what a user without servowatch runs), per row;
* the log's own paths: ``McapLogger.log_rows`` (zstd 1, the file closed) and
  ``read_blocks``, per row.

    .venv/bin/python bench/logio.py [--rows 20000] [--repeat 5] [--json]
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

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.log import McapLogger, read_blocks  # noqa: E402
from service.log.proclog import MEAS_LOG_FIELDS  # noqa: E402
from service.log.rows import row_layout  # noqa: E402
from service.monitor import EST_KEYS  # noqa: E402

MEAS = "/fleet/AC001/elevator_L/meas"
EST = "/fleet/AC001/elevator_L/est"
_HEAD = np.dtype([("op", "u1"), ("len", "<u8"), ("cid", "<u2"), ("seq", "<u4"),
                  ("lt", "<u8"), ("pt", "<u8")])  # fmt: skip


def signals(n: int, names: tuple[str, ...], seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Sample times (1 kHz from t = 1.7e9 s) and an (n, F) array of smooth noisy signals
    with the magnitudes of the service's fields (full 17-digit doubles), ~5 % NaN; ``seq``
    counts, ``t`` is the time."""
    rng = np.random.default_rng(seed)
    t = 1.7e9 + np.arange(n) * 1e-3
    scale = 10.0 ** rng.integers(-5, 8, size=len(names))
    phase = rng.uniform(0, 2 * np.pi, size=len(names))
    tt = t - t[0]
    v = scale * (np.sin(2 * np.pi * 3.0 * tt[:, None] + phase) + 0.01 * rng.normal(size=(n, 1)))
    v[rng.random((n, len(names))) < 0.05] = np.nan
    if "seq" in names:
        v[:, names.index("seq")] = np.arange(n)
    if "t" in names:
        v[:, names.index("t")] = t
    return t, v


def best(fn: Callable[[], object], repeat: int) -> float:
    """The least CPU time [s] of ``repeat`` calls (this process, all threads: the machine
    is shared, wall time measures the others' load)."""
    ts = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        ts.append(time.process_time() - t0)
    return min(ts)


# ------------------------------------------------------------------ CDR (ROS 2) rows
def cdr_records(v: np.ndarray, ints: list[int], lts: np.ndarray) -> np.ndarray:
    """MCAP Message records of CDR rows (little-endian encapsulation, 8-byte fields)."""
    n, f = v.shape
    size = 4 + 8 * f
    out = np.empty((n, 31 + size), np.uint8)
    head = np.zeros(1, _HEAD)
    head["op"], head["len"] = 5, 22 + size
    out[:, :31] = head.view(np.uint8)
    hv = out[:, :31].copy().view(_HEAD).reshape(n)
    hv["seq"] = np.arange(n)
    hv["lt"] = hv["pt"] = lts
    out[:, :31] = hv.view(np.uint8).reshape(n, 31)
    out[:, 31:35] = (0, 1, 0, 0)  # CDR_LE
    w = v.copy()
    for k in ints:
        w.view(np.int64)[:, k] = v[:, k]
    out[:, 35:] = w.view(np.uint8).reshape(n, 8 * f)
    return out


def cdr_decode(buf: np.ndarray, offs: np.ndarray, f: int, ints: list[int]) -> np.ndarray:
    raw = buf[offs[:, None] + 4 + np.arange(8 * f)]
    vals = raw.view("<f8").reshape(len(offs), f).copy()
    for k in ints:
        vals[:, k] = raw.view("<i8").reshape(len(offs), f)[:, k]
    return vals


def ros2msg(names: tuple[str, ...], ints: list[int]) -> str:
    return "\n".join(f"{'int64' if k in ints else 'float64'} {n}" for k, n in enumerate(names))


# ------------------------------------------------------------------ JSON rows
def json_datas(names: tuple[str, ...], v: np.ndarray, ints: list[int]) -> list[bytes]:
    enc = json.JSONEncoder(separators=(",", ":")).encode
    isf = math.isfinite
    return [
        enc({k: (None if not isf(x) else int(x) if j in ints else x)
             for j, (k, x) in enumerate(zip(names, row, strict=True))}).encode()
        for row in v.tolist()
    ]  # fmt: skip


def json_records(datas: list[bytes], lts: np.ndarray) -> bytes:
    import struct

    s = struct.Struct("<BQHIQQ")
    return b"".join(
        s.pack(5, 22 + len(d), 1, k, lt, lt) + d
        for k, (d, lt) in enumerate(zip(datas, lts.tolist(), strict=True))
    )


# ------------------------------------------------------------------ stock readers
def stock_protobuf(path: Path) -> int:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages(log_time_order=False))  # fmt: skip


def stock_ros2(path: Path) -> int:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages(log_time_order=False))  # fmt: skip


def write_cdr_file(path: Path, topic: str, names, ints, v, lts) -> None:
    from mcap.writer import Writer

    recs = cdr_records(v, ints, lts)
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema(f"servowatch/msg/{topic.rsplit('/', 1)[-1].capitalize()}",
                                "ros2msg", ros2msg(names, ints).encode())  # fmt: skip
        cid = w.register_channel(topic, "cdr", sid)
        for k in range(len(v)):
            w.add_message(cid, int(lts[k]), recs[k, 31:].tobytes(), int(lts[k]), k)
        w.finish()


def run(n: int, repeat: int) -> dict[str, dict[str, float]]:
    res: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as d:
        for label, topic, names, int_names in (
            ("meas9", MEAS, MEAS_LOG_FIELDS, ("seq",)),
            ("est18", EST, tuple(EST_KEYS), ()),
        ):
            res[label] = _one(Path(d), label, topic, names, int_names, n, repeat)
    return res


def _one(dd: Path, label: str, topic: str, names: tuple[str, ...], int_names: tuple[str, ...],
         n: int, repeat: int) -> dict[str, float]:  # fmt: skip
    cctx = zstandard.ZstdCompressor(level=1)
    t, v = signals(n, names, seed=len(names))
    lts = np.rint(t * 1e9).astype(np.int64)
    ints = [names.index(x) for x in int_names]
    lay = row_layout(topic.rsplit("/", 1)[-1], names, frozenset(int_names))
    r: dict[str, float] = {}
    seqs = np.arange(n)
    r["pb_encode_us"] = best(lambda: lay.records(v, 1, seqs, lts), repeat) / n * 1e6
    r["cdr_encode_us"] = best(lambda: cdr_records(v, ints, lts), repeat) / n * 1e6
    datas = json_datas(names, v, ints)
    r["json_encode_us"] = best(lambda: json_datas(names, v, ints), repeat) / n * 1e6
    pb = lay.records(v, 1, seqs, lts)
    cdr = cdr_records(v, ints, lts)
    js = json_records(datas, lts)
    pbf = pb.reshape(-1)
    offs = np.arange(n, dtype=np.int64) * lay.record_size + 31
    lens = np.full(n, lay.size)
    exp = np.where(np.isin(np.arange(len(names)), ints), np.trunc(v), v)
    assert np.array_equal(lay.decode_block(pbf, offs, lens), exp, equal_nan=True)
    r["pb_decode_us"] = best(lambda: lay.decode_block(pbf, offs, lens), repeat) / n * 1e6
    cf = cdr.reshape(-1)
    coffs = np.arange(n, dtype=np.int64) * cdr.shape[1] + 31
    assert np.array_equal(cdr_decode(cf, coffs, len(names), ints), exp, equal_nan=True)
    r["cdr_decode_us"] = best(lambda: cdr_decode(cf, coffs, len(names), ints), repeat) / n * 1e6
    r["json_decode_us"] = best(lambda: [json.loads(x) for x in datas], repeat) / n * 1e6
    for key, blob in (("pb", pb.tobytes()), ("cdr", cdr.tobytes()), ("json", js)):
        r[f"{key}_bytes"] = len(blob) / n
        r[f"{key}_zstd1_bytes"] = len(cctx.compress(blob)) / n
        r[f"{key}_zstd1_us"] = best(lambda b=blob: cctx.compress(b), repeat) / n * 1e6
    # the stock readers
    pp, cp = dd / f"{label}-pb.mcap", dd / f"{label}-cdr.mcap"
    with McapLogger(pp, background_flush=False) as lg:
        lg.log_rows([topic], [n], t, names, v, int_fields=int_names)
    write_cdr_file(cp, topic, names, ints, v, lts)
    assert stock_protobuf(pp) == n and stock_ros2(cp) == n
    r["pb_stock_decode_us"] = best(lambda: stock_protobuf(pp), max(1, repeat // 2)) / n * 1e6
    r["cdr_stock_decode_us"] = best(lambda: stock_ros2(cp), max(1, repeat // 2)) / n * 1e6
    # the log's own paths (protobuf, zstd level 1, file opened and closed)
    wp = dd / f"{label}-w.mcap"

    def write() -> None:
        with McapLogger(wp, background_flush=False) as lg:
            for k in range(0, n, 100):  # the log process's batches: 100 rows
                lg.log_rows([topic], [min(100, n - k)], t[k : k + 100], names, v[k : k + 100],
                            int_fields=int_names)  # fmt: skip

    write()
    r["log_rows_us"] = best(write, repeat) / n * 1e6
    r["file_bytes"] = wp.stat().st_size / n
    list(read_blocks(wp))  # compile / load the numba cache
    r["read_blocks_us"] = best(lambda: list(read_blocks(wp)), repeat) / n * 1e6
    return r


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    res = run(args.rows, args.repeat)
    if args.json:
        print(json.dumps(res))
        return 0
    import os

    print(f"MCAP log rows, {args.rows} rows, CPU best of {args.repeat}; us and bytes per row; "
          f"load average {'/'.join(f'{x:.1f}' for x in os.getloadavg())}")  # fmt: skip
    cols = ("encode us", "decode us", "bytes", "zstd-1 bytes", "zstd-1 us", "stock decode us")
    for label, r in res.items():
        print(f"\n{label}: {'':>8}" + "".join(f"{c:>16}" for c in cols))
        for key, name in (("pb", "protobuf"), ("cdr", "ROS 2 CDR"), ("json", "JSON")):
            vals = [r.get(f"{key}_encode_us"), r.get(f"{key}_decode_us"), r.get(f"{key}_bytes"),
                    r.get(f"{key}_zstd1_bytes"), r.get(f"{key}_zstd1_us"),
                    r.get(f"{key}_stock_decode_us")]  # fmt: skip
            print(f"  {name:>14}" + "".join("{:>16}".format("-" if x is None else f"{x:.3f}")
                                             for x in vals))  # fmt: skip
        print(f"  log path (protobuf, zstd 1): McapLogger.log_rows {r['log_rows_us']:.3f} us/row"
              f" (100-row batches, file closed), {r['file_bytes']:.1f} file bytes/row; "
              f"read_blocks {r['read_blocks_us']:.3f} us/row")  # fmt: skip
    print(
        "\nencode: numpy rows -> MCAP records (JSON: json.dumps per row, text only); decode: "
        "records -> (N, F) float64 (JSON: json.loads per row, to dicts); stock decode: "
        "mcap's reader with mcap-protobuf-support / mcap-ros2-support decoders"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
