"""Virtual actuator: the HF EHA bench paced by the wall clock, publishing its sensors on Zenoh.

The plant is ``models.eha.EHAStepper`` (physics.md section 3) driven by a scenario's command,
load and supply profiles (repeated with period ``duration_s`` so the actuator can run for as
long as it is asked to), with the scenario's sensor noise (``SensorNoise``) added to each
measured channel. Faults commanded on ``fleet/{aircraft}/{actuator}/@fault`` act on the plant
(leakage ``c_lk`` step or ramp, supply ``P_SR`` drop) or on the sensors (bias, dropout), and
``clear`` removes them. The fault state machine (``FaultState``) and the sample generator
(``VirtualActuator.produce``) are pure in-memory objects; ``VirtualActuator.serve`` adds the
wall-clock pacing and the Zenoh I/O.

Sample times: ``t = t_origin + seq / rate_hz`` with ``t_origin`` the wall-clock (Unix) time at
start, so a restarted actuator keeps a monotonic time axis while its sequence restarts at 0.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from models.scenario import Scenario

__all__ = [
    "SENSOR_CHANNELS",
    "FaultRefused",
    "FaultState",
    "VirtualActuator",
    "LEAK_RANGE",
    "SUPPLY_RANGE",
]

log = logging.getLogger("servowatch.actuator")

#: measured channels a sensor fault may target
SENSOR_CHANNELS: tuple[str, ...] = ("i", "x_s", "x_j", "p1", "p2", "p_sr")
#: accepted leakage coefficient for a ``leak`` fault [m^3/s/Pa]
LEAK_RANGE: tuple[float, float] = (0.0, 1e-10)
#: accepted supply pressure P_SR for a ``supply`` fault [Pa]
SUPPLY_RANGE: tuple[float, float] = (1e5, 40e6)
#: largest sensor bias accepted per channel (SI): 50 mm, 1 A, 50 MPa
_BIAS_LIMIT = {"i": 1.0, "x_s": 0.05, "x_j": 0.05, "p1": 50e6, "p2": 50e6, "p_sr": 50e6}


class FaultRefused(ValueError):  # noqa: N818 (a refusal, not an internal error)
    """A fault command that cannot be applied; the message says why."""


@dataclass
class _Ramp:
    """A value moving linearly from ``v0`` at ``t0`` to ``v1`` at ``t0 + ramp_s``."""

    t0: float
    v0: float
    v1: float
    ramp_s: float
    until: float | None = None  # auto-clear time (sim s), None = permanent

    def at(self, t: float) -> float:
        if self.ramp_s <= 0 or t >= self.t0 + self.ramp_s:
            return self.v1 if t >= self.t0 else self.v0
        return self.v0 + (self.v1 - self.v0) * max(0.0, (t - self.t0) / self.ramp_s)


@dataclass
class FaultState:
    """Faults active on one virtual actuator, as functions of simulation time ``t`` [s].

    - ``leak``: plant cross-port leakage C_Lk [m^3/s/Pa] moves to ``value`` (step, or linear
      over ``ramp_s`` from the value in force when the command arrives).
    - ``supply``: plant P_SR [Pa] moves to ``value`` (step or ramp), replacing the scenario's.
    - ``sensor_bias``: ``value`` (SI) added to measured ``channel``.
    - ``dropout``: ``channel`` is missing from the samples; no channel = no samples at all.
    - ``clear``: removes the fault of kind ``channel`` (``leak``, ``supply``, a sensor channel)
      or every fault when ``channel`` is None; plant faults return to the scenario's value,
      over ``ramp_s`` if given.
    ``duration_s`` (any kind but clear) makes the fault clear itself after that time.
    """

    leak: _Ramp | None = None
    supply: _Ramp | None = None
    bias: dict[str, tuple[float, float | None]] = field(default_factory=dict)
    dropout: dict[str | None, float | None] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    # -- plant ---------------------------------------------------------------------------
    def c_lk(self, t: float, nominal: float) -> float:
        """Plant leakage coefficient at ``t`` given the scenario's ``nominal`` value."""
        r = self.leak
        if r is None:
            return nominal
        if r.until is not None and t >= r.until:
            self.leak = None
            return nominal
        return r.at(t) if not math.isnan(r.v1) else nominal

    def p_sr(self, t: float, nominal: float) -> float:
        """Plant supply pressure P_SR at ``t`` given the scenario's ``nominal`` value."""
        r = self.supply
        if r is None:
            return nominal
        if r.until is not None and t >= r.until:
            self.supply = None
            return nominal
        return r.at(t)

    # -- sensors -------------------------------------------------------------------------
    def silent(self, t: float) -> bool:
        """True while a whole-actuator dropout is in force (no samples published)."""
        until = self.dropout.get(None, -1.0)
        if until == -1.0:
            return False
        if until is not None and t >= until:
            self.dropout.pop(None, None)
            return False
        return True

    def corrupt(self, t: float, meas: dict[str, float | None]) -> dict[str, float | None]:
        """Apply sensor biases and channel dropouts to one measured sample (in place)."""
        for ch, (b, until) in list(self.bias.items()):
            if until is not None and t >= until:
                del self.bias[ch]
            elif meas.get(ch) is not None:
                meas[ch] = meas[ch] + b
        for ch, until in list(self.dropout.items()):
            if ch is None:
                continue
            if until is not None and t >= until:
                del self.dropout[ch]
            else:
                meas[ch] = None
        return meas

    # -- commands ------------------------------------------------------------------------
    def apply(
        self,
        cmd: Any,
        t: float,
        nominal_c_lk: float,
        nominal_p_sr: float,
    ) -> str:
        """Apply a ``FaultCommand`` at simulation time ``t``; return a one-line description.

        Raises ``FaultRefused`` (nothing changed) for a value that is missing, not finite or
        out of range, an unknown channel, or a negative ramp or duration.
        """
        kind = cmd.kind
        value = cmd.value
        ramp_s = float(cmd.ramp_s or 0.0)
        channel = cmd.channel
        duration = cmd.duration_s
        if not math.isfinite(ramp_s) or ramp_s < 0:
            raise FaultRefused(f"ramp_s must be finite and >= 0, got {ramp_s}")
        if duration is not None and (not math.isfinite(duration) or duration <= 0):
            raise FaultRefused(f"duration_s must be finite and > 0, got {duration}")
        until = None if duration is None else t + float(duration)
        if kind in ("leak", "supply", "sensor_bias") and (
            value is None or not math.isfinite(value)
        ):
            raise FaultRefused(f"{kind} needs a finite value, got {value}")
        if kind == "leak":
            lo, hi = LEAK_RANGE
            if not lo <= value <= hi:
                raise FaultRefused(f"leak value {value:g} m^3/s/Pa outside [{lo:g}, {hi:g}]")
            v0 = self.c_lk(t, nominal_c_lk)
            self.leak = _Ramp(t, v0, float(value), ramp_s, until)
            how = f"over {ramp_s:g} s" if ramp_s > 0 else "step"
            return f"leak c_lk {v0:.3g} -> {value:.3g} m^3/s/Pa ({how})"
        if kind == "supply":
            lo, hi = SUPPLY_RANGE
            if not lo <= value <= hi:
                raise FaultRefused(f"supply value {value:g} Pa outside [{lo:g}, {hi:g}]")
            v0 = self.p_sr(t, nominal_p_sr)
            self.supply = _Ramp(t, v0, float(value), ramp_s, until)
            return f"supply P_SR {v0 / 1e6:.3g} -> {value / 1e6:.3g} MPa"
        if kind == "sensor_bias":
            if channel not in SENSOR_CHANNELS:
                raise FaultRefused(
                    f"sensor_bias needs channel in {list(SENSOR_CHANNELS)}, got {channel}"
                )
            if abs(value) > _BIAS_LIMIT[channel]:
                raise FaultRefused(
                    f"bias {value:g} on {channel} exceeds the limit {_BIAS_LIMIT[channel]:g}"
                )
            self.bias[channel] = (float(value), until)
            return f"sensor bias {value:g} on {channel}"
        if kind == "dropout":
            if channel is not None and channel not in SENSOR_CHANNELS:
                raise FaultRefused(
                    f"dropout channel must be one of {list(SENSOR_CHANNELS)} or none"
                )
            self.dropout[channel] = until
            what = channel if channel is not None else "all channels (no samples)"
            return f"dropout of {what}" + (f" for {duration:g} s" if duration else "")
        if kind == "clear":
            return self._clear(channel, t, ramp_s, nominal_c_lk, nominal_p_sr)
        raise FaultRefused(f"unknown fault kind {kind!r}")

    def _clear(self, what: str | None, t: float, ramp_s: float, c_lk0: float, p_sr0: float) -> str:
        valid = (None, "leak", "supply", "all", *SENSOR_CHANNELS)
        if what not in valid:
            raise FaultRefused(
                f"clear channel must be leak, supply, all or one of {SENSOR_CHANNELS}"
            )
        done: list[str] = []
        if what in (None, "all", "leak") and self.leak is not None:
            v = self.c_lk(t, c_lk0)
            self.leak = _Ramp(t, v, c_lk0, ramp_s, t + ramp_s) if ramp_s > 0 else None
            done.append("leak")
        if what in (None, "all", "supply") and self.supply is not None:
            v = self.p_sr(t, p_sr0)
            self.supply = _Ramp(t, v, p_sr0, ramp_s, t + ramp_s) if ramp_s > 0 else None
            done.append("supply")
        for ch in SENSOR_CHANNELS:
            if what in (None, "all", ch):
                if self.bias.pop(ch, None) is not None:
                    done.append(f"bias {ch}")
                if ch in self.dropout:
                    del self.dropout[ch]
                    done.append(f"dropout {ch}")
        if what in (None, "all") and None in self.dropout:
            del self.dropout[None]
            done.append("dropout all")
        return "cleared " + (", ".join(done) if done else "nothing (no active fault)")

    def active(self, t: float, c_lk0: float, p_sr0: float) -> list[dict]:
        """The faults in force at ``t``, as plain dicts (for ``FaultAck.active``)."""
        out: list[dict] = []
        if self.leak is not None:
            out.append(
                {
                    "kind": "leak",
                    "value": self.c_lk(t, c_lk0),
                    "target": self.leak.v1,
                    "until": self.leak.until,
                }
            )
        if self.supply is not None:
            out.append(
                {
                    "kind": "supply",
                    "value": self.p_sr(t, p_sr0),
                    "target": self.supply.v1,
                    "until": self.supply.until,
                }
            )
        for ch, (b, until) in self.bias.items():
            out.append({"kind": "sensor_bias", "channel": ch, "value": b, "until": until})
        for ch, until in self.dropout.items():
            out.append({"kind": "dropout", "channel": ch, "until": until})
        return out


