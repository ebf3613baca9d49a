"""Offline replay: logged samples through the same monitor code, as fast as possible or paced.

The logged ``/fleet/{aircraft}/{actuator}/meas`` messages are read as column blocks
(``service.log.read_blocks``: per chunk and topic, no per-message dicts; it survives a
truncated file and skips a corrupt chunk), checked by the daemon's intake time rules
(``UnitClock``: samples at or before the unit's last accepted time refused and counted, a
clock that steps back followed after ``resync_n`` consistent samples with the filter
restarted, non-finite samples refused) and fed to one ``service.monitor.MonitorBank`` keyed by actuator, in batches
of consecutive samples (``MonitorBank.update_arrays``; as fast as possible, its two halves
``step_arrays`` and ``rows_of`` run pipelined in two threads). The bank
gives results that do not depend on the batch composition (``tests/test_monitor.py``), so a
replay reproduces the live daemon's estimates when it uses the same monitor configuration and
baseline. Outputs go to a new MCAP log with the daemon's topic layout (``meas`` copied, ``est``,
``residual``, ``health``, ``events``) and, optionally, are republished on Zenoh and served
live to Foxglove (``live``, a ``service.edge.foxglove_feed.FoxgloveFeed``: the same channels as the
daemon's, best paced).

With a health store (``store``), each actuator runs on its latest baseline from the store
(``service.monitor.MonitorFleet``; none: the default, ``commissioned: false``), and the
fan-out's operating periods and alarm raises are written to the store at the end in one
transaction (``HealthStore.ingest_log``), named by each unit's stream identity
(``service.store.identity``: digests of all of its accepted samples, built while the log is
read and compared there with the unit's stored streams; never the file's name), so replaying
the same log again, a copy of it, or a log whose samples are stored already adds nothing,
and a log that holds stored ones (a log ingested while still written, a repaired log, the
rotation set of stored members, the daemon's own log beside its live periods) replaces
them. Each period is stamped with its flight and calendar time (``service.prognostics.life``:
the log's ``servowatch.flight`` record, the caller's ``flight``/``start_unix``, or the gap
rule, renumbered by the store along the unit's life order so that the flights never depend
on the order, split or names of the ingests). Each file is opened once
(``service.log.logfile.LogSet``): its check, metadata, flight records, units and blocks
are read through that one handle.

``replay_many`` ingests many logs into one store in one process, in a reading order (``log_order``;
the store's flights do not depend on it).
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from service.daemon.fanout import FanOut
from service.jsonutil import jsonable
from service.log import (
    CorruptChunkWarning,
    LogBlock,
    LogReadStats,
    McapLogger,
    TruncatedLogWarning,
    rotated_files,
)
from service.log.flightrec import MAX_FLIGHT
from service.log.logfile import LogSet
from service.monitor import (
    EST_KEYS,
    HEALTH_KEYS,
    RES_KEYS,
    BankRows,
    Baseline,
    MonitorBank,
    MonitorConfig,
    MonitorFleet,
    RowEvents,
    check_baseline_model,
)
from service.prognostics import PeriodConfig
from service.prognostics.life import FLIGHT_GAP_S, FlightStamper
from service.replay.input import (
    LogError,
    StoreWriteError,
    UnitClock,
    block_columns,
    check_mcap,
    legacy_log_source,
    named,
    unit_source,
)
from service.replay.stored import store_result
from service.store.identity import StreamDigest, stream_source
from service.wire import messages as m

__all__ = [
    "ReplaySummary",
    "replay",
    "replay_many",
    "log_order",
    "expand_logs",
    "INPUT_KEYS",
    "read_metadata",
    "unit_source",
    "legacy_log_source",
    "check_mcap",
    "LogError",
    "StoreWriteError",
    "log_actuators",
]

log = logging.getLogger("servowatch.replay")

INPUT_KEYS: tuple[str, ...] = ("t", *m.CHANNELS)
_BATCH = 512  # samples per step_arrays call (amortised; small enough to pipeline)
_PACED_SLICE = 10  # samples run together in a paced replay
_IN_FLIGHT = 4  # step_arrays calls queued ahead of the one being handled


@dataclass
class ReplaySummary:
    """What a replay did; ``speed`` is log duration / wall time (x real time)."""

    log: str
    out: str | None
    samples: int = 0
    outputs: int = 0
    skipped: int = 0
    actuators: list[str] = field(default_factory=list)
    final: dict[str, dict[str, Any]] = field(default_factory=dict)
    alarms: list[dict[str, Any]] = field(default_factory=list)
    counters: dict[str, dict[str, int]] = field(default_factory=dict)
    t_start: float | None = None
    t_end: float | None = None
    duration_s: float = 0.0
    wall_s: float = 0.0
    speed: float | None = None
    truncated: bool = False
    published: int = 0
    warnings: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    source: str | None = None  # the periods' source in the store
    periods: int = 0  # periods closed
    periods_new: int = 0  # of which new in the store
    commissioned: dict[str, int | None] = field(default_factory=dict)  # baseline versions
    first_t: dict[str, float] = field(default_factory=dict)  # each actuator's first sample
    flights: dict[str, list[int]] = field(default_factory=dict)  # flights of its periods
    sources: dict[str, str] = field(default_factory=dict)  # each unit's source (identity)
    unit_samples: dict[str, int] = field(default_factory=dict)  # accepted samples per unit
    stored: dict[str, str] = field(default_factory=dict)  # new, superseded or stored, per unit
    time: dict[str, dict[str, int]] = field(default_factory=dict)  # time checks per unit
    corrupt_chunks: int = 0  # chunks skipped (bad CRC, undecodable)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types (non-finite floats as None)."""
        return jsonable(asdict(self))


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``servowatch`` metadata record of an MCAP file ({} if absent or unreadable)."""
    from service.log.logfile import LogFile

    try:
        with LogFile(path) as lf:
            return lf.metadata
    except Exception:
        return {}


def _read_files(logset: LogSet, stats: LogReadStats) -> Iterator[LogBlock | None]:
    """The meas blocks of every file of ``logset`` in order; None where a corrupt chunk was
    skipped (a gap in the samples: the stream identities start a new run there)."""
    for lf in logset.files:
        st = LogReadStats()
        seen = 0
        for blk in lf.blocks(stats=st, match=_is_meas):
            if st.corrupt != seen:
                seen = st.corrupt
                yield None
            yield blk
        f = lf.path
        if not st.chunks and not st.messages and not st.footer and not st.corrupt:
            raise LogError(f"{f}: not a usable MCAP log: no complete chunk "
                           f"({st.reason or 'header only'})")  # fmt: skip
        stats.chunks += st.chunks
        stats.messages += st.messages
        stats.corrupt += st.corrupt
        stats.truncated = stats.truncated or st.truncated


def _is_meas(topic: str) -> bool:
    return topic.startswith("/fleet/") and topic.endswith("/meas")


def _parse_topic(topic: str) -> tuple[str, str] | None:
    parts = topic.split("/")
    if len(parts) != 5 or parts[0] != "" or parts[1] != "fleet" or parts[4] != "meas":
        return None
    return parts[2], parts[3]


def _no_rows() -> BankRows:
    """The output rows of a block that gave none."""
    e = np.empty
    return BankRows(
        e(0, np.int64), e(0), e((0, len(EST_KEYS))), e((0, len(RES_KEYS))),
        e((0, len(HEALTH_KEYS))), RowEvents(0),
    )  # fmt: skip


@dataclass
class _Input:
    """Accepted samples of one logged meas block: ``row`` is the actuator's bank row (set by
    the monitor stage); ``meas`` the block's values to copy to the output log."""

    name: str
    at: tuple[str, str]
    topic: str
    t: NDArray
    ch: NDArray
    names: tuple[str, ...]
    meas: NDArray
    row: int = -1
    restart: bool = False  # the unit's clock went back before it: the filter restarts


