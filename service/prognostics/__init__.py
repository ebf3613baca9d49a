"""Prognostics: condition indicators per operating period, degradation models with a fleet
prior, remaining useful life to a failure threshold derived from the actuator, PHM metrics
and a fleet simulator for validation (docs/prognostics.md)."""

from service.prognostics.indicators import BAD_COUNTERS, PeriodAccumulator, PeriodConfig

__all__ = ["PeriodAccumulator", "PeriodConfig", "BAD_COUNTERS"]
