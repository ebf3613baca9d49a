"""Per-actuator health monitor: a UKF on the simplified (C-type) EHA model, no I/O.

``config`` (MonitorConfig, Baseline, noise and alarm settings), ``outputs`` (the output
row layout EST_KEYS / RES_KEYS / HEALTH_KEYS and the output types), ``bank`` (MonitorBank,
Monitor) and ``kernels`` (the compiled per-sample loops). See docs/estimation.md.
"""

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