def _read_stage(
    logset: LogSet,
    stats: LogReadStats,
    summary: ReplaySummary,
    records: list | tuple = (),
    digests: dict[str, StreamDigest] | None = None,
    stored: Callable[[str], dict] | None = None,
) -> Iterator[_Input]:
    """Stage 1: the logged meas blocks as accepted samples per actuator (time order), by the
    daemon's intake time checks (``UnitClock``); each unit's accepted samples into its
    stream identity (``digests``: ``service.store.identity.StreamDigest``, compared while it
    reads with the unit's ``stored`` streams) and, for an older store's records, its
    first-sample id (``unit_source``) at its first accepted sample."""
    from service.daemon.ratelimit import RateLimitedLog

    clocks: dict[str, UnitClock] = {}
    names: dict[str, tuple[str, str] | None] = {}
    digests = {} if digests is None else digests
    bad_log = RateLimitedLog(log)
    for blk in _read_files(logset, stats):
        if blk is None:  # a corrupt chunk skipped: a gap in every unit's stream
            for d in digests.values():
                d.cut()
            continue
        if blk.topic not in names:
            names[blk.topic] = _parse_topic(blk.topic)
        at = names[blk.topic]
        if at is None:
            continue
        name = f"{at[0]}/{at[1]}"
        if name not in clocks:
            clocks[name] = UnitClock(at[0], at[1], bad_log)
            summary.actuators.append(name)
            summary.unit_samples[name] = 0
            digests[name] = StreamDigest(stored(name) if stored is not None else None)
        t_all, ch_all, seq = block_columns(blk)
        parts = clocks[name].check(t_all, ch_all, seq)
        n_keep = sum(len(k) for k, _ in parts)
        summary.skipped += len(t_all) - n_keep
        summary.time[name] = clocks[name].counts()
        for keep, restart in parts:
            t, ch, vals = t_all[keep], ch_all[keep], blk.values[keep]
            if name not in summary.first_t:
                summary.first_t[name] = float(t[0])
                summary.sources[name] = unit_source(name, float(t[0]), ch[0], records)
            digests[name].add(np.column_stack([t, ch]))
            summary.unit_samples[name] += len(t)
            summary.samples += len(t)
            if summary.t_start is None:
                summary.t_start = float(t[0])
            summary.t_end = max(float(t[-1]), summary.t_end or -math.inf)
            yield _Input(name, at, blk.topic, t, ch, blk.names, vals, restart=restart)


