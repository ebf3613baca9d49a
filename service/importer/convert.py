"""``import_file``: one recording (TDMS, MDF, Parquet, CSV) and a channel map -> an ordinary
servowatch log (docs/import.md).

The log holds the unit's ``/fleet/{aircraft}/{actuator}/meas`` rows as the daemon writes them
(the mapped channels in SI, ``seq`` = the grid index, ``t``), a ``servowatch.flight`` record
when the flight is known, and a ``servowatch.import`` record: the source file's name and
sha256, the map's text and sha256, the start and flight used, and the counts of what the
time base did. It is written to a hidden file beside the output and renamed into place only
when complete: a bad input leaves nothing behind. The same input bytes and map give the same
log bytes; importing them again finds the log and writes nothing.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import itertools
import json
import logging
import os
import queue
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from service.importer.errors import InputError
from service.importer.mapping import ChannelMap, map_digest, si_factor
from service.importer.merge import ColumnSpool
from service.importer.source import Series, Source, sniff
from service.importer.timebase import GridCounts, SeriesResampler
from service.wire import messages as m

__all__ = ["ImportResult", "import_file", "IMPORT_RECORD", "read_import_record", "file_digest"]

IMPORT_RECORD = "servowatch.import"
log = logging.getLogger("servowatch.import")


@dataclass
class ImportResult:
    """What one import did (``--json``)."""

    source: str
    out: str
    status: str  # "written" or "unchanged" (the same input was imported before)
    format: str = ""
    samples: int = 0
    t0: float | None = None
    duration_s: float = 0.0
    channels: list[str] = field(default_factory=list)
    counts: dict = field(default_factory=dict)


def file_digest(path: Path) -> str:
    """sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while b := fh.read(1 << 22):
            h.update(b)
    return h.hexdigest()


