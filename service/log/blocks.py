"""The column-block reader: the messages of :func:`service.log.reader.read_log` as arrays.

:func:`read_blocks` yields one :class:`LogBlock` per chunk and channel: the records of a
decompressed chunk are found by a compiled scan, and the messages of a channel become an
(N, F) float64 array: protobuf rows (decision 0011) by one numpy gather of their fixed layout
(:meth:`service.log.rows.RowLayout.decode_block`; a message in another layout is decoded
field by field), JSON objects (older logs, and :meth:`McapLogger.log`'s messages) by the
compiled JSON parser of :mod:`service.log.codec` with ``json.loads`` for what it declines.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import numpy as np
from mcap.opcode import Opcode
from mcap.records import Channel, Schema

from service.log.reader import (
    _SKIP,
    Channels,
    LogReadStats,
    TruncatedLogWarning,
    _warn_corrupt,
    iter_stream,
    log,
    truncation_text,
)

__all__ = ["LogBlock", "read_blocks"]


class LogBlock(NamedTuple):
    """Messages of one channel with the same fields: ``values[k, f]`` is field ``names[f]``
    of the message logged at ``t[k]`` [s] (``log_time``). Protobuf rows: the doubles as
    written (NaN, inf included), integer fields as float. JSON: null and strings -> NaN,
    integers -> float, booleans -> 0/1."""

    topic: str
    t: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray


_NAN = float("nan")


def _as_float(v: Any) -> float:
    if isinstance(v, float):
        return v
    if isinstance(v, int):  # and bool
        try:
            return float(v)
        except OverflowError:
            return math.inf if v > 0 else -math.inf
    return _NAN


def _json_blocks(topic: str, items: Iterable[tuple[int, bytes]]) -> Iterator[LogBlock]:
    """Blocks from ``(log_time, data)`` messages decoded by ``json.loads``: one per run of
    messages with the same keys (messages that are not JSON objects are skipped)."""
    loads = json.loads
    keys: tuple[str, ...] | None = None
    ts: list[float] = []
    rows: list[list[float]] = []
    for lt, data in items:
        try:
            obj = loads(data)
        except ValueError:
            continue
        if not isinstance(obj, dict):
            continue
        k = tuple(obj)
        if k != keys:
            if ts:
                yield _make_block(topic, keys, ts, rows)  # type: ignore[arg-type]
            keys, ts, rows = k, [], []
        ts.append(lt * 1e-9)
        rows.append([_as_float(v) for v in obj.values()])
    if ts:
        yield _make_block(topic, keys, ts, rows)  # type: ignore[arg-type]


def _make_block(
    topic: str, keys: tuple[str, ...], ts: list[float], rows: list[list[float]]
) -> LogBlock:
    vals = np.array(rows, dtype=np.float64).reshape(len(rows), len(keys))
    return LogBlock(topic, np.array(ts, dtype=np.float64), keys, vals)


def _key_names(data: bytes, ks: np.ndarray, kl: np.ndarray) -> tuple[str, ...] | None:
    try:
        names = tuple(
            data[s : s + n].decode("utf-8", "surrogatepass")
            for s, n in zip(ks.tolist(), kl.tolist(), strict=True)
        )
    except UnicodeDecodeError:
        return None
    return names if len(set(names)) == len(names) else None


def _chunk_groups(
    data: bytes, channels: Channels
) -> tuple[np.ndarray, list[tuple[str | None, Any, np.ndarray, np.ndarray, np.ndarray]]]:
    """The messages of a decompressed chunk grouped by channel, in the order of each
    channel's first message: (chunk as uint8, [(topic, codec, log_times, data offsets, data
    lengths)]). Schema and Channel records in the chunk update ``channels``; a message takes
    the topic and codec its channel had at that point (as :func:`read_log`)."""
    from mcap.data_stream import ReadDataStream

    from service.log.codec import MSG_OPCODE, scan_records

    buf = np.frombuffer(data, np.uint8)
    ops, starts, lens, cids, lts = scan_records(buf)
    ismsg = ops == MSG_OPCODE
    chans = []
    for r in np.flatnonzero((ops == Opcode.CHANNEL) | (ops == Opcode.SCHEMA)).tolist():
        s0 = int(starts[r])
        rs = ReadDataStream(io.BytesIO(data[s0 : s0 + lens[r]]))
        if ops[r] == Opcode.SCHEMA:
            channels.add_schema(Schema.read(rs))
            continue
        ch = Channel.read(rs)
        prev = (channels.get(ch.id), channels.codec(ch.id))
        channels.add(ch)
        chans.append((r, ch.id, prev, (ch.topic, channels.codec(ch.id))))
    midx = np.flatnonzero(ismsg)
    mc = cids[midx]
    ver = np.zeros(midx.size, np.int64)  # how many Channel records of its id precede it
    versions: dict[int, list[tuple[str | None, Any]]] = {}
    for r, cid, prev, now in chans:
        versions.setdefault(cid, [prev]).append(now)
        ver[(mc == cid) & (midx > r)] += 1
    if midx.size == 0:
        return buf, []
    key = mc * (int(ver.max()) + 1) + ver if chans else mc
    uniq, first, inv = np.unique(key, return_index=True, return_inverse=True)
    order = np.argsort(inv, kind="stable")
    bounds = np.concatenate(([0], np.cumsum(np.bincount(inv, minlength=uniq.size))))
    groups = []
    for g in np.argsort(first).tolist():
        sel = midx[order[bounds[g] : bounds[g + 1]]]
        k0 = int(np.searchsorted(midx, sel[0]))
        c, v = int(mc[k0]), int(ver[k0])
        topic, codec = versions[c][v] if c in versions else (channels.get(c), channels.codec(c))
        groups.append((topic, codec, lts[sel], starts[sel] + 22, lens[sel] - 22))
    return buf, groups


def _row_block(
    topic: str, lay: Any, data: bytes, buf: np.ndarray, lts: np.ndarray, offs: np.ndarray,
    lens: np.ndarray,
) -> LogBlock:  # fmt: skip
    """A channel's protobuf rows as one block (messages that are not valid protobuf: NaN)."""
    vals = lay.decode_block(buf, offs, lens)
    if vals is None:
        vals = np.full((len(offs), len(lay.names)), np.nan)
        for k, (o, n) in enumerate(zip(offs.tolist(), lens.tolist(), strict=True)):
            with contextlib.suppress(ValueError):
                vals[k] = lay.decode_one(data[o : o + n])
    return LogBlock(topic, lts.astype(np.float64) * 1e-9, lay.names, vals)


