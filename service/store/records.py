"""Record types of the health store (SI units; times in seconds).

``BaselineRecord`` is one calibrated baseline version of an actuator, ``Period`` one closed
operating period with its condition indicators, ``AlarmEvent`` one alarm raised by the
monitor. All are frozen dataclasses; they validate their identity fields on construction.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from service.names import MAX_NAME_CHARS, is_unit

__all__ = [
    "ActuatorKey",
    "BaselineRecord",
    "Period",
    "AlarmEvent",
    "PERIOD_FIELDS",
    "PERIOD_FLOAT_FIELDS",
    "PERIOD_INT_FIELDS",
    "USAGE_FIELDS",
    "POOLED_FIELDS",
    "check_actuator",
]

ActuatorKey = str  # "AC001/elevator_L": aircraft / actuator


def check_actuator(actuator: object, field_name: str = "actuator") -> str:
    """Return ``actuator`` if it reads ``AIRCRAFT/ACTUATOR``, two names of the station's
    grammar (``service.names``: letters, digits, ``_.-``, at most 128 each)."""
    if not is_unit(actuator):
        raise ValueError(
            f"{field_name}: expected 'AIRCRAFT/ACTUATOR' (letters, digits, '_', '.', '-', at "
            f"most {MAX_NAME_CHARS} each), got {str(actuator)[:300]!r}"
        )
    return actuator


def _check_finite(name: str, v: object) -> None:
    if not isinstance(v, int | float) or not math.isfinite(v):
        raise ValueError(f"{name}: expected a finite number, got {v!r}")


@dataclass(frozen=True)
class BaselineRecord:
    """One baseline version of an actuator.

    ``baseline`` is ``service.monitor.Baseline.model_dump()``, ``figures`` the calibration
    figures (free-form JSON), ``created_s`` the unix time it was recorded.
    """

    actuator: str
    version: int
    source: str
    created_s: float
    baseline: dict[str, Any] = field(default_factory=dict)
    figures: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_actuator(self.actuator)
        if not isinstance(self.version, int) or self.version < 1:
            raise ValueError(f"version: expected an integer >= 1, got {self.version!r}")
        _check_finite("created_s", self.created_s)


@dataclass(frozen=True)
class Period:
    """One closed operating period of an actuator with its condition indicators.

    ``start_t``/``end_t`` are sample times [s]; ``op_time_s`` the operating time in it [s].
    C_Lk statistics are taken over the ``observable_samples`` only (NaN when there were
    none); ``c_lk_ratio`` is ``c_lk_mean`` over the baseline's C_Lk. ``nis_in_band`` is a
    fraction in [0, 1]. ``source`` names what produced it (a log file id, ``live:station``);
    ``(actuator, source, start_t)`` identifies a period in the store.

    The ``usage_*`` fields are what wears the seals and the spool in the period
    (docs/prognostics.md, section 1, "Usage"): jack travel [m], load-weighted travel
    (integral of |F_J| |v_J| dt [J] and of F_J^2 |v_J| dt [N^2 m]), reversals (a whole number),
    time under load and time at pressure [s]; NaN where unknown (a period stored before
    migration 5, rows without usage; the load figures also without both chamber pressures).
    """

    actuator: str
    start_t: float
    end_t: float
    op_time_s: float
    samples: int
    flight: int | None
    c_lk_mean: float
    c_lk_sigma: float
    c_lk_ratio: float
    observable_samples: int
    p_sr_mean: float
    p_sr_min: float
    i_b_mean: float
    nis_mean: float
    nis_in_band: float
    alarms: int
    bad_samples: int
    dropped: int
    source: str
    start_unix: float | None = None
    usage_travel_m: float = math.nan
    usage_load_travel_j: float = math.nan
    usage_load2_travel_n2m: float = math.nan
    usage_reversals: float = math.nan
    usage_loaded_s: float = math.nan
    usage_pressurised_s: float = math.nan
    c_lk_pooled: float = math.nan
    c_lk_pooled_sigma: float = math.nan

    def __post_init__(self) -> None:
        check_actuator(self.actuator)
        _check_finite("start_t", self.start_t)
        _check_finite("end_t", self.end_t)
        if self.end_t < self.start_t:
            raise ValueError(f"end_t: {self.end_t} is before start_t {self.start_t}")
        _check_finite("op_time_s", self.op_time_s)
        if self.op_time_s < 0:
            raise ValueError(f"op_time_s: expected >= 0, got {self.op_time_s}")
        for name in PERIOD_INT_FIELDS:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name}: expected an integer >= 0, got {v!r}")
        if self.flight is not None and (
            isinstance(self.flight, bool) or not isinstance(self.flight, int)
        ):
            raise ValueError(f"flight: expected an integer or None, got {self.flight!r}")
        for name in PERIOD_FLOAT_FIELDS:
            if not isinstance(getattr(self, name), int | float):
                raise ValueError(f"{name}: expected a number, got {getattr(self, name)!r}")
        if not isinstance(self.source, str) or not self.source:
            raise ValueError(f"source: expected a non-empty string, got {self.source!r}")
        if self.start_unix is not None:
            _check_finite("start_unix", self.start_unix)
        for name in USAGE_FIELDS:
            v = getattr(self, name)
            if not (math.isnan(v) or (math.isfinite(v) and v >= 0)):
                raise ValueError(f"{name}: expected a finite number >= 0 or NaN, got {v!r}")

    def c_lk_ratio_sigma(self) -> float:
        """The 1-sigma of ``c_lk_ratio`` (a share of baseline C_Lk): the scatter of the
        observable estimates (``c_lk_sigma``) over the baseline the median reading came with;
        NaN where it abstains. The pooled reading has its own (``c_lk_pooled_sigma``)."""
        if math.isfinite(self.c_lk_mean) and self.c_lk_mean > 0:
            return self.c_lk_sigma * self.c_lk_ratio / self.c_lk_mean
        return math.nan

    def __eq__(self, other: object) -> bool:
        """Field by field, a NaN equal to a NaN (an unknown indicator reads back as NaN; two
        records of the same period are equal whichever backend they came through)."""
        if other.__class__ is not self.__class__:
            return NotImplemented
        for f in PERIOD_FIELDS:
            a, b = getattr(self, f), getattr(other, f)
            if a != b and not (isinstance(a, float) and isinstance(b, float) and a != a and b != b):
                return False
        return True

    def to_dict(self) -> dict[str, Any]:
        """The fields as a plain dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Period:
        """Inverse of ``to_dict``; ``None`` in a float field reads as NaN, as does a usage or
        pooled field the dict lacks (a period written before them)."""
        kw = {k: d[k] if k not in LATER_FIELDS else d.get(k) for k in PERIOD_FIELDS}
        del kw["start_unix"]
        su = d.get("start_unix")
        kw["start_unix"] = None if su is None or not math.isfinite(float(su)) else float(su)
        for k in PERIOD_FLOAT_FIELDS:
            kw[k] = math.nan if kw[k] is None else float(kw[k])
        for k in PERIOD_INT_FIELDS:
            kw[k] = int(kw[k])
        if kw["flight"] is not None:
            kw["flight"] = int(kw["flight"])
        return cls(**kw)


