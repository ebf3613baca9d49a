"""The usage totals of an actuator's summary row (store migration 5): kept up to date with
its periods, and read back for the fleet view (docs/store.md, docs/prognostics.md section 1,
"Usage")."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from service.store.records import Period

__all__ = ["USAGE_TOTALS", "add_usage", "usage_totals"]

# the summary's usage columns: over the periods that carry usage (NaN: stored before
# migration 5, or from rows without it), and over those with a load figure
USAGE_TOTALS: tuple[str, ...] = (
    "usage_periods",
    "usage_op_time_s",
    "usage_travel_m",
    "usage_reversals",
    "usage_load_op_time_s",
    "usage_load_travel_j",
)


def add_usage(s: dict[str, Any], fresh: Iterable[Period]) -> None:
    """Add the usage of the periods ``fresh`` to the summary row ``s`` (in place)."""
    for p in fresh:
        if math.isfinite(p.usage_travel_m):
            s["usage_periods"] = int(s["usage_periods"]) + 1
            s["usage_op_time_s"] = float(s["usage_op_time_s"]) + p.op_time_s
            s["usage_travel_m"] = float(s["usage_travel_m"]) + p.usage_travel_m
            s["usage_reversals"] = float(s["usage_reversals"]) + p.usage_reversals
        if math.isfinite(p.usage_load_travel_j):
            s["usage_load_op_time_s"] = float(s["usage_load_op_time_s"]) + p.op_time_s
            s["usage_load_travel_j"] = float(s["usage_load_travel_j"]) + p.usage_load_travel_j


def usage_totals(s: dict[str, Any]) -> dict[str, Any]:
    """The fleet view's usage of an actuator from its summary row ``s``: the totals and the
    figures per operating hour (None without periods that carry them)."""
    v = {c: float(s.get(c) or 0.0) for c in USAGE_TOTALS}
    op_h, load_h = v["usage_op_time_s"] / 3600.0, v["usage_load_op_time_s"] / 3600.0
    return {
        "periods": int(v["usage_periods"]),
        "op_time_s": v["usage_op_time_s"],
        "travel_m": v["usage_travel_m"],
        "reversals": v["usage_reversals"],
        "load_op_time_s": v["usage_load_op_time_s"],
        "load_travel_j": v["usage_load_travel_j"],
        "travel_m_per_h": v["usage_travel_m"] / op_h if op_h > 0 else None,
        "reversals_per_h": v["usage_reversals"] / op_h if op_h > 0 else None,
        "load_travel_j_per_h": v["usage_load_travel_j"] / load_h if load_h > 0 else None,
    }
