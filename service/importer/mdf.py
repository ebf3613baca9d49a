"""ASAM MDF 3 and 4 through asammdf. A column is a channel's name (``name`` or, where a name
repeats, ``group:name``); each channel group is one time base, its master channel (relative
seconds) plus the file's ``header.start_time`` (absolute). The records are read in blocks
(``MDF.get(record_offset=, record_count=)``)."""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from service.importer.errors import InputError
from service.importer.mapping import ChannelMap
from service.importer.source import BLOCK_ROWS, Series, Source, as_float, check_columns

__all__ = ["open_mdf"]


def _where(mdf, name: str) -> tuple[int, int] | None:
    """(group, index) of a column ``name`` or ``group:name``."""
    if ":" in name:
        g, _, n = name.partition(":")
        if g.isdigit():
            hits = [h for h in mdf.whereis(n) if h[0] == int(g)]
            return hits[0] if hits else None
    hits = mdf.whereis(name)
    return hits[0] if len(hits) == 1 else None


def open_mdf(path: Path, cmap: ChannelMap, stack: contextlib.ExitStack) -> Source:
    """The MDF file, kept open on ``stack`` while the import streams it."""
    from asammdf import MDF

    if cmap.time.column is not None:
        raise InputError(path, "time.column", "an MDF file has its own time base: leave it out")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mdf = stack.enter_context(MDF(path))
            # data fragments of about 4 MB (asammdf's default is 256 MB, per channel read)
            mdf.configure(read_fragment_size=4 << 20)
    except Exception as e:  # asammdf raises many kinds on a damaged file
        raise InputError(
            path, "file", f"not a readable MDF file: {type(e).__name__}: {e}"
        ) from None
    names: list[str] = []
    for name, where in mdf.channels_db.items():
        names += [name] if len(where) == 1 else [f"{g}:{name}" for g, _ in where]
    wanted = [(f"channels.{k}.column", s.column) for k, s in cmap.ordered()]
    missing = [(f, c) for f, c in wanted if _where(mdf, c) is None]
    check_columns(path, missing, [n for n in names if not n.startswith("$")])
    by_group: dict[int, list[tuple[str, int]]] = {}
    for _, s in cmap.ordered():
        g, i = _where(mdf, s.column)
        by_group.setdefault(g, []).append((s.column, i))
    start = mdf.header.start_time
    t_zero = start.timestamp() if start is not None and start.year > 1980 else None
    series = [_group(path, mdf, g, chans, t_zero) for g, chans in by_group.items()]
    return Source(path, "mdf", names, series, start_unix=t_zero)


def _group(path: Path, mdf, group: int, chans: list[tuple[str, int]], t_zero) -> Series:
    cycles = int(mdf.groups[group].channel_group.cycles_nr)

    def fragments() -> Iterator[tuple[NDArray, dict[str, NDArray]]]:
        # one iterator per channel over the group's data fragments, in lockstep
        its = [mdf.iter_get(group=group, index=idx) for _, idx in chans]
        for sigs in zip(*its, strict=True):
            t = np.asarray(sigs[0].timestamps, np.float64)
            yield (
                t,
                {
                    col: as_float(path, col, s.samples)
                    for (col, _), s in zip(chans, sigs, strict=True)
                },
            )

    def blocks() -> Iterator[tuple[NDArray, dict[str, NDArray]]]:
        got, buf = 0, []
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                for t, vals in fragments():
                    if any(len(v) != len(t) for v in vals.values()):
                        raise InputError(path, "file", f"truncated: channel group {group}")
                    buf.append((t, vals))
                    got += len(t)
                    if sum(len(b[0]) for b in buf) >= BLOCK_ROWS:
                        yield _joined(buf, t_zero)
                        buf = []
        except InputError:
            raise
        except Exception as e:
            raise InputError(path, "file", f"cannot read on at record {got} of channel group "
                             f"{group}: {type(e).__name__}: {e}") from None  # fmt: skip
        if buf:
            yield _joined(buf, t_zero)
        if got != cycles:
            raise InputError(path, "file", f"truncated: channel group {group} holds {got} of "
                             f"its {cycles} records")  # fmt: skip

    return Series(f"group {group}", [c for c, _ in chans], blocks, t_zero is not None)


def _joined(buf: list, t_zero: float | None) -> tuple[NDArray, dict[str, NDArray]]:
    t = np.concatenate([b[0] for b in buf]) + (t_zero or 0.0)
    return t, {c: np.concatenate([b[1][c] for b in buf]) for c in buf[0][1]}
