"""Monitors of actuators with their own baselines, all in one ``MonitorBank``.

``MonitorFleet`` resolves each actuator's baseline when it first appears (``resolve(key)``:
its baseline and its version in the health store, None: not commissioned, the default) and
gives it to the bank (``MonitorBank.index_of(key, baseline)``), which keeps the
baseline-dependent vectors as one row per actuator: one batched update serves every
actuator whatever its baseline. It presents the bank interface the daemon and the replay
use (``index_of``, ``update_arrays``, ``step_arrays``/``rows_of``, ``counters_of``,
``c_lk_changes_of``); with
every actuator on the default, the numbers are those of a plain ``MonitorBank``.
``rebase`` moves an actuator to another baseline (auto-commissioning).

A stored baseline identified for another process model than the fleet's is never used: the
actuator runs on the default, uncommissioned, the refusal logged as an error naming both
models and counted in ``refused`` (recalibrate it: ``servowatch calibrate --model M
--actuator A --store ...``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from numpy.typing import NDArray

from service.monitor.bank import MonitorBank
from service.monitor.config import Baseline, BaselineModelError, MonitorConfig, check_baseline_model
from service.monitor.outputs import BankRows, StepBlock

__all__ = ["MonitorFleet", "Resolver"]

log = logging.getLogger(__name__)

Resolver = Callable[[str], tuple[Baseline, int | None]]
"""actuator key -> (its baseline, its baseline version in the store or None)."""


class MonitorFleet:
    """Actuators on their own baselines in one ``MonitorBank`` (module docstring)."""

    def __init__(
        self,
        config: MonitorConfig | None = None,
        default: Baseline | None = None,
        resolve: Resolver | None = None,
        capacity: int = 8,
    ) -> None:
        self.bank = MonitorBank(config, default, capacity)
        self.config = self.bank.config
        self.baseline = self.bank.baseline
        self._resolve = resolve
        self.versions: dict[str, int | None] = {}  # actuator key -> baseline version
        # actuator key -> the process model of the stored baseline it refused
        self.refused: dict[str, str] = {}

    @property
    def ids(self) -> dict[str, int]:
        """actuator key -> bank row."""
        return self.bank.ids

    @property
    def baselines(self) -> dict[str, Baseline]:
        """actuator key -> the baseline it runs on."""
        return {k: self.bank.baseline_of(k) for k in self.bank.ids}

    def commissioned(self, key: str) -> bool:
        """True when ``key`` runs on its own baseline from the store."""
        return self.versions.get(key) is not None

    def index_of(self, key: str) -> int:
        """Bank row of actuator ``key`` (created on first use, its baseline resolved)."""
        k = self.bank.ids.get(key)
        if k is not None:
            return k
        base, version = (None, None) if self._resolve is None else self._resolve(key)
        if version is not None and base is not None:
            try:
                check_baseline_model(base, self.config.model, f"stored baseline v{version}")
            except BaselineModelError as e:
                log.error("%s: %s; monitoring it on the default baseline, uncommissioned", key, e)
                self.refused[key] = base.law
                base, version = None, None
        self.versions[key] = version
        return self.bank.index_of(key, None if version is None else base)

    def rebase(self, key: str, baseline: Baseline, version: int | None) -> None:
        """Run ``key`` on ``baseline`` from its next sample (fresh filter state)."""
        self.index_of(key)
        self.bank.set_baseline(key, baseline)
        self.versions[key] = version

    def counters_of(self, key: str) -> dict[str, int]:
        """The monitor's sample counters of ``key``."""
        return self.bank.counters_of(key)

    def c_lk_changes_of(self, key: str) -> int:
        """``MonitorBank.c_lk_changes_of``."""
        return self.bank.c_lk_changes_of(key)

    def step_arrays(self, ks: NDArray, t: NDArray, channels: NDArray) -> StepBlock | None:
        """``MonitorBank.step_arrays``."""
        return self.bank.step_arrays(ks, t, channels)

    def rows_of(self, sb: StepBlock) -> BankRows:
        """``MonitorBank.rows_of``."""
        return self.bank.rows_of(sb)

    def update_arrays(self, ks: NDArray, t: NDArray, channels: NDArray) -> BankRows:
        """``MonitorBank.update_arrays``."""
        return self.bank.update_arrays(ks, t, channels)
