"""The grid values of several time bases merged in bounded memory: each channel's values are
written at their grid index into a file of its own (``float64``, with a byte per index saying
it was written), then read back in windows as rows. One time base needs none of it: its
blocks go straight to the log (``ColumnSpool`` is only for a file of several rates)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["ColumnSpool"]

_WINDOW = 1 << 18


class ColumnSpool:
    """Column files beside ``near`` (removed by :meth:`close`)."""

    def __init__(self, near: Path, channels: list[str]) -> None:
        self.dir = near.with_name(near.name + ".cols")
        self.dir.mkdir()
        self.n = len(channels)
        self._v = [os.open(self.dir / f"{c}.f8", os.O_RDWR | os.O_CREAT, 0o600) for c in channels]
        self._ok = [os.open(self.dir / f"{c}.ok", os.O_RDWR | os.O_CREAT, 0o600) for c in channels]
        self.k_end = 0

    def put(self, k: NDArray, cols: list[int], v: NDArray) -> None:
        """Values ``v`` (n, len(cols)) of channels ``cols`` at grid indices ``k`` (increasing)."""
        if not len(k):
            return
        cuts = np.flatnonzero(np.diff(k) != 1) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(k)], strict=True):
            k0 = int(k[a])
            for j, c in enumerate(cols):
                os.pwrite(self._v[c], np.ascontiguousarray(v[a:b, j], np.float64).tobytes(), 8 * k0)
                os.pwrite(self._ok[c], b"\1" * (b - a), k0)
        self.k_end = max(self.k_end, int(k[-1]) + 1)

    def rows(self) -> Iterator[tuple[NDArray, NDArray]]:
        """``(k, values (n, channels))`` of every grid index some channel has, NaN where a
        channel has none, in windows of ``_WINDOW`` indices."""
        for a in range(0, self.k_end, _WINDOW):
            w = min(_WINDOW, self.k_end - a)
            vals = np.full((w, self.n), np.nan)
            anyv = np.zeros(w, bool)
            for c in range(self.n):
                ok = np.frombuffer(os.pread(self._ok[c], w, a), np.uint8)
                raw = np.frombuffer(os.pread(self._v[c], 8 * w, 8 * a), np.float64)
                m = min(len(ok), len(raw))  # the two files of a channel have one extent
                sel = ok[:m].astype(bool)
                vals[:m, c][sel] = raw[:m][sel]
                anyv[:m] |= sel
            idx = np.flatnonzero(anyv)
            if len(idx):
                yield a + idx.astype(np.int64), vals[idx]

    def close(self) -> None:
        """Close and remove the column files."""
        for fd in self._v + self._ok:
            os.close(fd)
        self._v, self._ok = [], []
        shutil.rmtree(self.dir, ignore_errors=True)
