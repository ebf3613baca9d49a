"""``servowatch import`` on a long flight (issue 52): a 2 h recording of 7 channels at 1 kHz
(7.2 M samples, 50.4 M values) written by each format's own library (pyarrow Parquet and CSV,
nptdms TDMS, asammdf MDF4), then imported, each in a child process of its own: wall and CPU
time, the child's peak anonymous resident memory (its heap: ``RssAnon``, sampled every 20 ms)
and its peak resident set (``ru_maxrss``, which also counts the pages of a file a reader maps,
as asammdf does: page cache the kernel can drop), side by side in one run.

The recording is made block by block (a smooth position sine, pressures about 100 bar, noise),
so neither the writer nor the importer ever holds it whole; the peak memory shows that the
import streams (the file itself is 400 MB of values).

    .venv/bin/python bench/import_speed.py [--hours 2] [--formats parquet,tdms,mdf,csv] [--json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RATE = 1000.0
BLOCK = 1 << 20
COLS = {  # rig column: (servowatch channel, unit)
    "PosDemand": ("x_cmd", "mm"),
    "ValveCurrent": ("i", "mA"),
    "SpoolPos": ("x_s", "um"),
    "RamPos": ("x_j", "mm"),
    "P_A": ("p1", "bar"),
    "P_B": ("p2", "bar"),
    "P_Supply": ("p_sr", "bar"),
}


def blocks(n: int):
    """(t [s], {column: values}) blocks of the recording."""
    rng = np.random.default_rng(1)
    for a in range(0, n, BLOCK):
        t = (a + np.arange(min(BLOCK, n - a))) / RATE
        s = np.sin(2 * np.pi * 0.3 * t)
        yield (
            t,
            {
                "PosDemand": 2.0 * s,
                "ValveCurrent": 0.5 * s + 0.01 * rng.standard_normal(len(t)),
                "SpoolPos": 20.0 * s + 0.5 * rng.standard_normal(len(t)),
                "RamPos": 2.0 * s + 0.05 * rng.standard_normal(len(t)),
                "P_A": 105.0 + 10 * s + 0.5 * rng.standard_normal(len(t)),
                "P_B": 105.0 - 10 * s + 0.5 * rng.standard_normal(len(t)),
                "P_Supply": 205.0 + 0.5 * rng.standard_normal(len(t)),
            },
        )


def write(fmt: str, path: Path, n: int) -> None:
    if fmt in ("parquet", "csv"):
        import pyarrow as pa
        import pyarrow.csv as pcsv
        import pyarrow.parquet as pq

        w = None
        for t, cols in blocks(n):
            tb = pa.table({"Time": t, **cols})
            if w is None:
                w = (pq.ParquetWriter(path, tb.schema) if fmt == "parquet"
                     else pcsv.CSVWriter(path, tb.schema))  # fmt: skip
            w.write_table(tb)
        w.close()
    elif fmt == "tdms":
        from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

        props = {"wf_increment": 1 / RATE, "wf_start_offset": 0.0,
                 "wf_start_time": np.datetime64("2026-03-01T08:00:00", "us")}  # fmt: skip
        with TdmsWriter(path) as w:
            for _, cols in blocks(n):
                w.write_segment([RootObject({}), GroupObject("Rig")] + [
                    ChannelObject("Rig", k, v, properties=props) for k, v in cols.items()])  # fmt: skip
    elif fmt == "mdf":
        import datetime as dt

        from asammdf import MDF, Signal

        mdf = MDF(version="4.10")
        mdf.header.start_time = dt.datetime(2026, 3, 1, 8, tzinfo=dt.UTC)
        first = True
        for t, cols in blocks(n):
            sigs = [Signal(v, t, name=k, unit=COLS[k][1]) for k, v in cols.items()]
            if first:
                mdf.append(sigs)
                first = False
            else:
                mdf.extend(0, [(t, None)] + [(v, None) for v in cols.values()])
        mdf.save(path, overwrite=True)
        mdf.close()


def map_text(fmt: str) -> str:
    prefix = "Rig/" if fmt == "tdms" else ""
    time = "" if fmt in ("tdms", "mdf") else '[time]\ncolumn = "Time"\n'
    lines = [time, "[actuator]", 'aircraft = "BENCH"', 'name = "rudder"', "[channels]"]
    lines += [f'{ch} = {{ column = "{prefix}{c}", unit = "{u}" }}' for c, (ch, u) in COLS.items()]
    return "\n".join(lines) + "\n"


CHILD = """
import resource, sys, threading, time
from service.cli import main