def _group_blocks(
    topic: str,
    codec: Any,
    data: bytes,
    buf: np.ndarray,
    lts: np.ndarray,
    offs: np.ndarray,
    lens: np.ndarray,
) -> Iterator[LogBlock]:
    if codec is _SKIP:
        return
    if codec is not None:
        yield _row_block(topic, codec, data, buf, lts, offs, lens)
        return
    from service.log.codec import parse_objects

    res = parse_objects(buf, offs, lens)
    if res is not None:
        names = _key_names(data, res[0], res[1])
        if names is not None:
            yield LogBlock(topic, lts.astype(np.float64) * 1e-9, names, res[2])
            return
    yield from _json_blocks(
        topic,
        (
            (lt, data[o : o + n])
            for lt, o, n in zip(lts.tolist(), offs.tolist(), lens.tolist(), strict=True)
        ),
    )


def read_blocks(
    path: str | Path | BinaryIO,
    topics: Iterable[str] | None = None,
    *,
    stats: LogReadStats | None = None,
    match: Callable[[str], bool] | None = None,
    name: str | Path | None = None,
) -> Iterator[LogBlock]:
    """The messages of :func:`read_log` as :class:`LogBlock` arrays.

    One block per chunk and channel (split where the key list changes); within a channel the
    messages keep file order; the blocks of one chunk come in the order of each channel's
    first message in it. Un-chunked messages come as blocks of consecutive messages per
    channel. Messages that are not JSON objects are skipped. ``topics``, ``match``, ``stats``
    and the truncation warning as in :func:`read_log`. Flat objects of numbers, null, booleans
    and plain strings are parsed by compiled code (numbers equal to ``float(text)``), anything
    else by ``json.loads``. ``path`` may be a binary file open at its start
    (``service.log.logfile.LogFile``: read on that handle, left open; ``name`` names it).
    """
    p = Path(name) if name is not None else (Path(path) if not hasattr(path, "read") else Path("?"))
    src = path if hasattr(path, "read") else p
    st = stats if stats is not None else LogReadStats()
    want = None if topics is None else set(topics)
    decided: dict[str, bool] = {}

    def keep(topic: str | None) -> bool:
        if topic is None:
            return False
        k = decided.get(topic)
        if k is None:
            k = decided[topic] = (want is None or topic in want) and (
                match is None or bool(match(topic))
            )
        return k

    channels = Channels()
    pending: list[tuple[int, str, int, bytes, Any]] = []  # un-chunked messages
    for item in iter_stream(src, st, channels):
        if isinstance(item, tuple):
            topic = channels.get(item[0])
            if keep(topic):
                pending.append((item[0], topic, item[1], item[2], channels.codec(item[0])))
            continue
        if pending:
            for b in _pending_blocks(pending):
                st.messages += b.t.size
                yield b
            pending = []
        try:
            buf, groups = _chunk_groups(item, channels)
        except Exception as e:  # a corrupt chunk that passed its CRC (or has none): skipped
            st.corrupt += 1
            st.corrupt_reason = st.corrupt_reason or f"{type(e).__name__} {e}".strip()
            continue
        st.chunks += 1
        for topic, codec, lts, offs, lens in groups:
            if keep(topic):
                for b in _group_blocks(topic, codec, item, buf, lts, offs, lens):  # type: ignore[arg-type]
                    st.messages += b.t.size
                    yield b
    for b in _pending_blocks(pending):
        st.messages += b.t.size
        yield b
    _warn_corrupt(p, st)
    text = truncation_text(p, st)
    if text is not None:
        log.warning(text)
        warnings.warn(text, TruncatedLogWarning, stacklevel=2)


def _pending_blocks(pending: list[tuple[int, str, int, bytes, Any]]) -> Iterator[LogBlock]:
    by: dict[tuple[int, str], list[tuple[int, bytes, Any]]] = {}
    for cid, topic, lt, data, codec in pending:
        by.setdefault((cid, topic), []).append((lt, data, codec))
    for (_cid, topic), items in by.items():
        codec = items[0][2]
        if codec is _SKIP:
            continue
        if codec is None:
            yield from _json_blocks(topic, ((lt, d) for lt, d, _ in items))
            continue
        data = b"".join(d for _, d, _ in items)
        lens = np.fromiter((len(d) for _, d, _ in items), np.int64, len(items))
        offs = np.cumsum(lens) - lens
        lts = np.fromiter((lt for lt, _, _ in items), np.int64, len(items))
        yield _row_block(topic, codec, data, np.frombuffer(data, np.uint8), lts, offs, lens)
