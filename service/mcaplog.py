"""MCAP logging for the monitoring service, and a reader that survives a killed writer.

Writing (:class:`McapLogger`, built on ``mcap.writer.Writer``): one JSON message per sample with
flat fields and a jsonschema per topic (Foxglove's Plot panel shows the fields directly),
``log_time`` = ``publish_time`` = sample time in ns, topics like
``/fleet/AC001/elevator_L/residual``. The chunk in progress is ended and written at least every
``flush_s`` seconds (by ``log`` and by a background thread), so a writer killed with ``kill -9``
loses at most about ``flush_s`` of data; files rotate by size or age; ``close`` finishes the
file (summary, footer). ``log`` is thread-safe.

Block writing (:meth:`McapLogger.log_block`): many samples of one topic from a float array, the
same bytes as one :meth:`McapLogger.log` per row, formatted and packed by the compiled kernels of
:mod:`service.logcodec`.

Reading (:func:`read_log`): a streaming pass over the records that yields every message of every
complete chunk, in file order, and stops with one :class:`TruncatedLogWarning` at the first
incomplete or corrupt record (a file whose writer was killed has no footer and may end inside a
chunk). :func:`read_blocks` reads the same messages as (N, F) float arrays per channel and chunk.
"""

from __future__ import annotations

import io
import itertools
import json
import logging
import math
import struct
import threading
import time
import warnings
import zlib
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, MessageIndex, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer

try:
    import zstandard
except ImportError:  # pragma: no cover
    zstandard = None
try:
    import lz4.frame as lz4_frame
except ImportError:  # pragma: no cover
    lz4_frame = None

__all__ = [
    "McapLogger",
    "LogBlock",
    "read_blocks",
    "read_log",
    "read_log_files",
    "rotated_files",
    "json_schema_for",
    "TruncatedLogWarning",
    "LogReadStats",
]

log = logging.getLogger("servowatch.mcaplog")

_LIBRARY = "servowatch"
_MSG_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
_REC_HEAD = struct.Struct("<BQ")  # opcode, length
_ENCODE = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


class TruncatedLogWarning(UserWarning):
    """An MCAP file that ends early or holds a corrupt record (its writer was killed)."""


def _sanitize(v: Any) -> Any:
    """A JSON-safe scalar: non-finite floats -> None, numpy scalars -> Python, containers ->
    JSON text (flat fields for Foxglove), anything else -> str."""
    if v is None or isinstance(v, bool | int | str):
        return v
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, Mapping | list | tuple):
        return (
            json.dumps(v, default=str, allow_nan=False)
            if _finite_tree(v)
            else json.dumps(_null_nonfinite(v), default=str)
        )
    try:
        f = float(v)  # numpy scalars
    except (TypeError, ValueError):
        return str(v)
    return f if math.isfinite(f) else None


def _finite_tree(v: Any) -> bool:
    try:
        json.dumps(v, default=str, allow_nan=False)
    except ValueError:
        return False
    return True


def _null_nonfinite(v: Any) -> Any:
    if isinstance(v, Mapping):
        return {str(k): _null_nonfinite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_null_nonfinite(x) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


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


_MSG_RECORD = struct.Struct("<BQHIQQ")  # opcode, length, channel_id, sequence, log/publish time
_MSG_HEAD_DTYPE = np.dtype(
    [("op", "u1"), ("len", "<u8"), ("cid", "<u2"), ("seq", "<u4"), ("lt", "<u8"), ("pt", "<u8")]
)  # packed: 31 bytes, the header of one Message record


class _PackedMessageIndex(MessageIndex):
    """``MessageIndex`` that packs its entries in one call when written, and takes entries
    already packed (``add_packed``, from blocks) besides the ``records`` tuples."""

    def __init__(self, channel_id: int, records: list[tuple[int, int]]):
        super().__init__(channel_id, records)
        self.packed: list[tuple[int, bytes]] = []  # (insert before records[i], "<u8" pairs)

    def add_packed(self, log_times: np.ndarray, offsets: np.ndarray) -> None:
        pairs = np.empty((log_times.size, 2), "<u8")
        pairs[:, 0] = log_times
        pairs[:, 1] = offsets
        self.packed.append((len(self.records), pairs.tobytes()))

    def write(self, stream: Any) -> None:
        recs = self.records
        n = len(recs) + sum(len(b) for _, b in self.packed) // 16
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(n * 16)
        prev = 0
        for at, b in [*self.packed, (len(recs), b"")]:
            if at > prev:
                part = recs[prev:at]
                stream.write(
                    struct.pack(f"<{2 * len(part)}Q", *itertools.chain.from_iterable(part))
                )
            stream.write(b)
            prev = at
        stream.finish_record()


class _ZstdShim:
    """Stands in for the ``zstandard`` module inside ``mcap.writer``: its ``compress`` uses
    the level the calling thread set (``_FastWriter`` with ``zstd_level``), else zstd's
    default, so other writers are unaffected."""

    def __init__(self, mod: Any):
        self._mod = mod
        self.local = threading.local()

    def compress(self, data: bytes) -> bytes:
        level = getattr(self.local, "level", None)
        return self._mod.compress(data) if level is None else self._mod.compress(data, level)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._mod, name)


