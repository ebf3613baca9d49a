"""The daemon's status snapshot: counters, latency percentiles, alarms, the log's health."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

__all__ = ["percentiles", "service_state"]


def percentiles(values: Iterable[float], qs: Sequence[float] = (50, 99)) -> list[float | None]:
    """Percentiles (nearest rank: the smallest value with at least q % of the values at or
    below it, ``numpy.percentile(method="inverted_cdf")``), or None for an empty set."""
    v = np.fromiter(values, float)
    if v.size == 0:
        return [None for _ in qs]
    return [float(x) for x in np.percentile(v, list(qs), method="inverted_cdf")]


def service_state(log_failure: str | None) -> str:
    """``"degraded"`` when the log failed (samples are no longer recorded), else ``"ok"``;
    counted errors (bad input, a failed publish) do not degrade the service."""
    return "degraded" if log_failure else "ok"
