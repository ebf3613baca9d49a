"""Offline replay: logged samples through the same monitor code, as fast as possible or paced.

The logged ``/fleet/{aircraft}/{actuator}/meas`` messages are read as column blocks
(``service.log.read_blocks``: per chunk and topic, no per-message dicts; it survives a
truncated file) and fed to one ``service.monitor.MonitorBank`` keyed by actuator, in batches
of consecutive samples (``MonitorBank.update_arrays``; as fast as possible, its two halves
``step_arrays`` and ``rows_of`` run pipelined in two threads). The bank
gives results that do not depend on the batch composition (``tests/test_monitor.py``), so a
replay reproduces the live daemon's estimates when it uses the same monitor configuration and
baseline. Outputs go to a new MCAP log with the daemon's topic layout (``meas`` copied, ``est``,
``residual``, ``health``, ``events``) and, optionally, are republished on Zenoh.
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

from service import messages as m
from service.jsonutil import event_dict, flat, jsonable
from service.log import (
    LogBlock,
    LogReadStats,
    McapLogger,
    TruncatedLogWarning,
    read_blocks,
    rotated_files,
)
from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS, Baseline, MonitorBank, MonitorConfig

__all__ = ["ReplaySummary", "replay", "INPUT_KEYS", "read_metadata"]

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

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types (non-finite floats as None)."""
        return jsonable(asdict(self))


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``servowatch`` metadata record of an MCAP file ({} if absent or unreadable).

    McapLogger writes it right after the header, so the scan stops at the first chunk; a
    file from another writer is looked up through its summary's metadata index.
    """
    from mcap.reader import make_reader
    from mcap.records import Chunk, Metadata
    from mcap.stream_reader import StreamReader

    try:
        with open(path, "rb") as fh:
            for rec in StreamReader(fh, emit_chunks=True).records:
                if isinstance(rec, Metadata) and rec.name == "servowatch":
                    return dict(rec.metadata)
                if isinstance(rec, Chunk):
                    break
        with open(path, "rb") as fh:
            for md in make_reader(fh).iter_metadata():
                if md.name == "servowatch":
                    return dict(md.metadata)
    except Exception:
        return {}
    return {}


def _read_files(files: list[Path], stats: LogReadStats) -> Iterator[LogBlock]:
    for f in files:
        st = LogReadStats()
        yield from read_blocks(f, stats=st, match=_is_meas)
        stats.chunks += st.chunks
        stats.messages += st.messages
        stats.truncated = stats.truncated or st.truncated


def _block_inputs(blk: LogBlock, t_last: float) -> tuple[NDArray, NDArray, NDArray]:
    """Sample times (the ``t`` field, else the log time), channels (n, 7) in
    ``messages.CHANNELS`` order (NaN: absent) and the samples to keep: finite t later than
    ``t_last`` and than every earlier sample of the block (the daemon logs accepted samples
    only; a replay checks again)."""
    col = {k: c for c, k in enumerate(blk.names)}
    n = len(blk.t)
    t = blk.values[:, col["t"]] if "t" in col else blk.t
    ch = np.full((n, len(m.CHANNELS)), np.nan)
    for c, k in enumerate(m.CHANNELS):
        if k in col:
            ch[:, c] = blk.values[:, col[k]]
    fin = np.isfinite(t)
    prev = np.maximum.accumulate(np.where(fin, t, -np.inf))
    prev = np.concatenate([[t_last], np.maximum(prev[:-1], t_last)]) if n else prev
    return t, ch, fin & (t > prev)


def _is_meas(topic: str) -> bool:
    return topic.startswith("/fleet/") and topic.endswith("/meas")


def _parse_topic(topic: str) -> tuple[str, str] | None:
    parts = topic.split("/")
    if len(parts) != 5 or parts[0] != "" or parts[1] != "fleet" or parts[4] != "meas":
        return None
    return parts[2], parts[3]


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
) -> ReplaySummary:
    """Feed the logged ``/fleet/*/*/meas`` samples of ``log_path`` through the monitor.

    ``log_path`` is a file or, when no such file exists, the base name of a rotation set
    (``{stem}-NNNN-*.mcap`` beside it, replayed in order).

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

    A truncated log is replayed up to its last complete chunk; the summary says so in
    ``truncated`` and ``warnings``.
    """
    if speed is not None and not speed > 0:
        raise ValueError("speed must be > 0 or None")
    if log_every < 1 or publish_every < 1:
        raise ValueError("log_every and publish_every must be >= 1")
    log_path = Path(log_path)
    files = rotated_files(log_path)
    if not files:
        raise FileNotFoundError(f"{log_path}: no such log (nor a rotation set {log_path.stem}-*)")
    meta = read_metadata(files[0])
    if monitor_config is None and "monitor_config" in meta:
        monitor_config = MonitorConfig.model_validate_json(meta["monitor_config"])
    if baseline is None and "baseline" in meta:
        baseline = Baseline.model_validate_json(meta["baseline"])
    cfg = monitor_config or MonitorConfig()
    base = baseline or Baseline.default(cfg.model)
    bank = MonitorBank(cfg, base)
    summary = ReplaySummary(log=str(log_path), out=str(out) if out is not None else None)
    summary.files = [str(f) for f in files]
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
    pubs: dict[tuple[str, str], Any] = {}
    n_out: dict[str, int] = {}
    last_t: dict[str, float] = {}
    names: dict[str, tuple[str, str]] = {}
    prefix: dict[str, str] = {}
    row_name: dict[int, str] = {}  # bank row -> actuator name
    topics: dict[str, str | None] = {}
    pending: list[tuple[NDArray, NDArray, NDArray]] = []  # (ks, t, channels) not yet run
    n_pending = 0
    stats = LogReadStats()
    wall0 = time.perf_counter()
    t_first: float | None = None

    # as fast as possible: the filter steps run in a worker thread (MonitorBank.step_arrays, a
    # compiled loop that releases the GIL) while this thread reads the next blocks, makes
    # the output rows of the stepped ones (rows_of, also compiled) and logs them
    pool = ThreadPoolExecutor(1, thread_name_prefix="replay-monitor") if speed is None else None
    # step_arrays calls queued on the one worker (run in order: the bank is sequential), so
    # it runs back to back while this thread reads ahead; their outputs handled in order
    running: deque[tuple[Future, NDArray]] = deque()

    def finish(fut: Future, ks: NDArray) -> None:
        sb = fut.result()
        if sb is not None:
            handle(bank.rows_of(sb), ks)

    def collect(wait: bool) -> None:
        while running and (wait or running[0][0].done()):
            finish(*running.popleft())

    def drain() -> None:
        collect(True)

    def flush_batch() -> None:
        # one update_arrays call for what is pending; outputs stay numpy rows and are logged
        # as blocks; dicts only for what is published or kept in the summary
        nonlocal n_pending
        if not pending:
            return
        if len(pending) == 1:
            ks, t, ch = pending[0]
        else:
            ks, t, ch = (np.concatenate(c) for c in zip(*pending, strict=True))
        pending.clear()
        n_pending = 0
        if pool is None:
            handle(bank.update_arrays(ks, t, ch), ks)
            return
        # the worker steps the filters; this thread makes the rows (alarms, outputs) of the
        # blocks it has stepped, in order, while it steps the next ones
        running.append((pool.submit(bank.step_arrays, ks, t, ch), ks))
        while len(running) > _IN_FLIGHT:  # bounded read-ahead
            finish(*running.popleft())
        collect(False)

    def handle(rows: Any, ks: NDArray) -> None:
        idx = rows.index
        if len(idx) == 0:
            return
        summary.outputs += len(idx)
        owner = ks[idx]
        has_ev = rows.events.flags()
        order = np.argsort(owner, kind="stable")
        for g in np.split(order, np.flatnonzero(np.diff(owner[order])) + 1):
            name = row_name[int(owner[g[0]])]
            n0 = n_out.get(name, 0)
            num = n0 + 1 + np.arange(len(g))
            n_out[name] = n0 + len(g)
            ev = has_ev[g]
            b = prefix[name]
            if writer is not None:
                sel = g[(num % log_every == 0) | ev]
                if len(sel):
                    ts = rows.t[sel]
                    writer.log_block(b + "est", ts, EST_KEYS, rows.est[sel])
                    writer.log_block(b + "residual", ts, RES_KEYS, rows.res[sel])
                    writer.log_block(b + "health", ts, HEALTH_KEYS, rows.health[sel])
            for r in g[ev].tolist():
                t_r = float(rows.t[r])
                for e in rows.events[r]:
                    d = event_dict(e)
                    summary.alarms.append({"actuator": name, **d})
                    if writer is not None:
                        writer.log(b + "events", float(d.get("t") or t_r), flat(d))
            if publish is not None:
                ac, act = names[name]
                for r in g[num % publish_every == 0].tolist():
                    _publish(publish, pubs, ac, act, rows.output(r))
                    summary.published += 1
            o = rows.output(int(g[-1]))
            summary.final[name] = {"t": o.t, "est": o.est, "health": o.health}

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TruncatedLogWarning)
        try:
            for blk in _read_files(files, stats):
                name = topics.get(blk.topic, "")
                if name == "":
                    at = _parse_topic(blk.topic)
                    name = topics[blk.topic] = None if at is None else f"{at[0]}/{at[1]}"
                    if name is not None and name not in names:
                        drain()  # index_of may grow the bank's arrays: not while it runs
                        names[name] = at  # type: ignore[assignment]
                        prefix[name] = f"/fleet/{at[0]}/{at[1]}/"  # type: ignore[index]
                        summary.actuators.append(name)
                        row_name[bank.index_of(name)] = name
                if name is None:
                    continue
                t, ch, keep = _block_inputs(blk, last_t.get(name, -math.inf))
                n_keep = int(keep.sum())
                summary.skipped += len(keep) - n_keep
                if n_keep == 0:
                    continue
                if n_keep < len(keep):
                    t, ch = t[keep], ch[keep]
                last_t[name] = float(t[-1])
                summary.samples += n_keep
                if t_first is None:
                    t_first = float(t[0])
                    summary.t_start = t_first
                summary.t_end = float(t[-1])
                if writer is not None:
                    vals = blk.values if n_keep == len(keep) else blk.values[keep]
                    ints = ("seq",) if "seq" in blk.names else ()
                    writer.log_block(blk.topic, t, blk.names, vals, int_fields=ints)
                ks = np.full(n_keep, bank.index_of(name), np.int64)
                if speed is None:
                    pending.append((ks, t, ch))
                    n_pending += n_keep
                    if n_pending >= _BATCH:
                        flush_batch()
                        if progress is not None:
                            progress(summary)
                    continue
                # paced: run what is due in slices of about 10 ms of data, then wait
                for a in range(0, n_keep, _PACED_SLICE):
                    sl = slice(a, a + _PACED_SLICE)
                    pending.append((ks[sl], t[sl], ch[sl]))
                    flush_batch()
                    due = wall0 + (float(t[sl][-1]) - t_first) / speed
                    time.sleep(max(0.0, due - time.perf_counter()))
            flush_batch()
            drain()
        finally:
            if pool is not None:
                pool.shutdown(wait=True)
            if writer is not None:
                writer.close()
    summary.wall_s = time.perf_counter() - wall0
    for w in caught:
        if issubclass(w.category, TruncatedLogWarning):
            summary.truncated = True
            summary.warnings.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if summary.t_start is not None and summary.t_end is not None:
        summary.duration_s = summary.t_end - summary.t_start
        if summary.wall_s > 0 and summary.samples > 1:
            summary.speed = summary.duration_s / summary.wall_s
    summary.counters = {n: bank.counters_of(n) for n in summary.actuators}
    if summary.samples == 0:
        summary.warnings.append(f"{log_path}: no /fleet/*/*/meas samples")
    return summary


def _publish(session: Any, pubs: dict, ac: str, act: str, o: Any) -> None:
    for tmpl, leaf, d in (
        (m.KEY_EST, "est", o.est),
        (m.KEY_RES, "res", o.res),
        (m.KEY_HEALTH, "health", o.health),
    ):
        p = pubs.get((ac, act, leaf))
        if p is None:
            p = pubs[(ac, act, leaf)] = session.declare_publisher(
                tmpl.format(aircraft=ac, actuator=act)
            )
        p.put(m.encode_json({"t": o.t, **jsonable(d)}))
