"""``servowatch fleet --png``: the most urgent units' C_Lk-ratio histories against the failure
threshold, each on its own life axis (flights, or operating hours), with the stored RUL
interval where there is one."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

__all__ = ["plot_trends"]


def plot_trends(store: Any, ranked: list[dict[str, Any]], path: str | Path) -> int:
    """Draw one panel per unit of ``ranked`` (``rank_fleet`` rows, most urgent first): its C_Lk
    ratio per period in the unit's life order (``history_of(store.life(...))``: the RUL's own
    series and axis, as the page's; the store's row order drew flights backwards), the threshold ratio
    the stored RUL used (else the default), and the RUL median with its 90 % interval ahead
    of the last period. Writes ``path`` (PNG); returns the number of units drawn."""
    import numpy as np

    from service.plots import _save, plt
    from service.prognostics.rul import default_threshold_ratio, history_of

    units = [r for r in ranked if store.has_actuator(r["actuator"])]
    hists = [history_of(r["actuator"], store.life(r["actuator"])) for r in units]
    n = max(1, len(units))
    cols = 2 if n > 1 else 1
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 3.0 * rows), squeeze=False)
    for ax in axes.flat[len(units) :]:
        ax.set_visible(False)
    for ax, r, h in zip(axes.flat, units, hists, strict=False):
        x, y = h.observed()
        rul = r.get("rul") or {}
        thr = rul.get("threshold_ratio") or default_threshold_ratio()
        unit = "flights" if h.axis == "flights" else "h"
        ax.plot(x, y, ".-", ms=3, lw=0.8, label="C_Lk / baseline, per period")
        ax.axhline(thr, color="tab:red", ls="--", lw=1, label=f"threshold {thr:.3g} x")
        iv = r.get("rul_interval") or {}
        now = h.t_now()
        med = iv.get("median")
        if med is not None and iv.get("unit") == ("flights" if unit == "flights" else "h"):
            lo, hi = iv.get("lo"), iv.get("hi")
            if lo is not None and hi is not None:
                ax.axvspan(now + lo, now + hi, color="tab:orange", alpha=0.15,
                           label="RUL 90 % interval")  # fmt: skip
            ax.axvline(now + med, color="tab:orange", lw=1, label=f"RUL median {med:.0f} {unit}")
        if len(y):
            top = max(float(np.nanmax(y)), thr) * 1.1
            ax.set_ylim(0, top)
        ax.set_title(f"#{r['rank']} {r['actuator']}", fontsize=10)
        ax.set_xlabel("flights" if unit == "flights" else "operating hours")
        ax.set_ylabel("C_Lk ratio")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    _save(fig, path)
    return len(units)