def _zstd_shim() -> _ZstdShim | None:
    import mcap.writer as mw

    cur = getattr(mw, "zstandard", None)
    if isinstance(cur, _ZstdShim):
        return cur
    if cur is None or not callable(getattr(cur, "compress", None)):
        return None  # another mcap version: the library's own level is used
    mw.zstandard = shim = _ZstdShim(cur)
    return shim


class _FastWriter(Writer):
    """``mcap.writer.Writer`` with a faster ``add_message`` and a bulk ``add_messages`` for
    the chunked case.

    Same bytes as the base class (``tests/test_mcaplog.py`` and
    ``tests/test_mcaplog_blocks.py`` compare the files): a message record is packed in one
    ``struct`` call instead of a ``Message`` object and five writes; ``add_messages`` and
    ``_add_records`` (records packed by :mod:`service.logcodec`) append many records of one
    channel at once. It reaches the base class's private state, so it checks that state
    exists and falls back to the base method otherwise (another mcap version).
    """

    def __init__(self, *args: Any, zstd_level: int | None = None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._zstd_level = zstd_level
        self._shim = _zstd_shim() if zstd_level is not None else None
        cb = getattr(self, "_Writer__chunk_builder", None)
        self._cb = cb
        self._st = getattr(self, "_Writer__statistics", None)
        self._csize = getattr(self, "_Writer__chunk_size", None)
        self._finalize = getattr(self, "_Writer__maybe_finalize_chunk", None)
        rw = getattr(cb, "record_writer", None)
        self._fast = (
            cb is not None
            and isinstance(getattr(rw, "_buffer", None), io.BytesIO)
            and isinstance(getattr(cb, "message_indices", None), dict)
            and hasattr(self._st, "channel_message_counts")
            and isinstance(self._csize, int)
            and callable(self._finalize)
        )

    def _Writer__finalize_chunk(self) -> None:  # the base class's private hook
        shim = self._shim
        if shim is None:
            return Writer._Writer__finalize_chunk(self)  # type: ignore[attr-defined]
        shim.local.level = self._zstd_level
        try:
            Writer._Writer__finalize_chunk(self)  # type: ignore[attr-defined]
        finally:
            shim.local.level = None

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        if not self._fast:
            super().add_message(channel_id, log_time, data, publish_time, sequence)
            return
        st = self._st
        if st.message_count == 0 or log_time < st.message_start_time:
            st.message_start_time = log_time
        if log_time > st.message_end_time:
            st.message_end_time = log_time
        st.channel_message_counts[channel_id] += 1
        st.message_count += 1
        cb = self._cb
        if cb.num_messages == 0 or log_time < cb.message_start_time:
            cb.message_start_time = log_time
        if log_time > cb.message_end_time:
            cb.message_end_time = log_time
        idx = cb.message_indices.get(channel_id)
        if idx is None:
            idx = cb.message_indices[channel_id] = _PackedMessageIndex(channel_id, [])
        buf = cb.record_writer._buffer
        idx.records.append((log_time, buf.tell()))
        cb.num_messages += 1
        buf.write(
            _MSG_RECORD.pack(
                Opcode.MESSAGE, 22 + len(data), channel_id, sequence, log_time, publish_time
            )
        )
        buf.write(data)
        if buf.tell() > self._csize:
            self._finalize()

    def add_messages(
        self,
        channel_id: int,
        log_times: Iterable[int],
        datas: list[bytes],
        sequences: Iterable[int],
    ) -> None:
        """:meth:`add_message` for each message (``publish_time`` = ``log_time``), the record
        headers packed at once; the same bytes as one call per message."""
        lts = np.fromiter(log_times, np.uint64, len(datas))
        seqs = np.fromiter(sequences, np.uint32, len(datas))
        if not self._fast:
            for lt, data, seq in zip(lts.tolist(), datas, seqs.tolist(), strict=True):
                super().add_message(channel_id, lt, data, lt, seq)
            return
        n = len(datas)
        if n == 0:
            return
        lens = np.fromiter(map(len, datas), np.int64, n)
        head = np.empty(n, _MSG_HEAD_DTYPE)
        head["op"] = Opcode.MESSAGE
        head["len"] = lens + 22
        head["cid"] = channel_id
        head["seq"] = seqs
        head["lt"] = lts
        head["pt"] = lts
        hb = head.tobytes()
        parts: list[bytes] = [b""] * (2 * n)
        parts[0::2] = [hb[i : i + 31] for i in range(0, 31 * n, 31)]
        parts[1::2] = datas
        self._add_records(channel_id, lts, b"".join(parts), np.cumsum(lens + 31))

    def _add_records(
        self, channel_id: int, log_times: np.ndarray, recs: Any, ends: np.ndarray
    ) -> None:
        """Append packed Message records ``recs`` (record k ends at ``ends[k]``) of one
        channel: statistics, chunk times and message index as :meth:`add_message` keeps them,
        and the chunk ends after the same record as with one :meth:`add_message` per record."""
        n = len(ends)
        if n == 0:
            return
        st = self._st
        lo, hi = int(log_times.min()), int(log_times.max())
        if st.message_count == 0 or lo < st.message_start_time:
            st.message_start_time = lo
        if hi > st.message_end_time:
            st.message_end_time = hi
        st.channel_message_counts[channel_id] += n
        st.message_count += n
        starts = np.empty(n, np.int64)
        starts[0] = 0
        starts[1:] = ends[:-1]
        mv = memoryview(recs)
        k = 0
        while k < n:
            cb = self._cb
            buf = cb.record_writer._buffer
            base = buf.tell()
            # add_message ends the chunk after the first record that takes it past chunk_size
            j = k + int(np.searchsorted(ends[k:], self._csize - base + starts[k], "right")) + 1
            j = min(j, n)
            part = log_times[k:j]
            lo, hi = int(part.min()), int(part.max())
            if cb.num_messages == 0 or lo < cb.message_start_time:
                cb.message_start_time = lo
            if hi > cb.message_end_time:
                cb.message_end_time = hi
            idx = cb.message_indices.get(channel_id)
            if idx is None:
                idx = cb.message_indices[channel_id] = _PackedMessageIndex(channel_id, [])
            idx.add_packed(part, starts[k:j] + (base - starts[k]))
            cb.num_messages += j - k
            buf.write(mv[starts[k] : ends[j - 1]])
            if buf.tell() > self._csize:
                self._finalize()
            k = j


def _row_dicts(names: tuple[str, ...], isint: np.ndarray, vals: np.ndarray) -> list[dict]:
    """The message dicts :meth:`McapLogger.log_block` writes for the rows of ``vals``."""
    kinds = isint.tolist()
    isfinite = math.isfinite
    return [
        {
            k: (None if not isfinite(v) else int(v) if ii else v)
            for k, ii, v in zip(names, kinds, row, strict=True)
        }
        for row in vals.tolist()
    ]


class McapLogger:
    """Thread-safe MCAP writer: JSON messages, one jsonschema per topic, periodic flush,
    rotation by size (``rotate_bytes``) and/or age (``rotate_s``).

    Without rotation the file is ``path`` itself; with rotation the files are
    ``{stem}-{counter:04d}-{UTC timestamp}{suffix}`` beside ``path``. ``paths`` lists the
    files written so far. Use as a context manager or call :meth:`close`.
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
        self.paths: list[Path] = []
        self.message_count = 0
        self.flush_count = 0
        self._lock = threading.RLock()
        self._closed = False
        self._counter = 0
        self._fh: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
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
        self._writer = _FastWriter(
            self._fh,
            chunk_size=self.chunk_size,
            compression=self._compression,
            zstd_level=self.zstd_level,
        )
        self._writer.start(profile="", library=_LIBRARY)
        if self._metadata:
            self._writer.add_metadata("servowatch", self._metadata)
        self._channels.clear()
        self._schemas.clear()
        self._seq.clear()
        self._opened_at = time.monotonic()
        self._last_flush = self._opened_at
        self.paths.append(p)
        log.debug("mcap: writing %s", p)

    def _finish_current(self) -> None:
        if self._writer is not None:
            self._writer.finish()
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

    def log(self, topic: str, t: float, msg: Mapping[str, Any]) -> None:
        """Append ``msg`` (flat JSON-serialisable mapping) on ``topic`` at sample time ``t`` [s].

        Non-finite floats are written as ``null`` (JSON has no NaN), numpy scalars as numbers,
        nested lists or mappings as JSON text (the fields stay flat), other objects as text.
        """
        try:
            data = _ENCODE(msg).encode()
        except (ValueError, TypeError):
            msg = {str(k): _sanitize(v) for k, v in msg.items()}
            data = _ENCODE(msg).encode()
        t_ns = max(0, int(round(t * 1e9)))
        with self._lock:
            if self._closed:
                raise ValueError("log() on a closed McapLogger")
            cid = self._channels.get(topic)
            if cid is None:
                cid = self._channel(topic, msg)
            seq = self._seq[cid]
            self._seq[cid] = (seq + 1) & 0xFFFFFFFF
            self._writer.add_message(cid, t_ns, data, t_ns, seq)  # type: ignore[union-attr]
            self.message_count += 1
            self._dirty = True
            self._since_check += 1
            if self._since_check >= 64:
                self._since_check = 0
                if time.monotonic() - self._last_flush >= self.flush_s:
                    self._flush_locked()
                self._maybe_rotate()

    def log_block(
        self,
        topic: str,
        t: np.ndarray,
        names: Iterable[str],
        values: np.ndarray,
        *,
        int_fields: Iterable[str] = (),
    ) -> None:
        """Append one message per row of ``values`` (N, F) on ``topic`` at times ``t`` (N,) [s].

        Row k is written exactly as ``log(topic, t[k], {names[f]: values[k, f]})`` writes it
        (floats as ``float.__repr__``, fields named in ``int_fields`` as integers, truncated;
        non-finite values as ``null``); the schema comes from the first row if the topic is
        new. Same flush and rotation as :meth:`log` (checked once per block).
        """
        names_t = tuple(str(n) for n in names)
        tt = np.asarray(t, dtype=np.float64).reshape(-1)
        vals = np.ascontiguousarray(values, dtype=np.float64)
        if vals.ndim != 2 or vals.shape != (tt.size, len(names_t)):
            raise ValueError(
                f"values must be (len(t), len(names)) = ({tt.size}, {len(names_t)}), "
                f"got {vals.shape}"
            )
        if len(set(names_t)) != len(names_t):
            raise ValueError(f"duplicate field names in {names_t}")
        n = tt.size
        if n == 0:
            return
        tns = tt * 1e9
        if not (np.isfinite(tns).all() and tns.max() < 2.0**63):
            raise ValueError("log_block: t must be finite and < 2**63 ns")
        lts = np.maximum(np.rint(tns), 0.0).astype(np.int64)  # = max(0, int(round(t * 1e9)))
        from service.logcodec import encode_records, row_format  # numba: imported on use

        fmt = row_format(names_t, frozenset(int_fields))
        packed = True
        if fmt.isint.any():
            iv = vals[:, fmt.isint]
            packed = not bool((np.abs(iv[np.isfinite(iv)]) >= 2.0**63).any())
        with self._lock:
            if self._closed:
                raise ValueError("log_block() on a closed McapLogger")
            cid = self._channels.get(topic)
            if cid is None:
                cid = self._channel(topic, _row_dicts(names_t, fmt.isint, vals[:1])[0])
            seq0 = self._seq[cid]
            self._seq[cid] = (seq0 + n) & 0xFFFFFFFF
            w = self._writer
            if packed and isinstance(w, _FastWriter) and w._fast:
                recs, ends = encode_records(fmt, vals, cid, seq0, lts)
                w._add_records(cid, lts, recs, ends)
            else:
                datas = [_ENCODE(d).encode() for d in _row_dicts(names_t, fmt.isint, vals)]
                seqs = [(seq0 + k) & 0xFFFFFFFF for k in range(n)]
                if isinstance(w, _FastWriter):
                    w.add_messages(cid, lts.tolist(), datas, seqs)
                else:  # pragma: no cover
                    for lt, data, seq in zip(lts.tolist(), datas, seqs, strict=True):
                        w.add_message(cid, lt, data, lt, seq)  # type: ignore[union-attr]
            self.message_count += n
            self._dirty = True
            if time.monotonic() - self._last_flush >= self.flush_s:
                self._flush_locked()
            self._maybe_rotate()

    def log_many(self, records: Iterable[tuple[str, float, Mapping[str, Any]]]) -> None:
        """:meth:`log` for each ``(topic, t, msg)``, taking the lock once (fewer switches)."""
        with self._lock:
            for topic, t, msg in records:
                self.log(topic, t, msg)

    def _flush_locked(self) -> None:
        if self._writer is not None and self._dirty:
            self._writer.flush()  # ends the chunk in progress and flushes the stream
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
                if self._closed:
                    return
                if time.monotonic() - self._last_flush >= self.flush_s - period:
                    try:
                        self._flush_locked()
                        self._maybe_rotate()
                    except Exception:  # pragma: no cover - disk full etc.
                        log.exception("mcap: background flush failed")

    def close(self) -> None:
        """Finish the current file (summary and footer) and stop the flusher; idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            self._finish_current()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> McapLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------- reading


class LogReadStats:
    """What :func:`read_log` found: chunks read, messages, truncation (filled while iterating)."""

    def __init__(self) -> None:
        self.chunks = 0
        self.messages = 0
        self.truncated = False
        self.reason = ""
        self.footer = False


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == "":
        data = chunk.data
    elif chunk.compression == "zstd":
        if zstandard is None:  # pragma: no cover
            raise RuntimeError("zstd chunk but the zstandard package is missing")
        data = zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    elif chunk.compression == "lz4":
        if lz4_frame is None:  # pragma: no cover
            raise RuntimeError("lz4 chunk but the lz4 package is missing")
        data = lz4_frame.decompress(chunk.data)
    else:
        raise ValueError(f"unknown chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise ValueError("chunk size mismatch")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    return data


def _iter_chunk(data: bytes) -> Iterator[tuple[int, Any]]:
    """Records inside a decompressed chunk: (opcode, parsed) with messages as tuples."""
    from io import BytesIO

    from mcap.data_stream import ReadDataStream

    pos, end = 0, len(data)
    mv = memoryview(data)
    while pos < end:
        op, length = _REC_HEAD.unpack_from(data, pos)
        body = pos + 9
        if body + length > end:
            raise ValueError("record overruns its chunk")
        if op == Opcode.MESSAGE:
            cid, seq, lt, pt = _MSG_HEAD.unpack_from(data, body)
            yield op, (cid, seq, lt, bytes(mv[body + 22 : body + length]))
        elif op in (Opcode.SCHEMA, Opcode.CHANNEL):
            rs = ReadDataStream(BytesIO(bytes(mv[body : body + length])))
            yield op, (Schema.read(rs) if op == Opcode.SCHEMA else Channel.read(rs))
        pos = body + length


class _StreamReader(StreamReader):
    """``StreamReader`` that skips MessageIndex records instead of parsing them (the readers
    here do not use them; parsing costs about 2 us per message)."""

    def _read_record(self, opcode: int, length: int) -> Any:
        if opcode == Opcode.MESSAGE_INDEX:
            stream = self._stream
            if len(stream.read(length)) < length:
                raise EndOfFile()
            return None
        return super()._read_record(opcode, length)


def _iter_stream(
    path: Path, stats: LogReadStats, channels: dict[int, str]
) -> Iterator[bytes | tuple[int, int, bytes]]:
    """Decompressed chunks (``bytes``) and un-chunked messages ``(channel_id, log_time, data)``
    in file order. Channel records outside chunks go into ``channels``; ``stats`` gets the
    footer and the truncation (the caller counts chunks). Each chunk is decompressed and
    CRC-checked in a helper thread (zstd and zlib release the GIL) while the next record is
    read and the previous chunk is used."""
    ahead: deque = deque()  # in file order: futures of chunks, un-chunked messages
    pool: ThreadPoolExecutor | None = None

    def resolved(item):
        if not isinstance(item, Future):
            return item
        try:
            return item.result()
        except Exception as e:
            stats.truncated = True
            stats.reason = f"incomplete chunk: {type(e).__name__} {e}".strip()
            return None

    try:
        with open(path, "rb") as fh:
            reader = _StreamReader(fh, emit_chunks=True, record_size_limit=1 << 30)
            records = reader.records
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    break
                except Exception as e:  # EndOfFile, struct.error, InvalidMagic, ...
                    stats.truncated = True
                    stats.reason = f"{type(e).__name__} {e}".strip()
                    break
                if isinstance(rec, Chunk):
                    if pool is None:
                        pool = ThreadPoolExecutor(1, thread_name_prefix="mcap-read")
                    ahead.append(pool.submit(_decompress, rec))
                    while len(ahead) > 1:  # one chunk decompressing ahead
                        item = resolved(ahead.popleft())
                        if item is None:
                            return
                        yield item
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Footer):
                    stats.footer = True
                    if fh.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
                        stats.truncated = True
                        stats.reason = "trailing magic missing"
                    break
                elif getattr(rec, "channel_id", None) is not None and hasattr(rec, "data"):
                    ahead.append((rec.channel_id, rec.log_time, rec.data))  # un-chunked
        while ahead:
            item = resolved(ahead.popleft())
            if item is None:
                return
            yield item
    finally:
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)


