"""The block that passes through the daemon's pipeline: one worker tick's accepted samples.

The intake fills it (:class:`Part` per accepted message, the service events in arrival
order), the monitor stage adds the monitor's block arrays (``ks``, ``t``, ``ch``: the input of
``MonitorBank.update_arrays``) and its output rows, the outputs stage logs, publishes and
stores it. Nothing else passes between the stages.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from service.wire import messages as m

__all__ = ["Block", "Event", "Part"]


class Part(NamedTuple):
    """The accepted samples ``j0:`` of one message of actuator ``st`` (an
    ``intake.ActuatorState``), received at ``t_recv`` (``time.monotonic()``)."""

    st: Any
    key: str  # its meas key
    a: m.MeasArrays
    j0: int
    t_recv: float


class Event(NamedTuple):
    """A daemon-side event of actuator ``st`` (resumed, restart) met by the intake."""

    st: Any
    kind: str
    t: float | None
    value: Any = None


@dataclass
class Block:
    """One tick: filled by the intake, the monitor stage, then read by the outputs."""

    parts: list[Part] = field(default_factory=list)
    log: list[Part | Event] = field(default_factory=list)  # in arrival order
    restarts: list[str] = field(default_factory=list)  # meas keys whose clock went back
    # set by the monitor stage
    ks: NDArray[np.int64] | None = None  # bank row of each sample
    rows: Any = None  # the monitor's ``BankRows`` (None: no output, or the monitor failed)
    states: dict[int, Any] = field(default_factory=dict)  # bank row -> ActuatorState
    new_rows: list[tuple[int, Any, dict[str, Any]]] = field(default_factory=list)  # to track
    _cat: tuple | None = field(default=None, repr=False)

    @property
    def samples(self) -> int:
        """Accepted samples in the block."""
        return sum(len(p.a.t) - p.j0 for p in self.parts)

    def preset_arrays(
        self, seq: NDArray[np.int64], t: NDArray[np.float64], ch: NDArray[np.float64]
    ) -> None:
        """Give :meth:`arrays` its result when the intake has it at hand (the parts' samples
        in order, decoded into one buffer)."""
        self._cat = (seq, t, ch)

    def arrays(self) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        """The accepted samples of every part, in order: ``(seq, t, channels)`` (made once)."""
        if self._cat is None:
            ps = self.parts
            self._cat = (
                np.concatenate([p.a.seq[p.j0 :] for p in ps]),
                np.concatenate([p.a.t[p.j0 :] for p in ps]),
                np.concatenate([p.a.values[p.j0 :] for p in ps]),
            )
        return self._cat