def _restart(bank: MonitorBank | MonitorFleet, row: int) -> None:
    """The filter of bank row ``row`` starts afresh at its next sample (as the daemon's
    monitoring stage does on a clock that went back)."""
    b = bank.bank if isinstance(bank, MonitorFleet) else bank
    b.t_last[row] = -np.inf


def _monitor_stage(
    inputs: Iterator[_Input],
    bank: MonitorBank | MonitorFleet,
    speed: float | None,
    t0: Callable[[], float],
) -> Iterator[tuple[list[_Input], NDArray, BankRows]]:
    """Stage 2: the samples through the bank; yields (inputs, bank rows of the samples,
    output rows) in input order.

    As fast as possible, batches of about ``_BATCH`` samples are stepped in a worker thread
    (``MonitorBank.step_arrays``, compiled, releases the GIL) while this thread reads the
    next blocks and makes the output rows of the stepped ones (``rows_of``), up to
    ``_IN_FLIGHT`` batches ahead. Paced (``speed``), slices of ``_PACED_SLICE`` samples run
    when due: ``t0()`` is the time of the first sample, due when the first slice's output
    is ready (the bank's warm-up is not caught up by running the next ones flat out)."""
    ids: dict[str, int] = {}
    if speed is not None:
        wall0 = None  # the pace starts at the first slice's output (after any JIT warm-up)
        for inp in inputs:
            if inp.name not in ids:
                ids[inp.name] = bank.index_of(inp.name)
            inp.row = ids[inp.name]
            if inp.restart:
                _restart(bank, inp.row)
            ks = np.full(len(inp.t), inp.row, np.int64)
            for a in range(0, len(inp.t), _PACED_SLICE):
                sl = slice(a, a + _PACED_SLICE)
                rows = bank.update_arrays(ks[sl], inp.t[sl], inp.ch[sl])
                if wall0 is None:
                    wall0 = time.perf_counter() - (float(inp.t[sl][0]) - t0()) / speed
                yield ([inp] if a == 0 else []), ks[sl], rows
                due = wall0 + (float(inp.t[sl][-1]) - t0()) / speed
                time.sleep(max(0.0, due - time.perf_counter()))
        return
    running: deque[tuple[Future, list[_Input], NDArray]] = deque()
    pending: list[_Input] = []
    n_pending = 0
    with ThreadPoolExecutor(1, thread_name_prefix="replay-monitor") as pool:

        def submit() -> None:
            nonlocal n_pending
            ks = np.concatenate([np.full(len(i.t), i.row, np.int64) for i in pending])
            t = np.concatenate([i.t for i in pending])
            ch = np.concatenate([i.ch for i in pending])
            running.append((pool.submit(bank.step_arrays, ks, t, ch), list(pending), ks))
            pending.clear()
            n_pending = 0

        def done(wait: bool) -> Iterator[tuple[list[_Input], NDArray, BankRows]]:
            while running and (wait or len(running) > _IN_FLIGHT or running[0][0].done()):
                fut, inps, ks = running.popleft()
                sb = fut.result()
                yield inps, ks, (bank.rows_of(sb) if sb is not None else _no_rows())

        for inp in inputs:
            if inp.name not in ids:
                yield from done(True)  # index_of may grow the bank's arrays: not while it runs
                ids[inp.name] = bank.index_of(inp.name)
            inp.row = ids[inp.name]
            if inp.restart:  # the filter restarts: after every earlier sample was stepped
                if pending:
                    submit()
                yield from done(True)
                _restart(bank, inp.row)
            pending.append(inp)
            n_pending += len(inp.t)
            if n_pending >= _BATCH:
                submit()
                yield from done(False)
        if pending:
            submit()
        yield from done(True)