def _iter_raw(
    path: Path, stats: LogReadStats
) -> Iterator[tuple[str, int, bytes]]:  # (topic, log_time_ns, data)
    channels: dict[int, str] = {}
    for item in _iter_stream(path, stats, channels):
        if isinstance(item, tuple):
            topic = channels.get(item[0])
            if topic is not None:
                yield topic, item[1], item[2]
            continue
        try:
            parsed = list(_iter_chunk(item))
        except Exception as e:
            stats.truncated = True
            stats.reason = f"incomplete chunk: {type(e).__name__} {e}".strip()
            return
        stats.chunks += 1
        for op, r in parsed:
            if op == Opcode.CHANNEL:
                channels[r.id] = r.topic
            elif op == Opcode.MESSAGE:
                topic = channels.get(r[0])
                if topic is not None:
                    yield topic, r[2], r[3]


def _truncation_text(p: Path, st: LogReadStats) -> str | None:
    if not (st.truncated or not st.footer):
        return None
    if not st.truncated:
        st.truncated = True
        st.reason = "no footer"
    return (
        f"{p}: truncated MCAP log ({st.reason}); read {st.chunks} complete chunks, "
        f"{st.messages} messages"
    )


def read_log(
    path: str | Path,
    topics: Iterable[str] | None = None,
    *,
    stats: LogReadStats | None = None,
    match: Callable[[str], bool] | None = None,
) -> Iterator[tuple[str, float, dict]]:
    """Yield ``(topic, t_s, msg)`` for every message of every complete chunk, in file order.

    ``t_s`` is ``log_time`` in seconds; ``msg`` the decoded JSON object. ``topics`` keeps only
    those topics, ``match`` only the topics it accepts (messages of other topics are not
    decoded). A file that ends early or holds a corrupt chunk yields everything before
    it and then warns once with :class:`TruncatedLogWarning` (also logged). ``stats``, if
    given, is filled as the iteration proceeds.
    """
    p = Path(path)
    st = stats if stats is not None else LogReadStats()
    want = None if topics is None else set(topics)
    decided: dict[str, bool] = {}
    loads = json.loads
    for topic, lt, data in _iter_raw(p, st):
        keep = decided.get(topic)
        if keep is None:
            keep = decided[topic] = (want is None or topic in want) and (
                match is None or bool(match(topic))
            )
        if not keep:
            continue
        try:
            msg = loads(data)
        except ValueError:
            continue
        st.messages += 1
        yield topic, lt * 1e-9, msg
    text = _truncation_text(p, st)
    if text is not None:
        log.warning(text)
        warnings.warn(text, TruncatedLogWarning, stacklevel=2)


