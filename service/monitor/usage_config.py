"""The layout and the thresholds of the monitor's usage rates (``service.monitor.usage``,
docs/prognostics.md, section 1, "Usage"); no numba, so the period accumulator and the store
import it without the kernels."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "USAGE_KEYS",
    "N_USAGE",
    "UsageConfig",
    "new_state",
    "U_SPEED",
    "U_LOAD_SPEED",
    "U_LOAD2_SPEED",
    "U_LOADED",
    "U_PRESSURISED",
    "U_REVERSAL",
]

USAGE_KEYS: tuple[str, ...] = (
    "speed",
    "load_speed",
    "load2_speed",
    "loaded",
    "pressurised",
    "reversal",
)
U_SPEED, U_LOAD_SPEED, U_LOAD2_SPEED, U_LOADED, U_PRESSURISED, U_REVERSAL = range(6)
N_USAGE = len(USAGE_KEYS)

# per-actuator rows of the bank (n_act, N_UROW): jack area [m^2], load threshold [N],
# pressure threshold [Pa], reversal hysteresis [m]
UR_AREA, UR_LOAD, UR_PRESS, UR_HYST = range(4)
N_UROW = 4
# per-actuator state (n_act, N_USTATE): direction of travel, extreme (or anchor) x_J [m]
US_DIR, US_EXT = range(2)
N_USTATE = 2


@dataclass(frozen=True)
class UsageConfig:
    """Thresholds of the usage figures (SI; docs/prognostics.md, "Usage")."""

    load_fraction: float = 0.1  # under load: |F_J| above this share of A_J P_SR,rated
    pressure_fraction: float = 0.5  # at pressure: estimated P_SR above this share of rated
    reversal_m: float = 0.2e-3  # reversal hysteresis on the estimated x_J [m]

    def __post_init__(self) -> None:
        for name in ("load_fraction", "pressure_fraction", "reversal_m"):
            v = getattr(self, name)
            if not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                raise ValueError(f"UsageConfig.{name}: expected a finite number >= 0, got {v!r}")

    def row(self, area: float, p_sr_rated: float) -> NDArray:
        """The bank's usage row of an actuator whose baseline has ``area`` [m^2] and
        ``p_sr_rated`` [Pa]."""
        r = np.empty(N_UROW)
        r[UR_AREA] = area
        r[UR_LOAD] = self.load_fraction * area * p_sr_rated
        r[UR_PRESS] = self.pressure_fraction * p_sr_rated
        r[UR_HYST] = self.reversal_m
        return r


def new_state(n: int) -> NDArray:
    """The reversal detectors of ``n`` actuators, nothing seen yet."""
    s = np.zeros((n, N_USTATE))
    s[:, US_EXT] = math.nan
    return s