def _write_stage(
    batches: Iterator[tuple[list[_Input], NDArray, BankRows]],
    writer: McapLogger | None,
    fanout: FanOut,
    summary: ReplaySummary,
    progress: Callable[[ReplaySummary], None] | None,
    fleet: MonitorFleet | None = None,
    live: Any | None = None,
) -> None:
    """Stage 3: the meas samples copied to the output log, the outputs through the fan-out
    (log blocks, events, publishing), the summary."""
    for inps, ks, rows in batches:
        for inp in inps:
            kw: dict[str, Any] = {}
            if fleet is not None:
                v = fleet.versions.get(inp.name)
                summary.commissioned[inp.name] = v
                info = {"commissioned": v is not None, "baseline_version": v}
                kw = {"c_lk0": fleet.bank.baseline_of(inp.name).c_lk, "info": info}
            if inp.restart:  # the open period closes; the next starts after the clock step
                fanout.retrack(inp.row, **({"c_lk0": None} | kw))
            fanout.track(inp.row, *inp.at, **kw)
            ints = ("seq",) if "seq" in inp.names else ()
            if writer is not None:
                writer.log_block(inp.topic, inp.t, inp.names, inp.meas, int_fields=ints)
            if live is not None and live.wants(inp.topic):
                live.log_block(inp.topic, inp.t, inp.names, inp.meas, int_fields=ints)
        summary.outputs += len(rows.index)
        for em in fanout.emit(rows, ks):
            summary.alarms.extend({"actuator": em.name, **d} for d in em.events)
            summary.published += em.published
            o = rows.output(em.last)
            summary.final[em.name] = {"t": o.t, "est": o.est, "health": o.health}
        if progress is not None:
            progress(summary)


