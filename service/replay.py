"""Offline replay: logged samples through the same monitor code, as fast as possible or paced.

The logged ``/fleet/{aircraft}/{actuator}/meas`` messages are read in log order
(``service.mcaplog.read_log``, which survives a truncated file) and fed to one
``service.monitor.MonitorBank`` keyed by actuator, in batches of consecutive samples. The bank
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
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from service import messages as m
from service.jsonutil import event_dict, flat, jsonable
from service.mcaplog import LogReadStats, McapLogger, TruncatedLogWarning, read_log, rotated_files
from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS, Baseline, MonitorBank, MonitorConfig

__all__ = ["ReplaySummary", "replay", "INPUT_KEYS", "read_metadata"]

log = logging.getLogger("servowatch.replay")

INPUT_KEYS: tuple[str, ...] = ("t", *m.CHANNELS)
_BATCH = 2048  # samples per update_rows call (the block path amortises over them)


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


def _read_files(files: list[Path], stats: LogReadStats):
    for f in files:
        st = LogReadStats()
        yield from read_log(f, stats=st, match=_is_meas)
        stats.chunks += st.chunks
        stats.messages += st.messages
        stats.truncated = stats.truncated or st.truncated


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
    topics: dict[str, str | None] = {}
    batch: list[tuple[str, dict[str, Any]]] = []
    stats = LogReadStats()
    wall0 = time.perf_counter()
    t_first: float | None = None

    def flush_batch() -> None:
        # update_rows: numpy rows; dicts are built only for what is logged, published or kept
        if not batch:
            return
        rows = bank.update_rows(batch)
        idx = rows.index.tolist()
        if not idx:
            batch.clear()
            return
        est_l, res_l, h_l = rows.est.tolist(), rows.res.tolist(), rows.health.tolist()
        t_l = rows.t.tolist()
        summary.outputs += len(idx)
        recs: list[tuple[str, float, Any]] = []
        last: dict[str, int] = {}
        for r, j in enumerate(idx):
            name = batch[j][0]
            last[name] = r
            k = n_out[name] = n_out.get(name, 0) + 1
            evs = rows.events[r]
            t_r = t_l[r]
            if writer is not None and (k % log_every == 0 or evs):
                # McapLogger makes NaN, numpy and nested values JSON-safe
                b = prefix[name]
                recs.append((b + "est", t_r, dict(zip(EST_KEYS, est_l[r], strict=True))))
                recs.append((b + "residual", t_r, dict(zip(RES_KEYS, res_l[r], strict=True))))
                recs.append((b + "health", t_r, dict(zip(HEALTH_KEYS, h_l[r], strict=True))))
            for ev in evs:
                d = event_dict(ev)
                summary.alarms.append({"actuator": name, **d})
                if writer is not None:
                    recs.append((prefix[name] + "events", float(d.get("t") or t_r), flat(d)))
            if publish is not None and k % publish_every == 0:
                ac, act = names[name]
                _publish(publish, pubs, ac, act, rows.output(r))
                summary.published += 1
        if recs:
            writer.log_many(recs)  # type: ignore[union-attr]
        for name, r in last.items():
            fin = summary.final.setdefault(name, {})
            fin["t"] = t_l[r]
            fin["est"] = dict(zip(EST_KEYS, est_l[r], strict=True))
            fin["health"] = dict(zip(HEALTH_KEYS, h_l[r], strict=True))
        batch.clear()

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TruncatedLogWarning)
        try:
            for topic, t_log, msg in _read_files(files, stats):
                name = topics.get(topic, "")
                if name == "":
                    at = _parse_topic(topic)
                    name = topics[topic] = None if at is None else f"{at[0]}/{at[1]}"
                    if name is not None and name not in names:
                        names[name] = at  # type: ignore[assignment]
                        prefix[name] = f"/fleet/{at[0]}/{at[1]}/"  # type: ignore[index]
                        summary.actuators.append(name)
                if name is None:
                    continue
                t = msg.get("t", t_log)
                if type(t) is not float and (not isinstance(t, int | float) or isinstance(t, bool)):
                    summary.skipped += 1
                    continue
                if not math.isfinite(t):
                    summary.skipped += 1
                    continue
                if name in last_t and t <= last_t[name]:
                    summary.skipped += 1  # the daemon logs accepted samples only; be safe
                    continue
                last_t[name] = t
                sample = {k: msg.get(k) for k in INPUT_KEYS}
                sample["t"] = float(t)
                summary.samples += 1
                if t_first is None:
                    t_first = float(t)
                    summary.t_start = t_first
                summary.t_end = float(t)
                if speed is not None:  # paced: process what is due, wait for this sample
                    due = wall0 + (float(t) - t_first) / speed
                    if due > time.perf_counter() + 0.002:
                        flush_batch()
                        time.sleep(max(0.0, due - time.perf_counter()))
                if writer is not None:
                    writer.log(topic, float(t), msg)
                batch.append((name, sample))
                if len(batch) >= _BATCH:
                    flush_batch()
                    if progress is not None:
                        progress(summary)
            flush_batch()
        finally:
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
