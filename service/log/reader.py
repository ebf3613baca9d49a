"""The streaming MCAP reader: every message of every complete chunk, in file order.

:func:`read_log` makes one pass over the records (MessageIndex records skipped) and stops
with one :class:`TruncatedLogWarning` at the first incomplete or corrupt record: a file whose
writer was killed has no footer and may end inside a chunk. Each chunk is decompressed and
CRC-checked one ahead in a helper thread (zstd and zlib release the GIL).

Messages are decoded by their channel's encoding: ``protobuf`` rows with a numeric schema
(:mod:`service.log.rows`, what the writer writes since decision 0011) and ``json`` (the
messages of :meth:`McapLogger.log`, and every message of logs written before). Channels of
other encodings are skipped.
:func:`service.log.blocks.read_blocks` reads the same chunks as column blocks.
"""

from __future__ import annotations

import contextlib
import json
import logging
import struct
import warnings
import zlib
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Schema
from mcap.writer import MCAP0_MAGIC

from service.compat.mcap import SkipIndexStreamReader
from service.log.retention import lock_shared

try:
    import zstandard
except ImportError:  # pragma: no cover
    zstandard = None
try:
    import lz4.frame as lz4_frame
except ImportError:  # pragma: no cover
    lz4_frame = None

__all__ = [
    "Channels",
    "LogReadStats",
    "TruncatedLogWarning",
    "CorruptChunkWarning",
    "corrupt_text",
    "read_log",
    "read_log_files",
    "rotated_files",
]

log = logging.getLogger("servowatch.log")

_MSG_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
_REC_HEAD = struct.Struct("<BQ")  # opcode, length


class TruncatedLogWarning(UserWarning):
    """An MCAP file that ends early or holds a corrupt record (its writer was killed)."""


class CorruptChunkWarning(UserWarning):
    """An MCAP chunk whose data is corrupt (bad CRC, undecodable): skipped, the chunks after
    it are read."""


class LogReadStats:
    """What :func:`read_log` found: chunks read, messages, truncation (filled while iterating)."""

    def __init__(self) -> None:
        self.chunks = 0
        self.messages = 0
        self.truncated = False
        self.reason = ""
        self.footer = False
        self.corrupt = 0  # chunks skipped: their record was whole, their data corrupt
        self.corrupt_reason = ""


_SKIP = "skip"  # the codec of a channel whose messages the readers skip


class Channels(dict):
    """Channel id -> topic, as the records of a file declare them, and each channel's codec
    (:meth:`codec`): a :class:`~service.log.rows.RowLayout` for protobuf rows, None for
    JSON, ``"skip"`` for anything else."""

    def __init__(self) -> None:
        super().__init__()
        self.schemas: dict[int, Schema] = {}
        self.codecs: dict[int, Any] = {}
        self._layouts: dict[tuple[str, bytes], Any] = {}

    def add_schema(self, schema: Schema) -> None:
        self.schemas[schema.id] = schema

    def add(self, channel: Channel) -> None:
        """Declare ``channel`` (its topic and codec)."""
        self[channel.id] = channel.topic
        self.codecs[channel.id] = self._codec(channel)

    def _codec(self, ch: Channel) -> Any:
        enc = ch.message_encoding
        if enc == "json":
            return None
        if enc != "protobuf":
            return _SKIP
        sc = self.schemas.get(ch.schema_id)
        if sc is None:
            return _SKIP
        if sc.name == "servowatch.Event" and sc.encoding == "protobuf":
            from service.log.events import EventCodec

            return EventCodec()
        key = (sc.name, sc.data)
        lay = self._layouts.get(key, _SKIP)
        if lay is _SKIP:
            from service.log.rows import layout_of_schema

            lay = self._layouts[key] = layout_of_schema(sc.name, sc.encoding, sc.data) or _SKIP
        return lay

    def codec(self, channel_id: int) -> Any:
        return self.codecs.get(channel_id, None)


def row_dict(lay: Any, data: bytes) -> dict[str, Any]:
    """A protobuf row as the dict :func:`read_log` yields (NaN as None, integers as int; an
    event as ``service.log.events.decode_event`` gives it)."""
    as_dict = getattr(lay, "as_dict", None)
    if as_dict is not None:
        return as_dict(data)
    return {
        k: (None if v != v else v) for k, v in zip(lay.names, lay.decode_one(data), strict=True)
    }


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


