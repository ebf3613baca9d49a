"""PNG plots of the evaluation suite and its bound (matplotlib, Agg backend)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from service.plots import _axes, _save, plt

__all__ = ["plot_suite", "plot_bound"]


def _increase_errors(ax, x: np.ndarray, inc: np.ndarray, target_pct: float, label: str) -> float:
    """The +-``target_pct`` band and the C_Lk increase errors ``inc`` [%] against ``x``: dots
    labelled ``label`` (red, "... missing", past the target), those past 5 x the target on
    that edge as triangles. Returns the edge."""
    lim = 5.0 * target_pct
    ax.axhspan(-target_pct, target_pct, color="C2", alpha=0.15, label=f"target +-{target_pct:g} %")
    miss = np.abs(inc) > target_pct
    for sel, colour, name in ((~miss, "C0", label), (miss, "C3", "... missing")):
        v = inc[sel]
        out = np.abs(v) > lim
        ax.scatter(x[sel][~out], v[~out], s=14, color=colour, label=name)
        ax.scatter(x[sel][out], np.sign(v[out]) * lim, s=30, marker="^", color=colour)
    return lim


def plot_suite(
    rows: Sequence[Mapping[str, object]],
    path: str | Path,
    title: str = "",
    inc_target_pct: float = 10.0,
    delay_target_s: float = 1.0,
) -> Path:
    """The duty-cycle suite's members against issue 10's targets (evaluation/suite.py
    rows): left, the C_Lk increase error [%] of the filter's last second (dots, red where it
    misses) and of the health indicator (rings; none where it abstains) against the true
    leak ratio, with the +-``inc_target_pct`` band; right, the leak alarm's delay after the
    true crossing [s] against the first observable window (``obs``) [s], with the
    ``delay_target_s`` lines and delay = obs (no alarm can come before that window).
    Values past the axes are drawn on their edge as triangles."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    leaks = [r for r in rows if r.get("inc%") is not None]
    x = np.array([float(r["leak_ratio"]) for r in leaks])
    inc = np.array([float(r["inc%"]) for r in leaks])
    lim = _increase_errors(ax1, x, inc, inc_target_pct, "filter, last second")
    ind = [(float(r["leak_ratio"]), float(r["ind%"])) for r in leaks if r.get("ind%") is not None]
    if ind:
        xi, vi = np.array(ind).T
        ax1.scatter(xi, np.clip(vi, -lim, lim), s=40, facecolors="none", edgecolors="k",
                    lw=0.7, label=f"health indicator ({len(ind)} of {len(leaks)} read)")  # fmt: skip
    ax1.set_ylim(-lim * 1.05, lim * 1.05)
    _axes(ax1, "true leak at the end / nominal C_Lk", "C_Lk increase error [%]", "upper right")
    alarms = [r for r in rows if r.get("delay") is not None and r.get("obs") is not None]
    d_max = 4.0 * delay_target_s
    ax2.axhline(delay_target_s, color="C3", ls="--", lw=0.8, label="target")
    ax2.axvline(delay_target_s, color="C1", ls=":", lw=0.8)
    ax2.plot([0.0, d_max], [0.0, d_max], "k", lw=0.6, label="delay = first window")
    for name, colour in (("within", "C0"), ("late", "C3"), ("late, no window in time", "C1")):
        pts = []
        for r in alarms:
            d, o = float(r["delay"]), float(r["obs"])
            kind = ("within" if d <= delay_target_s
                    else "late, no window in time" if o > delay_target_s else "late")  # fmt: skip
            if kind == name:
                pts.append((min(o, d_max), min(d, d_max), d > d_max or o > d_max))
        if pts:
            o, d, clipped = (np.array(v) for v in zip(*pts, strict=True))
            ax2.scatter(o[~clipped], d[~clipped], s=16, color=colour, label=f"{name} ({len(pts)})")
            ax2.scatter(o[clipped], d[clipped], s=30, marker="^", color=colour)
    ax2.set_xlim(0.0, d_max * 1.05)
    ax2.set_ylim(min(-0.3, ax2.get_ylim()[0]), d_max * 1.05)
    _axes(ax2, "first observable window after the crossing [s]",
          "leak alarm after the crossing [s]", "upper left")  # fmt: skip
    fig.suptitle(title)
    return _save(fig, path)


def plot_bound(
    rows: Sequence[Mapping[str, object]],
    path: str | Path,
    title: str = "",
    inc_target_pct: float = 10.0,
    delay_target_s: float = 1.0,
) -> Path:
    """The monitor's suite figures beside what its sensors carry (evaluation/bound.py rows
    with the monitor's ``inc%`` and ``delay``): left, the increase error [%] of the filter
    (dots, red where it misses the target) against the leak ratio, over the band of +-3
    Cramer-Rao sigma an ideal estimator would keep to with the plant unknown (grey bars;
    ``sigma%``, else ``sigma_known%``); right, the alarm's delay against the ideal test's
    (``t_ideal``) [s]. Values past the axes are drawn on their edge as triangles."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    leaks = [r for r in rows if r.get("d_inc") is not None]
    bars = [
        (float(r["leak_ratio"]), 3.0 * float(r.get("sigma%") or r.get("sigma_known%") or 0.0))
        for r in leaks
    ]
    if bars:
        xb, hb = np.array(bars).T
        ax1.vlines(xb, -hb, hb, color="0.4", lw=3, label="ideal estimator, +-3 sigma")
    read = [r for r in leaks if r.get("inc%") is not None]
    x = np.array([float(r["leak_ratio"]) for r in read])
    inc = np.array([float(r["inc%"]) for r in read])
    lim = _increase_errors(ax1, x, inc, inc_target_pct, "monitor")
    ax1.set_ylim(-lim * 1.05, lim * 1.05)
    _axes(ax1, "true leak ratio [x nominal]", "C_Lk increase error [% of the true increase]",
          "upper left")  # fmt: skip
    alarms = [r for r in leaks if r.get("t_ideal") is not None and r.get("delay") is not None]
    d_max = 4.0 * delay_target_s
    xi = np.array([float(r["t_ideal"]) for r in alarms])
    dl = np.array([float(r["delay"]) for r in alarms])
    late = dl > delay_target_s
    for sel, colour, label in ((~late, "C0", "within"), (late, "C3", "late")):
        v = dl[sel]
        out = v > d_max
        ax2.scatter(xi[sel][~out], v[~out], s=14, color=colour, label=f"{label} ({sel.sum()})")
        ax2.scatter(xi[sel][out], np.full(out.sum(), d_max), s=30, marker="^", color=colour)
    ax2.axhline(delay_target_s, color="C2", ls="--", lw=1, label=f"target {delay_target_s:g} s")
    ax2.axvline(delay_target_s, color="C2", ls=":", lw=1)
    ax2.set_ylim(top=d_max * 1.05)
    _axes(ax2, "ideal test's delay after the crossing [s]", "monitor's alarm delay [s]",
          "upper left")  # fmt: skip
    if title:
        fig.suptitle(title)
    return _save(fig, path)
