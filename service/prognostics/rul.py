"""Remaining useful life of each actuator from its period history (ISO 13374 "prognostic
assessment"): the C_Lk-ratio history against cumulative operating hours, fitted by
``degradation.fit_history`` under a fleet prior learned from the store, and the RUL to the
failure threshold (``threshold.leak_threshold``) as a median and a 90 % interval in operating
hours and in flights, with the probability of crossing within a planning horizon.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from service.prognostics.degradation import (
    FleetPrior,
    fit_history,
    learn_fleet_prior,
    sample_crossing,
)
from service.store.records import Period

__all__ = [
    "RulConfig",
    "History",
    "history_of",
    "rul_of_history",
    "fleet_prior",
    "compute_rul",
    "default_threshold_ratio",
]


@lru_cache(maxsize=1)
def default_threshold_ratio() -> float:
    """C_Lk,fail / C_Lk,baseline of ``threshold.leak_threshold()`` with the reference set."""
    from service.prognostics.threshold import leak_threshold

    return leak_threshold().ratio


@dataclass(frozen=True)
class RulConfig:
    """Threshold (C_Lk ratio; None = derived), planning horizon [operating hours], the
    probability of crossing within it that counts as a warning, Monte-Carlo draws, and the
    fewest observable periods a RUL is computed from."""

    threshold_ratio: float | None = None
    horizon_h: float = 50.0
    warn_p: float = 0.2
    n_samples: int = 4000
    min_periods: int = 4
    seed: int = 0

    def threshold(self) -> float:
        """The threshold ratio in use."""
        return (
            self.threshold_ratio if self.threshold_ratio is not None else default_threshold_ratio()
        )


@dataclass(frozen=True)
class History:
    """One unit's indicator history: cumulative operating hours at each period's end, the
    C_Lk ratio (NaN where unobservable) and the mean operating hours per flight."""

    actuator: str
    t_h: NDArray
    y: NDArray
    hours_per_flight: float | None

    def observed(self) -> tuple[NDArray, NDArray]:
        """(t_h, y) of the periods with an observable C_Lk."""
        ok = np.isfinite(self.y)
        return self.t_h[ok], self.y[ok]


def history_of(actuator: str, periods: Sequence[Period]) -> History:
    """The ``History`` of ``periods`` (sorted by start time here). Hours per flight: total
    operating hours of the periods with a flight number over the number of distinct flights."""
    ps = sorted(periods, key=lambda p: p.start_t)
    op = np.array([p.op_time_s for p in ps], float) / 3600.0
    t_h = np.cumsum(op)
    y = np.array([p.c_lk_ratio if p.observable_samples > 0 else math.nan for p in ps], float)
    flights = {p.flight for p in ps if p.flight is not None}
    hpf = None
    if flights:
        hours = sum(p.op_time_s for p in ps if p.flight is not None) / 3600.0
        hpf = hours / len(flights)
    return History(actuator, t_h, y, hpf)


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def rul_of_history(
    h: History, prior: FleetPrior | None = None, cfg: RulConfig | None = None
) -> dict:
    """RUL summary of one history (keys read by ``HealthStore.put_rul``/``fleet``): median_h,
    lo_h, hi_h (5 / 95 %), the same in flights, p_horizon, warning, the model probabilities
    and the threshold. None stands for "beyond any crossing the posterior predicts"."""
    cfg = cfg or RulConfig()
    thr = cfg.threshold()
    t, y = h.observed()
    out: dict = {
        "actuator": h.actuator,
        "threshold_ratio": thr,
        "horizon_h": cfg.horizon_h,
        "periods": int(len(t)),
        "t_now_h": float(h.t_h[-1]) if len(h.t_h) else 0.0,
        "hours_per_flight": h.hours_per_flight,
        "last_ratio": float(y[-1]) if len(y) else None,
    }
    if len(t) < cfg.min_periods:
        out.update(status="insufficient history", median_h=None, lo_h=None, hi_h=None,
                   median_flights=None, lo_flights=None, hi_flights=None, p_horizon=None,
                   warning=False)  # fmt: skip
        return out
    fit = fit_history(t, y, prior)
    rng = np.random.default_rng(cfg.seed)
    cross = sample_crossing(fit, thr, cfg.n_samples, rng)
    t_now = float(h.t_h[-1])  # periods after the last observable one still count as hours
    rul = np.maximum(cross - t_now, 0.0)
    lo, med, hi = np.quantile(rul, [0.05, 0.5, 0.95], method="inverted_cdf")
    p_h = float(np.mean(rul <= cfg.horizon_h))
    hpf = h.hours_per_flight
    out.update(
        status="ok",
        median_h=_finite(med),
        lo_h=_finite(lo),
        hi_h=_finite(hi),
        median_flights=_finite(med / hpf) if hpf else None,
        lo_flights=_finite(lo / hpf) if hpf else None,
        hi_flights=_finite(hi / hpf) if hpf else None,
        p_horizon=p_h,
        warning=bool(p_h >= cfg.warn_p),
        model=fit.best(),
        p_model={k: round(v, 4) for k, v in fit.p_model.items()},
        sigma=fit.sigma,
    )
    return out


def fleet_prior(histories: Iterable[History]) -> FleetPrior:
    """Fleet prior learned from every unit's observable history (``learn_fleet_prior``)."""
    return learn_fleet_prior([h.observed() for h in histories])


def compute_rul(
    store, actuator: str | None = None, cfg: RulConfig | None = None, save: bool = True
) -> tuple[list[dict], FleetPrior]:
    """RUL of every actuator in ``store`` (or just ``actuator``) under the fleet prior learned
    from all of them; each summary written with ``store.put_rul`` when ``save``."""
    names = store.actuators()
    hist = {a: history_of(a, store.periods(a)) for a in names}
    prior = fleet_prior(hist.values())
    out = []
    for a in [actuator] if actuator is not None else names:
        if a not in hist:
            raise KeyError(a)
        r = rul_of_history(hist[a], prior, cfg)
        if save:
            store.put_rul(a, r)
        out.append(r)
    return out, prior