class LogBlock(NamedTuple):
    """Messages of one channel with the same fields: ``values[k, f]`` is field ``names[f]``
    of the message logged at ``t[k]`` [s] (``log_time``). JSON null and strings -> NaN,
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
    data: bytes, channels: dict[int, str]
) -> tuple[np.ndarray, list[tuple[str | None, np.ndarray, np.ndarray, np.ndarray]]]:
    """The messages of a decompressed chunk grouped by channel, in the order of each
    channel's first message: (chunk as uint8, [(topic, log_times, data offsets, data
    lengths)]). Channel records in the chunk update ``channels``; a message takes the topic
    its channel had at that point (as :func:`read_log`)."""
    from mcap.data_stream import ReadDataStream

    from service.logcodec import MSG_OPCODE, scan_records

    buf = np.frombuffer(data, np.uint8)
    ops, starts, lens, cids, lts = scan_records(buf)
    ismsg = ops == MSG_OPCODE
    chans = []
    for r in np.flatnonzero(ops == Opcode.CHANNEL).tolist():
        s0 = int(starts[r])
        chans.append((r, Channel.read(ReadDataStream(io.BytesIO(data[s0 : s0 + lens[r]])))))
    midx = np.flatnonzero(ismsg)
    mc = cids[midx]
    ver = np.zeros(midx.size, np.int64)  # how many Channel records of its id precede it
    versions: dict[int, list[str | None]] = {}
    for r, ch in chans:
        versions.setdefault(ch.id, [channels.get(ch.id)]).append(ch.topic)
        ver[(mc == ch.id) & (midx > r)] += 1
        channels[ch.id] = ch.topic
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
        topic = versions[c][v] if c in versions else channels.get(c)
        groups.append((topic, lts[sel], starts[sel] + 22, lens[sel] - 22))
    return buf, groups


def _group_blocks(
    topic: str, data: bytes, buf: np.ndarray, lts: np.ndarray, offs: np.ndarray, lens: np.ndarray
) -> Iterator[LogBlock]:
    from service.logcodec import parse_objects

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
    path: str | Path,
    topics: Iterable[str] | None = None,
    *,
    stats: LogReadStats | None = None,
    match: Callable[[str], bool] | None = None,
) -> Iterator[LogBlock]:
    """The messages of :func:`read_log` as :class:`LogBlock` arrays.

    One block per chunk and channel (split where the key list changes); within a channel the
    messages keep file order; the blocks of one chunk come in the order of each channel's
    first message in it. Un-chunked messages come as blocks of consecutive messages per
    channel. Messages that are not JSON objects are skipped. ``topics``, ``match``, ``stats``
    and the truncation warning as in :func:`read_log`. Flat objects of numbers, null, booleans
    and plain strings are parsed by compiled code (numbers equal to ``float(text)``), anything
    else by ``json.loads``.
    """
    p = Path(path)
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

    channels: dict[int, str] = {}
    pending: list[tuple[int, str, int, bytes]] = []  # un-chunked messages
    for item in _iter_stream(p, st, channels):
        if isinstance(item, tuple):
            topic = channels.get(item[0])
            if keep(topic):
                pending.append((item[0], topic, item[1], item[2]))  # type: ignore[arg-type]
            continue
        if pending:
            for b in _pending_blocks(pending):
                st.messages += b.t.size
                yield b
            pending = []
        try:
            buf, groups = _chunk_groups(item, channels)
        except Exception as e:
            st.truncated = True
            st.reason = f"incomplete chunk: {type(e).__name__} {e}".strip()
            break
        st.chunks += 1
        for topic, lts, offs, lens in groups:
            if keep(topic):
                for b in _group_blocks(topic, item, buf, lts, offs, lens):  # type: ignore[arg-type]
                    st.messages += b.t.size
                    yield b
    for b in _pending_blocks(pending):
        st.messages += b.t.size
        yield b
    text = _truncation_text(p, st)
    if text is not None:
        log.warning(text)
        warnings.warn(text, TruncatedLogWarning, stacklevel=2)


def _pending_blocks(pending: list[tuple[int, str, int, bytes]]) -> Iterator[LogBlock]:
    by: dict[tuple[int, str], list[tuple[int, bytes]]] = {}
    for cid, topic, lt, data in pending:
        by.setdefault((cid, topic), []).append((lt, data))
    for (_cid, topic), items in by.items():
        yield from _json_blocks(topic, items)


def rotated_files(path: str | Path) -> list[Path]:
    """``path`` itself if it exists, else the rotation set ``{stem}-NNNN-*{suffix}`` in order."""
    p = Path(path)
    if p.exists():
        return [p]
    return sorted(p.parent.glob(f"{p.stem}-[0-9][0-9][0-9][0-9]-*{p.suffix}"))


def read_log_files(
    paths: Iterable[str | Path], topics: Iterable[str] | None = None
) -> Iterator[tuple[str, float, dict]]:
    """:func:`read_log` over several files in turn (a rotation set)."""
    tl = None if topics is None else list(topics)
    for p in paths:
        yield from read_log(p, tl)