def replay(
    log_path: str | Path,
    *,
    speed: float | None = None,
    out: str | Path | None = None,
    publish: Any | None = None,
    monitor_config: MonitorConfig | None = None,
    baseline: Baseline | None = None,
    publish_every: int = 10,
    log_every: int = 1,
    progress: Callable[[ReplaySummary], None] | None = None,
    store: str | Path | Any | None = None,
    period_config: PeriodConfig | None = None,
    flight: int | None = None,
    start_unix: float | None = None,
    flight_gap_s: float = FLIGHT_GAP_S,
    live: Any | None = None,
) -> ReplaySummary:
    """Feed the logged ``/fleet/*/*/meas`` samples of ``log_path`` through the monitor.

    ``log_path`` is a file or, when no such file exists, the base name of a rotation set
    (``{stem}-NNNN-*.mcap`` beside it, replayed in order). A pipeline of three stages, each
    passed once: read (``_read_stage``) -> monitor (``_monitor_stage``) -> fan-out and write
    (``_write_stage``, ``service.daemon.fanout.FanOut`` as in the daemon).

    Parameters
    ----------
    speed : None replays as fast as possible; ``s`` > 0 paces the samples at ``s`` x real time.
    out : a new MCAP log of the replay (meas, est, residual, health, events), or None.
    publish : a zenoh session; est/res/health are put on ``fleet/{ac}/{act}/{est,res,health}``
        every ``publish_every`` outputs per actuator.
    log_every : est/residual/health go to ``out`` every ``log_every`` outputs per actuator
        (1 = every output; events always).
    monitor_config, baseline : None takes the log's ``servowatch`` metadata (``monitor_config``,
        ``baseline`` JSON) when present, else ``MonitorConfig()`` and ``Baseline.default()``.

    store : a health store (path, URL or an open ``HealthStore``): per-actuator baselines
        from it, and the operating periods and alarm raises written to it (``period_config``
        cuts the periods).
    flight, start_unix, flight_gap_s : the periods' flight number and the calendar time of the
        log's first sample, else from the log's flight records, else the gap rule with this
        gap (``service.prognostics.life``); in the store, gap-rule flights are renumbered
        over each unit's whole history (``HealthStore.ingest_log``).
    live : a ``FoxgloveFeed``: meas, est, residual, health and events served live (the
        actuators named in the log's summary are advertised before the first sample).

    A truncated log is replayed up to its last complete chunk; the summary says so in
    ``truncated`` and ``warnings``. A corrupt chunk is skipped (``corrupt_chunks``); the
    time checks' counts are in ``time`` per unit. ``LogError`` names a file that is not an
    MCAP log, holds no complete chunk, or has malformed servowatch metadata;
    ``StoreWriteError`` a store that failed while the log was written (nothing of the log
    stored).
    """
    if speed is not None and not speed > 0:
        raise ValueError("speed must be > 0 or None")
    if log_every < 1 or publish_every < 1:
        raise ValueError("log_every and publish_every must be >= 1")
    log_path = Path(log_path)
    with LogSet(log_path) as logset:  # each file opened once, read through that handle
        return _replay_set(logset, log_path, speed, out, publish, monitor_config, baseline,
                           publish_every, log_every, progress, store, period_config, flight,
                           start_unix, flight_gap_s, live)  # fmt: skip


