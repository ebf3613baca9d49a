"""Remaining useful life of each actuator from its period history (ISO 13374 "prognostic
assessment"): the C_Lk-ratio history against its life axis (flights when every period has
a flight number, else cumulative operating hours: ``History``), fitted by
``degradation.fit_history`` under a fleet prior learned from the store, and the RUL to the
failure threshold (``threshold.leak_threshold``) as a median and a 90 % interval in flights,
calendar days and operating hours as far as the history supports them, with the probability
of crossing within a planning horizon.

Usage axes (``USAGE_AXES``): where every flight of a history has the monitor's usage figures,
the wear may be read against the unit's cumulative usage instead of its flights: each
flight counts its usage per operating second (its intensity: a log may hold a few seconds
of a flight) over the fleet's median (``FleetPrior.usage_ref``); an axis of ``MEAN_AXES``
counts a ratio of two figures instead (the mean squared load). Which axis explains the wear
is learned from the fleet (``fleet_prior``: each unit's best axis by the marginal likelihood
of its history, counted with Dirichlet(1) smoothing into ``FleetPrior.p_axis``), and each
unit's RUL averages over the axes, weighted by that prior times its own evidence on each. A
crossing on a usage axis becomes flights by the unit's own usage ahead: its per-flight usage
resampled (bootstrap), so its spread is part of the interval.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from service.prognostics.degradation import (
    FleetPrior,
    fit_history,
    learn_fleet_prior,
    robust_trend_prior,
    sample_crossing,
)
from service.store.records import Period

__all__ = [
    "USAGE_AXES",
    "MEAN_AXES",
    "RulConfig",
    "History",
    "history_of",
    "rul_of_history",
    "fleet_prior",
    "compute_rul",
    "default_threshold_ratio",
]


USAGE_AXES: dict[str, str] = {
    "travel": "usage_travel_m",
    "load_travel": "usage_load_travel_j",
    "load2_travel": "usage_load2_travel_n2m",
}
"""Usage life axes and the stored period field each cumulates (per operating second)."""

MEAN_AXES: dict[str, tuple[str, str]] = {"load2": ("load2_travel", "travel")}
"""Usage axes of a load level rather than a motion: each flight counts the ratio of two
``USAGE_AXES`` figures over its periods, here the F_J^2-weighted travel over the travel, the
flight's mean squared load along its travel [N^2] (wear per operating second that goes with
the load squared whatever the jack's motion: the command amplitude cancels)."""


@lru_cache(maxsize=1)
def default_threshold_ratio() -> float:
    """C_Lk,fail / C_Lk,baseline of ``threshold.leak_threshold()`` with the reference set."""
    from service.prognostics.threshold import leak_threshold

    return leak_threshold().ratio


