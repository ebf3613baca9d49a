"""Monitors of actuators with their own baselines: one ``MonitorBank`` per distinct baseline.

A ``MonitorBank`` holds one baseline for all its actuators (the kernels take one parameter
vector). ``MonitorFleet`` groups the actuators by baseline, so every group is still batched
in one compiled update, and presents the bank interface the daemon and the replay use
(``index_of``, ``update_arrays``, ``step_arrays``/``rows_of``, ``counters_of``). With a
single baseline there is one bank and the numbers are those of a plain ``MonitorBank``.

``resolve(key)`` gives an actuator's baseline and its version in the health store (None:
not commissioned, the default baseline). ``rebase`` moves an actuator to another baseline
(auto-commissioning); its filter starts again from its next sample.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from service.monitor.bank import MonitorBank
from service.monitor.config import Baseline, MonitorConfig
from service.monitor.outputs import BankRows, RowEvents, StepBlock, empty_rows

__all__ = ["MonitorFleet", "FleetStep", "Resolver"]

Resolver = Callable[[str], tuple[Baseline, int | None]]
"""actuator key -> (its baseline, its baseline version in the store or None)."""


@dataclass
class FleetStep:
    """``step_arrays`` of a fleet: per bank, the input positions and its ``StepBlock``."""

    n: int
    parts: list[tuple[MonitorBank, NDArray, StepBlock]]


class MonitorFleet:
    """Actuators in one ``MonitorBank`` per distinct baseline (module docstring)."""

    def __init__(
        self,
        config: MonitorConfig | None = None,
        default: Baseline | None = None,
        resolve: Resolver | None = None,
    ) -> None:
        self.config = config or MonitorConfig()
        self.baseline = default or Baseline.default(self.config.model)
        self._resolve = resolve
        self._banks: dict[str, MonitorBank] = {}  # baseline JSON -> bank
        self._bank_list: list[MonitorBank] = []
        self.ids: dict[str, int] = {}  # actuator key -> fleet row
        self._where: list[tuple[int, int, str]] = []  # fleet row -> (bank, bank row, bank key)
        self.versions: dict[str, int | None] = {}  # actuator key -> baseline version
        self.baselines: dict[str, Baseline] = {}  # actuator key -> its baseline
        self._bank_of(self.baseline)

    def _bank_of(self, baseline: Baseline) -> int:
        if baseline.law != self.config.model:
            baseline = baseline.model_copy(update={"law": self.config.model})
        sig = baseline.model_dump_json(exclude={"source"})
        bank = self._banks.get(sig)
        if bank is None:
            bank = self._banks[sig] = MonitorBank(self.config, baseline)
            self._bank_list.append(bank)
        return self._bank_list.index(bank)

    @property
    def banks(self) -> list[MonitorBank]:
        """The banks, one per distinct baseline (the default's first)."""
        return list(self._bank_list)

    def commissioned(self, key: str) -> bool:
        """True when ``key`` runs on its own baseline from the store."""
        return self.versions.get(key) is not None

    def index_of(self, key: str) -> int:
        """Fleet row of actuator ``key`` (created on first use, its baseline resolved)."""
        k = self.ids.get(key)
        if k is not None:
            return k
        base, version = (self.baseline, None) if self._resolve is None else self._resolve(key)
        k = len(self._where)
        self.ids[key] = k
        self._where.append(self._place(key, base, version, key))
        return k

    def _place(self, key: str, base: Baseline, version: int | None, bkey: str):
        b = self._bank_of(base)
        self.versions[key] = version
        self.baselines[key] = base
        return (b, self._bank_list[b].index_of(bkey), bkey)

    def rebase(self, key: str, baseline: Baseline, version: int | None) -> None:
        """Run ``key`` on ``baseline`` from its next sample (fresh filter state)."""
        k = self.index_of(key)
        bkey = f"{key}#v{version}"
        self._where[k] = self._place(key, baseline, version, bkey)

    def counters_of(self, key: str) -> dict[str, int]:
        """The monitor's sample counters of ``key`` (since its last rebase)."""
        b, _, bkey = self._where[self.ids[key]]
        return self._bank_list[b].counters_of(bkey)

    def step_arrays(self, ks: NDArray, t: NDArray, channels: NDArray) -> FleetStep | None:
        """``MonitorBank.step_arrays`` over the banks (``ks``: fleet rows)."""
        ks = np.asarray(ks, np.int64)
        if len(ks) == 0:
            return None
        if ks.min() < 0 or ks.max() >= len(self._where):
            raise ValueError("update_arrays: ks must be rows returned by index_of")
        bank_of = np.array([w[0] for w in self._where], np.int64)
        local = np.array([w[1] for w in self._where], np.int64)
        bk = bank_of[ks]
        parts = []
        for b in np.unique(bk).tolist():
            pos = np.flatnonzero(bk == b) if len(self._bank_list) > 1 else np.arange(len(ks))
            bank = self._bank_list[b]
            sb = bank.step_arrays(local[ks[pos]], t[pos], channels[pos])
            if sb is not None:
                parts.append((bank, pos, sb))
        return FleetStep(len(ks), parts)

    def rows_of(self, fs: FleetStep) -> BankRows:
        """``MonitorBank.rows_of`` over the banks; ``index`` refers to the fleet's input."""
        outs = [(pos, bank.rows_of(sb)) for bank, pos, sb in fs.parts]
        if len(outs) == 1 and len(outs[0][0]) == fs.n:
            return outs[0][1]
        outs = [(pos, r) for pos, r in outs if len(r.index)]
        if not outs:
            return empty_rows()
        idx = np.concatenate([pos[r.index] for pos, r in outs])
        order = np.argsort(idx, kind="stable")
        at: dict[int, list] = {}
        off = 0
        for _, r in outs:
            for j in r.events.rows():
                at[off + j] = r.events[j]
            off += len(r.index)
        inv = np.empty_like(order)
        inv[order] = np.arange(len(order))
        return BankRows(
            index=idx[order],
            t=np.concatenate([r.t for _, r in outs])[order],
            est=np.concatenate([r.est for _, r in outs])[order],
            res=np.concatenate([r.res for _, r in outs])[order],
            health=np.concatenate([r.health for _, r in outs])[order],
            events=RowEvents(len(idx), {int(inv[j]): ev for j, ev in at.items()}),
        )

    def update_arrays(self, ks: NDArray, t: NDArray, channels: NDArray) -> BankRows:
        """``MonitorBank.update_arrays`` for fleet rows ``ks``."""
        fs = self.step_arrays(ks, t, channels)
        return empty_rows() if fs is None else self.rows_of(fs)
