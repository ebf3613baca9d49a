"""Fleet simulator for validating the prognostics (docs/prognostics.md, "Fleet simulator").

Each unit gets a hidden wear law of its true C_Lk ratio r(t) against cumulative operating
hours t (C_Lk = r C_Lk,nominal):

- ``none``: r = 1;  ``linear``: r = 1 + k t;  ``exponential``: r = 1 + a (exp(b t) - 1);
- ``step``: r = 1 before t_s, r = 1 + s + k (t - t_s) after (a step at a random flight,
  then growth);

with the rates drawn so that the end of life (r reaching the fleet threshold) falls between
0.4 and 1.2 times the simulated hours, and unit-to-unit plant variation (mass, viscous and
dry friction, land underlap at a fixed port width, oil bulk modulus). Every flight is a short
segment of the duty cycle of ``scenarios/healthy_noise.toml`` on the HF bench at that flight's
leakage, with the scenario's sensor noise (seeded per unit and flight), through the real
monitor (``MonitorBank.update_arrays``, the unit's own baseline calibrated on its first flight
by ``service.calibration.calibrate``) and ``PeriodAccumulator``; one period per flight, whose
``op_time_s`` is the flight's operating time (the segment stands for the whole flight).
Units are independent, so they are simulated in parallel worker processes.

``evaluate`` predicts the RUL at every ``eval_every``-th flight from the history so far (the
fleet prior learned from every unit's history up to the same flight) and scores it with
``metrics.score_unit`` against the truth.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from multiprocessing import get_context

import numpy as np

from service.prognostics.metrics import LAMBDAS, score_unit
from service.store.records import AlarmEvent, Period

__all__ = [
    "FleetSimConfig",
    "UnitTruth",
    "draw_units",
    "simulate_unit",
    "run_fleet_sim",
    "evaluate",
    "WEAR_LAWS",
]

WEAR_LAWS: tuple[str, ...] = ("none", "linear", "exponential", "step")
C_LK_NOMINAL = 2e-13
FLIGHT_GAP_S = 60.0  # sample-time gap between two flights' segments (closes the period)


@dataclass(frozen=True)
class FleetSimConfig:
    """Fleet size, flights, seed, segment length [s], the fleet threshold (C_Lk ratio; None
    = ``threshold.leak_threshold``), evaluation cadence and horizon, worker processes."""

    actuators: int = 6
    flights: int = 20
    seed: int = 0
    segment_s: float = 2.0
    calibration_s: float = 4.0
    threshold_ratio: float | None = None
    eval_every: int = 1
    min_history: int = 5
    prior_every: int = 10
    horizon_h: float = 50.0
    warn_p: float = 0.2
    n_samples: int = 2000
    workers: int = 0  # 0: min(2, cpu count)

    def threshold(self) -> float:
        """The fleet threshold in use."""
        from service.prognostics.rul import default_threshold_ratio

        return (
            self.threshold_ratio if self.threshold_ratio is not None else default_threshold_ratio()
        )


@dataclass
class UnitTruth:
    """The hidden truth of one unit: wear law and its parameters, plant overrides, hours of
    each flight, true C_Lk ratio at each flight, end of life (hours and flights, inf if not
    reached at any time)."""

    actuator: str
    index: int
    law: str
    wear: dict[str, float]
    plant: dict[str, float]
    flight_hours: list[float]
    ratio: list[float] = field(default_factory=list)
    eol_h: float = math.inf
    eol_flight: float = math.inf
    flown: int = 0

    def ratio_at(self, t_h: float) -> float:
        """True C_Lk ratio at cumulative operating hours ``t_h``."""
        w = self.wear
        if self.law == "linear":
            return 1.0 + w["k"] * t_h
        if self.law == "exponential":
            return 1.0 + w["a"] * math.expm1(w["b"] * t_h)
        if self.law == "step":
            if t_h < w["t_s"]:
                return 1.0
            return 1.0 + w["s"] + w["k"] * (t_h - w["t_s"])
        return 1.0


def _eol_hours(law: str, w: dict[str, float], thr: float) -> float:
    if law == "linear":
        return (thr - 1.0) / w["k"]
    if law == "exponential":
        return math.log1p((thr - 1.0) / w["a"]) / w["b"]
    if law == "step":
        return w["t_s"] + (thr - 1.0 - w["s"]) / w["k"]
    return math.inf


def draw_units(cfg: FleetSimConfig) -> list[UnitTruth]:
    """The fleet's hidden truth (module docstring), reproducible from ``cfg.seed``."""
    from models.params import EHAParams

    rng = np.random.default_rng(cfg.seed)
    thr = cfg.threshold()
    p0 = EHAParams()
    units = []
    for i in range(cfg.actuators):
        law = WEAR_LAWS[i % len(WEAR_LAWS)] if i < len(WEAR_LAWS) else str(rng.choice(WEAR_LAWS))
        hpf = rng.uniform(1.0, 3.0)
        hours = (hpf * rng.uniform(0.8, 1.2, cfg.flights)).tolist()
        total = float(np.sum(hours))
        t_eol = rng.uniform(0.4, 1.2) * total
        w: dict[str, float] = {}
        if law == "linear":
            w["k"] = (thr - 1.0) / t_eol
        elif law == "exponential":
            w["b"] = rng.uniform(2.0, 4.0) / t_eol
            w["a"] = (thr - 1.0) / math.expm1(w["b"] * t_eol)
        elif law == "step":
            w["t_s"] = rng.uniform(0.15, 0.45) * total
            t_eol = max(t_eol, w["t_s"] + 0.25 * total)
            w["s"] = rng.uniform(0.5, 2.5)
            w["k"] = (thr - 1.0 - w["s"]) / (t_eol - w["t_s"])
        fr = rng.uniform(0.8, 1.3)
        u = p0.x_ss * rng.uniform(0.9, 1.2)
        plant = {
            "mass": p0.mass * rng.uniform(0.85, 1.3),
            "c_v": p0.c_v * rng.uniform(0.8, 1.2),
            "f_s": p0.f_s * fr,
            "f_d": p0.f_d * fr,
            "u1": u,
            "u2": u,
            "u3": u,
            "u4": u,
            "w": p0.w_eff,
            "beta_l": p0.beta_l * rng.uniform(0.75, 1.1),
        }
        unit = UnitTruth(f"FS{cfg.seed}-{i:03d}/eha", i, law, w, plant, hours)
        unit.eol_h = _eol_hours(law, w, thr)
        units.append(unit)
    return units


