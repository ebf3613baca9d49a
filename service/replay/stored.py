"""A replay's store fields from what the store did with its log: one function for a replay
that writes its own store (``core._store_log``) and for a batch whose workers' logs are
written here (``cluster.write_logs``)."""

from __future__ import annotations

import logging
from typing import Any

__all__ = ["store_result"]

log = logging.getLogger("servowatch.replay")


def store_result(summary: Any, res: dict[str, dict[str, Any]]) -> None:
    """A replay's store fields from what ``HealthStore.ingest_log`` did with its log
    (``res``): new periods, flights, status per unit, and the store's notes as warnings
    (one function: a replay's and a cluster batch's, ``cluster.write_logs``)."""
    summary.periods_new = sum(r["periods_new"] for r in res.values())
    summary.flights = {a: r["flights"] for a, r in res.items() if r["flights"]}
    summary.stored = {a: r["status"] for a, r in res.items()}
    for a, r in res.items():
        for note in r.get("notes", ()):
            text = f"{summary.log}: {a}: {note}"
            summary.warnings.append(text)
            log.info(text)
