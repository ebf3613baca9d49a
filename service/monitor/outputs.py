"""What the monitor returns: the column layout of its output rows and the output types.

An output row has three parts, named by ``EST_KEYS``, ``RES_KEYS`` and ``HEALTH_KEYS``; the
compiled kernels write them by the column indices below (``EST_P12`` ...), which are derived
from the key tuples, so a key moved in a tuple moves its column everywhere.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from models import eha_reduced as er

__all__ = [
    "log_reinit",
    "MEAS_CHANNELS",
    "ALARM_KINDS",
    "EST_KEYS",
    "RES_KEYS",
    "HEALTH_KEYS",
    "COUNTERS",
    "AlarmEvent",
    "MonitorOutput",
    "RowEvents",
    "BankRows",
    "StepBlock",
]

MEAS_CHANNELS: tuple[str, ...] = er.MEAS_NAMES  # x_s, x_j, p1, p2, p_sr
ALARM_KINDS: tuple[str, ...] = ("leak", "supply")

# est: (value, 1-sigma) of each filter state, in state order, then P12 and the C_Lk increase
EST_KEYS: tuple[str, ...] = tuple(
    [k for n in er.STATE_NAMES for k in (n, n + "_sigma")] + ["p12", "c_lk_increase"]
)
# res: innovation of each channel (scaled back to SI), NIS, its dof, open-loop residuals
RES_KEYS: tuple[str, ...] = tuple(
    [f"innov_{c}" for c in MEAS_CHANNELS] + ["nis", "nis_dof"] + [f"ol_{c}" for c in MEAS_CHANNELS]
)
HEALTH_KEYS: tuple[str, ...] = (
    ("leak_ratio", "supply_ratio") + tuple(f"alarm_{k}" for k in ALARM_KINDS) + ("nis_avg",)
)

# column indices of the output rows (compile-time constants in the kernels)
EST_STATE = EST_KEYS.index(er.STATE_NAMES[0])  # state r: value at EST_STATE + 2 r, sigma + 1
EST_P_SR_SIGMA = EST_KEYS.index("p_sr_sigma")
EST_C_LK_SIGMA = EST_KEYS.index("c_lk_sigma")
EST_P12 = EST_KEYS.index("p12")
EST_C_LK_INCREASE = EST_KEYS.index("c_lk_increase")
RES_INNOV = RES_KEYS.index(f"innov_{MEAS_CHANNELS[0]}")  # channel r at RES_INNOV + r
RES_NIS = RES_KEYS.index("nis")
RES_NIS_DOF = RES_KEYS.index("nis_dof")
RES_OL = RES_KEYS.index(f"ol_{MEAS_CHANNELS[0]}")  # channel r at RES_OL + r
HEALTH_LEAK_RATIO = HEALTH_KEYS.index("leak_ratio")
HEALTH_SUPPLY_RATIO = HEALTH_KEYS.index("supply_ratio")
HEALTH_ALARM = HEALTH_KEYS.index(f"alarm_{ALARM_KINDS[0]}")  # alarm a at HEALTH_ALARM + a
HEALTH_NIS_AVG = HEALTH_KEYS.index("nis_avg")
ALARM_LEAK = ALARM_KINDS.index("leak")
ALARM_SUPPLY = ALARM_KINDS.index("supply")
N_ALARMS = len(ALARM_KINDS)
HEALTH_INDICATOR = (HEALTH_LEAK_RATIO, HEALTH_SUPPLY_RATIO)  # the value alarm a compares
FIRE_RAISED, FIRE_CLEARED = 1, 2  # codes of an alarm change in a row (0: none)
assert EST_KEYS[EST_STATE::2][: er.N_STATES] == er.STATE_NAMES
assert RES_KEYS[RES_INNOV : RES_INNOV + len(MEAS_CHANNELS)] == tuple(
    f"innov_{c}" for c in MEAS_CHANNELS
)
assert RES_KEYS[RES_OL:] == tuple(f"ol_{c}" for c in MEAS_CHANNELS)
assert HEALTH_KEYS[HEALTH_ALARM : HEALTH_ALARM + N_ALARMS] == tuple(
    f"alarm_{k}" for k in ALARM_KINDS
)

COUNTERS: tuple[str, ...] = (
    "accepted",
    "skipped_nan",
    "skipped_time",
    "missing_channel",
    "bad_channel",
    "reinit",
    "gap",
)


@dataclass
class AlarmEvent:
    """An alarm raised or cleared at time ``t`` (``value`` is the indicator that crossed)."""

    t: float
    kind: str
    state: Literal["raised", "cleared"]
    value: float


@dataclass
class MonitorOutput:
    """One accepted sample's estimates (flat dicts of floats, never NaN)."""

    t: float
    est: dict[str, float]
    res: dict[str, float]
    health: dict[str, float]
    events: list[AlarmEvent] = field(default_factory=list)


