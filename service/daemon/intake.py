"""The daemon's intake, the pipeline's first stage (:class:`Intake`): the receive queue,
per-actuator state, decoding failures by reason, and the sequence and time checks that decide
which samples of a message are accepted.

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

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.daemon.block import Block, Event, Part
from service.daemon.ratelimit import RateLimitedLog
from service.wire import messages as m

__all__ = [
    "ActuatorState", "ClockCheck", "Intake", "MAX_ACTUATORS", "MAX_PER_AIRCRAFT", "EXPIRE_S",
    "accept", "reason_of",
]  # fmt: skip

log = logging.getLogger("servowatch.daemon")

#: actuators a daemon tracks at most; samples of further ones count as ``unknown_actuator``
MAX_ACTUATORS = 1000
#: actuators of one aircraft a daemon tracks at most (an acquisition identity is one
#: aircraft's, so this is a cap per identity); further ones count as ``aircraft_full``
MAX_PER_AIRCRAFT = 64
#: a unit silent this long leaves the table (and frees its aircraft's slot) [s]
EXPIRE_S = 3600.0


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


def _limits(st: ActuatorState, s: np.ndarray, ck: ClockCheck, period: float | None) -> np.ndarray:
    """``_limit`` of each seq of ``s`` (the same arithmetic, vectorised)."""
    assert st.last_t is not None and st.last_seq is not None
    ds = np.asarray(s, np.int64) - st.last_seq
    if period is None:
        return np.full(len(ds), math.inf)
    with np.errstate(over="ignore", invalid="ignore"):
        lim = st.last_t + ck.factor * ds * period + ck.tol_s
    return np.where(ds > 0, lim, math.inf)


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


def _follow(
    st: ActuatorState,
    a: m.MeasArrays,
    j: int,
    bad_log: RateLimitedLog,
    on_restart: Callable[[ActuatorState, float, int, bool], None],
    ck: ClockCheck,
    now: float | None,
) -> tuple[int, int]:
    """Re-synchronise the stream on its refused sample ``j`` (a clock that really jumped),
    then judge the rest of the message from there (``accept``); its accepted samples."""
    back = float(a.t[j]) < (st.last_t or 0.0)
    st.last_seq, st.last_t = int(a.seq[j]), float(a.t[j])
    st.restarts += 1
    st.resync, st.refused = None, 0
    on_restart(st, st.last_t, st.last_seq, back)
    k = j + 1
    r0, r1 = accept(st, m.MeasArrays(a.seq[k:], a.t[k:], a.values[k:]), bad_log, on_restart,
                    ck, now)  # fmt: skip
    return k + r0, k + r1


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
            if resync_at >= 0:  # followed here: the rest is judged from this sample
                return _follow(st, a, resync_at, bad_log, on_restart, ck, now)
        if j0 < jw:  # ahead of what the sequence gap implies: refused from there on
            lim = _limits(st, seq[j0:jw], ck, period)
            bad = np.flatnonzero(t[j0:jw] > lim)
            if len(bad):
                j1 = j0 + int(bad[0])
                j = j1
                while j < jw:
                    st.count_bad("clock")
                    st.refused += 1
                    if _candidate(st, int(seq[j]), float(t[j]), ck, period):
                        resync_at = j
                        if j0 >= j1:  # none accepted before it: the clock is followed here
                            break
                    j += 1
                bad_log.warning(
                    st.name, "clock: %d samples from %s ahead of the stream: t %.6f after t %.6f",
                    min(j + 1, jw) - j1, st.name, float(t[j1]), st.last_t,
                )  # fmt: skip
                if resync_at >= 0 and j0 >= j1:  # a clock that really jumped: followed here
                    return _follow(st, a, resync_at, bad_log, on_restart, ck, now)
    if jw < n:
        st.count_bad("clock", n - jw)
        bad_log.warning(
            st.name, "clock: %d samples from %s ahead of the receiving clock by %.3f s",
            n - jw, st.name, float(t[jw]) - (now or 0.0),
        )  # fmt: skip
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


class Intake:
    """The pipeline's first stage: the receive queue, per-actuator stream state, decoding and
    the acceptance checks. ``submit`` (any thread) queues a message; ``take`` (the worker)
    drains the queue into a :class:`~service.daemon.block.Block`.

    The unit table is bounded per source: :meth:`admit_key` lets a key in only if it follows
    the key grammar (``fleet/<aircraft>/<actuator>/meas``, names of letters, digits, ``_ . -``)
    and its aircraft has fewer than ``max_per_aircraft`` units in the table (and the table
    fewer than ``MAX_ACTUATORS``); a unit silent for ``expire_s`` leaves it (:meth:`expire`).
    Refusals are counted (``unknown``: ``invalid_key``, ``aircraft_full``,
    ``unknown_actuator``; per aircraft in ``refused_units``)."""

    def __init__(
        self,
        *,
        queue_size: int,
        max_bytes: int,
        clock: ClockCheck,
        max_batch: int,
        bad_log: RateLimitedLog,
        max_per_aircraft: int = MAX_PER_AIRCRAFT,
        expire_s: float = EXPIRE_S,
    ) -> None:
        self.queue_size = queue_size
        self.max_bytes = max_bytes
        self.clock = clock
        self.max_batch = max_batch
        self.bad_log = bad_log
        self.actuators: dict[str, ActuatorState] = {}
        self.unknown: dict[str, int] = {}  # reason -> count, for keys that name no actuator
        self._queue: deque = deque()
        self._arrival: dict[str, float] = {}  # key -> time.monotonic() of the last message
        self.first_arrival: dict[str, float] = {}  # key -> time.monotonic() of the first one
        self.alive_tokens: dict[str, bool] = {}  # fleet/{ac}/{act}/alive -> token present
        self._sources: dict[str, str] = {}  # advanced publisher id -> key
        self._lock = threading.Lock()  # guards the structure of self.actuators
        self.wake = threading.Event()  # set when the worker has something to do
        self.queue_high = 0
        self.max_per_aircraft = int(max_per_aircraft)
        self.expire_s = float(expire_s)
        self._per_aircraft: dict[str, int] = {}  # aircraft -> units in the table
        self.refused_units: dict[str, int] = {}  # aircraft -> messages of units refused
        self.expired = 0  # units that left the table for their silence

    # -- the unit table -----------------------------------------------------------------
    def _refuse(self, reason: str, key: str, aircraft: str | None = None) -> bool:
        with self._lock:
            self.unknown[reason] = self.unknown.get(reason, 0) + 1
            if aircraft is not None:
                self.refused_units[aircraft] = self.refused_units.get(aircraft, 0) + 1
        self.bad_log.warning("key:" + reason, "%s: %r", reason, key[:200])
        return False

    def admit_key(self, key: str, t_recv: float | None = None) -> bool:
        """Whether messages on ``key`` may enter (any thread): a unit in the table, or a new
        one that follows the key grammar and fits its aircraft's cap (it then takes a slot).
        A refusal is counted."""
        if key in self._arrival:
            return True
        try:
            aircraft, _ = m.parse_meas_key(key)
        except m.MessageError:
            return self._refuse("invalid_key", key)
        with self._lock:
            if key in self._arrival:
                return True
            n = self._per_aircraft.get(aircraft, 0)
            full = n >= self.max_per_aircraft
            if not full and len(self._arrival) < MAX_ACTUATORS:
                self._per_aircraft[aircraft] = n + 1
                t = time.monotonic() if t_recv is None else t_recv
                self._arrival[key] = t
                self.first_arrival.setdefault(key, t)
                return True
        return self._refuse("aircraft_full" if full else "unknown_actuator", key, aircraft)

    def expire(self, now: float) -> list[tuple[str, ActuatorState | None]]:
        """Units without a message for ``expire_s`` leave the table (their aircraft's slot
        freed, their stream state forgotten); returns (key, state) of each."""
        out: list[tuple[str, ActuatorState | None]] = []
        with self._lock:
            for key, last in list(self._arrival.items()):
                if now - last <= self.expire_s:
                    continue
                del self._arrival[key]
                self.first_arrival.pop(key, None)
                aircraft = key.split("/")[1]
                left = self._per_aircraft.get(aircraft, 1) - 1
                if left > 0:
                    self._per_aircraft[aircraft] = left
                else:
                    self._per_aircraft.pop(aircraft, None)
                out.append((key, self.actuators.pop(key, None)))
            if out:
                gone = {k for k, _ in out}
                self._sources = {s: k for s, k in self._sources.items() if k not in gone}
                self.expired += len(out)
        return out

    # -- any thread ---------------------------------------------------------------------
    def submit(self, key: str, payload: bytes, t_recv: float | None = None) -> bool:
        """Queue one message (never blocks); False if its key is refused (``admit_key``) or
        the queue was full (drop counted)."""
        t_recv = time.monotonic() if t_recv is None else t_recv
        if not self.admit_key(key, t_recv):
            return False
        if len(self._queue) >= self.queue_size:
            self._count("dropped", key, 1)
            return False
        self._arrival[key] = t_recv  # for silence detection, even while the worker lags
        self._queue.append((key, payload, t_recv))
        n = len(self._queue)
        if n > self.queue_high:
            self.queue_high = n
        if n == 1 or n % 64 == 0:
            self.wake.set()
        return True

    def source(self, source_id: str, key: str) -> None:
        """Publisher ``source_id`` sends on ``key`` (to count its misses; units in the table
        only, so the map is as bounded as the table)."""
        if key in self._arrival and (
            source_id in self._sources or len(self._sources) < 4 * MAX_ACTUATORS
        ):
            self._sources[source_id] = key

    def key_of_source(self, source_id: str) -> str:
        return self._sources.get(source_id, "")

    def missed(self, key: str, n: int) -> ActuatorState | None:
        """``n`` messages on ``key`` that the transport could not recover."""
        return self._count("missed", key, n)

    def alive(self, key: str, present: bool) -> None:
        """An actuator's liveliness token appeared or vanished (at most ``2 MAX_ACTUATORS``
        tokens tracked; a vanished one of a unit not in the table is forgotten)."""
        if not present and key[: -len("alive")] + "meas" not in self._arrival:
            self.alive_tokens.pop(key, None)
        elif key in self.alive_tokens or len(self.alive_tokens) < 2 * MAX_ACTUATORS:
            self.alive_tokens[key] = present
        else:
            self.unknown["alive_full"] = self.unknown.get("alive_full", 0) + 1

    def _count(self, what: str, key: str, n: int) -> ActuatorState | None:
        st = self.state_for_key(key)
        if st is not None:
            setattr(st, what, getattr(st, what) + n)
        else:
            self.unknown[what] = self.unknown.get(what, 0) + n
        return st

    @property
    def queued(self) -> int:
        """Messages waiting in the receive queue."""
        return len(self._queue)

    def state_for_key(self, key: str) -> ActuatorState | None:
        """The state of the actuator of meas key ``key`` (made on first use; None for a key
        that names no actuator or beyond ``MAX_ACTUATORS``)."""
        st = self.actuators.get(key)
        if st is not None:
            return st
        try:
            aircraft, actuator = m.parse_meas_key(key)
        except m.MessageError:
            return None
        with self._lock:
            st = self.actuators.get(key)
            if st is None:
                if key not in self._arrival:  # not admitted, or expired meanwhile
                    return None
                st = ActuatorState(aircraft, actuator)
                self.actuators[key] = st
                log.info("new actuator %s", st.name)
        return st

    # -- the worker ---------------------------------------------------------------------
    def take(self) -> Block | None:
        """Drain up to ``max_batch`` messages: decode, check, accept. None if none queued.

        The binary messages are decoded at once, and the plain ones (every sample accepted,
        no event) accepted by compiled code (``service.wire.kernels.intake_batch``); the rest
        go through :func:`accept` in arrival order, on the same stream state."""
        q = self._queue
        if not q:
            return None
        msgs = []
        while q and len(msgs) < self.max_batch:
            msgs.append(q.popleft())
        blk = Block()
        now = time.time()

        def on_restart(st: ActuatorState, t: float, seq: int, back: bool = False) -> None:
            if back:  # time went back: the filter restarts
                blk.restarts.append(f"fleet/{st.aircraft}/{st.actuator}/meas")
            blk.log.append(Event(st, "restart", t, seq))

        sts = [self.state_for_key(key) for key, _, _ in msgs]
        batch = self._batch(msgs, sts, now)
        if batch is None:  # a payload that is not bytes: every message one by one
            starts = counts = [0] * len(msgs)
            codes = [m.BATCH_UNDECODED] * len(msgs)
            seq = t = vals = None
        else:
            seq, t, vals, starts, counts, codes = batch
        contiguous = batch is not None  # the parts are the decoded rows in order, all of them
        pos = 0
        for (key, payload, t_recv), st, code, b0, nb in zip(
            msgs, sts, codes, starts, counts, strict=True
        ):
            if st is None:
                reason = "unknown_actuator" if key.endswith("/meas") else "invalid_key"
                try:
                    m.parse_meas_key(key)
                except m.MessageError:
                    reason = "invalid_key"
                self.unknown[reason] = self.unknown.get(reason, 0) + 1
                self.bad_log.warning("key:" + reason, "%s: %r", reason, key[:200])
                contiguous = contiguous and nb == 0
                continue
            st.messages += 1
            st.last_recv = t_recv
            if st.silent:
                st.silent = False
                blk.log.append(Event(st, "resumed", st.last_t))
            if code == m.BATCH_ACCEPTED:
                p = Part(st, key, m.MeasArrays(seq[b0 : b0 + nb], t[b0 : b0 + nb],
                                               vals[b0 : b0 + nb]), 0, t_recv)  # fmt: skip
                blk.parts.append(p)
                blk.log.append(p)
                pos += nb
                continue
            contiguous = False
            if code == m.BATCH_DECODED:
                a = m.MeasArrays(seq[b0 : b0 + nb], t[b0 : b0 + nb], vals[b0 : b0 + nb])
            else:
                try:
                    a = m.decode_meas_arrays(payload, self.max_bytes)
                except (m.MessageError, ValueError, OverflowError) as e:
                    # a value numpy cannot hold is a bad sample too, never an error that
                    # loses the rest of the batch (issue 50, item 8)
                    if not isinstance(e, m.MessageError):
                        e = m.MessageError(f"{type(e).__name__}: {e}", "samples")
                    reason = reason_of(e)
                    st.count_bad(reason)
                    self.bad_log.warning(
                        st.name, "bad message from %s: %s (%s)", st.name, e, reason
                    )
                    continue
            j0, j1 = accept(st, a, self.bad_log, on_restart, self.clock, now)
            if j0 >= j1:
                continue
            if j1 < len(a.t):
                a = m.MeasArrays(a.seq[:j1], a.t[:j1], a.values[:j1])
            p = Part(st, key, a, j0, t_recv)
            blk.parts.append(p)
            blk.log.append(p)
        if contiguous and blk.parts:
            blk.preset_arrays(seq[:pos], t[:pos], vals[:pos])
        return blk

    def warm_up(self) -> None:
        """Load the compiled batch (``take``'s) now, not on the first message."""
        p = m.encode_meas([{"seq": 0, "t": 0.0}])
        m.decode_into([p], np.empty(2, np.int64), np.empty(2), np.empty((2, len(m.CHANNELS))))

    def _batch(self, msgs: list, sts: list, now: float) -> tuple | None:
        """Decode the messages at once and accept the plain ones (``take``): (seq, t, values,
        start, count, status) with the stream state of the accepted ones updated; None when a
        payload is not ``bytes``."""
        payloads = [p for _, p, _ in msgs]
        if any(type(p) is not bytes for p in payloads):
            return None
        ck = self.clock
        slots: dict[int, int] = {}
        streams: list[ActuatorState] = []
        slot = []
        for st in sts:
            if st is None:
                slot.append(-1)
                continue
            k = slots.get(id(st))
            if k is None:
                k = slots[id(st)] = len(streams)
                streams.append(st)
            slot.append(k)
        ns = len(streams)
        lts = [st.last_t for st in streams]
        lss = [st.last_seq for st in streams]
        known = [a is not None and b is not None for a, b in zip(lts, lss, strict=True)]
        has_last = np.array(known, np.bool_).reshape(ns)
        # a silent stream's resumed event comes before its samples: no fast path, and
        # neither for a half-known state (its own rules are accept's)
        divert = np.array(
            [st.silent or (not k and (a is not None or b is not None))
             for st, k, a, b in zip(streams, known, lts, lss, strict=True)], np.bool_,
        ).reshape(ns)  # fmt: skip
        last_seq = np.array([b if k else 0 for b, k in zip(lss, known, strict=True)], np.int64)
        last_t = np.array([a if k else 0.0 for a, k in zip(lts, known, strict=True)], np.float64)
        refused = np.array([st.refused for st in streams], np.int64)
        period = np.array(
            [math.nan if st.period is None else st.period for st in streams], np.float64
        )
        first = np.array([-1 if st.first_seq is None else st.first_seq for st in streams], np.int64)
        n = sum(map(len, payloads)) // m.REC_BYTES + 1  # at least the samples
        seq, t, vals = np.empty(n, np.int64), np.empty(n), np.empty((n, len(m.CHANNELS)))
        gaps, samples = np.zeros(ns, np.int64), np.zeros(ns, np.int64)
        state = (has_last, divert, last_seq, refused, last_t, period, first, gaps, samples)
        clock = (float(ck.factor), float(ck.tol_s), float(now + ck.future_s))
        out = m.decode_into(
            payloads, seq, t, vals, self.max_bytes,
            np.array(slot, np.int64), state, clock,
        )  # fmt: skip
        if out is None:
            return None
        starts, counts, codes = out
        for st, dn, dg, ls, lt, pe, fs in zip(
            streams, samples.tolist(), gaps.tolist(), last_seq.tolist(), last_t.tolist(),
            period.tolist(), first.tolist(), strict=True,
        ):  # fmt: skip
            if dn:  # plain messages were accepted: the state accept() would have left
                st.samples += dn
                st.gaps += dg
                st.last_seq, st.last_t = ls, lt
                st.period = None if math.isnan(pe) else pe
                st.first_seq = fs
                st.refused = 0
                st.resync = None
        return seq, t, vals, starts.tolist(), counts.tolist(), codes.tolist()

    def silent(self, now: float, silence_s: float) -> list[tuple[str, ActuatorState, float]]:
        """Mark actuators silent after ``silence_s`` without a message: (key, state, seconds
        since its last message) of the new ones."""
        out = []
        for key, st in list(self.actuators.items()):
            last = self._arrival.get(key, st.last_recv)
            if not st.silent and last is not None and now - last > silence_s:
                st.silent = True
                out.append((key, st, now - last))
        return out

    def forget(self, key: str) -> ActuatorState | None:
        """The stream state of ``key`` starts afresh (a unit another group member took)."""
        st = self.actuators.get(key)
        if st is not None:
            st.first_seq = st.last_seq = st.last_t = st.period = st.resync = None
            st.refused = 0
            st.silent = True
        return st

    def status(self, now: float) -> dict[str, Any]:
        """Queue, unknown keys, liveliness and each actuator's entry (``now``:
        ``time.monotonic()``). May raise RuntimeError on a torn read (retry)."""
        with self._lock:
            acts = {k: st.snapshot(now) for k, st in list(self.actuators.items())}
            table = {
                "units": len(self._arrival),
                "max_units": MAX_ACTUATORS,
                "max_per_aircraft": self.max_per_aircraft,
                "expire_s": self.expire_s,
                "expired": self.expired,
                "per_aircraft": dict(sorted(self._per_aircraft.items())),
                "refused": dict(sorted(self.refused_units.items())),
            }
        return {
            "queue": self.queued,
            "queue_high": self.queue_high,
            "queue_size": self.queue_size,
            "unit_table": table,
            "unknown": dict(self.unknown),
            "alive_tokens": sorted(k for k, v in self.alive_tokens.items() if v),
            "lost_tokens": sorted(k for k, v in self.alive_tokens.items() if not v),
            "actuators": acts,
        }
