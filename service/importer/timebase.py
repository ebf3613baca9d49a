"""Several rates onto one time base (docs/import.md, "Rates, gaps and time"), in bounded memory.

Every time base of a source (a TDMS group, an MDF channel group, a table) is streamed through

1. the daemon's intake rules (``service.replay.input.UnitClock`` -> ``daemon.intake.accept``):
   non-finite times, repeated or older times refused and counted, a clock that steps back
   followed after ``resync_n`` samples (a restart);
2. cut into segments at gaps (a step over 1.5 nominal periods) and restarts: no value is ever
   made across a gap;
3. brought onto the grid ``t_k = T0 + k / rate`` (``rate`` the monitor's):

   - at the grid's rate and phase (within 1 % of a period): copied;
   - faster: ``scipy.signal.resample_poly`` (polyphase FIR, Kaiser window, anti-aliased) by
     the rational ratio ``up/down`` of the two rates, in blocks with an overlap of the filter's
     half length so that the result equals one call on the whole segment, then placed on the
     grid by linear interpolation when the segment's phase is off the grid's;
   - slower: linear interpolation (``numpy.interp``) between its samples.

   Grid points outside a segment get nothing (absent, as a gap in the live stream).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np
from numpy.typing import NDArray

__all__ = ["GridCounts", "SeriesResampler", "GAP_PERIODS"]

GAP_PERIODS = 1.5
"""A step of more than this many nominal periods is a gap (a segment boundary)."""
_PHASE_TOL = 0.01  # of a period
_BLOCK = 1 << 16  # input samples per resample_poly call (plus the overlap)


@dataclass
class GridCounts:
    """What was done to the samples, per reason (the import's summary)."""

    copied: int = 0  # source samples copied onto the grid as they were
    downsampled: int = 0  # source samples that went through the polyphase filter
    interpolated: int = 0  # grid samples made by interpolation (upsampling, phase)
    gaps: int = 0  # segment boundaries at a gap
    overlap: int = 0  # grid samples dropped: a clock followed back onto times already had
    intake: dict[str, int] = field(default_factory=dict)  # refused by the intake's rules

    def add(self, other: GridCounts) -> None:
        self.copied += other.copied
        self.downsampled += other.downsampled
        self.interpolated += other.interpolated
        self.gaps += other.gaps
        self.overlap += other.overlap
        for k, v in other.intake.items():
            self.intake[k] = self.intake.get(k, 0) + v


class SeriesResampler:
    """One time base's accepted samples (t [s], values (n, c) SI) onto the grid
    ``T0 + k / rate``: :meth:`push` then :meth:`finish` yield ``(k, values)`` blocks, k
    increasing."""

    def __init__(self, t0: float, rate: float, dt_nominal: float) -> None:
        self.t0, self.rate, self.dt = float(t0), float(rate), float(dt_nominal)
        r = self.dt * self.rate  # grid periods per source period
        if abs(r - 1.0) <= 1e-3:
            self.mode = "copy"
        elif r < 1.0:
            self.mode = "down"
            fr = Fraction(1.0 / self.dt / self.rate).limit_denominator(1000)
            self.up, self.down = fr.denominator, fr.numerator  # out/in = up/down
            # resample_poly's filter: half length 10 max(up, down) taps at up x the input rate
            half_in = math.ceil(10 * max(self.up, self.down) / self.up) + 2
            self.pad = self.down * math.ceil(half_in / self.down)
        else:
            self.mode = "up"
        self.counts = GridCounts()
        self._seg_t: list[NDArray] = []  # the current segment's pending samples
        self._seg_v: list[NDArray] = []
        self._seg_n = 0
        self._seg_first: float | None = None  # time of the current segment's sample 0
        self._seg_used = 0  # input samples of the segment consumed by the filter so far
        self._last_t: float | None = None
        self._carry: tuple[float, NDArray] | None = None  # "up": the segment's last sample

    # ----------------------------------------------------------------- input
    def push(
        self, t: NDArray, v: NDArray, restart: bool = False
    ) -> Iterator[tuple[NDArray, NDArray]]:
        """Accepted samples (strictly increasing ``t`` unless ``restart``)."""
        if not len(t):
            return
        steps = np.diff(t)
        cuts = np.flatnonzero(steps > GAP_PERIODS * self.dt) + 1
        gap0 = (
            self._last_t is not None and not restart and t[0] - self._last_t > GAP_PERIODS * self.dt
        )
        if restart or gap0:
            self.counts.gaps += int(gap0)
            yield from self._end_segment()
        self.counts.gaps += len(cuts)
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(t)], strict=True):
            if a > 0:
                yield from self._end_segment()
            yield from self._take(t[a:b], v[a:b])
        self._last_t = float(t[-1])

    def finish(self) -> Iterator[tuple[NDArray, NDArray]]:
        """The rest of the last segment."""
        yield from self._end_segment()

    # ----------------------------------------------------------------- per mode
    def _grid_k(self, t: NDArray) -> NDArray:
        return (t - self.t0) * self.rate

    def _take(self, t: NDArray, v: NDArray) -> Iterator[tuple[NDArray, NDArray]]:
        if self.mode == "copy":
            kf = self._grid_k(t)
            k = np.rint(kf)
            if np.all(np.abs(kf - k) <= _PHASE_TOL):
                self.counts.copied += len(t)
                yield k.astype(np.int64), v
                return
            yield from self._interp(t, v)  # same rate, another phase
            return
        if self.mode == "up":
            yield from self._interp(t, v)
            return
        if self._seg_first is None:
            self._seg_first = float(t[0])
        self._seg_t.append(t)
        self._seg_v.append(v)
        self._seg_n += len(t)
        if self._seg_n >= _BLOCK + 2 * self.pad:
            yield from self._filter(final=False)

    def _interp(self, t: NDArray, v: NDArray) -> Iterator[tuple[NDArray, NDArray]]:
        if self._carry is not None:
            t = np.r_[self._carry[0], t]
            v = np.vstack([self._carry[1][None, :], v])
        self._carry = (float(t[-1]), v[-1].copy())
        kf = self._grid_k(t)
        k_lo = math.ceil(kf[0] - _PHASE_TOL) if len(t) else 0
        k_hi = math.floor(kf[-1] + _PHASE_TOL)
        if self._carry_emitted is not None:
            k_lo = max(k_lo, self._carry_emitted + 1)
        if k_hi < k_lo:
            return
        k = np.arange(k_lo, k_hi + 1, dtype=np.int64)
        tk = np.clip(self.t0 + k / self.rate, t[0], t[-1])
        out = np.empty((len(k), v.shape[1]))
        for c in range(v.shape[1]):
            out[:, c] = np.interp(tk, t, v[:, c])
        self.counts.interpolated += len(k)
        self._carry_emitted = int(k[-1])
        yield k, out

    _carry_emitted: int | None = None

    def _filter(self, final: bool) -> Iterator[tuple[NDArray, NDArray]]:
        from scipy.signal import resample_poly

        t = np.concatenate(self._seg_t)
        v = np.concatenate(self._seg_v)
        n = len(t)
        first = self._seg_used == 0
        # the inputs whose outputs are final (those of the last pad inputs wait for more)
        take_in = n if final else (n - self.pad) // self.down * self.down
        y = resample_poly(v, self.up, self.down, axis=0, padtype="edge")
        j0 = 0 if first else self.pad * self.up // self.down
        j1 = len(y) if final else take_in * self.up // self.down
        if j1 > j0:
            # output j of the block lies at its input j * down / up; the block starts at the
            # segment's input b (a multiple of down)
            b = self._seg_used
            ts = self._seg_first + (b + np.arange(j0, j1) * self.down / self.up) * self.dt
            self.counts.downsampled += take_in - (0 if first else self.pad)
            yield from self._place(ts, y[j0:j1])
        if final:
            return
        keep = take_in - self.pad  # next block starts pad inputs before the first new output
        self._seg_t, self._seg_v = [t[keep:]], [v[keep:]]
        self._seg_n = n - keep
        self._seg_used += keep

    def _place(self, ts: NDArray, y: NDArray) -> Iterator[tuple[NDArray, NDArray]]:
        kf = self._grid_k(ts)
        k = np.rint(kf)
        if np.all(np.abs(kf - k) <= _PHASE_TOL):
            yield k.astype(np.int64), y
            return
        yield from self._interp(ts, y)

    def _end_segment(self) -> Iterator[tuple[NDArray, NDArray]]:
        if self.mode == "down" and self._seg_n:
            yield from self._filter(final=True)
        self._seg_t, self._seg_v, self._seg_n = [], [], 0
        self._seg_first, self._seg_used = None, 0
        self._carry = None
        self._carry_emitted = None