@dataclass(frozen=True)
class RulConfig:
    """Threshold (C_Lk ratio; None = derived), planning horizons (in flights, used when the
    history counts flights; in operating hours otherwise), the probability of crossing within
    it that counts as a warning, Monte-Carlo draws, the fewest observable periods a RUL is
    computed from, and ``robust_trend``: the opt-in Student-t readings and trend model
    (``degradation.robust_trend_prior``, decision records 0030-0032; off by default: on fresh
    fleets it regressed the step, quadratic and linear laws and let a one-flight transient
    warn)."""

    threshold_ratio: float | None = None
    horizon_h: float = 50.0
    horizon_flights: float = 20.0
    warn_p: float = 0.2
    n_samples: int = 4000
    min_periods: int = 8
    seed: int = 0
    robust_trend: bool = False

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
    usage: dict[str, NDArray] | None = None
    """Per period, each ``USAGE_AXES`` figure's total in the period (NaN: not recorded)."""

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
        us = None if self.usage is None else {a: v[:k] for a, v in self.usage.items()}
        return History(self.actuator, self.t_h[:k], self.y[:k], self.hours_per_flight,
                       cut(self.flight), cut(self.start_unix), us)  # fmt: skip

    def flight_rates(self, axis: str) -> NDArray | None:
        """Usage per operating second of each flight from the first to the last (a
        ``MEAN_AXES`` axis: the ratio of its two figures over the flight's periods; a flight
        without periods: the mean of the others), None unless the history counts flights and
        every flight's periods recorded the figures with operating time (and, for a ratio,
        a denominator above zero)."""
        if self.axis != "flights" or self.usage is None:
            return None
        num, den = MEAN_AXES.get(axis, (axis, None))
        if num not in self.usage or (den is not None and den not in self.usage):
            return None
        u = self.usage[num]
        op = np.diff(np.concatenate(([0.0], self.t_h))) * 3600.0
        if den is not None:
            op = self.usage[den]
        f = (self.flight - self.flight[0]).astype(int)
        if not (np.isfinite(u).all() and np.isfinite(op).all() and len(u)):
            return None
        tot = np.bincount(f, weights=u)
        sec = np.bincount(f, weights=op)
        seen = np.bincount(f) > 0
        if np.any(seen & (sec <= 0)):
            return None
        rate = np.full(len(tot), math.nan)
        rate[seen] = tot[seen] / sec[seen]
        rate[~seen] = float(np.mean(rate[seen]))
        return rate

    def usage_life(self, axis: str, ref: float | None = None) -> NDArray | None:
        """Each period's position on a usage axis: 1 + the usage of the flights before its
        own, each flight its usage per operating second over ``ref`` (None: the history's own
        mean), so that a flight of typical usage counts one; None where ``flight_rates`` is."""
        rate = self.flight_rates(axis)
        if rate is None:
            return None
        ref = ref if ref and ref > 0 else float(np.mean(rate))
        if not ref > 0:
            return None
        before = np.concatenate(([0.0], np.cumsum(rate / ref)))
        return 1.0 + before[(self.flight - self.flight[0]).astype(int)]

    def axes(self) -> list[str]:
        """The life axes this history supports: its own (flights or hours), then each usage
        axis every flight has."""
        return [self.axis] + [a for a in (*USAGE_AXES, *MEAN_AXES)
                              if self.flight_rates(a) is not None]  # fmt: skip


def history_of(actuator: str, periods: Sequence[Period]) -> History:
    """The ``History`` of ``periods``, taken in the caller's order: the unit's life order
    (``HealthStore.life``, the one order every view reads). Hours per flight: total
    operating hours of the periods with a flight number over the number of distinct
    flights."""
    ps = list(periods)
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
    usage = {a: np.array([_num(getattr(p, f, None)) for p in ps], float)
             for a, f in USAGE_AXES.items()}  # fmt: skip
    return History(actuator, t_h, y, hpf, fl, su, usage)


def _num(v) -> float:
    return math.nan if v is None else float(v)


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
    prior = _prior_for(prior, cfg)
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
    if len(y) and y[-1] >= thr:  # past the failure threshold: failed, whatever the fit
        out.update(status="failed", p_horizon=1.0, warning=True, **_NONE)
        for u, f in (("flights", 1.0), ("h", hpf if axis == "flights" else 1.0),
                     ("days", dpf if axis == "flights" else None)):  # fmt: skip
            for q in ("median", "lo", "hi"):
                out[f"{q}_{u}"] = 0.0 if f else None
        return out
    if len(t) < cfg.min_periods:
        out.update(status="insufficient history", p_horizon=None, warning=False, **_NONE)
        return out
    rng = np.random.default_rng(cfg.seed)
    kappa = prior.kappa if prior is not None else 1.0
    fits = axis_fits(h, prior)
    w = axis_weights(fits, prior)
    counts = ([cfg.n_samples] if len(fits) == 1
              else rng.multinomial(cfg.n_samples, [w[a] for a in fits]))  # fmt: skip
    parts = []
    for (a, (fit, pos)), c in zip(fits.items(), counts, strict=True):
        if c == 0:
            continue
        cross = sample_crossing(fit, thr, int(c), rng)
        if pos is None:  # the history's own axis
            parts.append(np.maximum(cross - h.t_now(), 0.0))
        else:
            rate = h.flight_rates(a) / pos[1]
            parts.append(usage_to_flights(cross, float(pos[0][-1]), rate, rng))
    # periods after the last observable one count
    rul = parts[0] if len(parts) == 1 else rng.permutation(np.concatenate(parts))
    # the most probable axis; on a tie (a unit without wear fits every axis alike) its own
    best_axis = max(w, key=lambda a: (round(w[a], 6), a == h.axis))
    fit = fits[best_axis][0]
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
        life_axis=best_axis,
        p_axis={k: round(v, 4) for k, v in w.items()},
    )
    return out