@dataclass(frozen=True)
class AlarmEvent:
    """One alarm: its sample time ``t`` [s], ``kind`` (e.g. ``leak``) and the value that
    raised it (SI). ``(actuator, source, t, kind)`` identifies it in the store."""

    actuator: str
    t: float
    kind: str
    value: float
    source: str

    def __post_init__(self) -> None:
        check_actuator(self.actuator)
        _check_finite("t", self.t)
        if not isinstance(self.kind, str) or not self.kind:
            raise ValueError(f"kind: expected a non-empty string, got {self.kind!r}")
        if not isinstance(self.value, int | float):
            raise ValueError(f"value: expected a number, got {self.value!r}")
        if not isinstance(self.source, str) or not self.source:
            raise ValueError(f"source: expected a non-empty string, got {self.source!r}")


PERIOD_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(Period))
PERIOD_INT_FIELDS: tuple[str, ...] = (
    "samples",
    "observable_samples",
    "alarms",
    "bad_samples",
    "dropped",
)
USAGE_FIELDS: tuple[str, ...] = (
    "usage_travel_m",
    "usage_load_travel_j",
    "usage_load2_travel_n2m",
    "usage_reversals",
    "usage_loaded_s",
    "usage_pressurised_s",
)
"""The usage fields of a period (migration 5), in the order of ``service.monitor.usage``."""
POOLED_FIELDS: tuple[str, ...] = ("c_lk_pooled", "c_lk_pooled_sigma")
"""The pooled C_Lk reading of a period and its sigma [m^3/s/Pa] (migration 6; NaN where the
indicator abstains, in a period stored before, or from rows without a pool)."""
LATER_FIELDS: tuple[str, ...] = (*USAGE_FIELDS, *POOLED_FIELDS)
"""Fields a period written before their migration lacks (they read as NaN)."""
PERIOD_FLOAT_FIELDS: tuple[str, ...] = (
    "start_t",
    "end_t",
    "op_time_s",
    "c_lk_mean",
    "c_lk_sigma",
    "c_lk_ratio",
    "p_sr_mean",
    "p_sr_min",
    "i_b_mean",
    "nis_mean",
    "nis_in_band",
    *USAGE_FIELDS,
    *POOLED_FIELDS,
)