def _replay_set(logset, log_path, speed, out, publish, monitor_config, baseline, publish_every,
                log_every, progress, store, period_config, flight, start_unix, flight_gap_s,
                live) -> ReplaySummary:  # fmt: skip
    """``replay`` of an open ``LogSet``."""
    files = logset.paths
    logset.check()
    meta = logset.metadata
    try:
        if monitor_config is None and "monitor_config" in meta:
            monitor_config = MonitorConfig.model_validate_json(meta["monitor_config"])
        logged = Baseline.model_validate_json(meta["baseline"]) if "baseline" in meta else None
    except ValueError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise LogError(f"{files[0]}: its servowatch metadata is malformed: {first}") from None
    cfg = monitor_config or MonitorConfig()
    summary = ReplaySummary(log=str(log_path), out=str(out) if out is not None else None)
    if baseline is None and logged is not None:
        if logged.law == cfg.model:
            baseline = logged
        else:  # the log's baseline is another model's: never carried over
            summary.warnings.append(
                f"the log's baseline is for process model {logged.law}, the replay runs "
                f"{cfg.model}: monitoring on {cfg.model}'s default baseline"
            )
    base = baseline or Baseline.default(cfg.model)
    check_baseline_model(base, cfg.model)
    summary.files = [str(f) for f in files]
    if flight is not None and (isinstance(flight, bool) or not 0 <= int(flight) <= MAX_FLIGHT):
        raise ValueError(f"flight must be an integer in 0..{MAX_FLIGHT}, got {flight!r}")
    hs, own = None, False
    if isinstance(store, str | Path):
        from service.store import open_store

        hs, own = open_store(store), True
    elif store is not None:
        hs = store
    life = None
    if hs is not None:
        records = logset.flight_records
        life = (FlightStamper(None, flight_gap_s), records, flight, start_unix, flight_gap_s)
    try:
        if live is not None:
            for ac, act in logset.units:
                live.add_actuator(ac, act)
        return _replay(logset, log_path, summary, cfg, base, hs, speed, out, publish,
                       publish_every, log_every, progress, period_config, life,
                       live)  # fmt: skip
    finally:
        if own and hs is not None:
            hs.close()


def log_actuators(files: list[Path]) -> list[tuple[str, str]]:
    """(aircraft, actuator) of the ``meas`` channels of ``files`` (a file without a summary,
    e.g. truncated, is scanned)."""
    from service.log.logfile import LogFile

    out: list[tuple[str, str]] = []
    for f in files:
        with LogFile(f) as lf:
            out.extend(at for at in lf.units if at not in out)
    return out


def _replay(logset, log_path, summary, cfg, base, hs, speed, out, publish, publish_every,
            log_every, progress, period_config, life=None, live=None) -> ReplaySummary:  # fmt: skip
    """``replay`` once the log, the configuration and the store (``hs``) are resolved."""
    closed: list = []
    alarms: list = []
    digests: dict[str, StreamDigest] = {}
    if hs is None:
        bank: MonitorBank | MonitorFleet = MonitorBank(cfg, base)
    else:

        def resolve(name: str) -> tuple[Baseline, int | None]:
            rec = hs.latest_baseline(name)
            if rec is None:
                return base, None
            return Baseline.model_validate(rec.baseline), rec.version

        bank = MonitorFleet(cfg, base, resolve)
        summary.source = "log:pending"  # each unit's source is known at its first sample
    writer = McapLogger(
        out,
        flush_s=1.0,
        metadata={
            "source": "replay",
            "replay_of": str(log_path),
            "monitor_config": cfg.model_dump_json(),
            "baseline": base.model_dump_json(),
        },
    ) if out is not None else None  # fmt: skip
    fanout = FanOut(
        writer, log_every=log_every, publish_every=publish_every, session=publish,
        on_periods=None if hs is None else (lambda p, a: (closed.extend(p), alarms.extend(a))),
        source=summary.source or "replay", period_config=period_config, live=live,
    )  # fmt: skip
    stats = LogReadStats()
    wall0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TruncatedLogWarning)
        warnings.simplefilter("always", CorruptChunkWarning)
        inputs = _read_stage(logset, stats, summary, life[1] if life is not None else (),
                             digests, hs.stream_ids if hs is not None else None)  # fmt: skip
        batches = _monitor_stage(inputs, bank, speed, lambda: summary.t_start or 0.0)
        try:
            fleet = bank if isinstance(bank, MonitorFleet) else None
            _write_stage(batches, writer, fanout, summary, progress, fleet, live)
            fanout.flush()
        finally:
            batches.close()  # stops the monitor stage's worker thread
            fanout.close()
            if writer is not None:
                writer.close()
    _check_read(log_path, stats)
    if hs is not None:
        _store_log(hs, logset.files, log_path, summary, closed, alarms, life, digests,
                   logset.metadata.get("log_id"))  # fmt: skip
    summary.wall_s = time.perf_counter() - wall0
    summary.corrupt_chunks = stats.corrupt
    for w in caught:
        if issubclass(w.category, CorruptChunkWarning):
            summary.warnings.append(str(w.message))
        elif issubclass(w.category, TruncatedLogWarning):
            summary.truncated = True
            summary.warnings.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if summary.t_start is not None and summary.t_end is not None:
        summary.duration_s = summary.t_end - summary.t_start
        if summary.wall_s > 0 and summary.samples > 1:
            summary.speed = summary.duration_s / summary.wall_s
    summary.counters = {
        n: bank.counters_of(n)
        for n in summary.actuators
        if n in digests and summary.unit_samples.get(n)
    }
    if hs is None:  # without a store: the units' stream identities all the same
        summary.sources = {a: stream_source(a, d.finish()) for a, d in digests.items()}
    for name, tc in summary.time.items():
        refused = sum(v for k, v in tc.items() if k != "restarts")
        if refused or tc["restarts"]:
            text = ", ".join(f"{k} {v}" for k, v in tc.items() if v and k != "restarts")
            w = (f"{log_path}: {name}: {refused} samples refused by the time checks ({text})"
                 if refused else f"{log_path}: {name}:")  # fmt: skip
            if tc["restarts"]:
                w += f"; clock followed after {tc['restarts']} step(s), the filter restarted"
            summary.warnings.append(w)
            log.warning(w)
    if summary.samples == 0:
        summary.warnings.append(f"{log_path}: no /fleet/*/*/meas samples")
    return summary


