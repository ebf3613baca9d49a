"""Seeded random duty cycles for the estimation suite (issue 10, deliverable 3).

``duty_cycle(seed, index)`` is pure: the same (seed, index) always gives the same two
validated scenarios on the same off-nominal plant:

- ``calibration``: a healthy segment (hold near mid stroke, position sines as
  ``scenarios/healthy_noise.toml``, under an opposing then an aiding load) from which the monitor's baseline is identified
  (``service.monitor.calibration.calibrate``) before the plant is judged;
- ``test``: the duty cycle: position steps and ramps up to +-80 % of the half stroke, sines,
  stepped-frequency chirps (phase-continuous sine bursts) and holds; a load that steps, ramps
  and oscillates within and across segments; supply drops and recoveries; a leak as a step, a
  ramp or a slow growth; sensor noise scaled from the bundled levels.

Plant tolerances (``EHAParams`` overrides, uniform): mass and viscous friction +-20 %,
dry friction (breakaway and Coulomb) -30..+50 %, land underlaps +-10 % common and +-3 % per
land, liquid bulk modulus -30..+15 %, entrained air 0.1-0.5 %. The last ``SETTLE_S`` seconds
of every test scenario carry no leak or supply change, so a settled C_Lk figure exists.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from models.params import EHAParams
from models.scenario import Event, Periodic, Profile, Scenario, SensorNoise

__all__ = [
    "DutyCycle",
    "duty_cycle",
    "suite",
    "scale_noise",
    "FAULT_KINDS",
    "STROKE_FRACTION",
    "SETTLE_S",
]

FaultKind = Literal["healthy", "leak", "supply", "leak+supply"]
FAULT_KINDS: tuple[str, ...] = ("healthy", "leak", "supply", "leak+supply")
STROKE_FRACTION = 0.8  # commanded positions stay within +-0.8 of the half stroke
SETTLE_S = 2.5  # no leak or supply change in the last SETTLE_S seconds of a test scenario
MAX_LOAD_N = 8e3  # |F_R| bound, below A P_SR at the deepest drop (1e-3 m^2 x 11 MPa)
_NOISE = {"x_s_m": 0.5e-6, "x_j_m": 50e-6, "p_pa": 50e3, "p_sr_pa": 50e3, "current_a": 1e-5}


@dataclass(frozen=True)
class DutyCycle:
    """One suite member: its healthy calibration segment, its test scenario and the truth
    of its events (times [s], levels as ratios to nominal C_Lk / rated P_SR)."""

    seed: int
    index: int
    kind: FaultKind
    calibration: Scenario
    test: Scenario
    leak_shape: str | None = None  # "step", "ramp", "growth"
    leak_ratio: float = 1.0  # final C_Lk / nominal
    leak_t: tuple[float, float] | None = None  # start, end of the leak change [s]
    supply_changes: tuple[tuple[float, float, float], ...] = ()  # (start, end, ratio after)
    params: dict[str, float] = field(default_factory=dict)
    noise_scale: float = 1.0


def _r(t: float) -> float:
    """A time rounded to the 1 ms sample grid (events on sample and integration boundaries)."""
    return round(t * 1000.0) / 1000.0


def _plant(rng: np.random.Generator) -> dict[str, float]:
    """Off-nominal plant overrides within the tolerances of the module docstring."""
    p = EHAParams()
    u = p.u1 * rng.uniform(0.9, 1.1)
    f_d = p.f_d * rng.uniform(0.7, 1.5)
    f_s = max(f_d, p.f_s * rng.uniform(0.7, 1.5))
    return {
        "mass": p.mass * rng.uniform(0.8, 1.2),
        "c_v": p.c_v * rng.uniform(0.8, 1.2),
        "f_d": f_d,
        "f_s": f_s,
        "u1": u * rng.uniform(0.97, 1.03),
        "u2": u * rng.uniform(0.97, 1.03),
        "u3": u * rng.uniform(0.97, 1.03),
        "u4": u * rng.uniform(0.97, 1.03),
        "beta_l": p.beta_l * rng.uniform(0.7, 1.15),
        "alpha0": rng.uniform(0.001, 0.005),
    }


def _sensors(scale: float, seed: int) -> SensorNoise:
    return SensorNoise(**{k: v * scale for k, v in _NOISE.items()}, rate_hz=1000.0, seed=seed)


def _command(rng: np.random.Generator, t0: float, t_end: float, stroke: float):
    """Position command after ``t0``: segments of steps, ramps, sines, chirps and holds."""
    lim = STROKE_FRACTION * stroke
    events: list[Event] = []
    periodic: list[Periodic] = []
    pos, t = 0.0, t0
    while t < t_end - 0.5:
        dur = min(float(rng.uniform(0.8, 2.5)), t_end - t)
        kind = rng.choice(["step", "ramp", "sine", "chirp", "hold"], p=[0.3, 0.2, 0.2, 0.15, 0.15])
        if kind == "step":
            pos = float(rng.uniform(-lim, lim))
            events.append(Event(t=_r(t), value=pos))
        elif kind == "ramp":
            new = float(rng.uniform(-lim, lim))
            ramp = _r(min(dur * 0.9, max(0.1, abs(new - pos) / rng.uniform(0.01, 0.08))))
            events.append(Event(t=_r(t), value=new, ramp_s=ramp))
            pos = new
        elif kind in ("sine", "chirp"):
            amp_max = 5e-3 if kind == "sine" else 3e-3
            amp = float(rng.uniform(0.5e-3, amp_max))
            if abs(pos) + amp > lim:  # move inward first so that the oscillation stays in range
                pos = math.copysign(lim - amp, pos)
                events.append(Event(t=_r(t), value=pos))
            if kind == "sine":
                periodic.append(
                    Periodic(amplitude=amp, freq_hz=float(rng.uniform(0.2, 2.0)),
                             t_start=_r(t), t_end=_r(t + dur))
                )  # fmt: skip
            else:  # stepped-frequency chirp 0.2 -> 3 Hz, phase-continuous bursts
                n_b = 8
                freqs = np.geomspace(0.2, 3.0, n_b)
                edges = [_r(t + dur * k / n_b) for k in range(n_b + 1)]
                phase = 0.0
                for k in range(n_b):
                    periodic.append(
                        Periodic(amplitude=amp, freq_hz=float(freqs[k]), t_start=edges[k],
                                 t_end=edges[k + 1], phase_rad=phase)
                    )  # fmt: skip
                    phase = (phase + 2 * math.pi * freqs[k] * (edges[k + 1] - edges[k])) % (
                        2 * math.pi
                    )
        t += dur
    return Profile(initial=0.0, events=events, periodic=periodic)


def _load(rng: np.random.Generator, t0: float, t_end: float) -> Profile:
    """Load: steps and ramps across segments, sines within them, |F_R| <= MAX_LOAD_N."""
    f0 = float(rng.uniform(-4e3, 6e3))
    events: list[Event] = []
    periodic: list[Periodic] = []
    f, t = f0, t0
    while t < t_end - 0.5:
        dur = min(float(rng.uniform(1.0, 3.0)), t_end - t)
        amp = float(rng.uniform(0.3e3, 2e3)) if rng.random() < 0.4 else 0.0
        if rng.random() < 0.6:
            delta = float(rng.choice([-1, 1]) * rng.uniform(1e3, 5e3))
            f = float(np.clip(f + delta, -MAX_LOAD_N + amp, MAX_LOAD_N - amp))
            ramp = _r(float(rng.uniform(0.05, 1.0))) if rng.random() < 0.5 else 0.0
            events.append(Event(t=_r(t), value=f, ramp_s=ramp))
        if amp > 0 and abs(f) + amp > MAX_LOAD_N:
            amp = MAX_LOAD_N - abs(f)
        if amp > 0:
            periodic.append(
                Periodic(amplitude=amp, freq_hz=float(rng.uniform(0.1, 1.0)), t_start=_r(t),
                         t_end=_r(t + dur))
            )  # fmt: skip
        t += dur
    return Profile(initial=f0, events=events, periodic=periodic)


CAL_SINE_END_S = 5.0  # the calibration's sines end here, both at a zero crossing
CAL_HOLD_SWAP_S = 6.5  # ... then a hold under the second load, the first load back here
CAL_HOLD_END_S = 8.0  # ... and a hold under it to the end of the segment


def duty_cycle(seed: int, index: int) -> DutyCycle:
    """Duty cycle ``index`` of suite ``seed`` (fault kind cycles healthy, leak, supply,
    leak+supply with the index; everything else drawn from ``default_rng([seed, index])``)."""
    rng = np.random.default_rng([seed, index])
    aux = np.random.default_rng([seed, index, 1])
    kind: FaultKind = FAULT_KINDS[index % len(FAULT_KINDS)]  # type: ignore[assignment]
    params = _plant(rng)
    plant = EHAParams().with_overrides(**params)
    noise_scale = float(rng.uniform(0.7, 1.5))
    c0, p0 = plant.c_lk, plant.p_sr
    # -- calibration segment: healthy, hold near mid stroke with sines under two loads
    cal = Scenario(
        name=f"dc{seed}_{index:03d}_cal",
        description="healthy calibration segment of the same plant",
        duration_s=CAL_HOLD_END_S,
        command=Profile(
            initial=0.0,
            periodic=[
                Periodic(
                    amplitude=float(rng.uniform(1.5e-3, 3e-3)), freq_hz=0.3, t_end=CAL_SINE_END_S
                ),
                Periodic(amplitude=0.2e-3, freq_hz=1.1, t_end=CAL_SINE_END_S),
            ],
        ),
        load=Profile(
            initial=(load_1 := float(rng.uniform(2e3, 5e3))),
            # a stream of its own: the test scenario's draws do not depend on this one
            events=[
                Event(t=2.5, value=float(aux.uniform(-5e3, -2e3)), ramp_s=0.2),
                Event(t=CAL_HOLD_SWAP_S, value=load_1, ramp_s=0.2),
            ],
        ),
        supply=Profile(initial=p0),
        params=params,
        sensors=_sensors(noise_scale, seed=int(rng.integers(2**31))),
    )
    # -- faults
    leak_shape, leak_ratio, leak_t = None, 1.0, None
    leak_events: list[Event] = []
    t_free = 3.0  # earliest time of a fault change
    if kind in ("leak", "leak+supply"):
        leak_shape = str(rng.choice(["step", "ramp", "growth"]))
        small = rng.random() < 0.4
        leak_ratio = float(rng.uniform(1.5, 1.9) if small else rng.uniform(2.75, 5.0))
        t_l = _r(float(rng.uniform(2.0, 5.0)))
        span = {
            "step": 0.0,
            "ramp": float(rng.uniform(1.0, 4.0)),
            "growth": float(rng.uniform(5.0, 8.0)),
        }
        ramp = _r(span[leak_shape])
        leak_events.append(Event(t=t_l, value=c0 * leak_ratio, ramp_s=ramp))
        leak_t = (t_l, t_l + ramp)
        t_free = t_l + ramp
    supply_events: list[Event] = []
    changes: list[tuple[float, float, float]] = []
    t_last = t_free
    if kind in ("supply", "leak+supply"):
        t_d = _r(float(rng.uniform(2.0, t_free + 2.0)))
        ratio = float(rng.uniform(0.55, 0.8))
        ramp = _r(float(rng.uniform(0.0, 0.1)))
        supply_events.append(Event(t=t_d, value=p0 * ratio, ramp_s=ramp))
        changes.append((t_d, t_d + ramp, ratio))
        t_last = max(t_last, t_d + ramp)
        if rng.random() < 0.5:  # recovery
            t_u = _r(t_d + ramp + float(rng.uniform(1.5, 3.0)))
            ramp_u = _r(float(rng.uniform(0.05, 0.5)))
            supply_events.append(Event(t=t_u, value=p0, ramp_s=ramp_u))
            changes.append((t_u, t_u + ramp_u, 1.0))
            t_last = max(t_last, t_u + ramp_u)
    duration = _r(max(12.0, t_last + SETTLE_S + 0.5))
    test = Scenario(
        name=f"dc{seed}_{index:03d}",
        description=f"random duty cycle, {kind}" + (f", leak {leak_shape}" if leak_shape else ""),
        duration_s=duration,
        command=_command(rng, 1.0, duration, plant.stroke),
        load=_load(rng, 1.0, duration),
        supply=Profile(initial=p0, events=supply_events),
        leak=Profile(initial=c0, events=leak_events),
        params=params,
        sensors=_sensors(noise_scale, seed=int(rng.integers(2**31))),
    )
    return DutyCycle(
        seed=seed,
        index=index,
        kind=kind,
        calibration=cal,
        test=test,
        leak_shape=leak_shape,
        leak_ratio=leak_ratio,
        leak_t=leak_t,
        supply_changes=tuple(changes),
        params=params,
        noise_scale=noise_scale,
    )


def scale_noise(dc: DutyCycle, factor: float) -> DutyCycle:
    """``dc`` with every sensor's noise (calibration segment and test) times ``factor``, the
    noise seeds kept: the same draws, scaled. A diagnostic: an error that stays when the
    noise is a tenth is the model's, not the sensors'
    (docs/decisions/0005-information-bound.md)."""
    if not factor >= 0.0:
        raise ValueError(f"noise factor must be >= 0, got {factor!r}")

    def scaled(sc: Scenario) -> Scenario:
        s = sc.sensors
        return sc.model_copy(
            update={"sensors": s.model_copy(update={k: getattr(s, k) * factor for k in _NOISE})}
        )

    return replace(
        dc,
        calibration=scaled(dc.calibration),
        test=scaled(dc.test),
        noise_scale=dc.noise_scale * factor,
    )


def ecu_noisy_x_j(dc: DutyCycle) -> DutyCycle:
    """``dc`` with the ECU closing its position loop on the jack LVDT's noisy reading in both
    segments (``SensorNoise.ecu_noisy_x_j``; the same draws), as an actuator's ECU does,
    instead of on the true x_J. A diagnostic: the suite's bench leaves the loop noise-free,
    so its current and spool follow the true jack (docs/evaluation.md, "An information
    bound on the suite's targets")."""

    def noisy_loop(sc: Scenario) -> Scenario:
        s = sc.sensors
        return sc.model_copy(update={"sensors": s.model_copy(update={"ecu_noisy_x_j": True})})

    return replace(dc, calibration=noisy_loop(dc.calibration), test=noisy_loop(dc.test))


def nominal_plant(dc: DutyCycle, frictionless: bool = False) -> DutyCycle:
    """``dc`` with its plant at the datasheet values (``EHAParams()``, none of ``_plant``'s
    tolerances) in both segments; the duty cycle, faults and noise are kept (the draws are
    made all the same). ``frictionless``: and no Coulomb or breakaway friction (F_d = F_s =
    0; the viscous c_v stays). A diagnostic: what stays is not the plants' tolerances
    (docs/decisions/0005-information-bound.md)."""
    params = {"f_d": 0.0, "f_s": 0.0} if frictionless else {}
    return replace(
        dc,
        calibration=dc.calibration.model_copy(update={"params": params}),
        test=dc.test.model_copy(update={"params": params}),
        params=dict(params),
    )


def suite(n: int, seed: int) -> list[DutyCycle]:
    """The first ``n`` duty cycles of suite ``seed``."""
    return [duty_cycle(seed, k) for k in range(n)]