peak = [0]

def anon():  # resident anonymous memory (heap), kB: a reader's mmap of the file is not in it
    for line in open("/proc/self/status"):
        if line.startswith("RssAnon:"):
            return int(line.split()[1])
    return 0

def watch():
    while True:
        peak[0] = max(peak[0], anon())
        time.sleep(0.02)

threading.Thread(target=watch, daemon=True).start()
t0 = time.perf_counter()
code = main(["import", sys.argv[1], "--map", sys.argv[2], "--out", sys.argv[3],
             "--start-unix", "1772352000"])
wall = time.perf_counter() - t0
ru = resource.getrusage(resource.RUSAGE_SELF)
print(wall, ru.ru_utime + ru.ru_stime, max(peak[0], anon()), ru.ru_maxrss, code)
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=2.0)
    ap.add_argument("--formats", default="parquet,tdms,mdf,csv")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    n = int(a.hours * 3600 * RATE)
    rows = []
    with tempfile.TemporaryDirectory(prefix="import-bench-") as tmp:
        d = Path(tmp)
        for fmt in a.formats.split(","):
            ext = {"parquet": ".parquet", "csv": ".csv", "tdms": ".tdms", "mdf": ".mf4"}[fmt]
            src, mp, out = d / f"flight{ext}", d / f"{fmt}.toml", d / f"{fmt}.mcap"
            t0 = time.perf_counter()
            write(fmt, src, n)
            write_s = time.perf_counter() - t0
            mp.write_text(map_text(fmt))
            r = subprocess.run([sys.executable, "-c", CHILD, str(src), str(mp), str(out)],
                               capture_output=True, text=True, check=False)  # fmt: skip
            last = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else ""
            if r.returncode or not last.endswith(" 0"):
                print(f"{fmt}: import failed: {r.stderr.strip()[-400:]}", file=sys.stderr)
                return 1
            wall, cpu, anon_kb, rss_kb, _ = last.split()
            rows.append({"format": fmt, "samples": n, "values": 7 * n,
                         "file_mb": src.stat().st_size / 1e6, "write_s": write_s,
                         "import_s": float(wall), "cpu_s": float(cpu),
                         "peak_anon_mb": int(anon_kb) / 1024, "peak_rss_mb": int(rss_kb) / 1024,
                         "log_mb": out.stat().st_size / 1e6})  # fmt: skip
            src.unlink()
            out.unlink()
    if a.json:
        print(json.dumps({"hours": a.hours, "rate_hz": RATE, "rows": rows}))
        return 0
    print(f"{a.hours:g} h at {RATE:g} Hz: {n} samples x 7 channels = {7 * n / 1e6:.1f} M values")
    print(f"{'format':<8} {'file MB':>8} {'import s':>9} {'CPU s':>6} {'heap MB':>8} "
          f"{'RSS MB':>7} {'log MB':>7}")  # fmt: skip
    for r in rows:
        print(f"{r['format']:<8} {r['file_mb']:>8.0f} {r['import_s']:>9.2f} {r['cpu_s']:>6.1f} "
              f"{r['peak_anon_mb']:>8.0f} {r['peak_rss_mb']:>7.0f} {r['log_mb']:>7.0f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
