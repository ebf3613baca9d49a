"""Prognostics: condition indicators per operating period, degradation models with a fleet
prior, remaining useful life to a failure threshold derived from the actuator, PHM metrics
(docs/prognostics.md; the fleet simulator that validates them is ``service.replay.fleetsim``).
May import models, compat, log, store, monitor, wire and the loose utilities."""

from service.prognostics.indicators import BAD_COUNTERS, PeriodAccumulator, PeriodConfig

__all__ = ["PeriodAccumulator", "PeriodConfig", "BAD_COUNTERS"]
