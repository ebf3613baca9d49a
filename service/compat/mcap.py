"""Every use of a private API of the ``mcap`` package, in one place.

The MCAP log writes and reads far more messages per second than the library's public API
allows (one ``Message`` object and five stream writes per message; a parsed ``MessageIndex``
per message when reading), so three pieces reach into its internals:

* :class:`BlockWriter` (``mcap.writer.Writer`` subclass): packs Message records straight into
  the chunk builder's buffer, one record (``add_message``) or many of one size at once
  (``add_rows``), and keeps the writer's statistics, chunk times and message indexes as
  the base class does. It uses the name-mangled ``_Writer__chunk_builder``,
  ``_Writer__statistics``, ``_Writer__chunk_size``, ``_Writer__maybe_finalize_chunk`` and
  the chunk builder's ``record_writer._buffer`` (an ``io.BytesIO``).
* the zstd level per writer: ``Writer._Writer__finalize_chunk`` compresses with the module
  global ``zstandard.compress(data)`` (zstd's default level 3). :func:`finalize_chunk_at`
  makes a copy of that function whose globals name a compressor at the wanted level, bound
  to one writer; the ``mcap.writer`` module itself is left alone.
* :class:`SkipIndexStreamReader` (``mcap.stream_reader.StreamReader`` subclass): overrides
  ``_read_record`` to skip MessageIndex records instead of parsing them (about 2 us per
  message).

:func:`check` tells whether the installed mcap still has all of it; ``tests/test_compat_mcap.py``
runs it and fails with a message that names the private API that changed. The bytes written
are those of the stock ``Writer`` (the tests compare files).
"""

from __future__ import annotations

import functools
import io
import itertools
import struct
import types
from typing import Any

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

__all__ = [
    "McapCompatError",
    "BlockWriter",
    "SkipIndexStreamReader",
    "finalize_chunk_at",
    "check",
    "MESSAGE_HEADER_BYTES",
]

_MSG_RECORD = struct.Struct("<BQHIQQ")  # opcode, length, channel_id, sequence, log/publish time
#: bytes of a Message record before its data: opcode, length, channel, sequence, two times
MESSAGE_HEADER_BYTES = _MSG_RECORD.size  # 31


class McapCompatError(RuntimeError):
    """The installed mcap release no longer has a private API that service/compat/mcap.py
    relies on."""


# ------------------------------------------------------------------------ zstd level


class _ZstdAtLevel:
    """Stands in for the ``zstandard`` module in a copy of ``Writer.__finalize_chunk``:
    ``compress`` at a fixed level, everything else from the real module."""

    def __init__(self, mod: Any, level: int):
        self._mod = mod
        self._level = level

    def compress(self, data: bytes) -> bytes:
        return self._mod.compress(data, self._level)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._mod, name)


@functools.lru_cache(maxsize=8)
def _finalize_function(level: int) -> types.FunctionType:
    import mcap.writer as mw

    base = Writer.__dict__.get("_Writer__finalize_chunk")
    if not isinstance(base, types.FunctionType) or "zstandard" not in base.__code__.co_names:
        raise McapCompatError(
            "mcap.writer.Writer._Writer__finalize_chunk is gone or no longer compresses with "
            "the module global 'zstandard': service/compat/mcap.py finalize_chunk_at needs "
            "updating"
        )
    zstd = getattr(mw, "zstandard", None)
    if zstd is None or not callable(getattr(zstd, "compress", None)):
        raise McapCompatError("mcap.writer.zstandard (the zstandard module) is missing")
    glb = dict(base.__globals__)
    glb["zstandard"] = _ZstdAtLevel(zstd, level)
    return types.FunctionType(
        base.__code__, glb, base.__name__, base.__defaults__, base.__closure__
    )


def finalize_chunk_at(writer: Writer, level: int) -> None:
    """Make ``writer`` compress its zstd chunks at ``level`` (only this writer)."""
    fn = _finalize_function(int(level))
    writer._Writer__finalize_chunk = types.MethodType(fn, writer)  # type: ignore[attr-defined]


# ------------------------------------------------------------------------ writer


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
        if not recs:  # rows only (add_rows): the packed entries at once
            stream.write(b"".join([b for _, b in self.packed]))
            stream.finish_record()
            return
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


def _writer_problems(w: Writer) -> list[str]:
    """The private parts of ``w`` that :class:`BlockWriter` needs and did not find."""
    cb = getattr(w, "_Writer__chunk_builder", None)
    out = []
    if cb is None:
        out.append("Writer._Writer__chunk_builder (chunking is on)")
    else:
        if not isinstance(getattr(getattr(cb, "record_writer", None), "_buffer", None), io.BytesIO):
            out.append("ChunkBuilder.record_writer._buffer (an io.BytesIO)")
        if not isinstance(getattr(cb, "message_indices", None), dict):
            out.append("ChunkBuilder.message_indices (a dict)")
        for a in ("num_messages", "message_start_time", "message_end_time"):
            if not isinstance(getattr(cb, a, None), int):
                out.append(f"ChunkBuilder.{a} (an int)")
    st = getattr(w, "_Writer__statistics", None)
    for a in ("channel_message_counts", "message_count", "message_start_time", "message_end_time"):
        if not hasattr(st, a):
            out.append(f"Writer._Writer__statistics.{a}")
    if not isinstance(getattr(w, "_Writer__chunk_size", None), int):
        out.append("Writer._Writer__chunk_size (an int)")
    if not callable(getattr(w, "_Writer__maybe_finalize_chunk", None)):
        out.append("Writer._Writer__maybe_finalize_chunk()")
    return out


