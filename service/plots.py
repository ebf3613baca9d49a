"""PNG plots for the CLI (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = [
    "save_png",
    "plot_characteristic",
    "plot_simulation",
    "plot_comparison",
]

_SIGNALS = (
    ("x_j", 1e3, "x_J [mm]"),
    ("v_j", 1e3, "v_J [mm/s]"),
    ("p12", 1e-6, "P12 [MPa]"),
    ("x_s", 1e3, "x_S [mm]"),
)


def save_png(fig, path: str | Path, dpi: int) -> Path:
    """Write ``fig`` to ``path`` as PNG at ``dpi`` through a file this function opens, so
    that a failed write (disk full, ``/dev/full``) raises its OSError: given the path,
    matplotlib's PNG writer loses the error of the file's close and leaves a truncated file."""
    path = Path(path)
    with open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    return path


def _save(fig, path: str | Path, dpi: int = 100) -> Path:
    """Lay out ``fig``, write it to ``path`` as PNG at ``dpi`` and close it."""
    fig.tight_layout()
    try:
        return save_png(fig, path, dpi)
    finally:
        plt.close(fig)


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
