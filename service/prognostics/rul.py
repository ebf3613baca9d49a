"""Remaining useful life of each actuator from its period history (ISO 13374 "prognostic
assessment"): the C_Lk-ratio history against its life axis (flights when every period has
a flight number, else cumulative operating hours: ``History``), fitted by
``degradation.fit_history`` under a fleet prior learned from the store, and the RUL to the
failure threshold (``threshold.leak_threshold``) as a median and a 90 % interval in flights,
calendar days and operating hours as far as the history supports them, with the probability
of crossing within a planning horizon.
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
    """Threshold (C_Lk ratio; None = derived), planning horizons (in flights, used when the
    history counts flights; in operating hours otherwise), the probability of crossing within
    it that counts as a warning, Monte-Carlo draws, and the fewest observable periods a RUL is
    computed from."""

    threshold_ratio: float | None = None
    horizon_h: float = 50.0
    horizon_flights: float = 20.0
    warn_p: float = 0.2
    n_samples: int = 4000
    min_periods: int = 8
    seed: int = 0

    def threshold(self) -> float:
        """The threshold ratio in use."""
        return (
            self.threshold_ratio if self.threshold_ratio is not None else default_threshold_ratio()
        )

    def horizon(self, axis: str) -> float:
        """The planning horizon in units of ``axis`` (``flights`` or ``hours``)."""
        return self.horizon_flights if axis == "flights" else self.horizon_h


@dataclass(frozen=True)
class History:
    """One unit's indicator history, per period in life order (flight, then sample time):
    cumulative operating hours at its end ``t_h``, the C_Lk ratio ``y`` (NaN where
    unobservable), its flight number (NaN: none) and calendar start (Unix s, NaN: none).

    The life axis is ``flights`` when every period has a flight number (the flights flown
    since the history's first flight, counting that one: flight - first + 1), else operating
    ``hours``. Conversions: operating hours per flight and calendar days per flight (over the
    flights with a calendar time, missed days included), when the history has them."""

    actuator: str
    t_h: NDArray
    y: NDArray
    hours_per_flight: float | None
    flight: NDArray | None = None
    start_unix: NDArray | None = None

    @property
    def axis(self) -> str:
        """``flights`` or ``hours`` (class docstring)."""
        f = self.flight
        return "flights" if f is not None and len(f) and np.isfinite(f).all() else "hours"

    def life(self) -> NDArray:
        """Each period's position on the life axis."""
        if self.axis == "flights":
            assert self.flight is not None
            return self.flight - self.flight[0] + 1.0
        return self.t_h

    def observed(self) -> tuple[NDArray, NDArray]:
        """(life, y) of the periods with an observable C_Lk."""
        ok = np.isfinite(self.y)
        return self.life()[ok], self.y[ok]

    def t_now(self) -> float:
        """Where the history ends on its life axis."""
        x = self.life()
        return float(x[-1]) if len(x) else 0.0

    def days_per_flight(self) -> float | None:
        """Calendar days per flight (class docstring), None without two dated flights."""
        if self.flight is None or self.start_unix is None:
            return None
        ok = np.isfinite(self.flight) & np.isfinite(self.start_unix)
        if ok.sum() < 2:
            return None
        f, u = self.flight[ok], self.start_unix[ok]
        df = float(f.max() - f.min())
        du = float(u[np.argmax(f)] - u[np.argmin(f)])
        return du / 86400.0 / df if df > 0 and du > 0 else None

    def head(self, k: int) -> History:
        """The history of the first ``k`` periods."""
        cut = lambda a: None if a is None else a[:k]  # noqa: E731
        return History(self.actuator, self.t_h[:k], self.y[:k], self.hours_per_flight,
                       cut(self.flight), cut(self.start_unix))  # fmt: skip


def _life_key(p: Period) -> tuple:
    return (p.flight if p.flight is not None else -1, p.start_t)


def history_of(actuator: str, periods: Sequence[Period]) -> History:
    """The ``History`` of ``periods`` (put in life order here: flight, then start time). Hours
    per flight: total operating hours of the periods with a flight number over the number of
    distinct flights."""
    ps = sorted(periods, key=_life_key)
    op = np.array([p.op_time_s for p in ps], float) / 3600.0
    t_h = np.cumsum(op)
    y = np.array([p.c_lk_ratio if p.observable_samples > 0 else math.nan for p in ps], float)
    flights = {p.flight for p in ps if p.flight is not None}
    hpf = None
    if flights:
        hours = sum(p.op_time_s for p in ps if p.flight is not None) / 3600.0
        hpf = hours / len(flights)
    fl = np.array([math.nan if p.flight is None else p.flight for p in ps], float)
    su = np.array([math.nan if p.start_unix is None else p.start_unix for p in ps], float)
    return History(actuator, t_h, y, hpf, fl, su)


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


_NONE = {f"{q}_{u}": None for q in ("median", "lo", "hi") for u in ("flights", "h", "days")}


def rul_of_history(
    h: History, prior: FleetPrior | None = None, cfg: RulConfig | None = None
) -> dict:
    """RUL summary of one history (keys read by ``HealthStore.put_rul``/``fleet``): on the
    history's life axis (``axis``: flights or hours) the median and the 5 / 95 % quantiles,
    converted to ``*_flights``, ``*_h`` (operating hours) and ``*_days`` (calendar) where the
    history has the conversion, ``p_horizon`` (crossing within ``horizon`` on that axis),
    warning, the model probabilities and the threshold. None stands for "beyond any crossing
    the posterior predicts" or "not known for this history"."""
    cfg = cfg or RulConfig()
    thr = cfg.threshold()
    t, y = h.observed()
    axis = h.axis
    hpf = h.hours_per_flight
    dpf = h.days_per_flight()
    out: dict = {
        "actuator": h.actuator,
        "threshold_ratio": thr,
        "axis": axis,
        "horizon": cfg.horizon(axis),
        "horizon_h": cfg.horizon_h,
        "periods": int(len(t)),
        "t_now": h.t_now(),
        "t_now_h": float(h.t_h[-1]) if len(h.t_h) else 0.0,
        "hours_per_flight": hpf,
        "days_per_flight": dpf,
        "last_ratio": float(y[-1]) if len(y) else None,
    }
    if len(t) < cfg.min_periods:
        out.update(status="insufficient history", p_horizon=None, warning=False, **_NONE)
        return out
    fit = fit_history(t, y, prior)
    rng = np.random.default_rng(cfg.seed)
    kappa = prior.kappa if prior is not None else 1.0
    cross = sample_crossing(fit, thr, cfg.n_samples, rng)
    rul = np.maximum(cross - h.t_now(), 0.0)  # periods after the last observable one count
    fin = np.isfinite(rul) & (rul > 0)
    med_all = float(np.quantile(rul, 0.5, method="inverted_cdf"))
    # the hindcast measured the fleet's errors on predictions within a history span ahead
    reach = prior.t_scale if prior is not None and prior.t_scale else math.inf
    if kappa > 1.0 and fin.sum() > 1 and med_all <= reach:
        # the fleet's hindcast widening, about the median in log space (stays > 0), where
        # the hindcast measured it: a median RUL within the fleet's typical history span.
        # Beyond it, or with a median of "never", the posterior's spread stands (widening a
        # far tail would pull crossings hundreds of flights ahead into the horizon)
        lm = float(np.median(np.log(rul[fin])))
        rul = rul.copy()
        rul[fin] = np.exp(lm + kappa * (np.log(rul[fin]) - lm))
    q = dict(zip(("lo", "median", "hi"),
                 np.quantile(rul, [0.05, 0.5, 0.95], method="inverted_cdf"), strict=True))  # fmt: skip
    p_h = float(np.mean(rul <= cfg.horizon(axis)))
    if axis == "flights":
        per = {"flights": 1.0, "h": hpf, "days": dpf}
    else:
        per = {"flights": 1.0 / hpf if hpf else None, "h": 1.0, "days": None}
    for k, v in q.items():
        for u, f in per.items():
            out[f"{k}_{u}"] = _finite(v * f) if f else None
    out.update(
        status="ok",
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
