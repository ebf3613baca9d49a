"""LabVIEW TDMS through nptdms (``TdmsFile.open``: the metadata read, the data streamed by
``channel.read_data(offset, length)``). Columns are ``"Group/Channel"``; each group is one
time base: the map's ``time.column`` in that group (``"Time"``, or ``"Group/Time"``: the
channel of that name in each group), else the waveform
properties of its channels (``wf_start_time``, ``wf_start_offset``, ``wf_increment``)."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from service.importer.errors import InputError
from service.importer.mapping import ChannelMap
from service.importer.source import BLOCK_ROWS, Series, Source, as_float, check_columns

__all__ = ["open_tdms"]

_TIME_SCALE = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def _unix(v) -> float | None:
    """A TDMS timestamp property (numpy datetime64, UTC) as Unix seconds."""
    if v is None:
        return None
    try:
        return float(np.datetime64(v, "ns").astype(np.int64)) * 1e-9
    except (TypeError, ValueError):
        return None


class _Warnings(logging.Handler):
    """nptdms's warnings while the file is open, kept instead of printed."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())

    def __enter__(self) -> _Warnings:
        self._log = logging.getLogger("nptdms")
        self._saved = self._log.handlers, self._log.propagate
        self._log.handlers, self._log.propagate = [self], False
        subs = [n for n in logging.root.manager.loggerDict if n.startswith("nptdms.")]
        for name in subs:  # each has its own console handler
            sub = logging.getLogger(name)
            self._saved = (*self._saved, (sub, sub.handlers, sub.propagate))
            sub.handlers, sub.propagate = [], True
        return self

    def __exit__(self, *exc: object) -> None:
        self._log.handlers, self._log.propagate = self._saved[0], self._saved[1]
        for sub, handlers, prop in self._saved[2:]:
            sub.handlers, sub.propagate = handlers, prop


def open_tdms(path: Path, cmap: ChannelMap, stack: contextlib.ExitStack) -> Source:
    """The TDMS file, kept open on ``stack`` while the import streams it."""
    from nptdms import TdmsFile

    warned = _Warnings()
    stack.enter_context(warned)
    try:
        f = stack.enter_context(TdmsFile.open(path))
        if warned.messages:  # nptdms reads a short last segment as far as it goes
            raise InputError(path, "file", f"truncated: {warned.messages[0]}")
    except InputError:
        raise
    except Exception as e:  # nptdms raises ValueError, struct.error, EOFError ...
        raise InputError(
            path, "file", f"not a readable TDMS file: {type(e).__name__}: {e}"
        ) from None
    chans = {f"{g.name}/{c.name}": c for g in f.groups() for c in g.channels()}
    names = list(chans)
    wanted = [(f"channels.{k}.column", s.column) for k, s in cmap.ordered()]
    check_columns(path, wanted, names)  # the time channel: per group, below
    by_group: dict[str, list[str]] = {}
    for _, s in cmap.ordered():
        by_group.setdefault(s.column.split("/", 1)[0], []).append(s.column)
    series = [_group(path, cmap, chans, g, cols) for g, cols in by_group.items()]
    return Source(path, "tdms", names, series)


def _group(path: Path, cmap: ChannelMap, chans: dict, group: str, cols: list[str]) -> Series:
    n = {c: len(chans[c]) for c in cols}
    length = max(n.values())
    short = [c for c in cols if n[c] != length]
    if short:
        raise InputError(path, short[0], f"{n[short[0]]} values, the group's others {length}")
    tcol = cmap.time.column
    if tcol is not None:
        tcol = f"{group}/{tcol.split('/', 1)[-1]}" if "/" in tcol else f"{group}/{tcol}"
        if tcol not in chans:
            raise InputError(path, "time.column", f"group {group!r} has no time channel {tcol!r}")
        if len(chans[tcol]) != length:
            raise InputError(path, "time.column", f"{tcol!r} has {len(chans[tcol])} values, "
                             f"the group's channels {length}")  # fmt: skip
        absolute = cmap.time.unit == "datetime"
    else:
        props = chans[cols[0]].properties
        inc = props.get("wf_increment")
        if inc is None or not float(inc) > 0:
            raise InputError(path, "time.column", f"group {group!r} has no waveform time "
                             "(wf_increment): name its time channel")  # fmt: skip
        inc = float(inc)
        start = _unix(props.get("wf_start_time"))
        off = float(props.get("wf_start_offset", 0.0) or 0.0)
        absolute = start is not None and start > 0
        t_zero = (start if absolute else 0.0) + off

    def blocks() -> Iterator[tuple[NDArray, dict[str, NDArray]]]:
        for a in range(0, length, BLOCK_ROWS):
            m = min(BLOCK_ROWS, length - a)
            try:
                vals = {c: as_float(path, c, chans[c].read_data(a, m)) for c in cols}
                if tcol is None:
                    t = t_zero + (a + np.arange(m)) * inc
                else:
                    raw = chans[tcol].read_data(a, m)
                    if cmap.time.unit == "datetime":
                        t = np.asarray(raw, "datetime64[ns]").astype(np.int64) * 1e-9
                    else:
                        t = as_float(path, tcol, raw) * _TIME_SCALE[cmap.time.unit]
            except InputError:
                raise
            except Exception as e:
                raise InputError(path, "file", f"cannot read on at value {a} of group "
                                 f"{group!r}: {type(e).__name__}: {e}") from None  # fmt: skip
            if any(len(v) != m for v in vals.values()) or len(t) != m:
                raise InputError(path, "file", f"truncated: group {group!r} ends before "
                                 f"its {length} values")  # fmt: skip
            yield t, vals

    return Series(group, cols, blocks, absolute)
