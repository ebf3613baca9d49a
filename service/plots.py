"""PNG plots for the CLI (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = [
    "plot_characteristic",
    "plot_simulation",
    "plot_comparison",
    "plot_member",
    "plot_readings",
    "plot_suite",
    "plot_bound",
]

_SIGNALS = (
    ("x_j", 1e3, "x_J [mm]"),
    ("v_j", 1e3, "v_J [mm/s]"),
    ("p12", 1e-6, "P12 [MPa]"),
    ("x_s", 1e3, "x_S [mm]"),
)


def _save(fig, path: str | Path, dpi: int = 100) -> Path:
    """Lay out ``fig``, write it to ``path`` as PNG at ``dpi`` and close it."""
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def _axes(ax, xlabel: str, ylabel: str, legend: str) -> None:
    """Axis labels, a light grid and a small legend at ``legend``."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc=legend)


def plot_characteristic(
    x_s: np.ndarray,
    q_j: Sequence[float],
    p12: np.ndarray,
    model: str,
    p_sr: float,
    path: str | Path,
) -> Path:
    """P12-x_S curves parameterised by Q_J (seed Figs. 2, 8-11)."""
    fig, ax = plt.subplots(figsize=(7, 5))
    for k, q in enumerate(q_j):
        ax.plot(np.asarray(x_s) * 1e3, p12[k] * 1e-6, label=f"Q_J = {q * 6e4:+.2f} L/min")
    ax.axhline(p_sr * 1e-6, color="k", lw=0.6, ls="--")
    ax.axhline(-p_sr * 1e-6, color="k", lw=0.6, ls="--")
    ax.set_xlabel("x_S [mm]")
    ax.set_ylabel("P12 [MPa]")
    ax.set_title(f"P12-x_S characteristic, model {model}, P_SR = {p_sr * 1e-6:.1f} MPa")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path, dpi=110)


def plot_simulation(res, path: str | Path, title: str = "") -> Path:
    """Time histories of one bench run: command/position, speed, pressures, spool, inputs."""
    fig, axes = plt.subplots(5, 1, figsize=(9, 11), sharex=True)
    t = res.t
    axes[0].plot(t, res.x_cmd * 1e3, "k--", lw=0.8, label="x_cmd")
    axes[0].plot(t, res.x_j * 1e3, label="x_J")
    axes[0].set_ylabel("position [mm]")
    axes[1].plot(t, res.v_j * 1e3)
    axes[1].set_ylabel("v_J [mm/s]")
    axes[2].plot(t, res.p12 * 1e-6, label="P12")
    axes[2].plot(t, res.p_sr * 1e-6, "k--", lw=0.8, label="+-P_SR")
    axes[2].plot(t, -res.p_sr * 1e-6, "k--", lw=0.8)
    axes[2].set_ylabel("pressure [MPa]")
    axes[3].plot(t, res.x_s * 1e3)
    axes[3].set_ylabel("x_S [mm]")
    axes[4].plot(t, res.f_r * 1e-3)
    axes[4].set_ylabel("F_R [kN]")
    axes[4].set_xlabel("t [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[2].legend(fontsize=8)
    fig.suptitle(title or f"EHA bench, valve {res.valve}")
    return _save(fig, path)


def plot_comparison(results: Mapping[str, object], path: str | Path, title: str = "") -> Path:
    """The same scenario through HF and each simplified model, side by side (seed Figs. 13-17)."""
    fig, axes = plt.subplots(len(_SIGNALS), 1, figsize=(9, 10), sharex=True)
    for name, res in results.items():
        style = {"lw": 1.0}
        if name == "HF":
            style = {"color": "k", "lw": 1.6}
        elif name == "WH":
            style = {"color": "tab:red", "lw": 1.1, "ls": "--"}
        for ax, (sig, scale, label) in zip(axes, _SIGNALS, strict=True):
            ax.plot(res.t, getattr(res, sig) * scale, label=name, **style)
            ax.set_ylabel(label)
    ref = results.get("HF")
    if ref is not None:
        axes[2].plot(ref.t, ref.p_sr * 1e-6, "k:", lw=0.8, label="+-P_SR")
        axes[2].plot(ref.t, -ref.p_sr * 1e-6, "k:", lw=0.8)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8, ncol=3)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title or "HF against the simplified models")
    return _save(fig, path)


