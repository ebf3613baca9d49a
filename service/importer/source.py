"""What every reader gives the importer: the file's columns, its own start time and flight
where it has them, and its time bases as streams of blocks (``Series``); and the format of a
file, told by its first bytes (``sniff``)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from service.importer.errors import InputError

__all__ = ["Series", "Source", "sniff", "check_columns", "BLOCK_ROWS"]

BLOCK_ROWS = 1 << 16
"""Rows per block a reader hands on (the importer's memory is a few such blocks)."""

_MAGIC = (
    (b"PAR1", "parquet"),
    (b"TDSm", "tdms"),
    (b"MDF     ", "mdf"),
    (b"UnFinMF ", "mdf"),
    (b"\x89MCAP0\r\n", "mcap"),
    (b"\x25\xeb", "ch10"),
)
_EXTENSIONS = {
    ".parquet": "parquet",
    ".pq": "parquet",
    ".csv": "csv",
    ".tdms": "tdms",
    ".mf4": "mdf",
    ".mdf": "mdf",
    ".dat": "mdf",
    ".ch10": "ch10",
    ".c10": "ch10",
}


@dataclass
class Series:
    """One time base of a source: its source columns (in the order of the value blocks) and
    ``blocks()``, a fresh iterator of ``(t [s], {column: raw values})`` in file order; ``t``
    is Unix time when ``absolute``."""

    name: str
    columns: list[str]
    blocks: Callable[[], Iterator[tuple[NDArray, dict[str, NDArray]]]]
    absolute: bool


@dataclass
class Source:
    """An opened file: its columns (for the error that names them), its start time [Unix s]
    and flight when its metadata has them, and its time bases for the mapped columns."""

    path: Path
    format: str
    columns: list[str]
    series: list[Series]
    start_unix: float | None = None
    flight: int | None = None


def sniff(path: Path, declared: str | None) -> str:
    """The file's format from its first bytes (CSV: text), checked against the map's
    ``format`` or the file's extension; ``InputError`` for an empty file, another format
    than declared, an MCAP log or a Chapter 10 file (decision 0029)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError as e:
        raise InputError(path, "file", e.strerror or str(e)) from None
    if not head:
        raise InputError(path, "file", "empty file")
    found = next((fmt for magic, fmt in _MAGIC if head.startswith(magic)), None)
    if found is None:
        text = b"\0" not in head
        if text:
            try:
                head.decode("utf-8")
            except UnicodeDecodeError as e:  # a character cut at 4096 bytes is still text
                text = e.start > len(head) - 4
        found = "csv" if text else "unknown binary"
    want = declared or _EXTENSIONS.get(path.suffix.lower())
    if found == "mcap":
        raise InputError(path, "format", "already an MCAP log: replay it (servowatch replay)")
    if found == "ch10":
        raise InputError(
            path, "format", "IRIG 106 Chapter 10 is not read yet (docs/decisions/0029)"
        )
    if want is not None and want != found:
        why = "map's format" if declared else f"extension {path.suffix}"
        raise InputError(path, "format", f"the {why} says {want}, the file is {found}")
    if found == "unknown binary":
        raise InputError(path, "format", "not Parquet, CSV, TDMS or MDF")
    return found


def check_columns(path: Path, wanted: list[tuple[str, str]], have: list[str]) -> None:
    """``InputError`` for the first ``(field, column)`` the file lacks, naming its columns."""
    have_set = set(have)
    for fld, col in wanted:
        if col not in have_set:
            shown = ", ".join(repr(c) for c in have[:40]) + (" ..." if len(have) > 40 else "")
            raise InputError(path, fld, f"no column {col!r}; the file has {shown or 'none'}")


def as_float(path: Path, col: str, a) -> NDArray:
    """A column as float64 (``InputError`` for text)."""
    x = np.asarray(a)
    if x.dtype.kind not in "fiub":
        raise InputError(path, col, f"column {col!r} is not numeric ({x.dtype})")
    return x.astype(np.float64, copy=False)
