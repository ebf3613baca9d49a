"""Parquet and CSV through pyarrow: one time base (the map's ``time.column``), read in record
batches (``ParquetFile.iter_batches``, ``pyarrow.csv.open_csv``) so a large file streams."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from service.importer.errors import InputError
from service.importer.mapping import ChannelMap
from service.importer.source import BLOCK_ROWS, Series, Source, as_float, check_columns

__all__ = ["open_parquet", "open_csv"]

_TIME_SCALE = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def _time(path: Path, cmap: ChannelMap, arr) -> NDArray:
    """The time column in seconds (Unix seconds for ``datetime``)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    col = cmap.time.column
    if cmap.time.unit == "datetime":
        if not pa.types.is_timestamp(arr.type):
            raise InputError(path, "time.unit", f"column {col!r} holds {arr.type}, not timestamps")
        ns = pc.cast(arr, pa.timestamp("ns", tz=arr.type.tz)).cast(pa.int64())
        return ns.to_numpy(zero_copy_only=False).astype(np.float64) * 1e-9
    if pa.types.is_timestamp(arr.type):
        raise InputError(path, "time.unit", f"column {col!r} holds timestamps: unit = datetime")
    return as_float(path, col, arr.to_numpy(zero_copy_only=False)) * _TIME_SCALE[cmap.time.unit]


def _series(path: Path, cmap: ChannelMap, batches) -> Series:
    cols = [spec.column for _, spec in cmap.ordered()]

    def blocks() -> Iterator[tuple[NDArray, dict[str, NDArray]]]:
        import pyarrow as pa

        try:
            for b in batches():
                t = _time(path, cmap, b.column(cmap.time.column))
                out = {}
                for c in cols:
                    a = b.column(c)
                    if pa.types.is_null(a.type):
                        out[c] = np.full(len(t), np.nan)
                        continue
                    out[c] = as_float(path, c, a.to_numpy(zero_copy_only=False))
                yield t, out
        except (pa.ArrowException, OSError) as e:
            raise InputError(path, "file", f"cannot read on: {e}") from None

    return Series("table", cols, blocks, cmap.time.unit == "datetime")


def _need_time(path: Path, cmap: ChannelMap) -> str:
    if cmap.time.column is None:
        raise InputError(path, "time.column", "required for a table (Parquet, CSV)")
    return cmap.time.column


def _wanted(cmap: ChannelMap) -> list[tuple[str, str]]:
    return [("time.column", cmap.time.column)] + [
        (f"channels.{k}.column", s.column) for k, s in cmap.ordered()
    ]


def open_parquet(path: Path, cmap: ChannelMap) -> Source:
    """A Parquet file: its schema's columns, read by row groups and batches."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    tcol = _need_time(path, cmap)
    try:
        pf = pq.ParquetFile(path, pre_buffer=False)  # pre-buffered column chunks pile up
    except (pa.ArrowException, OSError) as e:
        raise InputError(path, "file", f"not a readable Parquet file: {e}") from None
    names = list(pf.schema_arrow.names)
    check_columns(path, _wanted(cmap), names)
    read = [tcol] + [s.column for _, s in cmap.ordered() if s.column != tcol]
    return Source(
        path,
        "parquet",
        names,
        [_series(path, cmap, lambda: _row_groups(pf, read))],
    )


def _row_groups(pf, columns: list[str]):
    """The batches of a Parquet file, one row group after the other."""
    for g in range(pf.num_row_groups):
        yield from pf.iter_batches(batch_size=BLOCK_ROWS, columns=columns, row_groups=[g])


def open_csv(path: Path, cmap: ChannelMap) -> Source:
    """A CSV file with a header row: read in blocks by pyarrow's streaming reader."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    tcol = _need_time(path, cmap)
    ro = pcsv.ReadOptions(block_size=4 << 20, use_threads=False)
    try:
        with pcsv.open_csv(path, read_options=ro) as rd:
            names = list(rd.schema.names)
    except (pa.ArrowException, OSError) as e:
        raise InputError(path, "file", f"not a readable CSV file: {e}") from None
    check_columns(path, _wanted(cmap), names)
    read = [tcol] + [s.column for _, s in cmap.ordered() if s.column != tcol]
    types = {s.column: pa.float64() for _, s in cmap.ordered()}
    if cmap.time.unit != "datetime":
        types[tcol] = pa.float64()
    co = pcsv.ConvertOptions(include_columns=read, column_types=types)

    def batches():
        with pcsv.open_csv(path, read_options=ro, convert_options=co) as rd:
            yield from rd

    return Source(path, "csv", names, [_series(path, cmap, batches)])
