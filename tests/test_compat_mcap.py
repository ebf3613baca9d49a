"""Check tests of service/compat/mcap.py: each fails with a message naming the private mcap
API that a release changed."""

from __future__ import annotations

import io
import random

import pytest
import zstandard
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from service.compat import mcap as cm


def _messages(w: Writer, n: int = 2000) -> None:
    w.start()
    sid = w.register_schema("a", "jsonschema", b"{}")
    c1 = w.register_channel("x", "json", sid)
    c2 = w.register_channel("y", "json", sid)
    r = random.Random(1)
    for k in range(n):
        w.add_message(c1 if k % 3 else c2, 10**9 + r.randrange(10**6), b"{}" * (k % 50), 7, k)
        if k % 700 == 0:
            w.flush()
    w.finish()


def test_every_private_api_is_there():
    missing = cm.check()
    assert not missing, "mcap private APIs changed: " + "; ".join(missing)


def test_writer_private_state():
    w = Writer(io.BytesIO(), compression=CompressionType.NONE)
    missing = cm._writer_problems(w)
    assert not missing, "BlockWriter needs: " + "; ".join(missing)


def test_public_flush_exists():
    assert callable(getattr(Writer, "flush", None)), "mcap.writer.Writer.flush() is gone"


def test_finalize_chunk_reads_the_zstandard_global():
    fn = Writer.__dict__.get("_Writer__finalize_chunk")
    assert fn is not None, "mcap.writer.Writer._Writer__finalize_chunk is gone"
    assert "zstandard" in fn.__code__.co_names, (
        "Writer._Writer__finalize_chunk no longer calls the module global zstandard.compress"
    )


def test_block_writer_same_bytes_as_stock_writer():
    def run(cls) -> bytes:
        b = io.BytesIO()
        _messages(cls(b, chunk_size=4000, compression=CompressionType.ZSTD))
        return b.getvalue()

    assert run(cm.BlockWriter) == run(Writer), (
        "BlockWriter.add_message no longer writes the bytes of Writer.add_message"
    )


@pytest.mark.parametrize("level", [1, 9])
def test_zstd_level_is_per_writer_without_touching_the_module(level):
    import mcap.writer as mw

    before = mw.zstandard
    b = io.BytesIO()
    _messages(cm.BlockWriter(b, chunk_size=1 << 20, compression=CompressionType.ZSTD,
                             zstd_level=level))  # fmt: skip
    assert mw.zstandard is before  # no process-wide patch
    b.seek(0)
    chunks = [r for r in StreamReader(b, emit_chunks=True).records if isinstance(r, Chunk)]
    assert chunks
    for c in chunks:
        raw = zstandard.ZstdDecompressor().decompress(c.data, max_output_size=c.uncompressed_size)
        assert c.data == zstandard.compress(raw, level), "the zstd level did not reach the chunk"
    plain = io.BytesIO()
    _messages(Writer(plain, chunk_size=1 << 20, compression=CompressionType.ZSTD))
    plain.seek(0)
    for c in (r for r in StreamReader(plain, emit_chunks=True).records if isinstance(r, Chunk)):
        raw = zstandard.ZstdDecompressor().decompress(c.data, max_output_size=c.uncompressed_size)
        assert c.data == zstandard.compress(raw)  # another writer keeps zstd's default


def test_skip_index_reader_reads_what_the_stock_reader_reads():
    b = io.BytesIO()
    _messages(Writer(b, chunk_size=4000, compression=CompressionType.NONE))
    data = b.getvalue()

    def records(cls):
        return [r for r in cls(io.BytesIO(data)).records if r is not None]

    stock = [r for r in records(StreamReader) if type(r).__name__ != "MessageIndex"]
    assert records(cm.SkipIndexStreamReader) == stock, (
        "StreamReader._read_record(opcode, length) changed: SkipIndexStreamReader needs updating"
    )


def test_missing_private_state_is_reported_by_name(monkeypatch):
    w = Writer(io.BytesIO(), compression=CompressionType.NONE)
    cb = w._Writer__chunk_builder  # type: ignore[attr-defined]
    monkeypatch.setattr(cb.record_writer, "_buffer", None)
    assert "ChunkBuilder.record_writer._buffer (an io.BytesIO)" in cm._writer_problems(w)
