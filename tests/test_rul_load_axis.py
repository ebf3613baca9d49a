"""Wear that goes with the load squared per operating second, whatever the jack's motion
(fleet-sim's ``load`` law, issue 42): the flight's mean squared load along its travel (the
F^2-weighted travel over the travel, ``rul.MEAN_AXES``) is a life axis of its own, which the
fleet learns and on which the RUL holds, where the F^2-weighted travel per second carries
the command amplitude as noise."""

from __future__ import annotations

import numpy as np
import pytest

from service.prognostics.rul import (
    MEAN_AXES,
    History,
    RulConfig,
    axis_fits,
    fleet_prior,
    rul_of_history,
)
from tests.test_rul_axes import THR, usage_history


def _unit(rng: np.random.Generator, name: str, n: int, driver: str = "load2"):
    """One history, one period of 2 s per flight, the three usage figures recorded: the
    flight's load and command amplitude vary (x 0.65-1.35 and x 0.75-1.25 about the unit's
    profile) and its wear is hours x load^2 (``load2``) or hours x load x amplitude
    (``load_travel``), hours x 0.8-1.2 unseen."""
    p_load, p_amp = rng.uniform(0.8, 1.2), rng.uniform(0.85, 1.15)
    load = p_load * rng.uniform(0.65, 1.35, 200)
    amp = p_amp * rng.uniform(0.75, 1.25, 200)
    hours = rng.uniform(0.8, 1.2, 200)
    per = hours * (load**2 if driver == "load2" else load * amp)
    return usage_history(rng, name, n, per, load, amp, rng.uniform(18, 30))


def test_the_mean_squared_load_is_the_flights_f2_travel_over_its_travel():
    rng = np.random.default_rng(3)
    h, _ = _unit(rng, "AC/x", 12)
    rate = h.flight_rates("load2")
    want = h.usage["load2_travel"] / h.usage["travel"]  # one period per flight
    assert rate == pytest.approx(want, rel=1e-12)
    assert "load2" in h.axes() and set(MEAN_AXES) <= set(h.axes())
    # two periods in one flight: the ratio of the flight's totals, not a mean of ratios
    h2 = History("AC/x", h.t_h[:4], h.y[:4], h.hours_per_flight, np.array([0.0, 0.0, 1, 2]),
                 None, {a: v[:4] for a, v in h.usage.items()})  # fmt: skip
    u = h.usage
    assert h2.flight_rates("load2")[0] == pytest.approx(
        (u["load2_travel"][0] + u["load2_travel"][1]) / (u["travel"][0] + u["travel"][1])
    )
    # a flight without travel has no mean load: the axis is not offered
    u0 = {a: v.copy() for a, v in h.usage.items()}
    u0["travel"][3] = 0.0
    u0["load2_travel"][3] = 0.0
    h0 = History("AC/x", h.t_h, h.y, h.hours_per_flight, h.flight, None, u0)
    assert h0.flight_rates("load2") is None and "load2" not in h0.axes()


def test_wear_with_the_load_squared_is_read_on_the_mean_squared_load():
    """A fleet whose wear per flight goes with hours x load^2: it learns the ``load2`` axis,
    each long history's evidence is larger on it than on the F^2-weighted travel per second
    (which carries the command amplitude, x 0.75-1.25 per flight, as noise), its wearing
    units are read on it, and the RUL holds."""
    rng = np.random.default_rng(21)
    units = [_unit(rng, f"AC{i}/ail", 24 if i % 4 else 14) for i in range(10)]
    hs = [h for h, _ in units]
    prior = fleet_prior(hs)
    assert max(prior.p_axis, key=prior.p_axis.__getitem__) == "load2", prior.p_axis
    assert prior.p_axis["load2"] >= 0.5, prior.p_axis
    for h in hs:
        if len(h.y) >= 20:
            fits = axis_fits(h, prior)
            lz = {a: f.log_marginal(prior.p_model) for a, (f, _) in fits.items()}
            assert lz["load2"] > lz["load2_travel"] + 1.0, lz
    cfg = RulConfig(threshold_ratio=THR, n_samples=1000)
    hits = []
    for h, eol in units:
        for k in (10, 14, 18, 22):
            if k > len(h.y) or h.head(k).t_now() >= eol - 1:
                continue
            hk = h.head(k)
            true = eol - hk.t_now()
            res = rul_of_history(hk, prior, cfg)
            if k >= 14:
                assert res["life_axis"] == "load2", res["p_axis"]
            hits.append(0.8 * true <= res["median_flights"] <= 1.2 * true)
    assert len(hits) >= 12
    assert np.mean(hits) >= 0.75, hits


def test_wear_with_load_weighted_travel_stays_on_its_axis():
    """The new axis takes nothing from wear that follows the load-weighted travel (load x
    amplitude): that fleet still learns ``load_travel``."""
    rng = np.random.default_rng(22)
    hs = [_unit(rng, f"AC{i}/ail", 24, "load_travel")[0] for i in range(8)]
    prior = fleet_prior(hs)
    assert max(prior.p_axis, key=prior.p_axis.__getitem__) == "load_travel", prior.p_axis
