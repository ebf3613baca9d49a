"""One log file read through one object, opened once (issue 48, item 3).

``LogFile(path)`` opens the file once and carries, on that one handle, what the replay, the
batch and the store need of it: whether it is an MCAP log at all (``check``), its
``servowatch`` metadata, its ``servowatch.flight`` records, the units of its
``/fleet/{aircraft}/{actuator}/meas`` channels, its blocks of samples (``blocks``) and, once
read, each unit's stream identity (``identity``, filled by the replay:
``service.store.identity``). A file without a summary (cut short) is scanned once for its
metadata, records and channels. ``LogSet`` is a rotation set (or one file) as one log.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from functools import cached_property
from pathlib import Path
from typing import IO, Any

from service.log.blocks import LogBlock, read_blocks
from service.log.reader import LogReadStats, rotated_files
from service.log.retention import lock_shared

__all__ = ["LogFile", "LogSet", "LogFileError", "FLIGHT_RECORD", "parse_meas_topic"]

FLIGHT_RECORD = "servowatch.flight"


class LogFileError(ValueError):
    """A file that cannot be replayed: the message names the file and the cause."""


def parse_meas_topic(topic: str) -> tuple[str, str] | None:
    """(aircraft, actuator) of a ``/fleet/{aircraft}/{actuator}/meas`` topic, else None."""
    parts = topic.split("/")
    if len(parts) != 5 or parts[0] != "" or parts[1] != "fleet" or parts[4] != "meas":
        return None
    return parts[2], parts[3]


class LogFile:
    """One MCAP file, opened once (module docstring); a context manager."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self._fh: IO[bytes] = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        except OSError as e:
            raise LogFileError(f"{self.path}: cannot read: {e.strerror or e}") from None
        lock_shared(self._fh)  # held while open: a daemon's retention leaves it (decision 0041)
        self.identity: dict[str, Any] = {}  # unit -> StreamId, set by the replay

    def __enter__(self) -> LogFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._fh.close()

    @property
    def size(self) -> int:
        """The file's size [bytes] (of the open handle)."""
        import os

        return os.fstat(self._fh.fileno()).st_size

    def head(self, n: int) -> bytes:
        """The file's first ``n`` bytes."""
        return self._at().read(n)

    def _at(self, offset: int = 0) -> IO[bytes]:
        self._fh.seek(offset)
        return self._fh

    # -- what it is ------------------------------------------------------------------------
    def check(self) -> None:
        """LogFileError unless the file starts as an MCAP log with a chunk, message or
        footer after its header."""
        from mcap.records import Chunk, Footer, Message
        from mcap.writer import MCAP0_MAGIC

        from service.compat.mcap import SkipIndexStreamReader

        head = self._at().read(len(MCAP0_MAGIC))
        if not head:
            raise LogFileError(f"{self.path}: empty file, not an MCAP log")
        if head != MCAP0_MAGIC:
            raise LogFileError(f"{self.path}: not an MCAP log (no MCAP magic at its start)")
        why = "it ends after its header"
        try:
            rd = SkipIndexStreamReader(self._at(), emit_chunks=True, record_size_limit=1 << 30)
            for rec in rd.records:
                if isinstance(rec, Chunk | Message | Footer):
                    return
        except Exception:  # a record cut short (or garbled) before the first chunk
            why = "it ends inside a record"
        raise LogFileError(
            f"{self.path}: not a usable MCAP log: no chunk, message or footer ({why})"
        )

    @cached_property
    def _index(self) -> tuple[list[Any], set[str]]:
        """(metadata records, channel topics): from the summary, else one scan."""
        from mcap.reader import SeekingReader
        from mcap.records import Channel, Chunk, Metadata
        from mcap.stream_reader import StreamReader

        try:
            rd = SeekingReader(self._at())
            summ = rd.get_summary()
            if summ is not None:
                mds = list(rd.iter_metadata())
                return mds, {c.topic for c in summ.channels.values()}
        except Exception:
            pass
        mds: list[Any] = []
        topics: set[str] = set()
        try:
            for rec in StreamReader(self._at(), skip_magic=False, emit_chunks=True).records:
                if isinstance(rec, Metadata):
                    mds.append(rec)
                elif isinstance(rec, Channel):
                    topics.add(rec.topic)
                elif isinstance(rec, Chunk):
                    topics |= self._chunk_topics(rec)
        except Exception:  # cut short: what was read so far
            pass
        return mds, topics

    @staticmethod
    def _chunk_topics(chunk: Any) -> set[str]:
        from mcap.records import Channel
        from mcap.stream_reader import breakup_chunk

        try:
            return {r.topic for r in breakup_chunk(chunk) if isinstance(r, Channel)}
        except Exception:
            return set()

    @cached_property
    def metadata(self) -> dict[str, str]:
        """The ``servowatch`` metadata record ({} if none)."""
        for md in self._index[0]:
            if md.name == "servowatch":
                return dict(md.metadata)
        return {}

    @cached_property
    def flight_records(self) -> list[Any]:
        """The ``servowatch.flight`` records in file order (a malformed one: ValueError
        naming the file)."""
        from service.log.flightrec import FlightRecord

        try:
            return [FlightRecord.from_metadata(md.metadata) for md in self._index[0]
                    if md.name == FLIGHT_RECORD]  # fmt: skip
        except ValueError as e:
            raise ValueError(f"{self.path}: {e}") from None

    @cached_property
    def units(self) -> list[tuple[str, str]]:
        """(aircraft, actuator) of each meas channel (sorted)."""
        return sorted({at for t in self._index[1] if (at := parse_meas_topic(t)) is not None})

    def blocks(
        self, stats: LogReadStats | None = None, match: Callable[[str], bool] | None = None
    ) -> Iterator[LogBlock]:
        """The file's blocks of messages (``read_blocks`` on the open handle)."""
        return read_blocks(self._at(), stats=stats, match=match, name=self.path)


class LogSet:
    """A log as the replay takes it: a file, or the rotation set of a base name (its files
    in order), each a ``LogFile``; a context manager."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        files = rotated_files(self.path)
        if not files:
            raise FileNotFoundError(
                f"{self.path}: no such log (nor a rotation set {self.path.stem}-*)"
            )
        self.files: list[LogFile] = []
        try:
            for f in files:
                self.files.append(LogFile(f))
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> LogSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for f in self.files:
            f.close()

    @property
    def paths(self) -> list[Path]:
        return [f.path for f in self.files]

    def check(self) -> None:
        for f in self.files:
            f.check()

    @property
    def metadata(self) -> dict[str, str]:
        """The first file's ``servowatch`` metadata."""
        return self.files[0].metadata

    @property
    def flight_records(self) -> list[Any]:
        return [r for f in self.files for r in f.flight_records]

    @property
    def units(self) -> list[tuple[str, str]]:
        out: list[tuple[str, str]] = []
        for f in self.files:
            out.extend(at for at in f.units if at not in out)
        return out
