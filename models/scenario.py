"""Scenario schema (pydantic) and pure evaluation of its time profiles.

A scenario is data: a position command, an external load, a supply pressure, an optional
leakage-degradation profile applied to the plant, parameter overrides, sensor noise, the
duration and the integration step. Loading from TOML lives in ``service.sim.scenarios``.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from models.params import EHAParams

__all__ = ["Event", "Periodic", "Profile", "SensorNoise", "Scenario"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Event(_Strict):
    """From time ``t`` [s] the profile moves to ``value``, linearly over ``ramp_s`` (0 = step)."""

    t: float = Field(ge=0)
    value: float
    ramp_s: float = Field(0.0, ge=0)


class Periodic(_Strict):
    """A periodic component added to the profile between ``t_start`` and ``t_end``."""

    kind: Literal["sine", "square", "triangle"] = "sine"
    amplitude: float
    freq_hz: float = Field(gt=0)
    t_start: float = Field(0.0, ge=0)
    t_end: float = math.inf
    phase_rad: float = 0.0


class Profile(_Strict):
    """A scalar signal of time: initial value, events (steps/ramps), periodic components."""

    initial: float = 0.0
    events: list[Event] = Field(default_factory=list)
    periodic: list[Periodic] = Field(default_factory=list)

    @field_validator("events")
    @classmethod
    def _sorted(cls, v: list[Event]) -> list[Event]:
        ts = [e.t for e in v]
        if ts != sorted(ts):
            raise ValueError("events must be sorted by t")
        return v

    def sample(self, t: ArrayLike) -> NDArray:
        """Value of the profile at times ``t`` [s] (vectorised)."""
        t = np.asarray(t, dtype=float)
        y = np.full(t.shape, self.initial, dtype=float)
        for e in self.events:
            start = y.copy()  # value the ramp starts from, per time sample
            if e.ramp_s > 0:
                frac = np.clip((t - e.t) / e.ramp_s, 0.0, 1.0)
            else:
                frac = (t >= e.t).astype(float)
            y = np.where(t >= e.t, start + frac * (e.value - start), y)
        for p in self.periodic:
            on = (t >= p.t_start) & (t < p.t_end)
            arg = 2 * np.pi * p.freq_hz * (t - p.t_start) + p.phase_rad
            if p.kind == "sine":
                s = np.sin(arg)
            elif p.kind == "square":
                s = np.where(np.sin(arg) >= 0, 1.0, -1.0)
            else:
                s = 2.0 / np.pi * np.arcsin(np.sin(arg))
            y = y + np.where(on, p.amplitude * s, 0.0)
        return y

    def breakpoints(self) -> list[float]:
        """Times at which the profile has a kink or a jump (for aligning integration steps)."""
        out: list[float] = []
        for e in self.events:
            out.append(e.t)
            if e.ramp_s > 0:
                out.append(e.t + e.ramp_s)
        return out


class SensorNoise(_Strict):
    """1-sigma white noise of each sensor (SI), and the sampling rate of the measurements."""

    x_s_m: float = Field(0.0, ge=0, description="spool LVDT [m]")
    x_j_m: float = Field(0.0, ge=0, description="jack LVDT [m]")
    p_pa: float = Field(0.0, ge=0, description="chamber pressure transducers [Pa]")
    p_sr_pa: float = Field(0.0, ge=0, description="supply pressure transducer [Pa]")
    current_a: float = Field(0.0, ge=0, description="servovalve current [A]")
    rate_hz: float = Field(1000.0, gt=0, description="sampling rate of the measurements [Hz]")
    seed: int = 0
    ecu_noisy_x_j: bool = Field(
        False,
        description="the ECU closes its position loop on the jack LVDT's noisy reading (the "
        "x_J channel's own draws, held over each sample), not on the true x_J",
    )


class Scenario(_Strict):
    """One EHA test scenario (physics.md section 5 is ``scenarios/paper_bench.toml``)."""

    name: str
    description: str = ""
    duration_s: float = Field(gt=0)
    step_s: float = Field(1e-4, gt=0, le=1e-2, description="fixed integration step [s]")
    command: Profile = Field(default_factory=Profile, description="position command x_cmd [m]")
    load: Profile = Field(default_factory=Profile, description="external load F_R [N], >0 opposes")
    supply: Profile = Field(
        default_factory=lambda: Profile(initial=20e6), description="P_SR = P_S - P_R [Pa]"
    )
    leak: Profile | None = Field(None, description="plant C_Lk(t) [m^3/s/Pa]; None = params.c_lk")
    params: dict[str, float] = Field(default_factory=dict, description="EHAParams overrides")
    sensors: SensorNoise = Field(default_factory=SensorNoise)

    @field_validator("params")
    @classmethod
    def _known_params(cls, v: dict[str, float]) -> dict[str, float]:
        unknown = sorted(set(v) - set(EHAParams.model_fields))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown}")
        EHAParams.model_validate(v)  # type and range checks with field names
        return v

    @model_validator(mode="after")
    def _check(self) -> Scenario:
        if self.supply.initial <= 0:
            raise ValueError("supply.initial must be a positive P_SR [Pa]")
        return self

    def eha_params(self, base: EHAParams | None = None) -> EHAParams:
        """The plant parameters: ``base`` (default set) with this scenario's overrides."""
        base = base or EHAParams()
        return base.with_overrides(**self.params)

    def n_steps(self) -> int:
        """Number of integration steps covering ``duration_s``."""
        return int(round(self.duration_s / self.step_s))

    def time_grid(self) -> NDArray:
        """Step-boundary times t_k = k h, k = 0..n_steps [s]."""
        return np.arange(self.n_steps() + 1) * self.step_s

    def inputs(self, t: ArrayLike, params: EHAParams | None = None) -> dict[str, NDArray]:
        """Inputs sampled at ``t``: x_cmd [m], f_r [N], p_sr [Pa], c_lk [m^3/s/Pa]."""
        t = np.asarray(t, dtype=float)
        params = params or self.eha_params()
        c_lk = self.leak.sample(t) if self.leak is not None else np.full(t.shape, params.c_lk)
        return {
            "x_cmd": self.command.sample(t),
            "f_r": self.load.sample(t),
            "p_sr": np.maximum(self.supply.sample(t), 0.0),
            "c_lk": np.maximum(c_lk, 0.0),
        }