def _segment(unit: UnitTruth, flight: int, ratio: float, cfg: FleetSimConfig):
    """Measured signals of one flight's segment (HF bench + the scenario's sensor noise)."""
    from models.scenario import Profile
    from service.calibration import measured_run
    from service.scenarios import load_scenario

    base = load_scenario("healthy_noise")
    seed = int(np.random.SeedSequence([cfg.seed, unit.index, flight]).generate_state(1)[0])
    sc = base.model_copy(
        update={
            "name": f"{unit.actuator}#{flight}",
            "duration_s": cfg.calibration_s if flight == 0 else cfg.segment_s,
            "params": dict(unit.plant),
            "leak": Profile(initial=ratio * C_LK_NOMINAL),
            "sensors": base.sensors.model_copy(update={"seed": seed}),
        }
    )
    return measured_run(sc)[1]


def simulate_unit(unit: UnitTruth, cfg: FleetSimConfig) -> dict:
    """All flights of one unit (stops after the flight in which it reaches its end of life):
    periods (dicts), alarm events (dicts), the baseline, the truth, counts and wall time."""
    from service.calibration import calibrate, meas_channels
    from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS, MonitorBank, MonitorConfig
    from service.prognostics.indicators import PeriodAccumulator

    w0 = time.perf_counter()
    source = f"fleet-sim:{cfg.seed}"
    thr = cfg.threshold()
    cum = np.cumsum(unit.flight_hours)
    baseline = None
    bank = acc = None
    key = unit.actuator
    periods: list[dict] = []
    events: list[dict] = []
    false_alarms = 0
    truth_ratio: list[float] = []
    for k in range(cfg.flights):
        ratio = unit.ratio_at(float(cum[k] - cum[0]))
        truth_ratio.append(ratio)
        meas = _segment(unit, k, ratio, cfg)
        if baseline is None:
            baseline = calibrate(meas)
            bank = MonitorBank(MonitorConfig(), baseline, capacity=1)
            row = bank.index_of(key)
            acc = PeriodAccumulator(key, baseline.c_lk, source, EST_KEYS, HEALTH_KEYS, RES_KEYS)
        n = len(meas["t"])
        ch = meas_channels(meas)
        t = meas["t"] + k * (cfg.calibration_s + FLIGHT_GAP_S)
        rows = bank.update_arrays(np.full(n, row, np.int64), t, ch)
        acc.add_rows(
            rows.t, rows.est, rows.health, rows.res, counters=bank.counters_of(key), flight=k
        )
        for p in acc.flush():
            periods.append(replace(p, op_time_s=unit.flight_hours[k] * 3600.0).to_dict())
        clear = bank.config.alarms.leak_clear
        for ev in acc.alarm_events():
            events.append(asdict(ev))
            if ev.kind != "leak" or ratio < clear:
                false_alarms += 1
        if ratio >= thr:
            break
    unit.ratio = truth_ratio
    unit.flown = len(truth_ratio)
    if math.isfinite(unit.eol_h):
        unit.eol_h += float(cum[0])
        j = int(np.searchsorted(cum, unit.eol_h))
        prev = float(cum[j - 1]) if j > 0 else 0.0
        if j < len(cum):
            unit.eol_flight = j + (unit.eol_h - prev) / unit.flight_hours[j]
        else:
            unit.eol_flight = len(cum) + (unit.eol_h - float(cum[-1])) / float(
                np.mean(unit.flight_hours)
            )
    return {
        "truth": asdict(unit),
        "periods": periods,
        "events": events,
        "baseline": baseline.model_dump() if baseline is not None else None,
        "false_alarms": false_alarms,
        "segments": unit.flown,
        "wall_s": time.perf_counter() - w0,
    }


