"""The daemon's intake: per-actuator state, decoding failures by reason, and the sequence and
time checks that decide which samples of a message are accepted.

A sample is accepted when its time is later than the actuator's last accepted sample and
plausible (``ClockCheck``): not ahead of the last accepted sample by much more than its
sequence gap implies (``factor`` x gap x the stream's sample period + ``tol_s``), and, for
live data, not ahead of the receiving clock by more than ``future_s``. An implausible sample
is refused and counted (``bad.clock``); it never moves the stream's clock, so one bad
timestamp costs that sample only. A clock that really jumps (forward, or back as at a reboot
at 1970) is followed after ``resync_n`` consistent refused samples, counted as a restart. A
sequence number that falls back while time advances is a publisher restart (counted), a
sequence that jumps forward is a gap (missing samples counted). Only accepted samples reach
the monitor and the ``meas`` log topic, so a replay of the log feeds the monitor exactly the
live input.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service import messages as m
from service.daemon.ratelimit import RateLimitedLog

__all__ = ["ActuatorState", "ClockCheck", "MAX_ACTUATORS", "accept", "reason_of"]

#: actuators a daemon tracks at most; samples of further ones count as ``unknown_actuator``
MAX_ACTUATORS = 1000


@dataclass(frozen=True)
class ClockCheck:
    """Time plausibility of a stream's samples (see the module docstring; SI)."""

    factor: float = 2.0  # a sample may be ahead by factor x its seq gap x the sample period
    tol_s: float = 0.5  # plus this [s]
    future_s: float = 5.0  # live data: at most this far ahead of the receiving clock [s]
    resync_n: int = 5  # consistent refused samples that re-synchronise a jumped clock

    def __post_init__(self) -> None:
        for name in ("factor", "tol_s", "future_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"clock.{name}: must be finite and > 0, got {v}")
        if self.factor < 1:
            raise ValueError(f"clock.factor: must be >= 1, got {self.factor}")
        if self.resync_n < 1:
            raise ValueError(f"clock.resync_n: must be >= 1, got {self.resync_n}")


@dataclass
class ActuatorState:
    """Counters and latest outputs of one actuator (``fleet/{aircraft}/{actuator}``)."""

    aircraft: str
    actuator: str
    messages: int = 0
    samples: int = 0  # accepted samples (fed to the monitor and logged)
    dropped: int = 0  # messages dropped by the full queue
    gaps: int = 0  # samples missing according to sequence numbers
    restarts: int = 0  # sequence fell back while time advanced, or a jumped clock followed
    missed: int = 0  # samples lost in transport that Zenoh could not recover
    outputs: int = 0  # monitor outputs
    published: int = 0
    bad: dict[str, int] = field(default_factory=dict)  # reason -> count
    first_seq: int | None = None  # sequence number of the first accepted sample
    last_seq: int | None = None
    last_t: float | None = None
    last_recv: float | None = None  # time.monotonic() of the last message
    period: float | None = None  # sample period estimated from accepted samples [s]
    resync: tuple[int, float, int] | None = None  # (seq, t, count) of refused, consistent
    refused: int = 0  # samples refused for their clock since the last accepted one
    silent: bool = False
    alarms: dict[str, Any] = field(default_factory=dict)  # kind -> last event dict (active)
    events: deque = field(default_factory=lambda: deque(maxlen=20))
    latest: Any = None  # (BankRows, row) of the latest output; its dicts made on demand

    @property
    def name(self) -> str:
        return f"{self.aircraft}/{self.actuator}"

    def count_bad(self, reason: str, n: int = 1) -> None:
        self.bad[reason] = self.bad.get(reason, 0) + n

    def snapshot(self, now: float) -> dict[str, Any]:
        """The status entry of this actuator (``now``: time.monotonic())."""
        est: dict = {}
        health: dict = {}
        if self.latest is not None:
            out = self.latest[0].output(self.latest[1])
            est, health = out.est, out.health
        return {
            "aircraft": self.aircraft,
            "actuator": self.actuator,
            "messages": self.messages,
            "samples": self.samples,
            "dropped": self.dropped,
            "gaps": self.gaps,
            "restarts": self.restarts,
            "missed": self.missed,
            "outputs": self.outputs,
            "published": self.published,
            "bad": dict(self.bad),
            "bad_total": sum(self.bad.values()),
            "first_seq": self.first_seq,
            "last_seq": self.last_seq,
            "last_t": self.last_t,
            "age_s": None if self.last_recv is None else now - self.last_recv,
            "silent": self.silent,
            "est": est,
            "health": health,
            "alarms": list(self.alarms.values()),
            "events": list(self.events),
        }


def reason_of(e: m.MessageError) -> str:
    """A short counter name for a decoding failure."""
    f = (e.field or "").split(".")[-1]
    text = str(e)
    if f == "payload" and "exceeds max_bytes" in text:
        return "oversize"
    if "finite" in text:
        return "non_finite"
    if "not increasing" in text:
        return "out_of_order"
    if f == "payload" and "JSON" in text:
        return "malformed"
    if f in ("header", "n", "version", "kind", "payload"):
        return "malformed"
    return "schema"


def _stale(st: ActuatorState, s: int, t: float, ck: ClockCheck) -> bool:
    """A sample at or before the last accepted time that fits the stream's own history (a
    duplicate or a late sample), as opposed to a clock that went back."""
    if st.last_seq is None or st.last_t is None or s > st.last_seq:
        return False
    if st.period is None:
        return True
    return t >= st.last_t - ck.factor * (st.last_seq - s) * st.period - ck.tol_s


def _limit(st: ActuatorState, s: int, ck: ClockCheck, period: float | None) -> float:
    """Latest plausible time of a sample with seq ``s`` after the last accepted one [s]."""
    assert st.last_t is not None and st.last_seq is not None
    ds = s - st.last_seq
    if ds <= 0 or period is None:  # a restart (seq fell back) or no period known yet
        return math.inf
    return st.last_t + ck.factor * ds * period + ck.tol_s


def _candidate(st: ActuatorState, s: int, t: float, ck: ClockCheck, period: float | None) -> bool:
    """Count a refused sample towards re-synchronisation; True once K consistent ones came."""
    c = st.resync
    if c is not None and s > c[0] and t > c[1]:
        ok = period is None or t - c[1] <= ck.factor * (s - c[0]) * period + ck.tol_s
        if ok:
            st.resync = (s, t, c[2] + 1)
            return c[2] + 1 >= ck.resync_n
    st.resync = (s, t, 1)
    return ck.resync_n <= 1


def accept(
    st: ActuatorState,
    a: m.MeasArrays,
    bad_log: RateLimitedLog,
    on_restart: Callable[[ActuatorState, float, int, bool], None],
    clock: ClockCheck | None = None,
    now: float | None = None,
) -> tuple[int, int]:
    """Sequence and time checks of one decoded message against the actuator's last accepted
    sample; returns ``(j0, j1)``, the accepted samples ``j0:j1`` (the samples of a message are
    strictly increasing in seq and t, so the refused ones are a prefix and a suffix).

    ``now`` is the receiving clock (``time.time()``) for live data, None for a replay.
    ``on_restart(st, t, seq, back)`` is called when the sequence falls back while time
    advances, and when the stream is re-synchronised on a clock that jumped (``back``: the
    time went back)."""
    ck = clock if clock is not None else ClockCheck()
    t, seq = a.t, a.seq
    n = len(t)
    # ahead of the receiving clock: never accepted, never a re-synchronisation candidate
    jw = n if now is None else int(np.searchsorted(t, now + ck.future_s, side="right"))
    period = st.period
    if period is None and n > 1:
        period = float(t[-1] - t[0]) / float(seq[-1] - seq[0])
    j0, j1 = 0, jw
    resync_at = -1
    if st.last_t is not None:
        j0 = min(int(np.searchsorted(t, st.last_t, side="right")), jw)
        for j in range(j0):
            sj, tj = int(seq[j]), float(t[j])
            if _stale(st, sj, tj, ck):
                why = "duplicate" if sj == st.last_seq or tj == st.last_t else "out_of_order"
                st.resync = None
            else:  # the clock went back
                why = "clock"
                if _candidate(st, sj, tj, ck, period):
                    resync_at = j
            st.count_bad(why)
            bad_log.warning(
                st.name, "%s sample from %s: seq %d t %.6f after t %.6f",
                why, st.name, sj, tj, st.last_t,
            )  # fmt: skip
            if resync_at >= 0:
                break
        if j0 < jw:  # ahead of what the sequence gap implies: refused from there on
            lim = np.array([_limit(st, int(s), ck, period) for s in seq[j0:jw]])
            bad = np.flatnonzero(t[j0:jw] > lim)
            if len(bad):
                j1 = j0 + int(bad[0])
                for j in range(j1, jw):
                    st.count_bad("clock")
                    st.refused += 1
                    if _candidate(st, int(seq[j]), float(t[j]), ck, period):
                        resync_at = j
                bad_log.warning(
                    st.name, "clock: %d samples from %s ahead of the stream: t %.6f after t %.6f",
                    jw - j1, st.name, float(t[j1]), st.last_t,
                )  # fmt: skip
    if jw < n:
        st.count_bad("clock", n - jw)
        bad_log.warning(
            st.name, "clock: %d samples from %s ahead of the receiving clock by %.3f s",
            n - jw, st.name, float(t[jw]) - (now or 0.0),
        )  # fmt: skip
    if resync_at >= 0 and j0 >= j1:  # a clock that really jumped: follow it
        back = float(t[resync_at]) < (st.last_t or 0.0)
        st.last_seq, st.last_t = int(seq[resync_at]), float(t[resync_at])
        st.restarts += 1
        st.resync, st.refused = None, 0
        on_restart(st, st.last_t, st.last_seq, back)
        j0, j1 = resync_at + 1, jw
    if j0 >= j1:
        return j0, j0
    st.resync = None
    s0 = int(seq[j0])
    if st.last_seq is not None:
        if s0 > st.last_seq + 1:
            st.gaps += max(0, s0 - st.last_seq - 1 - st.refused)
        elif s0 <= st.last_seq:
            st.restarts += 1
            on_restart(st, float(t[j0]), s0, False)
    st.refused = 0
    if st.first_seq is None:
        st.first_seq = s0
    st.gaps += int(seq[j1 - 1]) - s0 - (j1 - 1 - j0)  # holes inside the message
    if j1 - j0 > 1:
        p = float(t[j1 - 1] - t[j0]) / float(seq[j1 - 1] - s0)
        st.period = p if st.period is None else 0.9 * st.period + 0.1 * p
    st.last_seq, st.last_t = int(seq[j1 - 1]), float(t[j1 - 1])
    st.samples += j1 - j0
    return j0, j1