def advanced_publisher(session, key: str, cache_messages: float, heartbeat_s: float = 0.5):
    """A ``zenoh.ext`` advanced publisher on ``key`` for measurements: reliable, blocking,
    a cache of the last ``cache_messages`` messages (answered to subscribers that detect a
    miss), sequence numbers with a heartbeat every ``heartbeat_s`` [s] (so a lost last message
    is detected too) and publisher detection (late-joining subscribers query the cache)."""
    import zenoh
    from zenoh import ext as zx

    n = int(cache_messages)
    if not (1 <= n <= 10_000_000):
        raise ValueError(f"cache_s: gives {n} cached messages, need 1..10000000")
    return zx.declare_advanced_publisher(
        session,
        key,
        congestion_control=zenoh.CongestionControl.BLOCK,
        reliability=zenoh.Reliability.RELIABLE,
        cache=zx.CacheConfig(max_samples=n),
        sample_miss_detection=zx.MissDetectionConfig(heartbeat=heartbeat_s),
        publisher_detection=True,
    )


def _default_stepper_factory(params, step_s: float):
    from models.eha import EHAStepper

    return EHAStepper(params, valve="HF", step_s=step_s)


class VirtualActuator:
    """The HF bench of ``scenario`` sampled at ``rate_hz`` with sensor noise and faults.

    ``produce(n)`` advances the plant by ``n`` sample periods and returns ``n`` sample dicts
    (keys seq, t, x_cmd, i, x_s, x_j, p1, p2, p_sr; SI, absolute pressures; a channel under
    dropout is None; nothing is returned for a sample under a whole-actuator dropout, its
    sequence number is consumed). Profiles repeat with period ``scenario.duration_s``.
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        rate_hz: float = 1000.0,
        t_origin: float = 0.0,
        seed: int | None = None,
        stepper_factory: Callable | None = None,
    ) -> None:
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.scenario = scenario
        self.params = scenario.eha_params()
        self.rate_hz = float(rate_hz)
        self.t_origin = float(t_origin)
        h = scenario.step_s
        self.steps_per_sample = max(1, int(round(1.0 / (self.rate_hz * h))))
        self.step_s = 1.0 / (self.rate_hz * self.steps_per_sample)
        self.stepper = (stepper_factory or _default_stepper_factory)(self.params, self.step_s)
        self.faults = FaultState()
        noise = scenario.sensors
        self.sigma = {
            "i": noise.current_a,
            "x_s": noise.x_s_m,
            "x_j": noise.x_j_m,
            "p1": noise.p_pa,
            "p2": noise.p_pa,
            "p_sr": noise.p_sr_pa,
        }
        self.rng = np.random.default_rng(noise.seed if seed is None else seed)
        self.seq = 0  # next sequence number
        self.n_steps = 0  # integration steps done
        self._started = False
        self.period = scenario.duration_s
        self.truth: dict[str, float] = {}

    # -- inputs ----------------------------------------------------------------------------
    def _nominal(self, t_sim: float) -> dict[str, float]:
        tt = np.array([t_sim % self.period])
        u = self.scenario.inputs(tt, self.params)
        return {k: float(v[0]) for k, v in u.items()}

    @property
    def t_sim(self) -> float:
        """Simulation time of the plant [s]."""
        return self.n_steps * self.step_s

    def apply_fault(self, cmd: Any) -> tuple[bool, str, list[dict]]:
        """Apply a fault command now; return (ok, message, active faults)."""
        with self.faults.lock:
            t = self.t_sim
            u = self._nominal(t)
            try:
                msg = self.faults.apply(cmd, t, u["c_lk"], u["p_sr"])
                ok = True
            except FaultRefused as e:
                msg, ok = f"refused: {e}", False
            active = self.faults.active(t, u["c_lk"], u["p_sr"])
            for d in active:  # when (sample clock) the actuator answered this command
                d["t_ack"] = self.t_origin + t
            return ok, msg, active

    # -- simulation ----------------------------------------------------------------------
    def produce(self, n: int) -> list[dict[str, float | None]]:
        """Advance ``n`` sample periods; return the published samples (see class doc)."""
        out: list[dict[str, float | None]] = []
        if n <= 0:
            return out
        k = self.steps_per_sample
        h = self.step_s
        # inputs held over each integration step, evaluated at its start (vectorised)
        t_steps = (self.n_steps + np.arange(n * k)) * h
        u = self.scenario.inputs(np.mod(t_steps, self.period), self.params)
        x_cmd, f_r, p_sr0, c_lk0 = (u[name].tolist() for name in ("x_cmd", "f_r", "p_sr", "c_lk"))
        noise = self.rng.standard_normal((n, len(SENSOR_CHANNELS)))
        sig = [self.sigma[ch] for ch in SENSOR_CHANNELS]
        # the ECU's position feedback: the true x_J, or the LVDT's reading (scenario option)
        c_xj = SENSOR_CHANNELS.index("x_j")
        fb_gain = sig[c_xj] if self.scenario.sensors.ecu_noisy_x_j else 0.0
        advance = self.stepper.advance
        faults = self.faults
        for i in range(n):
            with faults.lock:
                # sample seq is the plant at t = seq / rate, taken before its k steps
                j0 = i * k
                t = t_steps[j0]
                c_lk = faults.c_lk(t, c_lk0[j0]) if faults.leak is not None else c_lk0[j0]
                p_sr = faults.p_sr(t, p_sr0[j0]) if faults.supply is not None else p_sr0[j0]
                if not self._started:
                    advance(0, x_cmd[j0], f_r[j0], p_sr, c_lk)  # rest state at these inputs
                    self._started = True
                s = self.stepper.signals()
                self.truth = {
                    "t": t,
                    "c_lk": float(c_lk),
                    "p_sr": float(p_sr),
                    "f_r": float(f_r[j0]),
                }
                seq = self.seq
                self.seq += 1
                silent = bool(faults.dropout) and faults.silent(t)
                if not silent:
                    meas: dict[str, float | None] = {"x_cmd": float(x_cmd[j0])}
                    for c, ch in enumerate(SENSOR_CHANNELS):
                        meas[ch] = float(s[ch]) + sig[c] * float(noise[i, c])
                    meas["p_sr"] = float(p_sr) + sig[-1] * float(noise[i, -1])
                    if faults.bias or faults.dropout:
                        faults.corrupt(t, meas)
                fb = fb_gain * float(noise[i, c_xj])
                for j in range(j0, j0 + k):
                    if j > j0:
                        t = t_steps[j]
                        leak, supply = faults.leak, faults.supply
                        c_lk = c_lk0[j] if leak is None else faults.c_lk(t, c_lk0[j])
                        p_sr = p_sr0[j] if supply is None else faults.p_sr(t, p_sr0[j])
                    advance(1, x_cmd[j] - fb, f_r[j], p_sr, c_lk)
                self.n_steps += k
            if silent:
                continue
            out.append({"seq": seq, "t": self.t_origin + seq / self.rate_hz, **meas})
        return out

    # -- Zenoh -----------------------------------------------------------------------------
    def serve(
        self,
        session,
        aircraft: str,
        actuator: str,
        *,
        stop: threading.Event,
        duration_s: float | None = None,
        samples_per_msg: int = 10,
        fmt: str | None = None,
        on_batch: Callable[[list[dict]], None] | None = None,
        cache_s: float = 10.0,
    ) -> dict[str, int]:
        """Publish samples paced by the wall clock until ``stop`` is set or ``duration_s``.

        Serves fault commands on the ``@fault`` queryable (answered with a ``FaultAck``)
        and holds liveliness tokens on ``.../alive`` and ``.../@virtual`` (the latter tells
        ``servowatch inject`` that this key is a virtual actuator's). Returns counters.

        Publishes through a ``zenoh.ext`` advanced publisher (``advanced_publisher``) whose
        cache holds the last ``cache_s`` seconds of messages, so a subscriber recovers what a
        router restart or a short disconnect lost (docs/messages.md, "Publishing").
        """

        from service.wire import messages as m

        key = m.KEY_MEAS.format(aircraft=aircraft, actuator=actuator)
        fkey = m.KEY_FAULT.format(aircraft=aircraft, actuator=actuator)
        akey = m.KEY_ALIVE.format(aircraft=aircraft, actuator=actuator)
        counters = {"samples": 0, "messages": 0, "faults_ok": 0, "faults_refused": 0, "late": 0}

        def on_query(query) -> None:
            try:
                raw = query.payload.to_bytes() if query.payload is not None else b""
                cmd = m.FaultCommand.model_validate_json(raw or b"{}")
            except Exception as e:  # pydantic.ValidationError, JSON errors
                ack = m.FaultAck(ok=False, message=f"refused: invalid command: {e}", active=[])
            else:
                ok, msg, active = self.apply_fault(cmd)
                ack = m.FaultAck(ok=ok, message=msg, active=active)
            counters["faults_ok" if ack.ok else "faults_refused"] += 1
            log.info("fault command on %s: %s", fkey, ack.message)
            query.reply(query.key_expr, ack.model_dump_json().encode())

        spm = max(1, int(samples_per_msg))
        pub = advanced_publisher(session, key, cache_s * self.rate_hz / spm)
        qbl = session.declare_queryable(fkey, on_query)
        token = session.liveliness().declare_token(akey)
        vtoken = session.liveliness().declare_token(
            m.KEY_VIRTUAL.format(aircraft=aircraft, actuator=actuator)
        )
        enc_kw = {} if fmt is None else {"fmt": fmt}
        total = None if duration_s is None else int(round(duration_s * self.rate_hz))
        cap = max(spm, int(self.rate_hz * 0.1) // spm * spm)  # at most 0.1 s per burst
        w0 = time.monotonic()
        produced = 0
        try:
            while not stop.is_set():
                left = None if total is None else total - produced
                if left is not None and left <= 0:
                    break
                need = spm if left is None else min(spm, left)
                due = int((time.monotonic() - w0) * self.rate_hz) - produced
                if due < need:
                    stop.wait((need - due) / self.rate_hz)
                    continue
                if due > self.rate_hz:  # more than 1 s behind: the plant cannot keep up
                    counters["late"] += 1
                n = min(due, cap) if left is None else min(due, cap, left)
                if n >= spm:
                    n -= n % spm
                samples = self.produce(n)
                produced += n
                for j in range(0, len(samples), spm):
                    chunk = samples[j : j + spm]
                    if not chunk:
                        continue
                    pub.put(m.encode_meas(chunk, **enc_kw))
                    counters["messages"] += 1
                    counters["samples"] += len(chunk)
                if on_batch is not None:
                    on_batch(samples)
        finally:
            vtoken.undeclare()
            token.undeclare()
            qbl.undeclare()
            pub.undeclare()
        return counters
