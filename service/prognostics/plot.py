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
    t_now = float(h.t_h[-1])
    hi = r["hi_h"] if r.get("hi_h") is not None else 2.0 * cfg.horizon_h
    t_end = t_now + max(hi * 1.15, cfg.horizon_h)
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
        if r["median_h"] is not None:
            ax.axvline(t_now + r["median_h"], color="C3", lw=1.0, label="RUL median")
        if r["lo_h"] is not None:
            ax.axvspan(t_now + r["lo_h"], t_now + (r["hi_h"] if r["hi_h"] is not None else t_end - t_now),
                       color="C3", alpha=0.12, label="RUL 90 % interval")  # fmt: skip
    ax.axhline(thr, color="C3", ls="--", lw=1.0, label=f"threshold {thr:.2f}")
    ax.axvline(t_now, color="grey", lw=0.8, ls=":")
    ax.set_xlim(0.0, t_end)
    ax.set_ylim(0.0, max(thr * 1.3, float(np.nanmax(y)) * 1.1 if len(y) else thr))
    ax.set_xlabel("operating hours")
    ax.set_ylabel("C_Lk / C_Lk,baseline")
    med = r.get("median_h")
    title = f"{h.actuator}: RUL " + (
        f"{med:.1f} h [{r['lo_h']:.1f}, {r['hi_h'] if r['hi_h'] is None else round(r['hi_h'], 1)}]"
        if med is not None and r["lo_h"] is not None
        else "beyond the posterior's reach"
    )
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