def _prior_for(prior: FleetPrior | None, cfg: RulConfig) -> FleetPrior | None:
    """The prior a RUL is computed under: ``prior``, or with ``cfg.robust_trend`` and none the
    vague prior with the switch on; a prior learned with the other setting of the switch is
    refused (its model mix and noise model would not be the ones asked for)."""
    if prior is None:
        return robust_trend_prior() if cfg.robust_trend else None
    if prior.robust_trend != cfg.robust_trend:
        raise ValueError(f"the fleet prior was learned with robust_trend={prior.robust_trend}, "
                         f"the RUL asks for robust_trend={cfg.robust_trend}")  # fmt: skip
    return prior


def axis_fits(
    h: History, prior: FleetPrior | None, min_p: float = 0.0, wearing_only: bool = False
) -> dict[str, tuple]:
    """The history fitted on each life axis the fleet prior admits (``p_axis`` > ``min_p``;
    ``learn_axes`` gives every axis the fleet records a share) and the history
    supports: {axis: (Fit, None)} for its own axis, {axis: (Fit, (positions
    of every period, usage ref))} for a usage axis. ``wearing_only``: no usage axis for a
    history whose best model on its own axis is ``none``."""
    t, y = h.observed()
    own = fit_history(t, y, prior)
    out: dict[str, tuple] = {h.axis: (own, None)}
    if prior is None or h.axis != "flights" or (wearing_only and own.best() == "none"):
        return out
    ok = np.isfinite(h.y)
    for a in h.axes()[1:]:
        if prior.p_axis.get(a, 0.0) <= min_p:
            continue
        ref = prior.usage_ref.get(a)
        x = h.usage_life(a, ref)
        if x is None:
            continue
        ref = ref if ref and ref > 0 else float(np.mean(h.flight_rates(a)))
        out[a] = (fit_history(x[ok], y, prior), (x, ref))
    return out


def axis_weights(fits: dict[str, tuple], prior: FleetPrior | None) -> dict[str, float]:
    """Posterior probability of each fitted axis: the fleet's ``p_axis`` times the history's
    marginal likelihood on it (``Fit.log_marginal``); the history's own axis alone without a
    prior."""
    if len(fits) == 1:
        return {a: 1.0 for a in fits}
    assert prior is not None
    own = next(iter(fits))
    lz = {}
    for a, (fit, _) in fits.items():
        pa = prior.p_axis.get(a, 0.0) if a != own else prior.p_axis.get(a, 1.0)
        lz[a] = fit.log_marginal(prior.p_model) + math.log(max(pa, 1e-12))
    mx = max(lz.values())
    z = {a: math.exp(v - mx) for a, v in lz.items()}
    tot = sum(z.values())
    return {a: v / tot for a, v in z.items()}


