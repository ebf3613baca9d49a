"""Retention of the daemon's MCAP logs (``[log] keep_bytes`` and ``keep_days``; decision 0041).

A :class:`Retention` sweep deletes this daemon's closed log files, the oldest first, until
what is left is within ``keep_bytes`` and no file is older than ``keep_days``. A file's age
and order are its calendar end: the time it was last written (``st_mtime``; a rotated file is
not written after it is closed), the same for every file whatever its name says.

Never deleted: the files the writer has open (``open_paths``), and any file another process
holds: every reader of a log (:func:`service.log.reader.iter_stream`, the replay and the
ingest through :func:`hold`) and the writer itself take a shared ``flock`` on the file while
they use it, and a sweep deletes a file only under an exclusive, non-blocking ``flock``, so
it skips a busy file and tries it again at the next sweep. A reader that opened the file
before the sweep unlinked it still reads it to the end (POSIX keeps the inode).

Deleting a log deletes no history: the health store holds the periods the daemon wrote while
it logged (docs/store.md).
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import time
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

__all__ = [
    "Deleted",
    "Retention",
    "hold",
    "lock_shared",
    "pattern_of",
    "readable_time",
    "rfc3339",
]

log = logging.getLogger("servowatch.log")

DAY_S = 86400.0


def rfc3339(t: float) -> str:
    """``t`` [Unix s] as RFC 3339 UTC with milliseconds, e.g. ``2026-12-04T13:28:03.123Z``."""
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def readable_time(t: object, digits: int = 3) -> str:
    """A sample time for people: RFC 3339 for a calendar (Unix) time, ``t=12.500 s`` for a
    simulated one (seconds since its start), ``-`` for none."""
    if (
        isinstance(t, bool)
        or not isinstance(t, int | float)
        or t != t
        or t in (float("inf"), float("-inf"))
    ):
        return "-"
    return rfc3339(float(t)) if t > 1e8 else f"t={t:.{digits}f} s"


def lock_shared(fh: IO[bytes]) -> None:
    """Take a shared ``flock`` on an open log file (held until the file is closed): a
    retention sweep leaves the file alone meanwhile. Best effort: a file system without
    ``flock`` (some network mounts) is read unlocked."""
    with contextlib.suppress(OSError):
        fcntl.flock(fh.fileno(), fcntl.LOCK_SH)


@contextlib.contextmanager
def hold(paths: Iterable[str | Path]) -> Iterator[None]:
    """Hold a shared lock on each of ``paths`` for the block (an ingest of a file set: no
    file of it is deleted before the ingest ends). Files that do not exist are skipped."""
    fhs: list[IO[bytes]] = []
    try:
        for p in paths:
            try:
                fh = open(p, "rb")  # noqa: SIM115 - closed below
            except OSError:
                continue
            fhs.append(fh)
            lock_shared(fh)
        yield
    finally:
        for fh in fhs:
            fh.close()


def pattern_of(path: str | Path, default_prefix: str | None = None) -> str:
    """The glob of one daemon's log files: ``{default_prefix}*.mcap`` (every run of a daemon
    on its default path ``{log_name}-{station}-{shard}-{start}``), else the rotation set of
    ``path`` (``{stem}-NNNN-*{suffix}``, as ``McapLogger`` names it; an explicit ``--log``)."""
    if default_prefix is not None:
        return f"{default_prefix}*.mcap"
    p = Path(path)
    return f"{p.stem}-[0-9][0-9][0-9][0-9]-*{p.suffix}"


@dataclass(frozen=True)
class Deleted:
    """A log file a sweep deleted: its path, size [bytes], calendar end [Unix s], why
    (``keep_bytes`` or ``keep_days``) and when it was deleted [Unix s]."""

    path: str
    bytes: int
    end: float
    reason: str
    at: float

    def to_dict(self) -> dict[str, Any]:
        return {"path": self.path, "bytes": self.bytes, "end": rfc3339(self.end),
                "reason": self.reason, "deleted_at": rfc3339(self.at)}  # fmt: skip


class Retention:
    """The retention policy of the logs ``{directory}/{pattern}`` (one daemon's logs, a glob
    pattern: :func:`pattern_of`). ``keep_bytes`` / ``keep_days`` None: no limit of that
    kind. :meth:`sweep` deletes; :meth:`status` says what it did."""

    def __init__(
        self,
        directory: str | Path,
        pattern: str,
        *,
        keep_bytes: int | None = None,
        keep_days: float | None = None,
        remember: int = 20,
    ) -> None:
        if keep_bytes is not None and keep_bytes <= 0:
            raise ValueError("keep_bytes must be > 0 or None")
        if keep_days is not None and keep_days <= 0:
            raise ValueError("keep_days must be > 0 or None")
        self.directory = Path(directory)
        self.pattern = pattern
        self.keep_bytes = keep_bytes
        self.keep_days = keep_days
        self.deleted_files = 0
        self.deleted_bytes = 0
        self.kept_files = 0
        self.kept_bytes = 0
        self.busy_skipped = 0  # deletions put off because a reader held the file
        self.errors = 0
        self.last: deque[Deleted] = deque(maxlen=remember)
        self.last_sweep: float | None = None

    @property
    def active(self) -> bool:
        return self.keep_bytes is not None or self.keep_days is not None

    def files(self) -> list[tuple[Path, int, float]]:
        """This daemon's log files: (path, size, calendar end), the oldest end first."""
        out = []
        for p in self.directory.glob(self.pattern):
            try:
                s = p.stat()
            except OSError:  # deleted meanwhile
                continue
            out.append((p, s.st_size, s.st_mtime))
        out.sort(key=lambda r: (r[2], str(r[0])))
        return out

    def sweep(
        self, open_paths: Iterable[str | Path] = (), now: float | None = None
    ) -> list[Deleted]:
        """Delete the closed files beyond the limits, the oldest first; never one of
        ``open_paths`` nor one another process holds (then counted in ``busy_skipped`` and
        tried again at the next sweep; no newer file is deleted for ``keep_bytes`` meanwhile,
        a newer one past ``keep_days`` is). Returns what it deleted (each logged at INFO)."""
        now = time.time() if now is None else now
        self.last_sweep = now
        files = self.files()
        if not self.active:
            self.kept_files, self.kept_bytes = len(files), sum(f[1] for f in files)
            return []
        keep = {os.path.realpath(p) for p in open_paths}
        total = sum(f[1] for f in files)
        cutoff = None if self.keep_days is None else now - self.keep_days * DAY_S
        done: list[Deleted] = []
        blocked = False  # an older file is kept (open, held): no newer one goes for size
        for p, size, end in files:
            old = cutoff is not None and end < cutoff
            big = not blocked and self.keep_bytes is not None and total > self.keep_bytes
            if not (old or big):
                if blocked:
                    continue  # a newer file may still be past keep_days
                break  # files are in end order: the rest are newer, and the total fits
            if os.path.realpath(p) in keep or not self._unlink_unheld(p):
                blocked = True
                continue
            total -= size
            d = Deleted(str(p), size, end, "keep_days" if old else "keep_bytes", time.time())
            done.append(d)
            self.last.append(d)
            self.deleted_files += 1
            self.deleted_bytes += size
            log.info(
                "retention: deleted %s (%d bytes, ended %s; %s)",
                p, size, rfc3339(end), d.reason,
                extra={"fields": {"event": "log_deleted", "path": str(p), "bytes": size,
                                  "end": rfc3339(end), "reason": d.reason}},
            )  # fmt: skip
        left = self.files()
        self.kept_files, self.kept_bytes = len(left), sum(f[1] for f in left)
        return done

    def _unlink_unheld(self, p: Path) -> bool:
        """Unlink ``p`` under an exclusive non-blocking lock; False when another process
        holds it (a reader, an ingest, a writer) or it cannot be removed."""
        try:
            fh = open(p, "rb")  # noqa: SIM115 - closed below
        except FileNotFoundError:
            return False
        except OSError as e:
            self.errors += 1
            log.warning("retention: cannot open %s: %s", p, e)
            return False
        with fh:
            try:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                self.busy_skipped += 1
                log.info("retention: %s is in use (read or ingested); kept for now", p)
                return False
            except OSError:  # no flock on this file system: the open-paths rule still holds
                pass
            try:
                p.unlink()
            except FileNotFoundError:
                return False
            except OSError as e:
                self.errors += 1
                log.warning("retention: cannot delete %s: %s", p, e)
                return False
        return True

    def status(self) -> dict[str, Any]:
        """The policy, what is kept now (a directory listing), and what was deleted (counts
        and the last files)."""
        with contextlib.suppress(OSError):
            left = self.files()
            self.kept_files, self.kept_bytes = len(left), sum(f[1] for f in left)
        return {
            "keep_bytes": self.keep_bytes,
            "keep_days": self.keep_days,
            "kept_files": self.kept_files,
            "kept_bytes": self.kept_bytes,
            "deleted_files": self.deleted_files,
            "deleted_bytes": self.deleted_bytes,
            "busy_skipped": self.busy_skipped,
            "errors": self.errors,
            "last_sweep": None if self.last_sweep is None else rfc3339(self.last_sweep),
            "last_deleted": [d.to_dict() for d in self.last],
        }
