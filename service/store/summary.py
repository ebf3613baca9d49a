"""An actuator's summary row along its life order (docs/store.md, "What a re-run does";
decision record 0034): the running totals, the latest period and the recent
window for the trend, where the unit stands on its life axis and its latest observable C_Lk
ratio. ``summarise`` adds periods that come after every stored one; ``reset`` then
``summarise`` over the whole history make it afresh (``HealthStore.rebuild_summary``)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any

from service.store.records import Period
from service.store.schema import RECENT_WINDOW
from service.store.usage import USAGE_TOTALS, add_usage

__all__ = ["trend_of", "summarise", "reset", "key_text"]


def _dumps(obj: Any) -> str:
    return json.dumps(obj, separators=(",", ":"), sort_keys=True)


def key_text(key: Sequence[Any]) -> str:
    """A life-order key as the summary keeps it (``last_key``)."""
    return json.dumps(list(key), separators=(",", ":"))


def trend_of(recent: Sequence[Sequence[float]]) -> dict[str, Any]:
    """Least-squares slope of the C_Lk ratio against operating time over ``recent``
    ``[[start_t, op_time_s, c_lk_ratio, observable_samples], ...]`` (in life order).

    Returns ``slope_per_h`` (ratio per operating hour), the number of periods used, the
    ratio change over the window and a label: ``rising``/``falling`` when the change is
    above 0.05 and twice its standard error, else ``stable`` (``unknown`` below 3 periods).
    """
    xs: list[float] = []
    ys: list[float] = []
    cum = 0.0
    for row in recent:
        op, ratio, obs = float(row[1]), row[2], row[3]
        cum += op
        if ratio is None or obs <= 0 or not math.isfinite(float(ratio)):
            continue
        xs.append(cum / 3600.0)
        ys.append(float(ratio))
    n = len(xs)
    out: dict[str, Any] = {"periods": n, "slope_per_h": None, "change": None, "label": "unknown"}
    if n < 3:
        return out
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    if sxx <= 0:
        return out
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx
    resid = sum((y - my - slope * (x - mx)) ** 2 for x, y in zip(xs, ys, strict=True))
    se = math.sqrt(resid / (n - 2) / sxx) if n > 2 else math.inf
    span = xs[-1] - xs[0]
    change = slope * span
    label = "stable"
    if abs(change) > 0.05 and abs(slope) > 2 * se:
        label = "rising" if slope > 0 else "falling"
    out.update(slope_per_h=slope, change=change, label=label)
    return out


def reset(s: dict[str, Any]) -> None:
    """Empty the period part of summary row ``s`` (alarms and baselines stay)."""
    for k in ("n_periods", "samples", "alarms", "bad_samples", "dropped", "n_flights",
              "live_periods"):  # fmt: skip
        s[k] = 0
    s["op_time_s"] = 0.0
    for k in USAGE_TOTALS:
        s[k] = 0
    for k in ("first_start_t", "last_start_t", "last_period", "last_key", "first_flight",
              "last_ratio"):  # fmt: skip
        s[k] = None
    s["recent"] = "[]"
    s["life_axis"] = "hours"
    s["trend_n"], s["trend_slope_per_h"], s["trend_change"] = 0, None, None
    s["trend_label"] = "unknown"


def summarise(s: dict[str, Any], fresh: Sequence[Period], keys: Sequence[Sequence[Any]]) -> None:
    """Add ``fresh`` (in life order, each after every period ``s`` holds; ``keys`` their
    life-order keys) to summary row ``s`` in place."""
    if not fresh:
        return
    empty = int(s["n_periods"] or 0) == 0
    s["n_periods"] = int(s["n_periods"] or 0) + len(fresh)
    for k in ("samples", "alarms", "bad_samples", "dropped"):
        s[k] = int(s[k] or 0) + sum(getattr(p, k) for p in fresh)
    s["live_periods"] = int(s.get("live_periods") or 0) + sum(
        p.source.startswith("live:") for p in fresh
    )
    op = float(s["op_time_s"] or 0.0)
    for p in fresh:  # one addition per period in life order: a row added to in steps sums
        op += p.op_time_s  # exactly as the row made afresh over the whole history
    s["op_time_s"] = op
    if empty:
        s["first_start_t"] = fresh[0].start_t
        s["first_flight"] = fresh[0].flight
        s["life_axis"] = "flights"
    last = json.loads(s["last_period"]) if s.get("last_period") else None
    prev = None if last is None else last.get("flight")
    n_fl = int(s.get("n_flights") or 0)
    for p in fresh:
        if p.flight is None:
            s["life_axis"] = "hours"
        elif p.flight != prev or n_fl == 0:
            n_fl += 1
        prev = p.flight
        if p.observable_samples > 0 and math.isfinite(p.c_lk_ratio):
            s["last_ratio"] = float(p.c_lk_ratio)
    s["n_flights"] = n_fl
    s["last_start_t"] = fresh[-1].start_t
    # as the store reads them back (a float field a float, an int field an int), whether
    # the periods were read from it or are being written
    s["last_period"] = _dumps(Period.from_dict(fresh[-1].to_dict()).to_dict())
    s["last_key"] = key_text(keys[-1])
    recent = json.loads(s["recent"] or "[]")
    recent.extend([float(p.start_t), float(p.op_time_s), float(p.c_lk_ratio),
                   int(p.observable_samples)] for p in fresh)  # fmt: skip
    recent = recent[-RECENT_WINDOW:]
    s["recent"] = _dumps(recent)
    add_usage(s, fresh)
    tr = trend_of(recent)
    s["trend_n"], s["trend_slope_per_h"] = tr["periods"], tr["slope_per_h"]
    s["trend_change"], s["trend_label"] = tr["change"], tr["label"]
