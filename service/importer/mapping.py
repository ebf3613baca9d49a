"""The channel map of ``servowatch import`` (docs/import.md): a TOML file validated with
pydantic, units parsed and dimension-checked with pint.

A servowatch channel ``c`` (``messages.CHANNELS``) mapped to a source column with unit ``u``,
``scale`` ``a`` and ``offset`` ``b`` reads, in SI (messages.md)::

    c = (a * raw + b) [u] -> SI          (scale and offset in the source's unit)

A channel the map leaves out is absent (NaN on the log), as in the reduced channel set.
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from functools import cache
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from service.importer.errors import InputError
from service.wire import messages as m

__all__ = [
    "ChannelMap",
    "ChannelSpec",
    "TimeSpec",
    "ActuatorSpec",
    "load_map",
    "si_factor",
    "DIMENSION",
    "DEFAULT_RATE_HZ",
    "FORMATS",
]

FORMATS = ("parquet", "csv", "tdms", "mdf")
DEFAULT_RATE_HZ = 1000.0
"""The monitor's rate: its noise and its calibration assume the sensors' 1 kHz
(``models.scenario.Sensors.rate_hz``)."""

DIMENSION = {
    "x_cmd": "[length]",
    "x_s": "[length]",
    "x_j": "[length]",
    "i": "[current]",
    "p1": "[pressure]",
    "p2": "[pressure]",
    "p_sr": "[pressure]",
}
"""The physical dimension of each servowatch channel (pint's names)."""

_SI = {"[length]": "m", "[current]": "A", "[pressure]": "Pa"}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class TimeSpec(_Strict):
    """Where the samples' times come from."""

    column: str | None = Field(
        None, description="time column; omitted where the format has its own time base"
    )
    unit: Literal["s", "ms", "us", "ns", "datetime"] = Field(
        "s", description="relative seconds (or ms, us, ns), or absolute timestamps"
    )
    rate_hz: float = Field(
        DEFAULT_RATE_HZ, gt=0, le=1e6, description="the log's rate: the monitor's time base [Hz]"
    )


class ActuatorSpec(_Strict):
    """The unit the recording belongs to, and optionally its flight and start time."""

    aircraft: str
    name: str
    flight: int | None = Field(None, ge=0, le=2**31 - 1)
    start_unix: float | None = Field(None, description="calendar time of the time axis' zero")

    @field_validator("aircraft", "name")
    @classmethod
    def _key_chunk(cls, v: str) -> str:
        m.key("{x}", x=v)  # one Zenoh key chunk (MessageError is a ValueError)
        return v


class ChannelSpec(_Strict):
    """One servowatch channel's source column, unit, scale and offset."""

    column: str = Field(min_length=1)
    unit: str = Field(min_length=1)
    scale: float = 1.0
    offset: float = 0.0

    @field_validator("scale", "offset")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError("must be finite")
        return v


class ChannelMap(_Strict):
    """The whole map (docs/import.md, "The map")."""

    format: Literal["parquet", "csv", "tdms", "mdf"] | None = None
    time: TimeSpec = Field(default_factory=TimeSpec)
    actuator: ActuatorSpec
    channels: dict[str, ChannelSpec]

    @field_validator("channels")
    @classmethod
    def _known(cls, v: dict[str, ChannelSpec]) -> dict[str, ChannelSpec]:
        for k in v:
            if k not in DIMENSION:
                raise ValueError(f"{k!r} is not a servowatch channel ({', '.join(m.CHANNELS)})")
        if not v:
            raise ValueError("map at least one channel")
        cols = [spec.column for spec in v.values()]
        dup = next((c for c in cols if cols.count(c) > 1), None)
        if dup is not None:
            raise ValueError(f"column {dup!r} is mapped to two channels")
        return v

    def ordered(self) -> list[tuple[str, ChannelSpec]]:
        """The mapped channels in ``messages.CHANNELS`` order."""
        return [(k, self.channels[k]) for k in m.CHANNELS if k in self.channels]


@cache
def _ureg():
    import pint

    # the parsed definitions cached in the user's cache folder: 0.2 s instead of 0.7 s
    return pint.UnitRegistry(cache_folder=":auto:")


def si_factor(unit: str, channel: str) -> float:
    """SI value per 1 ``unit`` for ``channel`` (ValueError when pint does not know the unit
    or its dimension is not the channel's, ``DIMENSION``)."""
    import pint

    want = DIMENSION[channel]
    ureg = _ureg()
    try:
        q = ureg.Quantity(1.0, unit)
    except (pint.errors.PintError, AttributeError, TypeError, ValueError, SyntaxError) as e:
        raise ValueError(f"unit {unit!r} is not a unit ({type(e).__name__})") from None
    if q.dimensionality != ureg.get_dimensionality(want):
        raise ValueError(
            f"unit {unit!r} is {q.dimensionality or 'dimensionless'}, not {want} "
            f"(channel {channel} is in {_SI[want]})"
        )
    return float(q.to(_SI[want]).magnitude)


def load_map(path: str | Path) -> tuple[ChannelMap, bytes]:
    """The validated map and its bytes (kept in the log); ``InputError`` naming the file and
    the field otherwise (a typo in a field name is an unknown field)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise InputError(p, "map", e.strerror or str(e)) from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise InputError(p, "map", f"not TOML: {e}") from None
    try:
        cmap = ChannelMap.model_validate(data)
    except ValidationError as e:
        errs = e.errors()  # an unknown field first: a typo also makes its field "missing"
        err = next((x for x in errs if x["type"] == "extra_forbidden"), errs[0])
        field = ".".join(str(x) for x in err["loc"]) or "map"
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field (a typo?)"
        raise InputError(p, field, msg) from None
    for k, spec in cmap.channels.items():
        try:
            si_factor(spec.unit, k)
        except ValueError as e:
            raise InputError(p, f"channels.{k}.unit", str(e)) from None
    return cmap, raw


def map_digest(raw: bytes) -> str:
    """sha256 of the map's bytes."""
    return hashlib.sha256(raw).hexdigest()
