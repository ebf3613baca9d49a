"""The RUL fan plot: one unit's C_Lk-ratio history, the posterior band of its degradation
path and the RUL interval to the failure threshold (``servowatch rul --png``)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from service.prognostics.degradation import FleetPrior, fit_history, sample_paths  # noqa: E402
from service.prognostics.rul import History, RulConfig, rul_of_history  # noqa: E402

__all__ = ["plot_rul_fan"]


def plot_rul_fan(h: History, prior: FleetPrior | None, cfg: RulConfig, path: str | Path) -> Path:
    """History points, the 5-95 % and 25-75 % bands of the posterior paths, the threshold
    and the RUL median with its 90 % interval; written to ``path`` (PNG)."""
    t, y = h.observed()
    r = rul_of_history(h, prior, cfg)
    thr = cfg.threshold()
    t_now = h.t_now()
    u = "flights" if h.axis == "flights" else "h"
    hz = cfg.horizon(h.axis)
    hi = r[f"hi_{u}"] if r.get(f"hi_{u}") is not None else 2.0 * hz
    t_end = t_now + max(hi * 1.15, hz)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax.plot(t, y, "o", ms=3, color="k", label="C_Lk ratio per period")
    if r["status"] == "ok":
        fit = fit_history(t, y, prior)
        tg = np.linspace(0.0, t_end, 300)
        paths = sample_paths(fit, tg, 600, np.random.default_rng(cfg.seed))
        q = np.quantile(paths, [0.05, 0.25, 0.5, 0.75, 0.95], axis=0)
        ax.fill_between(tg, q[0], q[4], color="C0", alpha=0.2, label="5-95 % path")
        ax.fill_between(tg, q[1], q[3], color="C0", alpha=0.35, label="25-75 % path")
        ax.plot(tg, q[2], color="C0", lw=1.2, label=f"median path ({r['model']} most probable)")
        if r[f"median_{u}"] is not None:
            ax.axvline(t_now + r[f"median_{u}"], color="C3", lw=1.0, label="RUL median")
        if r[f"lo_{u}"] is not None:
            ax.axvspan(t_now + r[f"lo_{u}"], t_now + (r[f"hi_{u}"] if r[f"hi_{u}"] is not None else t_end - t_now),
                       color="C3", alpha=0.12, label="RUL 90 % interval")  # fmt: skip
    ax.axhline(thr, color="C3", ls="--", lw=1.0, label=f"threshold {thr:.2f}")
    ax.axvline(t_now, color="grey", lw=0.8, ls=":")
    ax.set_xlim(0.0, t_end)
    ax.set_ylim(0.0, max(thr * 1.3, float(np.nanmax(y)) * 1.1 if len(y) else thr))
    ax.set_xlabel("flights" if u == "flights" else "operating hours")
    ax.set_ylabel("C_Lk / C_Lk,baseline")
    med, lo, hi = r.get(f"median_{u}"), r.get(f"lo_{u}"), r.get(f"hi_{u}")
    title = f"{h.actuator}: RUL " + (
        f"{med:.1f} {u} [{lo:.1f}, {hi if hi is None else round(hi, 1)}]"
        if med is not None and lo is not None
        else "beyond the posterior's reach"
    )
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    from service.plots import save_png

    try:
        return save_png(fig, path, 110)
    finally:
        plt.close(fig)
