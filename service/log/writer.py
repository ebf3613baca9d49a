"""The MCAP writer: :class:`McapLogger` (protobuf rows, JSON messages, schemas, flush thread,
rotation).

Rows of numbers (:meth:`McapLogger.log_block`, :meth:`McapLogger.log_rows`: the daemon's meas,
est, residual and health) are protobuf messages of a fixed layout with the message's
FileDescriptorSet as the channel's schema (:mod:`service.log.rows`); other messages
(:meth:`McapLogger.log`: events, service events) are JSON with a jsonschema per topic. Foxglove
decodes both; ``log_time`` = ``publish_time`` = sample time in ns, topics like
``/fleet/AC001/elevator_L/residual``. The chunk in progress is ended and written at least every
``flush_s`` seconds (by the writing calls and by a background thread), so a writer killed with
``kill -9`` loses at most about ``flush_s`` of data; files rotate by size or age; ``close``
finishes the file (summary, footer). All methods are thread-safe.

:meth:`McapLogger.log_rows` writes the rows of many topics with the same fields from one float
array: one array copy into the records' template and one append (``BlockWriter.add_rows``), no
per-row Python.

The first failure to write or flush (disk full, a closed stream) is kept in
:attr:`McapLogger.failure`, logged at ERROR and raised to the caller; the background thread,
which has no caller, stops flushing after it. Messages logged after a failure are counted in
:attr:`McapLogger.dropped` and not written (the writer's state is unknown after a failed
write, and buffering them would only grow the memory).
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.writer import CompressionType

from service.compat.mcap import BlockWriter
from service.jsonutil import flat
from service.log.events import EVENT_FIELDS as _EVENT_FIELDS
from service.log.events import EVENT_MESSAGE, encode_event, event_schema
from service.log.retention import lock_shared
from service.log.rows import RowLayout, row_layout

try:
    import zstandard
except ImportError:  # pragma: no cover
    zstandard = None
try:
    import lz4.frame as lz4_frame
except ImportError:  # pragma: no cover
    lz4_frame = None

__all__ = ["McapLogger", "json_schema_for", "row_schema", "encode_message"]

log = logging.getLogger("servowatch.log")

_LIBRARY = "servowatch"
_ENCODE = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


EVENT_NAMES = tuple(f[0] for f in _EVENT_FIELDS)


def channel_metadata(names: Iterable[str]) -> dict[str, str]:
    """A channel's metadata: ``units``, the JSON ``{field: unit}`` of its fields
    (``service.log.units``)."""
    from service.log.units import units_of

    u = units_of(tuple(names))
    return {"units": json.dumps(u, separators=(",", ":"))} if u else {}


def json_schema_for(topic: str, msg: Mapping[str, Any]) -> dict[str, Any]:
    """A flat jsonschema for messages like ``msg`` (numbers may be null; extra keys allowed)."""
    props: dict[str, Any] = {}
    for k, v in msg.items():
        if isinstance(v, bool):
            props[k] = {"type": "boolean"}
        elif isinstance(v, int):
            props[k] = {"type": "integer"}
        elif isinstance(v, float) or v is None:
            props[k] = {"type": ["number", "null"]}
        elif isinstance(v, str):
            props[k] = {"type": "string"}
        else:
            props[k] = {}
    return {"title": topic, "type": "object", "properties": props}


def encode_message(msg: Mapping[str, Any]) -> bytes:
    """The JSON bytes :meth:`McapLogger.log` writes for ``msg`` (compact; non-finite floats
    as null and other values made flat by ``service.jsonutil.flat``)."""
    try:
        return _ENCODE(msg).encode()
    except (ValueError, TypeError):
        return _ENCODE(flat(dict(msg))).encode()


def row_schema(topic: str, names: Iterable[str], int_fields: Iterable[str] = ()) -> RowLayout:
    """The protobuf layout (message name, FileDescriptorSet in ``.schema``) that
    :meth:`McapLogger.log_block` gives rows of ``names`` on ``topic``."""
    return row_layout(
        topic.rsplit("/", 1)[-1], tuple(str(n) for n in names), frozenset(map(str, int_fields))
    )


class McapLogger:
    """Thread-safe MCAP writer: protobuf rows and JSON messages, periodic flush,
    rotation by size (``rotate_bytes``) and/or age (``rotate_s``).

    Without rotation the file is ``path`` itself; with rotation the files are
    ``{stem}-{counter:04d}-{UTC timestamp}{suffix}`` beside ``path``. ``paths`` lists the
    files written so far; ``failure`` is None or the first write/flush error (text). Use as a
    context manager or call :meth:`close`.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        rotate_bytes: int | None = None,
        rotate_s: float | None = None,
        flush_s: float = 1.0,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
        zstd_level: int = 1,
        background_flush: bool = True,
        metadata: Mapping[str, str] | None = None,
    ):
        if flush_s <= 0:
            raise ValueError("flush_s must be > 0")
        if rotate_bytes is not None and rotate_bytes <= 0:
            raise ValueError("rotate_bytes must be > 0 or None")
        if rotate_s is not None and rotate_s <= 0:
            raise ValueError("rotate_s must be > 0 or None")
        if compression not in ("zstd", "lz4", "none"):
            raise ValueError(f"compression must be zstd, lz4 or none, not {compression!r}")
        self.path = Path(path)
        self.rotate_bytes = rotate_bytes
        self.rotate_s = rotate_s
        self.flush_s = float(flush_s)
        self.chunk_size = int(chunk_size)
        self._compression = {
            "zstd": CompressionType.ZSTD if zstandard is not None else CompressionType.NONE,
            "lz4": CompressionType.LZ4 if lz4_frame is not None else CompressionType.NONE,
            "none": CompressionType.NONE,
        }[compression]
        self.zstd_level = int(zstd_level)
        self._metadata = dict(metadata or {})
        self._records: dict[str, dict[str, str]] = {}  # add_metadata, repeated in each file
        self.paths: list[Path] = []
        self.message_count = 0
        self.flush_count = 0
        self.failure: str | None = None
        self.dropped = 0  # messages not written because of the failure
        self._lock = threading.RLock()
        self._closed = False
        self._counter = 0
        self._fh: IO[bytes] | None = None
        self._writer: BlockWriter | None = None
        self._channels: dict[str, int] = {}  # JSON channels by topic
        self._row_channels: dict[tuple[str, RowLayout], int] = {}  # protobuf channels
        self._row_schemas: dict[RowLayout, int] = {}
        self._event_channels: dict[str, int] = {}
        self._event_schema: int | None = None
        self._seq: dict[int, int] = {}
        self._dirty = False
        self._since_check = 0
        self._open_next()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if background_flush:
            self._thread = threading.Thread(target=self._flush_loop, name="mcap-flush", daemon=True)
            self._thread.start()

    # ----------------------------------------------------------------- files
    def _next_path(self) -> Path:
        if self.rotate_bytes is None and self.rotate_s is None:
            return self.path
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        p = self.path.with_name(f"{self.path.stem}-{self._counter:04d}-{stamp}{self.path.suffix}")
        self._counter += 1
        return p

    def _open_next(self) -> None:
        p = self._next_path()
        p.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(p, "wb")  # noqa: SIM115 - closed in _finish_current
        lock_shared(self._fh)  # a retention sweep (of any process) never deletes it
        self._writer = BlockWriter(
            self._fh,
            chunk_size=self.chunk_size,
            compression=self._compression,
            zstd_level=self.zstd_level,
        )
        self._writer.start(profile="", library=_LIBRARY)
        if self._metadata:
            self._writer.add_metadata("servowatch", self._metadata)
        for name, md in self._records.items():
            self._writer.add_metadata(name, md)
        self._channels.clear()
        self._row_channels.clear()
        self._row_schemas.clear()
        self._event_channels.clear()
        self._event_schema = None
        self._seq.clear()
        self._opened_at = time.monotonic()
        self._last_flush = self._opened_at
        self.paths.append(p)
        log.debug("mcap: writing %s", p)

    def _finish_current(self) -> None:
        try:
            if self._writer is not None:
                self._writer.finish()
        finally:
            self._writer = None
            if self._fh is not None:
                self._fh.close()
                self._fh = None

    def _maybe_rotate(self) -> None:
        fh = self._fh
        if fh is None:
            return
        too_big = self.rotate_bytes is not None and fh.tell() >= self.rotate_bytes
        too_old = self.rotate_s is not None and time.monotonic() - self._opened_at >= self.rotate_s
        if too_big or too_old:
            self._finish_current()
            self._open_next()

    def _failed(self, what: str, e: BaseException) -> None:
        """Keep and log the first failure (the caller re-raises)."""
        if self.failure is None:
            self.failure = f"{what} {self.paths[-1] if self.paths else self.path}: " + (
                f"{type(e).__name__}: {e}"
            )
            log.error("mcap: %s", self.failure)

    # ----------------------------------------------------------------- writing
    def _channel(self, topic: str, msg: Mapping[str, Any]) -> int:
        w = self._writer
        assert w is not None
        schema = json_schema_for(topic, msg)
        sid = w.register_schema(
            name=topic.rsplit("/", 1)[-1] or topic,
            encoding="jsonschema",
            data=json.dumps(schema).encode(),
        )
        cid = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        self._channels[topic] = cid
        self._seq[cid] = 0
        return cid

    def add_metadata(self, name: str, metadata: Mapping[str, str]) -> None:
        """Write an MCAP metadata record ``name`` now (and again at the start of each later
        rotated file); a later record of the same name replaces it for those files."""
        md = {str(k): str(v) for k, v in metadata.items()}
        with self._lock:
            self._records[name] = md
            if self._writer is not None and self.failure is None:
                try:
                    self._writer.add_metadata(name, md)
                except Exception as e:
                    self._failed("metadata", e)
                    raise

    def log(self, topic: str, t: float, msg: Mapping[str, Any]) -> None:
        """Append ``msg`` (flat JSON-serialisable mapping) on ``topic`` at sample time ``t`` [s].

        Non-finite floats are written as ``null`` (JSON has no NaN), numpy scalars as numbers,
        nested lists or mappings as JSON text (the fields stay flat), other objects as text
        (``service.jsonutil.flat``).
        """
        try:
            data = _ENCODE(msg).encode()
        except (ValueError, TypeError):
            msg = flat(dict(msg))  # the schema of a new topic is made from the flat message
            data = _ENCODE(msg).encode()
        self._write_one("log", lambda: self._channels.get(topic), lambda: self._channel(topic, msg),
                        t, data, check_every=64)  # fmt: skip

    def _write_one(
        self,
        what: str,
        known: Callable[[], int | None],
        register: Callable[[], int],
        t: float,
        data: bytes,
        check_every: int,
    ) -> None:
        """One message at ``t`` [s] on the channel ``known()`` gives (``register()`` when it
        gives None), under the lock: numbered per channel, counted, dropped once the log
        failed; the flush and rotation checks every ``check_every``-th call (1: each)."""
        t_ns = max(0, int(round(t * 1e9)))
        with self._lock:
            if self._closed:
                raise ValueError(f"{what}() on a closed McapLogger")
            if self.failure is not None:
                self.dropped += 1
                return
            try:
                cid = known()
                if cid is None:
                    cid = register()
                seq = self._seq[cid]
                self._seq[cid] = (seq + 1) & 0xFFFFFFFF
                self._writer.add_message(cid, t_ns, data, t_ns, seq)  # type: ignore[union-attr]
                self.message_count += 1
                self._dirty = True
                if check_every > 1:
                    self._since_check += 1
                    if self._since_check < check_every:
                        return
                    self._since_check = 0
                if time.monotonic() - self._last_flush >= self.flush_s:
                    self._flush_locked()
                self._maybe_rotate()
            except Exception as e:
                self._failed("write", e)
                raise

    def _row_channel(self, topic: str, lay: RowLayout) -> int:
        cid = self._row_channels.get((topic, lay))
        if cid is None:
            w = self._writer
            assert w is not None
            sid = self._row_schemas.get(lay)
            if sid is None:
                sid = self._row_schemas[lay] = w.register_schema(
                    name=lay.message, encoding="protobuf", data=lay.schema
                )
            cid = w.register_channel(
                topic=topic, message_encoding="protobuf", schema_id=sid,
                metadata=channel_metadata(lay.names),
            )  # fmt: skip
            self._row_channels[(topic, lay)] = cid
            self._seq[cid] = 0
        return cid

    def log_block(
        self,
        topic: str,
        t: np.ndarray,
        names: Iterable[str],
        values: np.ndarray,
        *,
        int_fields: Iterable[str] = (),
    ) -> None:
        """Append one protobuf message per row of ``values`` (N, F) on ``topic`` at times
        ``t`` (N,) [s]: field ``names[f]`` is ``values[k, f]`` (a ``double``; an ``sfixed64``
        for the fields in ``int_fields``, truncated, which must be finite). Non-finite doubles
        are written as they are. See :meth:`log_rows`."""
        tt = np.asarray(t, dtype=np.float64).reshape(-1)
        self.log_rows([topic], [tt.size], tt, names, values, int_fields=int_fields)

    def log_rows(
        self,
        topics: Iterable[str],
        counts: Iterable[int],
        t: np.ndarray,
        names: Iterable[str],
        values: np.ndarray,
        *,
        int_fields: Iterable[str] = (),
    ) -> None:
        """:meth:`log_block` for consecutive runs of rows: rows ``sum(counts[:i]) :`` +
        ``counts[i]`` of ``t`` and ``values`` on ``topics[i]``, encoded and appended at once.
        The schema is the message ``servowatch.<Leaf>`` of the topic's last key chunk
        (:func:`service.log.rows.row_layout`); one channel per topic and field list. Same
        flush and rotation as :meth:`log` (checked once per call)."""
        topics_l = [str(x) for x in topics]
        counts_a = np.asarray(list(counts), dtype=np.int64).reshape(-1)
        names_t = tuple(str(n) for n in names)
        tt = np.asarray(t, dtype=np.float64).reshape(-1)
        vals = np.ascontiguousarray(values, dtype=np.float64)
        if vals.ndim != 2 or vals.shape != (tt.size, len(names_t)):
            raise ValueError(
                f"values must be (len(t), len(names)) = ({tt.size}, {len(names_t)}), "
                f"got {vals.shape}"
            )
        if len(topics_l) != counts_a.size or int(counts_a.sum()) != tt.size:
            raise ValueError("topics and counts must match, and counts sum to len(t)")
        if len(set(names_t)) != len(names_t):
            raise ValueError(f"duplicate field names in {names_t}")
        n = tt.size
        if n == 0:
            return
        tns = tt * 1e9
        if not (np.isfinite(tns).all() and tns.max() < 2.0**63):
            raise ValueError("log_block: t must be finite and < 2**63 ns")
        lts = np.maximum(np.rint(tns), 0.0).astype(np.int64)  # = max(0, int(round(t * 1e9)))
        ints = frozenset(str(x) for x in int_fields)
        leaves = {tp.rsplit("/", 1)[-1] for tp in topics_l}
        if len(leaves) > 1:  # one message name per call: split by leaf
            k = 0
            for tp, c in zip(topics_l, counts_a.tolist(), strict=True):
                self.log_rows([tp], [c], tt[k : k + c], names_t, vals[k : k + c], int_fields=ints)
                k += c
            return
        lay = row_layout(leaves.pop(), names_t, ints)
        recs = lay.records(vals, 0, 0, lts)  # raises on a bad integer field, before the lock
        with self._lock:
            if self._closed:
                raise ValueError("log_block() on a closed McapLogger")
            if self.failure is not None:
                self.dropped += n
                return
            try:
                cids = np.empty(len(topics_l), np.int64)
                seq0 = np.empty(len(topics_l), np.int64)
                for i, (tp, c) in enumerate(zip(topics_l, counts_a.tolist(), strict=True)):
                    cid = self._row_channel(tp, lay)
                    cids[i] = cid
                    seq0[i] = self._seq[cid]
                    self._seq[cid] = (int(seq0[i]) + c) & 0xFFFFFFFF
                if len(topics_l) == 1:
                    row_cid = cids[0]
                    seqs = (seq0[0] + np.arange(n)) & 0xFFFFFFFF
                else:
                    starts = np.cumsum(counts_a) - counts_a
                    row_cid = np.repeat(cids, counts_a)
                    seqs = (np.repeat(seq0 - starts, counts_a) + np.arange(n)) & 0xFFFFFFFF
                lay.set_channels(recs, row_cid, seqs)
                self._writer.add_rows(cids, counts_a, lts, recs)  # type: ignore[union-attr]
                self.message_count += n
                self._dirty = True
                if time.monotonic() - self._last_flush >= self.flush_s:
                    self._flush_locked()
                self._maybe_rotate()
            except Exception as e:
                self._failed("write", e)
                raise

    log_blocks = log_rows  # the name ProcessLogger and the fan-out use

    def log_event(self, topic: str, t: float, event: Mapping[str, Any]) -> None:
        """Append an event (an alarm, a service event: keys t, kind, state, value, wall,
        anything else) on ``topic`` at ``t`` [s] as a ``servowatch.Event`` protobuf message
        (``service.log.events``). Same flush and rotation as :meth:`log`."""
        data = encode_event(event)
        self._write_one("log_event", lambda: self._event_channels.get(topic),
                        lambda: self._event_channel(topic), t, data, check_every=1)  # fmt: skip

    def _event_channel(self, topic: str) -> int:
        """The ``servowatch.Event`` channel of ``topic``, registered (with the schema, once)."""
        w = self._writer
        assert w is not None
        if self._event_schema is None:
            self._event_schema = w.register_schema(
                name=EVENT_MESSAGE, encoding="protobuf", data=event_schema()
            )
        cid = self._event_channels[topic] = w.register_channel(
            topic=topic, message_encoding="protobuf", schema_id=self._event_schema,
            metadata=channel_metadata(EVENT_NAMES),
        )  # fmt: skip
        self._seq[cid] = 0
        return cid

    def log_many(self, records: Iterable[tuple[str, float, Mapping[str, Any]]]) -> None:
        """:meth:`log` for each ``(topic, t, msg)``, taking the lock once (fewer switches)."""
        with self._lock:
            for topic, t, msg in records:
                self.log(topic, t, msg)

    def commit(self) -> None:
        """Nothing to do in-process (``ProcessLogger.commit`` sends its queue)."""

    def _flush_locked(self) -> None:
        if self._writer is not None and self._dirty and self.failure is None:
            try:
                self._writer.flush()  # ends the chunk in progress and flushes the stream
            except Exception as e:
                self._failed("flush", e)
                raise
            self.flush_count += 1
            self._dirty = False
        self._last_flush = time.monotonic()

    def flush(self) -> None:
        """End the chunk in progress and write it out now (also rotates if due)."""
        with self._lock:
            if self._closed:
                return
            self._flush_locked()
            self._maybe_rotate()

    def _flush_loop(self) -> None:
        # wake 5 times per period and flush once the oldest unflushed data could be older
        # than flush_s by the next wake-up: nothing stays unwritten for more than flush_s
        period = self.flush_s / 5
        while not self._stop.wait(period):
            with self._lock:
                if self._closed or self.failure is not None:
                    return
                if time.monotonic() - self._last_flush >= self.flush_s - period:
                    try:
                        self._flush_locked()
                        self._maybe_rotate()
                    except Exception as e:  # disk full etc.: kept in self.failure
                        self._failed("flush", e)
                        return

    def close(self) -> None:
        """Finish the current file (summary and footer) and stop the flusher; idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            if self.failure is not None:  # the writer's state is unknown: just close the file
                self._writer = None
                with contextlib.suppress(Exception):
                    self._finish_current()
            else:
                try:
                    self._finish_current()
                except Exception as e:
                    self._failed("close", e)
                    raise
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> McapLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
