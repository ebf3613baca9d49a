"""The daemon's intake: per-actuator state, decoding failures by reason, and the sequence and
time checks that decide which samples of a message are accepted.

A sample is accepted when its time is later than the actuator's last accepted sample; a
sequence number that falls back while time advances is a publisher restart (counted), a
sequence that jumps forward is a gap (missing samples counted). Only accepted samples reach
the monitor and the ``meas`` log topic, so a replay of the log feeds the monitor exactly the
live input.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service import messages as m
from service.daemon.ratelimit import RateLimitedLog

__all__ = ["ActuatorState", "MAX_ACTUATORS", "accept", "reason_of"]

#: actuators a daemon tracks at most; samples of further ones count as ``unknown_actuator``
MAX_ACTUATORS = 1000


@dataclass
class ActuatorState:
    """Counters and latest outputs of one actuator (``fleet/{aircraft}/{actuator}``)."""

    aircraft: str
    actuator: str
    messages: int = 0
    samples: int = 0  # accepted samples (fed to the monitor and logged)
    dropped: int = 0  # messages dropped by the full queue
    gaps: int = 0  # samples missing according to sequence numbers
    restarts: int = 0  # sequence fell back while time advanced
    outputs: int = 0  # monitor outputs
    published: int = 0
    bad: dict[str, int] = field(default_factory=dict)  # reason -> count
    last_seq: int | None = None
    last_t: float | None = None
    last_recv: float | None = None  # time.monotonic() of the last message
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
            "outputs": self.outputs,
            "published": self.published,
            "bad": dict(self.bad),
            "bad_total": sum(self.bad.values()),
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


def accept(
    st: ActuatorState,
    a: m.MeasArrays,
    bad_log: RateLimitedLog,
    on_restart: Callable[[ActuatorState, float, int], None],
) -> int:
    """Sequence and time checks of one decoded message against the actuator's last accepted
    sample; returns the index of the first accepted sample (the samples of a message are
    strictly increasing in seq and t, so only a prefix can be refused). ``on_restart(st, t,
    seq)`` is called when the sequence falls back while time advances."""
    t, seq = a.t, a.seq
    n = len(t)
    j0 = 0
    if st.last_t is not None:
        j0 = int(np.searchsorted(t, st.last_t, side="right"))
        for j in range(j0):
            sj, tj = int(seq[j]), float(t[j])
            why = "duplicate" if sj == st.last_seq or tj == st.last_t else "out_of_order"
            st.count_bad(why)
            bad_log.warning(
                st.name, "%s sample from %s: seq %d t %.6f after t %.6f",
                why, st.name, sj, tj, st.last_t,
            )  # fmt: skip
    if j0 >= n:
        return n
    s0 = int(seq[j0])
    if st.last_seq is not None:
        if s0 > st.last_seq + 1:
            st.gaps += s0 - st.last_seq - 1
        elif s0 <= st.last_seq:
            st.restarts += 1
            on_restart(st, float(t[j0]), s0)
    st.gaps += int(seq[n - 1]) - s0 - (n - 1 - j0)  # holes inside the message
    st.last_seq, st.last_t = int(seq[n - 1]), float(t[n - 1])
    st.samples += n - j0
    return j0
