"""Comparison metrics between model runs (physics.md section 5)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["nrmse_pct"]


def nrmse_pct(y: ArrayLike, y_ref: ArrayLike) -> float:
    """NRMSE% = 100 RMS(y - y_ref) / (max y_ref - min y_ref) on a common grid (physics.md 5).

    Returns inf when the reference is constant and y differs from it, 0 when both agree.
    """
    y = np.asarray(y, float)
    y_ref = np.asarray(y_ref, float)
    if y.shape != y_ref.shape:
        raise ValueError(f"shape mismatch {y.shape} vs {y_ref.shape}")
    rms = float(np.sqrt(np.mean((y - y_ref) ** 2)))
    span = float(np.max(y_ref) - np.min(y_ref))
    if span == 0.0:
        return 0.0 if rms == 0.0 else float("inf")
    return 100.0 * rms / span