def _check_read(log_path: Path, stats: LogReadStats) -> None:
    """LogError for a log that held no meas message at all (nothing to replay)."""
    if stats.messages == 0:
        why = "; ".join(x for x in (stats.reason, f"{stats.corrupt} corrupt chunk(s)"
                                    if stats.corrupt else "") if x)  # fmt: skip
        raise LogError(f"{log_path}: no /fleet/*/*/meas messages in it"
                       + (f" ({why})" if why else ""))  # fmt: skip


def _store_log(hs, files, log_path, summary, closed, alarms, life, digests, log_id=None) -> None:
    """The log's periods and alarms into the store in one transaction
    (``HealthStore.ingest_log``: each unit by its stream identity against the stored ones;
    gap-rule flights renumbered along each unit's life order). ``log_id``: the daemon's id
    of the log (its live periods, ``live:...@{log_id}``, are replaced by the log's)."""
    from service.store.lifeorder import LogUnit

    st, records, flight, start_unix, gap_s = life
    order = {a: tuple(float(p.start_t) for p in closed if p.actuator == a)
             for a in summary.actuators}  # fmt: skip
    closed = st.stamp(closed, records=records, first_t=summary.first_t, flight=flight,
                      start_unix=start_unix)  # fmt: skip
    legacy = legacy_log_source(files)
    units = []
    for a in summary.actuators:
        if a not in summary.sources:
            continue
        d = digests[a]
        sid = d.finish()
        src = stream_source(a, sid)
        units.append(LogUnit(
            a, src, summary.unit_samples[a], log_path.name,
            flight is None and not any(r.name == a for r in records),
            (summary.sources[a], legacy), sid,
            d.relate(sid),
            order[a], flight, start_unix, summary.first_t.get(a),
            f"@{log_id}" if log_id else None,
        ))  # fmt: skip
        summary.sources[a] = src
    try:
        res = hs.ingest_log(units, closed, alarms, gap_s)
    except Exception as e:
        first = (str(e).strip().splitlines() or [""])[0] or type(e).__name__
        raise StoreWriteError(
            f"store {getattr(hs, 'where', hs)}: writing {log_path} failed: {first}"
        ) from e
    summary.source = summary.sources[units[0].actuator] if units else None
    summary.periods = len(closed)
    store_result(summary, res)


