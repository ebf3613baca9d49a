"""Per-actuator health monitor: a UKF on the simplified (C-type) EHA model, no I/O.

``config`` (MonitorConfig, Baseline, noise and alarm settings), ``outputs`` (the output
row layout EST_KEYS / RES_KEYS / HEALTH_KEYS and the output types), ``bank`` (MonitorBank,
Monitor) and ``kernels`` (the compiled per-sample loops). See docs/estimation.md.
Also ``ukf``, ``usage``, ``calibration`` and ``model_choice``. May import models, compat, log,
store and the loose utilities; never the wire, Zenoh or the daemon.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

# lazy (PEP 562): ``service.monitor.config`` (the settings a config file or a command line
# needs) is importable without compiling anything; the bank and its kernels (numba) load
# on first use of one of their names
_WHERE = {
    "Monitor": "bank",
    "MonitorBank": "bank",
    "MonitorFleet": "fleet",
    **dict.fromkeys(
        ("DEFAULT_MODEL", "AlarmConfig", "Baseline", "BaselineModelError", "MeasurementNoise",
         "MonitorConfig", "ProcessNoise", "check_baseline_model"),
        "config",
    ),
    **dict.fromkeys(
        ("ALARM_KINDS", "COUNTERS", "EST_KEYS", "HEALTH_KEYS", "MEAS_CHANNELS", "RES_KEYS",
         "AlarmEvent", "BankRows", "MonitorOutput", "RowEvents", "StepBlock"),
        "outputs",
    ),
}  # fmt: skip

if TYPE_CHECKING:
    from service.monitor.bank import Monitor, MonitorBank
    from service.monitor.config import (
        DEFAULT_MODEL,
        AlarmConfig,
        Baseline,
        BaselineModelError,
        MeasurementNoise,
        MonitorConfig,
        ProcessNoise,
        check_baseline_model,
    )
    from service.monitor.fleet import MonitorFleet
    from service.monitor.outputs import (
        ALARM_KINDS,
        COUNTERS,
        EST_KEYS,
        HEALTH_KEYS,
        MEAS_CHANNELS,
        RES_KEYS,
        AlarmEvent,
        BankRows,
        MonitorOutput,
        RowEvents,
        StepBlock,
    )


def __getattr__(name: str):
    sub = _WHERE.get(name)
    if sub is None:
        raise AttributeError(f"module 'service.monitor' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"service.monitor.{sub}"), name)
    globals()[name] = value
    return value


__all__ = [
    "MeasurementNoise",
    "ProcessNoise",
    "AlarmConfig",
    "MonitorConfig",
    "Baseline",
    "BaselineModelError",
    "check_baseline_model",
    "DEFAULT_MODEL",
    "AlarmEvent",
    "MonitorOutput",
    "Monitor",
    "MonitorBank",
    "MonitorFleet",
    "BankRows",
    "RowEvents",
    "StepBlock",
    "MEAS_CHANNELS",
    "ALARM_KINDS",
    "COUNTERS",
    "EST_KEYS",
    "RES_KEYS",
    "HEALTH_KEYS",
]
