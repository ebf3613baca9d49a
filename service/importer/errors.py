"""The importer's one error: a bad input, named by file and field (exit 2, nothing written)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["InputError"]


class InputError(ValueError):
    """A bad input file or map: ``{file}: {field}: {why}`` on one line."""

    def __init__(self, path: str | Path, field: str, why: str) -> None:
        why = " ".join(str(why).split())[:300]
        super().__init__(f"{path}: {field}: {why}")
        self.path, self.field, self.why = str(path), field, why