def read_import_record(path: Path) -> dict[str, str] | None:
    """The ``servowatch.import`` record of a log (None: none, or not a readable log)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            for md in make_reader(fh).iter_metadata():
                if md.name == IMPORT_RECORD:
                    return dict(md.metadata)
    except Exception:
        return None
    return None


def _open(path: Path, cmap: ChannelMap, stack: contextlib.ExitStack) -> Source:
    fmt = sniff(path, cmap.format)
    if fmt == "parquet":
        from service.importer.tabular import open_parquet

        return open_parquet(path, cmap)
    if fmt == "csv":
        from service.importer.tabular import open_csv

        return open_csv(path, cmap)
    if fmt == "tdms":
        from service.importer.tdms import open_tdms

        return open_tdms(path, cmap, stack)
    from service.importer.mdf import open_mdf

    return open_mdf(path, cmap, stack)


def import_file(
    path: str | Path,
    cmap: ChannelMap,
    map_raw: bytes,
    out: str | Path,
    *,
    start_unix: float | None = None,
    flight: int | None = None,
) -> ImportResult:
    """Import ``path`` through ``cmap`` into the log ``out`` (module docstring).
    ``start_unix`` (calendar time of a relative time axis' zero) and ``flight`` override the
    map's, which override the file's. ``InputError`` for a bad input (nothing written)."""
    path, out = Path(path), Path(out)
    with contextlib.ExitStack() as stack:
        src = _open(path, cmap, stack)
        start = next((x for x in (start_unix, cmap.actuator.start_unix, src.start_unix)
                      if x is not None), None)  # fmt: skip
        fl = next((x for x in (flight, cmap.actuator.flight, src.flight) if x is not None), None)
        ident = {
            "file": path.name,
            "sha256": "",  # below
            "map_sha256": map_digest(map_raw),
            "start_unix": "" if start is None else repr(float(start)),
            "flight": "" if fl is None else str(int(fl)),
        }
        if out.exists():
            ident["sha256"] = file_digest(path)
            old = read_import_record(out)
            if old is not None and all(old.get(k) == v for k, v in ident.items()):
                return ImportResult(str(path), str(out), "unchanged", src.format)
            raise InputError(out, "--out", "exists and is not this file's import (remove it "
                             "or choose another --out)")  # fmt: skip
        tmp = out.with_name(f".{out.name}.part-{os.getpid()}")
        made = [d for d in (out.parent, *out.parent.parents) if not d.exists()]
        hasher = stack.enter_context(ThreadPoolExecutor(1, "import-sha256"))
        digest = hasher.submit(file_digest, path)  # beside the import (hashlib frees the GIL)
        try:
            res = _write(src, cmap, map_raw, tmp, ident, start, fl, digest.result)
            os.replace(tmp, out)
        except BaseException:
            for d in made:  # the folders this import made, innermost first
                with contextlib.suppress(OSError):
                    tmp.unlink(missing_ok=True)
                    d.rmdir()
            raise
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        res.out = str(out)
        return res


def _first_times(path: Path, s: Series, start: float | None) -> tuple[float, float, Iterator]:
    """The first finite time [s] of a time base, its nominal period (the median step of its
    first block; their mean when all steps are within 1 % of it) and its blocks (the first
    one read again from memory)."""
    it = s.blocks()
    for t, raw in it:
        ok = _shift(t, s, start)
        ok = ok[np.isfinite(ok)]
        steps = np.diff(ok)
        fwd = steps[steps > 0]
        if not len(fwd):
            raise InputError(path, s.columns[0], f"{s.name}: fewer than 2 increasing times")
        med = float(np.median(fwd))
        blocks = itertools.chain([(t, raw)], it)
        if len(ok) > 2 and np.all(np.abs(steps - med) < 0.01 * med):
            # evenly sampled: the mean step, exact where a step of a Unix time is not
            return float(ok[0]), float(ok[-1] - ok[0]) / (len(ok) - 1), blocks
        return float(ok[0]), med, blocks
    raise InputError(path, s.columns[0], f"{s.name}: no samples")


def _shift(t: NDArray, s: Series, start: float | None) -> NDArray:
    return t if s.absolute or start is None else t + start


def _write(src: Source, cmap: ChannelMap, map_raw: bytes, tmp: Path, ident: dict,
           start: float | None, fl: int | None, sha256: Callable[[], str]) -> ImportResult:  # fmt: skip
    from service.daemon.ratelimit import RateLimitedLog
    from service.log import McapLogger
    from service.log.flightrec import FLIGHT_RECORD, FlightRecord
    from service.replay.input import UnitClock

    path, rate = src.path, cmap.time.rate_hz
    mapped = cmap.ordered()
    chan = [k for k, _ in mapped]
    conv = {s.column: (s.scale, s.offset, si_factor(s.unit, k), k) for k, s in mapped}
    firsts = [_first_times(path, s, start) for s in src.series]
    t0 = min(f[0] for f in firsts)
    ac, act = cmap.actuator.aircraft, cmap.actuator.name
    finite = dict.fromkeys(chan, 0)
    counts = GridCounts()
    topic = m.mcap_topic(ac, act, "meas")
    names = (*chan, "seq", "t")
    done = {"n": 0, "t": []}

    def write(k: NDArray, v: NDArray) -> None:
        t = t0 + k / rate
        lg.log_block(topic, t, names, np.column_stack([v, k, t]), int_fields=("seq",))
        done["n"] += len(k)
        done["t"] = [float(t[0]) if not done["t"] else done["t"][0], float(t[-1])]

    spool = ColumnSpool(tmp, chan) if len(src.series) > 1 else None
    try:
        with McapLogger(tmp, background_flush=False, flush_s=1e12) as lg, _Behind(write) as emit:
            if fl is not None:
                dated = start is not None or any(s.absolute for s in src.series)
                rec = FlightRecord(ac, act, int(fl), t0 if dated else None, t0)
                lg.add_metadata(FLIGHT_RECORD, rec.to_metadata())
            for s, (_, dt, blocks) in zip(src.series, firsts, strict=True):
                cols = [chan.index(conv[c][3]) for c in s.columns]
                rsm = SeriesResampler(t0, rate, dt)
                sink = emit if spool is None else functools.partial(_spool_put, spool, cols)
                put = _Forward(rsm.counts, sink)
                rs = _stream(s, blocks, conv, finite, rsm, start,
                             UnitClock(ac, act, RateLimitedLog(log)), put)  # fmt: skip
                counts.add(rs)
            if spool is not None:
                for k, v in spool.rows():
                    emit(k, v)
            emit.join()
            for k in chan:
                if not finite[k]:
                    col = cmap.channels[k].column
                    raise InputError(path, f"channels.{k}", f"column {col!r} holds no finite value")
            summary = {**asdict(counts), "rate_hz": rate}
            lg.add_metadata(IMPORT_RECORD, {**ident, "sha256": sha256(), "format": src.format,
                                            "map": map_raw.decode("utf-8")})  # fmt: skip
            lg.add_metadata(
                IMPORT_RECORD + ".counts", {"counts": json.dumps(summary, sort_keys=True)}
            )
    finally:
        if spool is not None:
            spool.close()
    n = done["n"]
    t_first, t_last = done["t"] or (None, None)
    if not n:
        raise InputError(path, "file", "no sample passed the intake's time checks")
    return ImportResult(str(path), "", "written", src.format, n, t_first,
                        (t_last or 0.0) - (t_first or 0.0), chan, summary)  # fmt: skip


def _spool_put(spool: ColumnSpool, cols: list[int], k: NDArray, v: NDArray) -> None:
    spool.put(k, cols, v)


class _Forward:
    """A time base's grid values to ``sink`` (the log, or the spool of a file of several
    rates), grid index increasing: after a clock was followed back, the values at indices
    already written are dropped and counted (``overlap``; the grid keeps the values written
    first), so the log's ``seq`` and ``t`` only increase and its replay accepts every row."""

    def __init__(self, counts: GridCounts, sink: Callable[[NDArray, NDArray], None]) -> None:
        self.counts, self.sink, self.last = counts, sink, -1

    def __call__(self, k: NDArray, v: NDArray) -> None:
        keep = k > self.last
        if not keep.all():
            self.counts.overlap += int((~keep).sum())
            k, v = k[keep], v[keep]
        if len(k):
            self.sink(k, v)
            self.last = int(k[-1])