@contextlib.contextmanager
def _opened(path: Any) -> Iterator[Any]:
    """``path`` opened for reading, or a binary file given open (left open)."""
    if hasattr(path, "read"):
        yield path
        return
    with open(path, "rb") as fh:
        yield fh


def iter_stream(
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
        except Exception as e:  # the chunk record was whole: skip it, read on
            stats.corrupt += 1
            stats.corrupt_reason = stats.corrupt_reason or f"{type(e).__name__} {e}".strip()
            return None

    try:
        with _opened(path) as fh:
            lock_shared(fh)  # held while read: a retention sweep leaves the file alone
            reader = SkipIndexStreamReader(fh, emit_chunks=True, record_size_limit=1 << 30)
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
                        if item is not None:
                            yield item
                elif isinstance(rec, Channel):
                    if isinstance(channels, Channels):
                        channels.add(rec)
                    else:
                        channels[rec.id] = rec.topic
                elif isinstance(rec, Schema) and isinstance(channels, Channels):
                    channels.add_schema(rec)
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
            if item is not None:
                yield item
    finally:
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)


def _iter_raw(
    path: Path, stats: LogReadStats
) -> Iterator[tuple[str, int, bytes, Any]]:  # (topic, log_time_ns, data, codec)
    channels = Channels()
    for item in iter_stream(path, stats, channels):
        if isinstance(item, tuple):
            topic = channels.get(item[0])
            if topic is not None:
                yield topic, item[1], item[2], channels.codec(item[0])
            continue
        try:
            parsed = list(_iter_chunk(item))
        except Exception as e:  # a corrupt chunk that passed its CRC (or has none): skipped
            stats.corrupt += 1
            stats.corrupt_reason = stats.corrupt_reason or f"{type(e).__name__} {e}".strip()
            continue
        stats.chunks += 1
        for op, r in parsed:
            if op == Opcode.SCHEMA:
                channels.add_schema(r)
            elif op == Opcode.CHANNEL:
                channels.add(r)
            elif op == Opcode.MESSAGE:
                topic = channels.get(r[0])
                if topic is not None:
                    yield topic, r[2], r[3], channels.codec(r[0])


def truncation_text(p: Path, st: LogReadStats) -> str | None:
    if not (st.truncated or not st.footer):
        return None
    if not st.truncated:
        st.truncated = True
        st.reason = "no footer"
    return (
        f"{p}: truncated MCAP log ({st.reason}); read {st.chunks} complete "
        f"chunk{'' if st.chunks == 1 else 's'}, {st.messages} message{'' if st.messages == 1 else 's'}"
    )


def corrupt_text(p: Path, st: LogReadStats) -> str | None:
    """The warning about the corrupt chunks skipped in ``p`` (None if none)."""
    if not st.corrupt:
        return None
    return (
        f"{p}: skipped {st.corrupt} corrupt chunk(s) ({st.corrupt_reason}); read the "
        f"{st.chunks} intact chunks before and after"
    )


def _warn_corrupt(p: Path, st: LogReadStats) -> None:
    text = corrupt_text(p, st)
    if text is not None:
        log.warning(text)
        warnings.warn(text, CorruptChunkWarning, stacklevel=3)


def read_log(
    path: str | Path,
    topics: Iterable[str] | None = None,
    *,
    stats: LogReadStats | None = None,
    match: Callable[[str], bool] | None = None,
) -> Iterator[tuple[str, float, dict]]:
    """Yield ``(topic, t_s, msg)`` for every message of every complete chunk, in file order.

    ``t_s`` is ``log_time`` in seconds; ``msg`` the decoded JSON object, or a protobuf row as
    a dict (field -> value; NaN as None, like JSON's null; integer fields as int). ``topics`` keeps only
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
    for topic, lt, data, codec in _iter_raw(p, st):
        keep = decided.get(topic)
        if keep is None:
            keep = decided[topic] = (want is None or topic in want) and (
                match is None or bool(match(topic))
            )
        if not keep:
            continue
        try:
            if codec is None:
                msg = loads(data)
            elif codec is _SKIP:
                continue
            else:
                msg = row_dict(codec, data)
        except ValueError:
            continue
        st.messages += 1
        yield topic, lt * 1e-9, msg
    _warn_corrupt(p, st)
    text = truncation_text(p, st)
    if text is not None:
        log.warning(text)
        warnings.warn(text, TruncatedLogWarning, stacklevel=2)


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
