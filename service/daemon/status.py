"""The daemon's status snapshot: counters, latency percentiles, alarms, the log's health."""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from service.jsonutil import jsonable

if TYPE_CHECKING:
    from service.daemon.core import Daemon

__all__ = ["percentiles", "service_state", "snapshot"]


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


def snapshot(d: Daemon) -> dict[str, Any]:
    """The daemon's status as plain JSON types: the monitor's process model, actuators,
    counters, latency and age percentiles, alarms, liveliness, silent actuators, the log's
    failure and the state."""
    now = time.monotonic()
    for attempt in range(5):  # the worker mutates counters meanwhile: retry a torn read
        try:
            with d._lock:
                acts = {k: st.snapshot(now) for k, st in list(d.actuators.items())}
            released: list[str] = []
            if d.group is not None:  # units it monitored, another member has now: listed only
                for k in list(acts):
                    if not d.group.owns_key(k):
                        a = acts.pop(k)
                        released.append(a["aircraft"] + "/" + a["actuator"])
            for k, a in acts.items():
                a["monitor"] = d.monitor_counters(k)
                a.update(d.prognostics_of(k))
            lat, age = list(d.latency), list(d.age)
            break
        except RuntimeError:  # "changed size during iteration"
            if attempt == 4:
                raise
            time.sleep(0.001)
    p50, p99 = percentiles(lat)
    a50, a99 = percentiles(age)
    up = time.time() - d.started
    return jsonable(
        {
            "state": service_state(d.log_failure),
            "log_failure": d.log_failure,
            "station": d.station,
            "shard": d.shard,
            "key_expr": d.key_expr,
            "model": d.bank.config.model,  # the model the monitors actually run
            "pid": os.getpid(),
            "uptime_s": up,
            "log": [str(p) for p in d.logger.paths],
            "queue": d.queued,
            "queue_high": d.queue_high,
            "queue_size": d.queue_size,
            "samples": sum(a["samples"] for a in acts.values()),
            "dropped": sum(a["dropped"] for a in acts.values()) + d.unknown.get("dropped", 0),
            "bad": sum(a["bad_total"] for a in acts.values()),
            "missed": sum(a["missed"] for a in acts.values()) + d.unknown.get("missed", 0),
            "unknown": dict(d.unknown),
            "errors": d.errors,
            "latency_ms": {
                "p50": None if p50 is None else 1e3 * p50,
                "p99": None if p99 is None else 1e3 * p99,
                "n": len(d.latency),
            },
            "age_ms": {
                "p50": None if a50 is None else 1e3 * a50,
                "p99": None if a99 is None else 1e3 * a99,
            },
            "busy_fraction": d.busy_s / up if up > 0 else 0.0,
            "actuators": acts,
            "alarms": [
                {"actuator": a["aircraft"] + "/" + a["actuator"], **al}
                for a in acts.values()
                for al in a["alarms"]
            ],
            "store": d.store_status() if hasattr(d, "store_status") else None,
            "alive_tokens": sorted(k for k, v in d.alive_tokens.items() if v),
            "lost_tokens": sorted(k for k, v in d.alive_tokens.items() if not v),
            "silent": [a["aircraft"] + "/" + a["actuator"] for a in acts.values() if a["silent"]],
            "foxglove": None if getattr(d, "foxglove", None) is None else d.foxglove.status(),
            "group": None if d.group is None else {**d.group.status(), "released_units": released},
        }
    )