class _Behind:
    """``fn(*args)`` on a thread of its own, a few calls behind the caller: the log's
    encoding and compression (which release the GIL) overlap the reading. An exception of
    ``fn`` is raised at the next call or at :meth:`join`."""

    def __init__(self, fn, depth: int = 2) -> None:
        self.fn, self.q = fn, queue.Queue(maxsize=depth)
        self.error: BaseException | None = None
        self.th = threading.Thread(target=self._run, name="import-write", daemon=True)

    def _run(self) -> None:
        while (args := self.q.get()) is not None:
            if self.error is None:
                try:
                    self.fn(*args)
                except BaseException as e:  # raised in the caller's thread
                    self.error = e

    def __call__(self, *args) -> None:
        if self.error is not None:
            raise self.error
        self.q.put(args)

    def join(self) -> None:
        """Wait for every call; raise what ``fn`` raised."""
        if self.th.is_alive():
            self.q.put(None)
            self.th.join()
        if self.error is not None:
            raise self.error

    def __enter__(self) -> _Behind:
        self.th.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.th.is_alive():
            self.q.put(None)
            self.th.join()


def _stream(s: Series, blocks: Iterator, conv: dict, finite: dict, rs: SeriesResampler, start: float | None,
            clock, put) -> GridCounts:  # fmt: skip
    """One time base: SI units, the intake's time checks, onto the grid, to ``put``."""
    refused = 0
    for t, raw in blocks:
        t = _shift(t, s, start)
        ch = np.full((len(t), len(m.CHANNELS)), np.nan)
        for c in s.columns:
            a, b, f, k = conv[c]
            v = (a * raw[c] + b) * f if (a, b) != (1.0, 0.0) else raw[c] * f
            ch[:, m.CHANNELS.index(k)] = v
            finite[k] += int(np.isfinite(v).sum())
        vals = ch[:, [m.CHANNELS.index(conv[c][3]) for c in s.columns]]
        for idx, restart in clock.check(t, ch, None):
            refused -= len(idx)
            for k, v in rs.push(t[idx], vals[idx], restart):
                put(k, v)
        refused += len(t)
    for k, v in rs.finish():
        put(k, v)
    # every sample the intake refused (its own counts name the reasons it counts)
    rs.counts.intake = {k: v for k, v in clock.counts().items() if v} | (
        {"refused": refused} if refused else {}
    )
    return rs.counts
