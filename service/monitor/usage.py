"""What wears the seals and the spool, per output row of the monitor (docs/prognostics.md,
section 1, "Usage"): the jack speed, the load on the jack and whether it reversed.

``usage_rows`` (compiled, no Python per sample) makes, for every row of a block, the rates
the period accumulator (``service.prognostics.indicators``) integrates over the sample
intervals it counts as operating time, in the columns ``USAGE_KEYS``:

- ``speed``: |v_J| [m/s], from the estimator's jack velocity (the filter state; within
  0.5 % of the HF bench's travel on the bundled scenarios, where a smoothed derivative of
  the measured x_J is off by 3-9 %: docs/decisions/0017-usage-from-the-estimated-v-j.md);
- ``load_speed``, ``load2_speed``: |F_J| |v_J| [W] and F_J^2 |v_J| [N^2 m/s], with the load on
  the jack F_J = A_J (P1 - P2) from the *measured* chamber pressures and the area of the
  actuator's baseline (NaN in a sample without both pressures);
- ``loaded``: 1 while |F_J| exceeds ``load_fraction`` of the stall force A_J P_SR,rated (NaN
  without both pressures), else 0;
- ``pressurised``: 1 while the estimated P_SR exceeds ``pressure_fraction`` of rated, else 0;
- ``reversal``: 1 on the sample where the jack reverses: the estimated x_J has come back by
  more than ``reversal_m`` from its extreme since the last reversal (a hysteresis, so noise
  and dither smaller than it count nothing), else 0.

The reversal detector keeps two numbers per actuator between blocks (``US_*`` columns of
``service.monitor.usage_config``): the direction of travel (+1, -1, 0 = not known yet) and
the extreme (or, direction unknown, the anchor) position [m]. The column layout and the
thresholds (``UsageConfig``) are in ``service.monitor.usage_config``, which imports no numba.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from service.compat.numba import borrowed_all
from service.monitor.kernels import S_P_SR, S_V_J, S_X_J, Z_P1, Z_P2
from service.monitor.usage_config import (
    N_UROW,
    N_USAGE,
    UR_AREA,
    UR_HYST,
    UR_LOAD,
    UR_PRESS,
    US_DIR,
    US_EXT,
    UsageConfig,
    new_state,
)

__all__ = ["usage_rows", "BankUsage"]


@njit(cache=True, nogil=True)
def usage_rows(ks, acc, snap, X, sc, zs, i_vj, i_xj, i_psr, z, mask, i_p1, i_p2, urow, ust, out):
    """Usage rates of the rows j with acc[j] (module docstring), in order, into out[j]
    (``USAGE_KEYS`` columns). The filter state of row j is X[j] (``snap``: a block's
    snapshot) or X[ks[j]] (the bank's state; the per-round path), in filter units: SI =
    X * sc[k]; i_vj, i_xj, i_psr its columns of v_J, x_J, P_SR. z (scaled by zs[k]), mask:
    the measured channels (i_p1, i_p2: P1 and P2). urow: the actuators' ``UR_*`` rows; ust:
    their reversal detectors (``US_*``), updated in place."""
    ks, acc, X, sc, zs, z, mask = borrowed_all((ks, acc, X, sc, zs, z, mask))
    urow, ust, out = borrowed_all((urow, ust, out))
    for j in range(ks.shape[0]):
        if not acc[j]:
            continue
        k = ks[j]
        kk = j if snap else k
        v = X[kk, i_vj] * sc[k, i_vj]
        speed = abs(v)
        out[j, 0] = speed
        if mask[j, i_p1] and mask[j, i_p2]:
            f = urow[k, UR_AREA] * (z[j, i_p1] * zs[k, i_p1] - z[j, i_p2] * zs[k, i_p2])
            out[j, 1] = abs(f) * speed
            out[j, 2] = f * f * speed
            out[j, 3] = 1.0 if abs(f) > urow[k, UR_LOAD] else 0.0
        else:
            out[j, 1] = math.nan
            out[j, 2] = math.nan
            out[j, 3] = math.nan
        out[j, 4] = 1.0 if X[kk, i_psr] * sc[k, i_psr] > urow[k, UR_PRESS] else 0.0
        x = X[kk, i_xj] * sc[k, i_xj]
        h = urow[k, UR_HYST]
        d, e = ust[k, US_DIR], ust[k, US_EXT]
        rev = 0.0
        if math.isnan(e):
            e = x
        elif d == 0.0:
            if x - e > h:
                d, e = 1.0, x
            elif e - x > h:
                d, e = -1.0, x
        elif (x - e) * d > 0.0:
            e = x  # further the same way: a new extreme
        elif (e - x) * d > h:
            d, e, rev = -d, x, 1.0
        ust[k, US_DIR] = d
        ust[k, US_EXT] = e
        out[j, 5] = rev


class BankUsage:
    """The usage side of a ``MonitorBank``: per actuator its ``UR_*`` row (the thresholds of
    ``config`` on its baseline's jack area and rated supply) and its reversal detector, and
    the rates of a block's rows (``rates``). ``enabled`` False: no rates (``BankRows.usage``
    None; ``bench/usage.py`` times the bank both ways)."""

    def __init__(self, baseline: Any, config: UsageConfig | None = None) -> None:
        self.config = config or UsageConfig()
        self.enabled = True
        self._default = baseline
        self._bases: list[Any] = []
        self.rows = np.zeros((0, N_UROW))
        self.state = new_state(0)

    def _row(self, b: Any) -> NDArray:
        return self.config.row(b.area, b.p_sr_rated)

    def resize(self, cap: int) -> None:
        """Room for ``cap`` actuators (the new ones on the default baseline)."""
        n = len(self._bases)
        if cap <= n:
            return
        rows, state = np.tile(self._row(self._default), (cap, 1)), new_state(cap)
        rows[:n], state[:n] = self.rows, self.state
        self.rows, self.state = rows, state
        self._bases += [self._default] * (cap - n)

    def set_baseline(self, k: int, baseline: Any) -> None:
        """Actuator ``k`` runs on ``baseline`` (its reversal detector carries on)."""
        self._bases[k] = baseline
        self.rows[k] = self._row(baseline)

    def set_config(self, config: UsageConfig) -> None:
        """New thresholds for every actuator."""
        self.config = config
        for k, b in enumerate(self._bases):
            self.rows[k] = self._row(b)

    def rates(self, ks, acc, snap: bool, X, mr, z, mask, sel=None) -> NDArray | None:
        """``usage_rows`` of a block (the bank's ``ModelRows`` mr for the scales); the rows
        ``sel`` of the result (None: all), or None when not ``enabled``."""
        if not self.enabled:
            return None
        u = np.zeros((len(ks), N_USAGE))
        usage_rows(ks, acc, snap, X, mr.scale, mr.zscale, S_V_J, S_X_J, S_P_SR, z, mask,
                   Z_P1, Z_P2, self.rows, self.state, u)  # fmt: skip
        return u if sel is None else u[sel]