class RowEvents(Sequence):
    """The alarm events of each output row, stored sparsely (most rows have none): a
    sequence of lists, ``[]`` for a row without events. A list per row would be one
    garbage-collected allocation per sample, which cost as much as the filter step."""

    __slots__ = ("_n", "_at")

    def __init__(self, n: int, at: dict[int, list[AlarmEvent]] | None = None):
        self._n = n
        self._at = at or {}

    @classmethod
    def of(cls, lists: Sequence[list[AlarmEvent]]) -> RowEvents:
        """From one list per row."""
        return cls(len(lists), {r: ev for r, ev in enumerate(lists) if ev})

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, r):  # type: ignore[override]
        if isinstance(r, slice):
            return [self[i] for i in range(*r.indices(self._n))]
        if r < 0:
            r += self._n
        if not 0 <= r < self._n:
            raise IndexError("RowEvents index out of range")
        ev = self._at.get(r)
        return [] if ev is None else ev

    def __eq__(self, other: object) -> bool:
        if isinstance(other, RowEvents):
            return self._n == other._n and self._at == other._at
        if isinstance(other, Sequence):
            return list(self) == list(other)
        return NotImplemented

    def __repr__(self) -> str:
        return f"RowEvents({self._n}, {self._at!r})"

    def rows(self) -> list[int]:
        """The rows that have events, ascending."""
        return sorted(self._at)

    def flags(self) -> NDArray:
        """(n,) bool: the row has events."""
        f = np.zeros(self._n, bool)
        if self._at:
            f[list(self._at)] = True
        return f


@dataclass
class BankRows:
    """Outputs of ``MonitorBank.update_rows``: one row per accepted sample, in input order.
    Columns are named by ``EST_KEYS``, ``RES_KEYS`` and ``HEALTH_KEYS`` (same values as the
    dicts of ``MonitorOutput``); ``usage`` by ``service.monitor.usage.USAGE_KEYS``."""

    index: NDArray  # (R,) position of each accepted sample in the input sequence
    t: NDArray  # (R,)
    est: NDArray  # (R, len(EST_KEYS))
    res: NDArray  # (R, len(RES_KEYS))
    health: NDArray  # (R, len(HEALTH_KEYS))
    events: RowEvents  # a sequence of lists, one per row
    # (R, len(service.monitor.usage.USAGE_KEYS)): the usage rates of each row (what wears the
    # seals and the spool; not logged, not published); None from a source that has none
    usage: NDArray | None = None
    # (R, 2): the pooled C_Lk of each row and its 1-sigma [m^3/s/Pa] (everything learnt since
    # the last detected change; docs/estimation.md, "The pooled C_Lk"; not logged, not
    # published: a replay makes it again); None from a source that has none
    pooled: NDArray | None = None
    _lists: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _n_out: int = field(default=0, init=False, repr=False, compare=False)

    def output(self, r: int) -> MonitorOutput:
        """Row ``r`` as a ``MonitorOutput``."""
        c = self._lists
        if c is None:
            self._n_out += 1
            if 8 * self._n_out < len(self.t):
                return MonitorOutput(
                    t=float(self.t[r]),
                    est=dict(zip(EST_KEYS, self.est[r].tolist(), strict=True)),
                    res=dict(zip(RES_KEYS, self.res[r].tolist(), strict=True)),
                    health=dict(zip(HEALTH_KEYS, self.health[r].tolist(), strict=True)),
                    events=self.events[r],
                )
            # many rows wanted: convert the arrays once (same floats, fewer calls)
            c = self._lists = (
                self.t.tolist(), self.est.tolist(), self.res.tolist(), self.health.tolist()
            )  # fmt: skip
        return MonitorOutput(
            t=c[0][r],
            est=dict(zip(EST_KEYS, c[1][r], strict=True)),
            res=dict(zip(RES_KEYS, c[2][r], strict=True)),
            health=dict(zip(HEALTH_KEYS, c[3][r], strict=True)),
            events=self.events[r],
        )


@dataclass
class StepBlock:
    """A block of samples stepped through the filters (``MonitorBank.step_arrays``) whose
    output rows are still to be made (``MonitorBank.rows_of``): inputs, innovations, NIS,
    which samples have a row (acc) and the state snapshot of each (X, diagonal of P, OL,
    T_INIT, NIS_AVG), and the re-initialisation events by sample."""

    ks: NDArray
    t: NDArray
    z: NDArray
    mask: NDArray
    y: NDArray
    nis: NDArray
    acc: NDArray
    snap: tuple[NDArray, NDArray, NDArray, NDArray, NDArray]
    extra: dict[int, list[AlarmEvent]]
    sm: tuple  # the same inputs as the kernels' Samples (service.monitor.kernels)
    so: tuple  # the step's outputs as the kernels' Stepped


def empty_rows() -> BankRows:
    """A ``BankRows`` without rows."""
    z = np.zeros((0,))
    return BankRows(np.zeros(0, int), z, z.reshape(0, len(EST_KEYS)),
                    z.reshape(0, len(RES_KEYS)), z.reshape(0, len(HEALTH_KEYS)), RowEvents(0))  # fmt: skip


def log_reinit(unit: str, t: float, diverged: bool, nis_avg: float) -> None:
    """A monitor's re-initialisation as one warning with its unit, time (RFC 3339 for a
    calendar time, ``t=... s`` for a simulated one) and NIS/dof average as fields."""
    from service.log.retention import readable_time

    when = readable_time(float(t), 6)
    why = "diverged" if diverged else "non-finite or not positive definite"
    logging.getLogger("service.monitor.bank").warning(
        "monitor %s re-initialised at %s (%s, NIS/dof average %.3g)", unit, when, why, nis_avg,
        extra={"fields": {"event": "reinit", "unit": unit, "event_time": when, "value": nis_avg}},
    )  # fmt: skip
