"""The replay's input checks (docs/store.md, "What identifies a log" and "What a re-run
does"): whether a file is an MCAP log at all (``check_mcap``, through ``LogFile``), the id
a store before schema v7 gave a unit of a log (``unit_source``: its first sample; adopted
when the log is replayed again), and the daemon's intake time checks on logged samples
(``UnitClock``).
``LogError`` names a file that cannot be replayed, ``StoreWriteError`` a store that failed
while a log was written."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from service.log import LogBlock
from service.log.logfile import LogFile, LogFileError
from service.wire import messages as m

__all__ = [
    "LogError",
    "StoreWriteError",
    "UnitClock",
    "block_columns",
    "check_mcap",
    "legacy_log_source",
    "named",
    "unit_source",
]


LogError = LogFileError
"""A file that cannot be replayed: the message names the file and the cause
(``service.log.logfile.LogFileError``)."""


def check_mcap(path: Path) -> None:
    """LogError unless ``path`` is a readable file that starts as an MCAP log."""
    with LogFile(path) as lf:
        lf.check()


def legacy_log_source(files: list[Path] | list[LogFile]) -> str:
    """The identity a store before schema v4 gave a log: ``log:{first file name}:{hash}``,
    the hash over the files' names, sizes and first MiB (its periods are adopted when the log
    is replayed again). ``files``: paths, or the ``LogFile`` handles the replay has open."""
    h = hashlib.sha256()
    for f in files:
        if isinstance(f, LogFile):
            h.update(f"{f.path.name}:{f.size};".encode())
            h.update(f.head(1 << 20))
            continue
        h.update(f"{f.name}:{f.stat().st_size};".encode())
        with open(f, "rb") as fh:
            h.update(fh.read(1 << 20))
    first = files[0].path if isinstance(files[0], LogFile) else files[0]
    return f"log:{first.name}:{h.hexdigest()[:16]}"


def block_columns(blk: LogBlock) -> tuple[NDArray, NDArray, NDArray | None]:
    """Sample times (the ``t`` field, else the log time), channels (n, 7) in
    ``messages.CHANNELS`` order (NaN: absent) and the ``seq`` field when every value of it
    is an integer >= 0 (else None)."""
    col = {k: c for c, k in enumerate(blk.names)}
    n = len(blk.t)
    t = blk.values[:, col["t"]] if "t" in col else blk.t
    ch = np.full((n, len(m.CHANNELS)), np.nan)
    for c, k in enumerate(m.CHANNELS):
        if k in col:
            ch[:, c] = blk.values[:, col[k]]
    seq = None
    if "seq" in col:
        sv = blk.values[:, col["seq"]]
        if np.all(np.isfinite(sv)) and np.all(sv >= 0) and np.all(sv == np.round(sv)) \
                and (not n or sv.max() < 2.0**62):  # fmt: skip
            seq = sv.astype(np.int64)
    return t, ch, seq


class UnitClock:
    """The daemon's intake time checks (``service.daemon.intake.accept``) on one unit's
    logged samples: refused samples are counted by reason, a clock that steps back is
    followed after ``ClockCheck.resync_n`` consistent samples (the filter restarts there)."""

    def __init__(self, aircraft: str, actuator: str, bad_log: Any) -> None:
        from service.daemon.intake import ActuatorState, ClockCheck

        self.st = ActuatorState(aircraft, actuator)
        # a log without ``seq`` has no sequence to judge a forward jump by: the daemon's rule
        # with an unbounded step (only samples at or before the last accepted time refused)
        self.clocks = (ClockCheck(factor=1e300, tol_s=1e300), ClockCheck())
        self.bad_log = bad_log
        self.non_finite = 0
        self.seq_last = -1  # the synthetic seq of a log without one
        self.t_raw: float | None = None  # the last logged time (for the synthetic seq)

    def _seq(self, t: NDArray) -> NDArray:
        """A seq for samples without one: +1 wherever the time changes, so a repeated time is
        a duplicate and a time that goes back a clock step (as the daemon would count)."""
        prev = np.concatenate(([np.nan if self.t_raw is None else self.t_raw], t[:-1]))
        seq = self.seq_last + np.cumsum(t != prev)
        if len(t):
            self.seq_last, self.t_raw = int(seq[-1]), float(t[-1])
        return seq

    def check(self, t: NDArray, ch: NDArray, seq: NDArray | None) -> list[tuple[NDArray, bool]]:
        """The accepted samples of a block as index arrays, each with whether the filter
        restarts before it (the clock went back and was followed)."""
        ok = np.isfinite(t) & ~np.isinf(ch).any(axis=1)
        idx = np.flatnonzero(ok)
        self.non_finite += len(t) - len(idx)
        if not len(idx):
            return []
        tt = t[idx]
        from service.daemon.intake import accept

        ck = self.clocks[seq is not None]
        ss = self._seq(tt) if seq is None else seq[idx]
        # runs strictly increasing in seq and t (what accept takes at once)
        cut = np.flatnonzero((np.diff(tt) <= 0) | (np.diff(ss) <= 0)) + 1
        out: list[tuple[NDArray, bool]] = []
        back: list[bool] = []

        def on_restart(_st, _t, _seq, went_back: bool) -> None:
            back.append(went_back)

        for a, b in zip(np.r_[0, cut], np.r_[cut, len(tt)], strict=True):
            back.clear()
            j0, j1 = accept(self.st, m.MeasArrays(ss[a:b], tt[a:b], ch[idx[a:b]]),
                            self.bad_log, on_restart, ck, None)  # fmt: skip
            if j1 > j0:
                restart = any(back)
                if out and not restart and out[-1][0][-1] == idx[a + j0] - 1:
                    out[-1] = (np.r_[out[-1][0], idx[a + j0 : a + j1]], out[-1][1])
                else:
                    out.append((idx[a + j0 : a + j1], restart))
        return out

    def counts(self) -> dict[str, int]:
        """Refused samples by reason, and the clock steps followed."""
        bad = self.st.bad
        return {
            "non_finite": self.non_finite,
            "duplicate": bad.get("duplicate", 0),
            "out_of_order": bad.get("out_of_order", 0),
            "clock": bad.get("clock", 0),
            "restarts": self.st.restarts,
        }


def unit_source(name: str, t0: float, ch0: NDArray, records: list | tuple = ()) -> str:
    """The id a store of schema v4 to v6 gave a log's unit (decision record 0010, replaced by
    0033): ``log:`` and a hash of the unit's name, its first accepted sample (time and
    channels) and its ``servowatch.flight`` records. Kept to adopt those stored logs when
    they are replayed again (``ingest._superseded``)."""
    h = hashlib.sha256(name.encode())
    h.update(np.float64(t0).tobytes())
    h.update(np.ascontiguousarray(ch0, np.float64).tobytes())
    for r in records:
        if r.name == name:
            h.update(repr((r.flight, r.start_unix, r.t0)).encode())
    return f"log:{h.hexdigest()[:24]}"


class StoreWriteError(RuntimeError):
    """The store failed while a log was written to it (disk full, server gone): the batch
    stops; the log's transaction was rolled back, the logs before it are stored."""


def named(p: Path, e: BaseException) -> str:
    """One line naming the file and the cause of ``e``."""
    text = (str(e).strip().splitlines() or [""])[0] or type(e).__name__
    if isinstance(e, OSError) and e.strerror:
        text = f"{e.strerror}" + (f": {e.filename}" if e.filename and str(e.filename) != str(p)
                                  else "")  # fmt: skip
    if not isinstance(e, LogError | OSError | ValueError):
        text = f"{type(e).__name__}: {text}"
    return text if text.startswith(str(p)) else f"{p}: {text}"
