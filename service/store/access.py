"""How the store's connections are opened read only, what a store engine's error says, and
``StoreError`` (``service.store.health`` uses them and exports ``StoreError``)."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from urllib.parse import quote

__all__ = ["StoreError", "sqlite_read_only", "engine_error", "first_line"]


class StoreError(RuntimeError):
    """The store cannot be opened or used (bad URL/path, newer schema, unreachable server)."""


def engine_error(e: BaseException) -> bool:
    """Whether ``e`` is an error of a store engine (sqlite3, psycopg)."""
    return type(e).__module__.split(".")[0] in ("sqlite3", "psycopg")


def first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def sqlite_read_only(path: Path, timeout_s: float) -> sqlite3.Connection:
    """A connection that cannot write ``path``: ``mode=ro``, so a store in a read-only
    folder or file reads too. A WAL store whose ``-shm`` cannot be created there (no writer
    has it open) is read as ``immutable`` when it has no ``-wal`` content to miss; with
    one, a ``StoreError`` says why (a writer must checkpoint it, or copy the store)."""
    uri = "file:" + quote(str(path.resolve())) + "?mode=ro"
    conn = sqlite3.connect(uri, uri=True, timeout=timeout_s, isolation_level=None)
    try:
        conn.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()
        return conn
    except sqlite3.OperationalError as e:
        conn.close()
        if getattr(e, "sqlite_errorname", "") not in ("SQLITE_CANTOPEN", "SQLITE_READONLY"):
            raise
        wal = path.with_name(path.name + "-wal")
        if wal.exists() and wal.stat().st_size > 0:
            raise StoreError(
                f"store: {path}: cannot read it in place: its write-ahead log {wal.name} "
                f"holds data and its shared-memory file cannot be created there ({e}); "
                "open it once with write access (a writer checkpoints it) or copy the store "
                "and its -wal file to a writable folder"
            ) from e
    return sqlite3.connect(uri + "&immutable=1", uri=True, timeout=timeout_s, isolation_level=None)