def usage_to_flights(
    cross: NDArray, u_now: float, rate: NDArray, rng: np.random.Generator, ahead: int = 200
) -> NDArray:
    """Flights from now to crossings ``cross`` on a usage axis (inf: never), the unit at
    ``u_now`` after its last reading: the flight of that reading adds its own known usage
    ``rate[-1]``, each flight after it a draw of the unit's per-flight usage (``rate`` of its
    flights after the first, the commissioning one, when there are three or more; resampled),
    the crossing interpolated within a flight; beyond ``ahead`` flights at the mean rate."""
    cross = np.asarray(cross, float)
    out = np.full(len(cross), np.inf)
    need = cross - u_now
    fin = np.isfinite(need)
    out[fin & (need <= 0)] = 0.0
    idx = np.flatnonzero(fin & (need > 0))
    if len(idx) == 0:
        return out
    pool = rate[1:] if len(rate) >= 4 else rate
    pool = pool[np.isfinite(pool) & (pool > 0)]
    if len(pool) == 0:
        return out
    steps = rng.choice(pool, size=(len(idx), ahead - 1))
    cum = np.concatenate(
        [np.zeros((len(idx), 1)), rate[-1] + np.concatenate(
            [np.zeros((len(idx), 1)), np.cumsum(steps, axis=1)], axis=1)], axis=1,
    )  # fmt: skip  # cum[:, j]: usage after j flights
    nd = need[idx]
    above = cum >= nd[:, None]
    hit = above.any(axis=1)
    j = np.argmax(above, axis=1)
    r = np.empty(len(idx))
    jj = np.maximum(j[hit], 1)
    lo, hi = cum[hit, jj - 1], cum[hit, jj]
    r[hit] = jj - 1 + (nd[hit] - lo) / np.where(hi > lo, hi - lo, 1.0)
    r[~hit] = ahead + (nd[~hit] - cum[~hit, -1]) / float(np.mean(pool))
    out[idx] = r
    return out


def fleet_prior(
    histories: Iterable[History], min_points: int = 8, robust_trend: bool = False
) -> FleetPrior:
    """Fleet prior learned from every unit's observable history (``learn_fleet_prior``) and
    which life axis explains the fleet's wear (``learn_axes``); ``robust_trend``: with the
    opt-in Student-t readings and trend model (``RulConfig.robust_trend``)."""
    hs = list(histories)
    base = robust_trend_prior() if robust_trend else None
    return learn_axes(hs, learn_fleet_prior([h.observed() for h in hs], base), min_points)


def learn_axes(hs: Sequence[History], prior: FleetPrior, min_points: int = 8) -> FleetPrior:
    """``prior`` with the fleet's usage reference of each usage axis (the median of every
    flight's usage per operating second) and its axis probabilities ``p_axis``: every
    history with ``min_points`` observable periods and the usage figures is fitted on each
    axis, its best axis by marginal likelihood counted (Dirichlet(1) smoothing over the axes
    the fleet records, each of them kept). A fleet without usage figures keeps its own axis
    alone."""
    ref = {}
    for a in (*USAGE_AXES, *MEAN_AXES):
        rates = [r for h in hs if (r := h.flight_rates(a)) is not None]
        if rates:
            v = np.concatenate(rates)
            v = v[np.isfinite(v) & (v > 0)]
            if len(v):
                ref[a] = float(np.median(v))
    if not ref:
        return prior
    probe = replace(prior, p_axis=dict.fromkeys(("flights", *ref), 1.0), usage_ref=ref)
    counts = dict.fromkeys(probe.p_axis, 1.0)
    for h in hs:
        if np.isfinite(h.y).sum() < min_points or h.axis != "flights":
            continue
        fits = axis_fits(h, probe, wearing_only=True)
        if len(fits) < 2:
            continue
        lz = {a: f.log_marginal(prior.p_model) for a, (f, _) in fits.items()}
        counts[max(lz, key=lz.__getitem__)] += 1.0
    # every axis the fleet records keeps its Dirichlet(1)-smoothed share, also one no wearing
    # unit chose: a unit whose own evidence favours it still reads its wear on it
    # (``axis_weights``: this prior times the unit's marginal likelihood on each axis)
    tot = sum(counts.values())
    return replace(prior, p_axis={a: c / tot for a, c in counts.items()}, usage_ref=ref)


def compute_rul(
    store, actuator: str | None = None, cfg: RulConfig | None = None, save: bool = True
) -> tuple[list[dict], FleetPrior]:
    """RUL of every actuator in ``store`` (or just ``actuator``) under the fleet prior learned
    from all of them; each summary written with ``store.put_rul`` when ``save``."""
    names = store.actuators()
    hist = {a: history_of(a, store.life(a)) for a in names}
    prior = fleet_prior(hist.values(), robust_trend=cfg is not None and cfg.robust_trend)
    out = []
    for a in [actuator] if actuator is not None else names:
        if a not in hist:
            raise KeyError(a)
        r = rul_of_history(hist[a], prior, cfg)
        if save:
            store.put_rul(a, r)
        out.append(r)
    return out, prior