def _sim_job(args: tuple[UnitTruth, FleetSimConfig]) -> dict:
    return simulate_unit(*args)


def run_fleet_sim(
    cfg: FleetSimConfig,
    store=None,
    progress: Callable[[float], None] | None = None,
) -> dict:
    """Simulate the fleet; periods, baselines and alarms go to ``store`` (a ``HealthStore``)
    when given. Returns {"units": [simulate_unit results], "wall_s": ...}."""
    w0 = time.perf_counter()
    units = draw_units(cfg)
    workers = cfg.workers or min(2, os.cpu_count() or 1)
    results: list[dict] = []
    jobs = [(u, cfg) for u in units]

    def done(r: dict) -> None:  # each unit is stored as soon as it is simulated
        results.append(r)
        if store is not None:
            a = r["truth"]["actuator"]
            store.ensure_actuator(a)
            last = store.latest_baseline(a)
            if r["baseline"] is not None and (last is None or last.baseline != r["baseline"]):
                store.add_baseline(a, r["baseline"], f"fleet-sim:{cfg.seed} first flight")
            store.add_periods([Period.from_dict(p) for p in r["periods"]])
            if r["events"]:
                store.add_alarms([AlarmEvent(**e) for e in r["events"]])
        if progress:
            progress(len(results) / len(jobs))

    if workers <= 1 or len(units) <= 1:
        for job in jobs:
            done(_sim_job(job))
    else:
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as ex:
            for r in ex.map(_sim_job, jobs):
                done(r)
    return {"units": results, "wall_s": time.perf_counter() - w0}


