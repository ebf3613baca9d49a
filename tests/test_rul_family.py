"""The model family after issue 42's knee: a knee followed by growth (``knee_exp``), wear whose
rate changes once and then keeps growing (a running-in rate, then a runaway). Without it the
fit read such a path as a knee (the new rate, linear) and the RUL came out long."""

from __future__ import annotations

import numpy as np

from service.prognostics.degradation import fit_history, sample_crossing
from service.prognostics.paths import basis, crossing

THR = 11.0


def _knee_growth(x: np.ndarray, rate: float, knee: float, jump: float, g: float) -> np.ndarray:
    """y = 1 + rate x + jump (exp(g (x - knee)+) - 1) / g: the rate ``rate`` until the knee,
    then rate + jump exp(g (x - knee))."""
    return 1 + rate * x + jump * np.expm1(g * np.maximum(x - knee, 0.0)) / g


def test_a_knee_then_growth_is_not_read_as_a_knee():
    """After the knee the rate grows by e every 5-10 flights; at three quarters of the way from
    the knee to the end the median RUL is within +-20 % in at least 8 of 10 histories (10 with
    knee_exp; the family without it read 4 of them as a knee, the new rate kept linear, at
    2.2-3.8 times the true RUL: 6 of 10)."""
    rng = np.random.default_rng(7)
    ok = []
    for _ in range(10):
        rate, knee = rng.uniform(0.08, 0.15), rng.uniform(6.0, 12.0)
        jump, g = rng.uniform(0.1, 0.3), rng.uniform(0.1, 0.2)
        x = np.arange(1.0, 80.0)
        r = _knee_growth(x, rate, knee, jump, g)
        life = float(np.interp(THR, r, x))
        k = int(knee + 0.75 * (life - knee))
        y = r[:k] + 0.04 * rng.standard_normal(k)
        fit = fit_history(x[:k], y)
        rul = float(np.median(sample_crossing(fit, THR, 2000, np.random.default_rng(0)))) - x[k - 1]
        ok.append(abs(rul / (life - x[k - 1]) - 1.0) <= 0.2)
    assert sum(ok) >= 8, ok


def test_the_knee_exp_crossing_is_the_first_one_ahead():
    """The closed form (Lambert's W, both branches) against a fine search along the path, on
    draws of every sign of the two rates: rising, falling, a path that turns back down before
    the threshold, one that dips and then runs away, and rates too small for exp's range."""
    rng = np.random.default_rng(3)
    u = np.linspace(0.0, 40.0, 200001)
    for _ in range(120):
        tau, b = rng.uniform(0.1, 0.8), 10 ** rng.uniform(-1.0, 1.0)
        t_now = rng.uniform(tau + 0.01, 1.0)
        w = np.array([[rng.normal(1.0, 0.3),
                       rng.normal(0.0, 5.0) * 10 ** rng.uniform(-4, 0),
                       rng.normal(0.0, 5.0) * 10 ** rng.uniform(-4, 0)]])  # fmt: skip
        tc = float(crossing("knee_exp", w, np.array([tau, b]), THR, t_now)[0])
        ahead = u[u >= t_now]
        with np.errstate(over="ignore"):
            above = np.flatnonzero(basis("knee_exp", ahead, (tau, b)) @ w[0] >= THR)
        if len(above) == 0:
            assert tc > 39.0, (tau, b, t_now, w, tc)
        else:
            assert abs(tc - ahead[above[0]]) <= 4e-4 * max(1.0, tc), (tau, b, t_now, w, tc)