def plot_member(
    t: np.ndarray,
    est: Mapping[str, np.ndarray],
    truth: Mapping[str, np.ndarray],
    gates: Mapping[str, float],
    alarms: Sequence[tuple[float, str, str]],
    path: str | Path,
    title: str = "",
) -> Path:
    """One monitor run against its truth (docs/estimation.md, "WH on the duty-cycle suite"):
    C_Lk / nominal with its 1-sigma band and the leak alarm level, P_SR [MPa], |P12| [MPa]
    and |v_J| [mm/s] of the truth with the observability gates (``gates``: p12 [Pa], v_j
    [m/s], leak_raise [x nominal]); alarms as (t, kind, state) lines."""
    c0 = float(truth["c_lk"][0])
    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    c, sd = est["c_lk"] / c0, est["c_lk_sigma"] / c0
    ax[0].fill_between(t, c - sd, c + sd, color="C0", alpha=0.25, lw=0, label="1 sigma")
    ax[0].plot(t, c, "C0", lw=0.8, label="estimate")
    ax[0].plot(t, truth["c_lk"] / c0, "k", lw=1.2, label="truth")
    ax[0].axhline(gates["leak_raise"], color="C3", ls="--", lw=0.8, label="alarm level")
    ax[0].set_ylabel("C_Lk / nominal")
    ax[1].plot(t, est["p_sr"] * 1e-6, "C0", lw=0.8, label="estimate")
    ax[1].plot(t, truth["p_sr"] * 1e-6, "k", lw=1.2, label="truth")
    ax[1].set_ylabel("P_SR [MPa]")
    ax[2].plot(t, np.abs(truth["p12"]) * 1e-6, "C2", lw=0.8)
    ax[2].axhline(gates["p12"] * 1e-6, color="C3", ls="--", lw=0.8, label="C_Lk gate")
    ax[2].set_ylabel("|P12| [MPa]")
    ax[3].plot(t, np.abs(truth["v_j"]) * 1e3, "C2", lw=0.8)
    ax[3].axhline(gates["v_j"] * 1e3, color="C3", ls="--", lw=0.8, label="C_Lk gate")
    ax[3].set_ylabel("|v_J| [mm/s]")
    ax[3].set_xlabel("t [s]")
    for tt, kind, state in alarms:
        for a in ax[:2]:
            a.axvline(tt, color="C3" if state == "raised" else "C1", lw=0.6, alpha=0.7)
        ax[0].text(tt, ax[0].get_ylim()[1], f" {kind} {state}", fontsize=7, va="top")
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend(fontsize=7, loc="upper left")
    fig.suptitle(title)
    return _save(fig, path)


def plot_readings(
    rows: Sequence[Mapping[str, object]], flow: float, path: str | Path, title: str = ""
) -> Path:
    """Settled C_Lk reading errors of suite members (docs/estimation.md, "Where the settled
    C_Lk reading errs"): err [nominal C_Lk] against the last second's |P12| [MPa], one dot a
    member, coloured by the supply at the end (share of rated), with +-``flow`` / |P12|, the
    error a constant flow error of ``flow`` [nominal x MPa] gives."""
    p12 = np.abs([float(r["p12_mpa"]) for r in rows])
    err = np.array([float(r["err"]) for r in rows])
    sup = np.array([float(r["supply"]) for r in rows])
    fig, ax = plt.subplots(figsize=(8, 5))
    sc = ax.scatter(p12, err, c=sup, cmap="viridis", vmin=0.5, vmax=1.0, s=14)
    fig.colorbar(sc, ax=ax, label="supply at the end / rated")
    x = np.linspace(0.5, max(float(p12.max()), 1.0), 200)
    for sign in (1.0, -1.0):
        ax.plot(x, sign * flow / x, "C3", ls="--", lw=0.8,
                label=f"+-{flow:.2f} / |P12| (a constant flow error)" if sign > 0 else None)  # fmt: skip
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_ylim(-0.8, 0.8)
    _axes(
        ax, "|P12| over the last second [MPa]", "settled C_Lk error [nominal C_Lk]", "upper right"
    )
    ax.set_title(title)
    return _save(fig, path)


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
    """The duty-cycle suite's members against issue 10's targets (bench/estimation_suite.py
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
    """The monitor's suite figures beside what its sensors carry (bench/suite_bound.py rows
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