def evaluate(
    results: list[dict],
    cfg: FleetSimConfig,
    progress=None,
    learn: Callable | None = None,
    predict: Callable | None = None,
) -> dict:
    """RUL predictions at every ``eval_every``-th flight from the history so far, scored
    against the truth (module docstring). ``learn(histories) -> prior`` (default
    ``learn_fleet_prior``) gets every unit's observable (t_h, y) up to the same flight;
    ``predict(history, prior, rul_config) -> (median RUL [h] or inf, warning) | None``
    (default ``rul_of_history``): another method can be scored on the same histories
    (bench/prognostics.py). Returns the metrics and per-unit details."""
    from service.prognostics.degradation import learn_fleet_prior
    from service.prognostics.rul import RulConfig, history_of, rul_of_history

    rcfg = RulConfig(
        threshold_ratio=cfg.threshold(), horizon_h=cfg.horizon_h, warn_p=cfg.warn_p,
        n_samples=cfg.n_samples, min_periods=cfg.min_history,
    )  # fmt: skip

    def _ours(h, prior, rc):
        res = rul_of_history(h, prior, rc)
        if res["status"] != "ok":
            return None
        med = res["median_h"] if res["median_h"] is not None else math.inf
        return med, bool(res["warning"])

    learn = learn or learn_fleet_prior
    predict = predict or _ours
    hist = {}
    for r in results:
        a = r["truth"]["actuator"]
        hist[a] = history_of(a, [Period.from_dict(p) for p in r["periods"]])
    truths = {r["truth"]["actuator"]: r["truth"] for r in results}
    preds: dict[str, list[tuple[float, float, bool]]] = {a: [] for a in hist}
    prior = None
    max_k = max(len(h.t_h) for h in hist.values())
    ks = list(range(cfg.min_history - 1, max_k, max(1, cfg.eval_every)))
    every = max(1, cfg.prior_every // max(1, cfg.eval_every))
    for step, k in enumerate(ks):
        if prior is None or step % every == 0:
            obs = []
            for h in hist.values():
                ok = np.isfinite(h.y[: k + 1])
                obs.append((h.t_h[: k + 1][ok], h.y[: k + 1][ok]))
            prior = learn(obs)
        for a, h in hist.items():
            if k >= len(h.t_h):
                continue
            sub = replace(h, t_h=h.t_h[: k + 1], y=h.y[: k + 1])
            res = predict(sub, prior, rcfg)
            if res is None:
                continue
            preds[a].append((float(sub.t_h[-1]), float(res[0]), bool(res[1])))
        if progress:
            progress((step + 1) / len(ks))
    by_law: dict[str, dict[str, list]] = {law: {"acc": [], "ra": [], "ph": []} for law in WEAR_LAWS}
    units = []
    healthy = 0
    false_warn = 0
    for a, p in preds.items():
        tr = truths[a]
        warned = any(w for _, _, w in p)
        row = {
            "actuator": a,
            "law": tr["law"],
            "eol_h": tr["eol_h"],
            "predictions": len(p),
            "warned": warned,
        }
        if tr["law"] == "none":
            healthy += 1
            false_warn += int(warned)
        elif (
            p
            and tr["eol_h"] <= float(np.sum(tr["flight_hours"][: tr["flown"]]))
            and p[0][0] < tr["eol_h"]
        ):
            s = score_unit([x[0] for x in p], [x[1] for x in p], tr["eol_h"])
            by_law[tr["law"]]["acc"].extend(s.accurate)
            by_law[tr["law"]]["ra"].append(s.relative_accuracy[0])
            by_law[tr["law"]]["ph"].append(s.horizon_frac)
            row.update(
                accurate=list(s.accurate), ra_05=s.relative_accuracy[0], ph_frac=s.horizon_frac
            )
        units.append(row)

    def pct(v: list) -> float | None:
        return 100.0 * float(np.mean(v)) if v else None

    def ra_pct(v: list) -> float | None:
        v = [max(x, 0.0) for x in v]  # a missed prediction (inf) scores 0, not -inf
        return 100.0 * float(np.mean(v)) if v else None

    target = ("linear", "exponential")
    acc_t = [x for law in target for x in by_law[law]["acc"]]
    ra_t = [x for law in target for x in by_law[law]["ra"]]
    ph_t = [x for law in target for x in by_law[law]["ph"]]
    return {
        "alpha_lambda_pct": pct(acc_t),
        "relative_accuracy_pct": ra_pct(ra_t),
        "prognostic_horizon_pct": pct(ph_t),
        "scored_units": len(ra_t),
        "by_law": {
            law: {
                "units": len(v["ra"]),
                "alpha_lambda_pct": pct(v["acc"]),
                "relative_accuracy_pct": ra_pct(v["ra"]),
                "prognostic_horizon_pct": pct(v["ph"]),
            }
            for law, v in by_law.items()
            if law != "none"
        },
        "healthy_units": healthy,
        "false_rul_warnings": false_warn,
        "lambdas": list(LAMBDAS),
        "units": units,
    }
