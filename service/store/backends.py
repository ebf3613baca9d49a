"""The store's two backends: the dialect and connection of SQLite and of PostgreSQL, the only
code that differs between them (docs/store.md, "Backends")."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from service.store.access import StoreError, sqlite_read_only


def describe_url(url: str) -> str:
    """``url`` with any password replaced by ``***`` (for messages)."""
    if "://" in url and "@" in url.split("://", 1)[1]:
        scheme, rest = url.split("://", 1)
        cred, host = rest.rsplit("@", 1)
        if ":" in cred:
            cred = cred.split(":", 1)[0] + ":***"
        return f"{scheme}://{cred}@{host}"
    return url


class _Backend:
    """Dialect and connection: the only code that differs between SQLite and PostgreSQL."""

    name = "?"

    def __init__(self) -> None:
        self.conn: Any = None

    def sql(self, text: str) -> str:
        return text

    def execute(self, text: str, params: Sequence[Any] = ()) -> Any:
        raise NotImplementedError

    def executemany(self, text: str, rows: list[Sequence[Any]]) -> None:
        raise NotImplementedError

    def bulk_insert(self, table: str, cols: Sequence[str], rows: list[Sequence[Any]]) -> None:
        ph = ",".join("?" * len(cols))
        self.executemany(f"INSERT INTO {table} ({','.join(cols)}) VALUES ({ph})", rows)

    @contextmanager
    def transaction(self) -> Iterator[None]:
        raise NotImplementedError

    def lock_migrations(self) -> None:
        """Serialise concurrent migrators (inside the migration transaction)."""

    for_update = ""

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None


class _SQLite(_Backend):
    name = "sqlite"

    def __init__(self, path: Path, timeout_s: float = 30.0, read_only: bool = False) -> None:
        super().__init__()
        self.path = path
        if read_only:  # a reader: opened read only, no journal-mode change, never a write
            self.conn = sqlite_read_only(path, timeout_s)
            self.conn.execute("PRAGMA query_only=ON")
        else:
            self.conn = sqlite3.connect(str(path), timeout=timeout_s, isolation_level=None)
            self.conn.execute("PRAGMA journal_mode=WAL")
            # WAL + NORMAL: a killed process loses nothing committed; power loss may lose the
            # last transactions but never leaves a half-written one
            self.conn.execute("PRAGMA synchronous=NORMAL")
        self.conn.execute("PRAGMA foreign_keys=ON")
        self._depth = 0

    def execute(self, text: str, params: Sequence[Any] = ()) -> Any:
        return self.conn.execute(text, tuple(params))

    def executemany(self, text: str, rows: list[Sequence[Any]]) -> None:
        self.conn.executemany(text, rows)

    @contextmanager
    def transaction(self) -> Iterator[None]:
        if self._depth:
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
            return
        self.conn.execute("BEGIN IMMEDIATE")  # take the write lock now: no upgrade deadlock
        self._depth = 1
        try:
            yield
        except BaseException:
            self._depth = 0
            self.conn.execute("ROLLBACK")
            raise
        self._depth = 0
        self.conn.execute("COMMIT")


class _Postgres(_Backend):
    name = "postgresql"
    for_update = " FOR UPDATE"

    def __init__(self, url: str, timeout_s: float = 30.0, read_only: bool = False) -> None:
        super().__init__()
        try:
            import psycopg
        except ImportError as e:  # pragma: no cover - a dependency
            raise StoreError("store: PostgreSQL needs the psycopg package") from e
        self._psycopg = psycopg
        try:  # no server-side prepared statements: a plan made while a table was small
            # (a store being filled) kept reading a unit's periods where the per-log index
            # serves them (bench/cluster.py: the write cost grew with the history)
            self.conn = psycopg.connect(url, autocommit=True, connect_timeout=int(timeout_s),
                                        prepare_threshold=None)  # fmt: skip
        except psycopg.Error as e:
            msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise StoreError(f"store: cannot connect to {describe_url(url)}: {msg}") from e
        self.cur = self.conn.cursor()
        if read_only:  # every transaction of this session is read only, and waits for a
            # writer's lock (a migration's) at most timeout_s
            self.cur.execute("SET default_transaction_read_only = on")
            self.cur.execute(f"SET lock_timeout = {int(timeout_s * 1000)}")

    def sql(self, text: str) -> str:
        return text.replace("?", "%s")

    def execute(self, text: str, params: Sequence[Any] = ()) -> Any:
        self.cur.execute(self.sql(text), tuple(params))
        return self.cur

    def executemany(self, text: str, rows: list[Sequence[Any]]) -> None:
        self.cur.executemany(self.sql(text), rows)

    def bulk_insert(self, table: str, cols: Sequence[str], rows: list[Sequence[Any]]) -> None:
        with self.cur.copy(f"COPY {table} ({','.join(cols)}) FROM STDIN") as cp:
            for r in rows:
                cp.write_row(r)

    @contextmanager
    def transaction(self) -> Iterator[None]:
        with self.conn.transaction():
            yield

    def lock_migrations(self) -> None:
        self.execute("SELECT pg_advisory_xact_lock(7431201)")
