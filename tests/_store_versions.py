"""What each store migration added, read from its SQL (``service.store.schema.MIGRATIONS``):
the tests that make a store as an older servowatch wrote it take the columns and indexes of
the later migrations from here, so a new migration needs no edit of their lists."""

from __future__ import annotations

import re
from typing import Any

from service.store.schema import MIGRATIONS

_COLUMN = re.compile(r"ALTER TABLE (\w+) ADD COLUMN (\w+)")
_INDEX = re.compile(r"CREATE INDEX (\w+) ON")


def _after(version: int, pattern: re.Pattern[str]) -> list[re.Match[str]]:
    return [m for v, _, stmts in MIGRATIONS if v > version for s in stmts
            if (m := pattern.match(s))]  # fmt: skip


def columns_after(version: int, table: str | None = None) -> tuple[tuple[str, str], ...]:
    """``(table, column)`` of every column the migrations after ``version`` added (of
    ``table`` only, when given), in migration order."""
    return tuple((m[1], m[2]) for m in _after(version, _COLUMN) if table in (None, m[1]))


def summary_columns_after(version: int) -> tuple[str, ...]:
    """The summary columns the migrations after ``version`` added."""
    return tuple(c for _, c in columns_after(version, "summary"))


def roll_back(b: Any, version: int) -> None:
    """Make the open store of backend ``b`` (inside a transaction) as a servowatch of schema
    ``version`` wrote it: the later migrations' columns and indexes dropped, their rows in
    ``schema_migrations`` deleted (their data steps are the caller's to undo)."""
    for t, c in columns_after(version):
        b.execute(f"ALTER TABLE {t} DROP COLUMN {c}")
    for m in _after(version, _INDEX):
        b.execute(f"DROP INDEX {m[1]}")
    b.execute("DELETE FROM schema_migrations WHERE version > ?", (version,))