def expand_logs(items: list[str | Path]) -> list[Path]:
    """Log paths of ``items``: a file, a folder (its ``*.mcap`` files, recursively), a glob
    pattern, or a rotation set's base name; each path once. FileNotFoundError names an item
    that matches nothing."""
    import glob

    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(p.rglob("*.mcap"))
        elif p.is_file():
            found = [p]
        elif any(c in str(item) for c in "*?["):
            found = sorted(Path(f) for f in glob.glob(str(item), recursive=True))
            found = [f for f in found if f.is_file()]
        else:
            found = [p] if rotated_files(p) else []
        if not found:
            raise FileNotFoundError(f"{item}: no such log, folder or matching file")
        out.extend(found)
    seen: set[Path] = set()
    return [f for f in out if not (f.resolve() in seen or seen.add(f.resolve()))]


def log_order(paths: list[Path]) -> list[Path]:
    """``paths`` in life order: logs with a flight record by its calendar start, then by its
    flight number, then the rest by name (digits compared as numbers;
    ``service.replay.cluster.order_key``). The order a batch reads its logs in; the flights stored
    do not depend on it (``HealthStore.ingest_log``)."""
    from service.replay.cluster import order_key

    return sorted(paths, key=lambda p: order_key(Path(p), str(p)))


def replay_many(
    logs: list[Path],
    store: str | Path | Any,
    *,
    on_log: Callable[[Path, ReplaySummary | None, Exception | None], None] | None = None,
    flight_gap_s: float = FLIGHT_GAP_S,
    jobs: int = 1,
    tick: Callable[[], None] | None = None,
    pool: Any | None = None,
    report: Any | None = None,
    task_logs: int | None = None,
    **kw: Any,
) -> list[ReplaySummary]:
    """Ingest ``logs`` (in the given order: ``log_order``) into ``store`` (one store
    connection per process); ``kw`` as ``replay`` takes them (a ``flight`` is not: each log
    has its own). A log that cannot be replayed is reported to ``on_log(path, None,
    LogError naming it)`` and the batch goes on; the others to ``on_log(path, summary,
    None)``; ``tick()`` is called as each log is done (a progress bar). A store that fails
    while a log is written raises ``StoreWriteError`` (the logs before it are stored).

    ``jobs`` > 1 or a ``pool`` (``service.replay.cluster``: ``ProcessPool``, ``DaskPool``;
    a store path or URL only): the logs (paths or fsspec URLs) are split into groups that
    share no actuator, each group in life order, one task per group (at most ``task_logs``
    logs each) on the pool's workers, which replay them with this function and return the
    periods; this process writes them to the store as the tasks complete
    (``service.replay.cluster.run_batch``; ``report`` gets each worker's load). ``jobs``: spawned
    processes that die with the batch."""
    if "flight" in kw:
        raise ValueError("replay_many: flight numbers come from each log (or the gap rule)")
    if (pool is not None or jobs > 1) and isinstance(store, str | Path):
        from service.replay.cluster import ProcessPool, run_batch

        return run_batch(logs, store, pool if pool is not None else ProcessPool(jobs),
                         on_log=on_log, tick=tick, flight_gap_s=flight_gap_s, kw=kw,
                         work=replay_many, report=report, task_logs=task_logs)  # fmt: skip
    hs, own = store, False
    if isinstance(store, str | Path):
        from service.store import open_store

        hs, own = open_store(store), True
    try:
        out = []
        for p in logs:
            try:
                s = replay(p, store=hs, flight_gap_s=flight_gap_s, **kw)
            except StoreWriteError:
                raise
            except Exception as e:  # the file's fault: named, and the batch goes on
                log.debug("%s failed", p, exc_info=True)
                if on_log is not None:
                    on_log(p, None, LogError(named(p, e)))
                s = None
            if tick is not None:
                tick()
            if s is None:
                continue
            out.append(s)
            if on_log is not None:
                on_log(p, s, None)
        return out
    finally:
        if own:
            hs.close()
