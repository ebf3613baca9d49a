"""The daemon's status snapshot, made of its stages' ``status()``: counters, latency
percentiles, alarms, the log's health."""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from service.jsonutil import jsonable

__all__ = ["feed_failure", "percentiles", "service_state", "snapshot"]


def percentiles(values: Iterable[float], qs: Sequence[float] = (50, 99)) -> list[float | None]:
    """Percentiles (nearest rank: the smallest value with at least q % of the values at or
    below it, ``numpy.percentile(method="inverted_cdf")``), or None for an empty set."""
    v = np.fromiter(values, float)
    if v.size == 0:
        return [None for _ in qs]
    return [float(x) for x in np.percentile(v, list(qs), method="inverted_cdf")]


def feed_failure(foxglove: dict[str, Any] | None) -> str | None:
    """Why the live Foxglove feed does not accept connections (its guard's listener), or
    None when it does or there is none."""
    g = (foxglove or {}).get("guard") or {}
    state = g.get("listener", "ok")
    return None if state == "ok" else f"the Foxglove feed's listener: {state}"


def service_state(log_failure: str | None, foxglove: dict[str, Any] | None = None) -> str:
    """``"degraded"`` when the log failed (samples are no longer recorded) or the live feed's
    listener is down (``feed_failure``), else ``"ok"``; counted errors (bad input, a failed
    publish) do not degrade the service."""
    return "degraded" if log_failure or feed_failure(foxglove) else "ok"


def snapshot(
    service: dict[str, Any],
    intake: Any,
    monitor: Any,
    outputs: Any,
    member: Any = None,
    *,
    busy_s: float = 0.0,
    errors: int = 0,
) -> dict[str, Any]:
    """The daemon's status as plain JSON types, from the stages' own status: ``service``
    (station, shard, key_expr, started), ``intake.status(now)`` (queue, actuators,
    liveliness), ``monitor.status()`` and ``unit_status(key)`` (model, latency, each
    actuator's monitor counters and commissioning), ``outputs.status()`` and
    ``unit_status(name, row)`` (log, store, live feed, the unit's NIS in band), ``member`` (a ``GroupMember`` or None);
    ``busy_s`` and ``errors`` are the worker's."""
    now = time.monotonic()
    for attempt in range(5):  # the worker mutates counters meanwhile: retry a torn read
        try:
            ins = intake.status(now)
            acts = ins["actuators"]
            released: list[str] = []
            if member is not None:  # units it monitored, another member has now: listed only
                for k in list(acts):
                    if not member.group.owns_key(k):
                        a = acts.pop(k)
                        released.append(a["aircraft"] + "/" + a["actuator"])
            for k, a in acts.items():
                a.update(monitor.unit_status(k))
                name = a["aircraft"] + "/" + a["actuator"]
                a.update(outputs.unit_status(name, monitor.row_of(k)))
            mon = monitor.status()
            break
        except RuntimeError:  # "changed size during iteration"
            if attempt == 4:
                raise
            time.sleep(0.001)
    out = outputs.status()
    up = time.time() - service["started"]
    errors += mon["errors"] + out["errors"] + (0 if member is None else member.errors)
    return jsonable(
        {
            "state": service_state(out["log_failure"], out["foxglove"]),
            "log_failure": out["log_failure"],
            "feed_failure": feed_failure(out["foxglove"]),
            "station": service["station"],
            "shard": service["shard"],
            "key_expr": service["key_expr"],
            "model": mon["model"],
            "pid": os.getpid(),
            "uptime_s": up,
            "log": out["log"],
            "log_retention": out.get("log_retention"),
            "queue": ins["queue"],
            "queue_high": ins["queue_high"],
            "queue_size": ins["queue_size"],
            "samples": sum(a["samples"] for a in acts.values()),
            "dropped": sum(a["dropped"] for a in acts.values()) + ins["unknown"].get("dropped", 0),
            "bad": sum(a["bad_total"] for a in acts.values()),
            "missed": sum(a["missed"] for a in acts.values()) + ins["unknown"].get("missed", 0),
            "unknown": ins["unknown"],
            "unit_table": ins["unit_table"],
            "errors": errors,
            "latency_ms": mon["latency_ms"],
            "latency_hist": mon.get("latency_hist"),
            "age_ms": mon["age_ms"],
            "busy_fraction": busy_s / up if up > 0 else 0.0,
            "actuators": acts,
            "alarms": [
                {"actuator": a["aircraft"] + "/" + a["actuator"], **al}
                for a in acts.values()
                for al in a["alarms"]
            ],
            "store": out["store"],
            "alive_tokens": ins["alive_tokens"],
            "lost_tokens": ins["lost_tokens"],
            "silent": [a["aircraft"] + "/" + a["actuator"] for a in acts.values() if a["silent"]],
            "foxglove": out["foxglove"],
            "group": None if member is None else member.status(released),
        }
    )