class BlockWriter(Writer):
    """``mcap.writer.Writer`` that packs Message records itself: one (``add_message``) or
    many of one size (``add_rows``), the same bytes as the base class's
    ``add_message`` (chunked writers only). ``zstd_level`` sets this writer's zstd level
    (None: zstd's default, as the base class)."""

    def __init__(self, *args: Any, zstd_level: int | None = None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        missing = _writer_problems(self)
        if missing:
            raise McapCompatError(
                "the installed mcap lacks private writer state that service/compat/mcap.py "
                "uses: " + "; ".join(missing)
            )
        if zstd_level is not None and kwargs.get("compression", CompressionType.ZSTD) == (
            CompressionType.ZSTD
        ):
            finalize_chunk_at(self, zstd_level)
        self._cb = self._Writer__chunk_builder  # type: ignore[attr-defined]
        self._st = self._Writer__statistics  # type: ignore[attr-defined]
        self._csize: int = self._Writer__chunk_size  # type: ignore[attr-defined]
        self._finalize = self._Writer__maybe_finalize_chunk  # type: ignore[attr-defined]

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
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

    def add_rows(
        self, channel_ids: Any, counts: Any, log_times: np.ndarray, recs: np.ndarray
    ) -> None:
        """Append Message records of one size, ``recs`` (n, size) uint8, in runs: the first
        ``counts[0]`` records on channel ``channel_ids[0]``, the next ``counts[1]`` on
        ``channel_ids[1]``, ...; record k at ``log_times[k]``. Statistics, chunk times and
        message indexes as :meth:`add_message` keeps them, and the chunk ends after the same
        record as with one :meth:`add_message` per record."""
        n, size = recs.shape
        if n == 0:
            return
        cids = [int(c) for c in channel_ids]
        cnts = [int(c) for c in counts]
        st = self._st
        lo, hi = int(log_times.min()), int(log_times.max())
        if st.message_count == 0 or lo < st.message_start_time:
            st.message_start_time = lo
        if hi > st.message_end_time:
            st.message_end_time = hi
        ends: list[int] = []
        e = 0
        for c, k in zip(cids, cnts, strict=True):
            st.channel_message_counts[c] += k
            e += k
            ends.append(e)
        st.message_count += n
        flat = recs.reshape(-1)
        k = 0
        r = 0  # the run of record k
        while k < n:
            cb = self._cb
            buf = cb.record_writer._buffer
            base = buf.tell()
            # add_message ends the chunk after the first record that takes it past chunk_size
            j = min(n, k + max(0, self._csize - base) // size + 1)
            part = log_times[k:j]
            lo, hi = int(part.min()), int(part.max())
            if cb.num_messages == 0 or lo < cb.message_start_time:
                cb.message_start_time = lo
            if hi > cb.message_end_time:
                cb.message_end_time = hi
            idxs = cb.message_indices
            pairs = np.empty((j - k, 2), "<u8")  # the message index entries of k..j
            pairs[:, 0] = part
            pairs[:, 1] = np.arange(base, base + (j - k) * size, size, dtype=np.int64)
            pb = pairs.tobytes()
            a = k
            while a < j:
                while ends[r] <= a:
                    r += 1
                b = min(j, ends[r])
                c = cids[r]
                idx = idxs.get(c)
                if idx is None:
                    idx = idxs[c] = _PackedMessageIndex(c, [])
                idx.packed.append((len(idx.records), pb[(a - k) * 16 : (b - k) * 16]))
                a = b
            cb.num_messages += j - k
            buf.write(flat[k * size : j * size])
            if buf.tell() > self._csize:
                self._finalize()
            k = j


# ------------------------------------------------------------------------ reader


class SkipIndexStreamReader(StreamReader):
    """``StreamReader`` that skips MessageIndex records instead of parsing them (the readers
    here do not use them; parsing costs about 2 us per message)."""

    def _read_record(self, opcode: int, length: int) -> Any:
        if opcode == Opcode.MESSAGE_INDEX:
            if len(self._stream.read(length)) < length:
                raise EndOfFile()
            return None
        return super()._read_record(opcode, length)


# ------------------------------------------------------------------------ check


def check() -> list[str]:
    """What service/compat/mcap.py needs from the installed mcap and did not find: [] if
    all is there."""
    import inspect

    out: list[str] = []
    if not callable(getattr(Writer, "flush", None)):
        out.append("Writer.flush() (public from mcap 1.5)")
    try:
        _finalize_function(1)
    except McapCompatError as e:
        out.append(str(e))
    try:
        w = Writer(io.BytesIO(), compression=CompressionType.NONE)
        out.extend(_writer_problems(w))
    except Exception as e:  # pragma: no cover - a different constructor
        out.append(f"Writer(stream, compression=...) failed: {e}")
    rr = getattr(StreamReader, "_read_record", None)
    if rr is None:
        out.append("StreamReader._read_record(opcode, length)")
    else:
        params = list(inspect.signature(rr).parameters)
        if params[1:3] != ["opcode", "length"]:
            out.append(f"StreamReader._read_record(opcode, length) has parameters {params}")
    if not hasattr(StreamReader(io.BytesIO(b"")), "_stream"):
        out.append("StreamReader._stream")
    return out
