"""PHM prognostic metrics of Saxena et al. (2010, "Metrics for offline evaluation of
prognostic performance", IJPHM 1(1)), for one unit's RUL predictions against its true end of
life (docs/prognostics.md, "Metrics"). Times in any one unit (operating hours here).

For predictions r_i made at t_i (point estimate: the median RUL), true RUL r*_i = t_EOL - t_i,
first prediction at t_s and lambda-time t_lambda = t_s + lambda (t_EOL - t_s):

- alpha-lambda accuracy: at each lambda the latest prediction made at or before t_lambda is
  accurate when (1 - alpha) r* <= r <= (1 + alpha) r*;
- relative accuracy RA_lambda = 1 - |r* - r| / r* of that prediction;
- prognostic horizon PH = t_EOL - t_i of the first prediction from which every later one lies
  in the band r* +- alpha (t_EOL - t_s) (the band of Saxena et al. is alpha t_EOL; measured
  from the first prediction here so that it does not depend on where the clock started),
  reported as a share of t_EOL - t_s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["UnitScore", "score_unit", "LAMBDAS"]

LAMBDAS: tuple[float, ...] = (0.5, 0.6, 0.7, 0.8, 0.9)


@dataclass(frozen=True)
class UnitScore:
    """Metrics of one unit: per lambda (accurate?, RA), the prognostic horizon as a share of
    the unit's predicted life (0 when the last prediction is outside the band)."""

    lambdas: tuple[float, ...]
    accurate: tuple[bool, ...]
    relative_accuracy: tuple[float, ...]
    horizon: float
    horizon_frac: float


def _at_or_before(t: np.ndarray, t_q: float) -> int:
    """Index of the latest t <= t_q (-1 if none)."""
    return int(np.searchsorted(t, t_q + 1e-9 * max(1.0, abs(t_q)), side="right")) - 1


def score_unit(
    t_pred: Sequence[float],
    rul_pred: Sequence[float],
    t_eol: float,
    alpha: float = 0.2,
    lambdas: Sequence[float] = LAMBDAS,
) -> UnitScore:
    """Saxena et al.'s metrics (module docstring) for predictions ``rul_pred`` made at
    ``t_pred`` (ascending, all before ``t_eol``; inf for "no end of life predicted")."""
    t = np.asarray(t_pred, float)
    r = np.asarray(rul_pred, float)
    if len(t) == 0 or np.any(np.diff(t) < 0):
        raise ValueError("score_unit: need ascending prediction times")
    keep = t < t_eol
    t, r = t[keep], r[keep]
    if len(t) == 0:
        raise ValueError("score_unit: no prediction before the end of life")
    t_s = float(t[0])
    life = t_eol - t_s
    acc, ra = [], []
    for lam in lambdas:
        j = _at_or_before(t, t_s + lam * life)
        true = t_eol - t[j]
        ok = (1 - alpha) * true <= r[j] <= (1 + alpha) * true
        acc.append(bool(ok))
        ra.append(float(1.0 - abs(true - r[j]) / true) if math.isfinite(r[j]) else -math.inf)
    true_all = t_eol - t
    inside = np.abs(r - true_all) <= alpha * life
    # first index from which every later prediction is inside the band
    h = 0.0
    if inside[-1]:
        outside = np.flatnonzero(~inside)
        i0 = int(outside[-1]) + 1 if len(outside) else 0
        h = float(t_eol - t[i0])
    return UnitScore(tuple(lambdas), tuple(acc), tuple(ra), h, h / life if life > 0 else 0.0)
