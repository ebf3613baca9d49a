"""Fleet simulator for validating the prognostics (docs/prognostics.md, "Fleet simulator").

The simulator makes what a user has, a folder of measurement logs, and takes them the user's
way: one MCAP log per unit and flight (``/fleet/{aircraft}/{actuator}/meas`` with its
``servowatch.flight`` record, ``service.log.flightrec``), the unit's baseline calibrated on its
flight 0 (``service.monitor.calibration.calibrate``, as ``servowatch calibrate --log``), and every
log ingested by ``service.replay.replay_many`` (the code of ``servowatch replay``: monitor,
periods, flights, calendar time, alarms). No period is written any other way.

Each unit gets a hidden wear law of its true C_Lk ratio r against its damage d (operating
hours; for ``load`` hours times the flight's load factor squared; for ``usage`` the flight's
load-weighted jack travel, hours x load x amplitude), C_Lk = r C_Lk,nominal:

- ``none``: r = 1;  ``linear``: r = 1 + k d;  ``exponential``: r = 1 + a (exp(b d) - 1);
- ``step``: r = 1 before d_s, r = 1 + s + k (d - d_s) after;
- ``power``: r = 1 + k d^p, p in [1.5, 3] (outside the RUL's model set);
- ``load``: r = 1 + k sum(hours x load^2) (wear that speeds up with load; outside it too);
- ``knee``: r = 1 + k d up to a knee d_k, then m = 4-8 times faster, linear, without a jump;
- ``usage``: r = 1 + k sum(hours x load x amplitude) (wear that follows the flight's
  load-weighted travel, which the monitor measures per period);

with the rates drawn so that the end of life (r reaching the fleet threshold) falls between
0.4 and 1.2 times the simulated hours. What varies between units and flights: plant
(mass, viscous and dry friction, land underlap, oil bulk modulus), sensor noise (x 0.8-1.5),
operating hours per flight, the operator's profile (mean load x 0.8-1.2 of the scenario's
4 kN, mean command amplitude x 0.85-1.15) and about it the load (x 0.65-1.35) and command
amplitude (x 0.75-1.25) of each flight, 1-3 flights a day with a fifth of the days missed, and the log length (the
typical ``segment_s``, a short ground test, or three times longer). Every log is the duty
cycle of ``scenarios/healthy_noise.toml`` on the HF bench at the flight's leakage.
Units are independent, so their logs are simulated in parallel worker processes.

``evaluate`` predicts the RUL after each flight from the stored history so far and scores it
against the truth on the life axis of flights.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from service.monitor.model_choice import DEFAULT_MODEL
from service.prognostics.metrics import LAMBDAS, score_unit

__all__ = [
    "FleetSimConfig",
    "UnitTruth",
    "draw_units",
    "simulate_unit",
    "run_fleet_sim",
    "evaluate",
    "evaluate_store",
    "kendall_tau",
    "mid_life_taus",
    "WEAR_LAWS",
    "MODEL_LAWS",
]

WEAR_LAWS: tuple[str, ...] = (
    "none", "linear", "exponential", "step", "power", "load", "knee", "usage",
)  # fmt: skip
MODEL_LAWS: tuple[str, ...] = ("none", "linear", "exponential", "step", "knee")
"""The wear laws that are also models of the RUL (``degradation.MODELS``)."""
C_LK_NOMINAL = 2e-13
EPOCH0 = 1.7e9  # calendar time of the fleet's first day [Unix s]
F_R_NOMINAL = 4000.0  # the scenario's load [N]


@dataclass(frozen=True)
class FleetSimConfig:
    """Fleet size, flights, seed, typical log length per flight [s] (each flight's log is
    drawn from a few seconds to several times it), the calibration flight's [s], the fleet
    threshold (C_Lk ratio; None = ``threshold.leak_threshold``), evaluation cadence, horizon
    (flights), worker processes, the monitor's process model, where the logs go (None: a
    temporary folder), and the RUL's opt-in Student-t readings and trend model
    (``RulConfig.robust_trend``)."""

    actuators: int = 6
    flights: int = 20
    seed: int = 0
    segment_s: float = 2.0
    calibration_s: float = 4.0
    threshold_ratio: float | None = None
    eval_every: int = 1
    min_history: int = 8
    prior_every: int = 5
    horizon_h: float = 50.0
    horizon_flights: float = 20.0
    warn_p: float = 0.2
    n_samples: int = 2000
    workers: int = 0  # 0: min(2, cpu count)
    model: str = DEFAULT_MODEL
    log_dir: str | None = None
    robust_trend: bool = False

    def threshold(self) -> float:
        """The fleet threshold in use."""
        from service.prognostics.rul import default_threshold_ratio

        return (
            self.threshold_ratio if self.threshold_ratio is not None else default_threshold_ratio()
        )


@dataclass
class UnitTruth:
    """The hidden truth of one unit: wear law and parameters, plant overrides, per flight
    (simulated ones and a schedule beyond, for the end of life) its operating hours, load
    factor, calendar start, log length, the true C_Lk ratio at each flown flight, and the end
    of life on the life axis of flights (the crossing between two flights, interpolated; inf
    if none within the schedule) and in hours."""

    actuator: str
    index: int
    law: str
    wear: dict[str, float]
    plant: dict[str, float]
    flight_hours: list[float]
    flight_load: list[float] = field(default_factory=list)
    flight_start_unix: list[float] = field(default_factory=list)
    log_s: list[float] = field(default_factory=list)
    noise: float = 1.0
    ratio: list[float] = field(default_factory=list)
    eol_h: float = math.inf
    eol_flight: float = math.inf
    flown: int = 0
    usage_h: float = math.nan  # mean operating hours per flight (the draws' scale)
    flight_amp: list[float] = field(default_factory=list)  # command amplitude factor
    profile: dict[str, float] = field(default_factory=dict)  # operator's mean load, amplitude

    def amp(self, flight: int) -> float:
        """Command amplitude factor of a flight (flight 0, the calibration: 1)."""
        if flight == 0:
            return 1.0
        if self.flight_amp:
            return float(self.flight_amp[flight])
        return 0.75 + 0.5 * ((flight * 0.618034) % 1.0)  # truth files before the profiles

    def increments(self) -> np.ndarray:
        """Damage of each flight of the schedule: operating hours (``load``: times the load
        factor squared; ``usage``: times the load and the amplitude factor)."""
        h = np.asarray(self.flight_hours, float)
        if self.law == "load":
            h = h * np.asarray(self.flight_load, float) ** 2
        elif self.law == "usage":
            amp = np.array([self.amp(k) for k in range(len(h))])
            h = h * np.asarray(self.flight_load, float) * amp
        return h

    def damage(self) -> np.ndarray:
        """Damage before each flight of the schedule (``increments`` summed)."""
        return np.concatenate(([0.0], np.cumsum(self.increments())[:-1]))

    def ratio_at(self, d: float) -> float:
        """True C_Lk ratio at damage ``d`` (operating hours for every law but ``load``)."""
        w = self.wear
        if self.law in ("linear", "load", "usage"):
            return 1.0 + w["k"] * d
        if self.law == "knee":
            return 1.0 + w["k"] * min(d, w["d_k"]) + w["m"] * w["k"] * max(d - w["d_k"], 0.0)
        if self.law == "exponential":
            return 1.0 + w["a"] * math.expm1(w["b"] * d)
        if self.law == "power":
            return 1.0 + w["k"] * d ** w["p"]
        if self.law == "step":
            if d < w["t_s"]:
                return 1.0
            return 1.0 + w["s"] + w["k"] * (d - w["t_s"])
        return 1.0

    def ratios(self) -> np.ndarray:
        """True ratio at each flight of the schedule."""
        return np.array([self.ratio_at(float(d)) for d in self.damage()])


def _draw_wear(law: str, rng: np.random.Generator, thr: float, total: float, lsq: float):
    t_eol = rng.uniform(0.4, 1.2) * total
    w: dict[str, float] = {}
    if law == "linear":
        w["k"] = (thr - 1.0) / t_eol
    elif law == "exponential":
        w["b"] = rng.uniform(2.0, 4.0) / t_eol
        w["a"] = (thr - 1.0) / math.expm1(w["b"] * t_eol)
    elif law == "power":
        w["p"] = rng.uniform(1.5, 3.0)
        w["k"] = (thr - 1.0) / t_eol ** w["p"]
    elif law in ("load", "usage"):  # lsq: the mean damage per hour
        w["k"] = (thr - 1.0) / (t_eol * lsq)
    elif law == "knee":
        f, m = rng.uniform(0.3, 0.6), rng.uniform(4.0, 8.0)
        w["d_k"], w["m"] = f * t_eol, m
        w["k"] = (thr - 1.0) / (f * t_eol + m * (1.0 - f) * t_eol)
    elif law == "step":
        w["t_s"] = rng.uniform(0.15, 0.45) * total
        t_eol = max(t_eol, w["t_s"] + 0.25 * total)
        w["s"] = rng.uniform(0.5, 2.5)
        w["k"] = (thr - 1.0 - w["s"]) / (t_eol - w["t_s"])
    return w


def draw_units(cfg: FleetSimConfig) -> list[UnitTruth]:
    """The fleet's hidden truth (module docstring), reproducible from ``cfg.seed``."""
    from models.params import EHAParams

    rng = np.random.default_rng(cfg.seed)
    thr = cfg.threshold()
    p0 = EHAParams()
    units = []
    n_sched = 4 * cfg.flights  # the schedule beyond the simulated flights (end of life)
    for i in range(cfg.actuators):
        law = WEAR_LAWS[i % len(WEAR_LAWS)] if i < len(WEAR_LAWS) else str(rng.choice(WEAR_LAWS))
        hpf = rng.uniform(1.0, 3.0)
        hours = hpf * rng.uniform(0.8, 1.2, n_sched)
        # the operator's profile, and each flight's load and amplitude about it
        prof = {"load": float(rng.uniform(0.8, 1.2)), "amp": float(rng.uniform(0.85, 1.15))}
        load = prof["load"] * rng.uniform(0.65, 1.35, n_sched)
        amp = prof["amp"] * rng.uniform(0.75, 1.25, n_sched)
        total = float(np.sum(hours[: cfg.flights]))
        scale = {"load": float(np.mean(load**2)), "usage": float(np.mean(load * amp))}
        w = _draw_wear(law, rng, thr, total, scale.get(law, 1.0))
        # calendar: 1-3 flights a day, a fifth of the days without a flight
        per_day = int(rng.integers(1, 4))
        starts, day = [], 0
        while len(starts) < n_sched:
            if rng.uniform() >= 0.2:
                starts += [EPOCH0 + 86400.0 * day + 3600.0 * (6 + 4 * j) for j in range(per_day)]
            day += 1
        # log length: mostly the typical one, some ground-test short, some long
        kind = rng.choice(3, n_sched, p=[0.6, 0.25, 0.15])
        log_s = np.where(
            kind == 0, cfg.segment_s,
            np.where(kind == 1, max(1.5, 0.5 * cfg.segment_s), 3.0 * cfg.segment_s),
        )  # fmt: skip
        log_s[0] = cfg.calibration_s
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
        unit = UnitTruth(
            f"FS{cfg.seed}-{i:03d}/eha", i, law, w, plant, hours.tolist(), load.tolist(),
            starts[:n_sched], log_s.tolist(), float(rng.uniform(0.8, 1.5)),
        )  # fmt: skip
        unit.usage_h = float(hpf)
        unit.flight_amp = amp.tolist()
        unit.profile = prof
        _set_eol(unit, thr)
        units.append(unit)
    return units


def _set_eol(unit: UnitTruth, thr: float) -> None:
    """End of life on the flights axis (flight k is at k + 1, its ratio read before it) and
    in operating hours (the same interpolation on cumulative hours)."""
    r = unit.ratios()
    above = np.flatnonzero(r >= thr)
    if unit.law == "none" or len(above) == 0:
        return
    j = int(above[0])
    cum_h = np.concatenate(([0.0], np.cumsum(unit.flight_hours)[:-1]))
    if j == 0:
        unit.eol_flight, unit.eol_h = 1.0, 0.0
        return
    f = (thr - r[j - 1]) / (r[j] - r[j - 1])
    unit.eol_flight = float(j + f)  # between x = j (flight j-1) and x = j + 1 (flight j)
    unit.eol_h = float(cum_h[j - 1] + f * (cum_h[j] - cum_h[j - 1]))


def _segment(unit: UnitTruth, flight: int, ratio: float, cfg: FleetSimConfig):
    """Measured signals of one flight's log (HF bench at the flight's leakage, load and
    command amplitude, with the scenario's sensor noise times the unit's factor)."""
    from models.scenario import Profile
    from service.monitor.calibration import measured_run
    from service.sim.scenarios import load_scenario

    base = load_scenario("healthy_noise")
    seed = int(np.random.SeedSequence([cfg.seed, unit.index, flight]).generate_state(1)[0])
    load = unit.flight_load[flight] if flight > 0 else 1.0
    sens = base.sensors
    noisy = {k: getattr(sens, k) * unit.noise for k in ("x_s_m", "x_j_m", "p_pa", "p_sr_pa",
                                                          "current_a")}  # fmt: skip
    amp = unit.amp(flight)
    cmd = base.command.model_copy(
        update={"periodic": [p.model_copy(update={"amplitude": p.amplitude * amp})
                             for p in base.command.periodic]}
    )  # fmt: skip
    sc = base.model_copy(
        update={
            "name": f"{unit.actuator}#{flight}",
            "duration_s": float(unit.log_s[flight]),
            "params": dict(unit.plant),
            "leak": Profile(initial=ratio * C_LK_NOMINAL),
            "load": Profile(initial=F_R_NOMINAL * load),
            "command": cmd,
            "sensors": sens.model_copy(update={"seed": seed, **noisy}),
        }
    )
    return measured_run(sc)[1]


def simulate_unit(unit: UnitTruth, cfg: FleetSimConfig, log_dir: str) -> dict:
    """One unit's flights as MCAP logs, one per flight with its ``servowatch.flight`` record
    (stops after the flight in which it reaches its end of life), and its baseline calibrated
    on flight 0 (``service.monitor.calibration.calibrate``, as ``servowatch calibrate --log``)."""
    from service.log.flightrec import FlightRecord, write_flight_log
    from service.monitor.calibration import calibrate

    w0 = time.perf_counter()
    thr = cfg.threshold()
    ratios = unit.ratios()
    ac, act = unit.actuator.split("/")
    folder = Path(log_dir) / ac
    folder.mkdir(parents=True, exist_ok=True)
    baseline = None
    logs: list[str] = []
    truth_ratio: list[float] = []
    for k in range(cfg.flights):
        ratio = float(ratios[k])
        truth_ratio.append(ratio)
        meas = _segment(unit, k, ratio, cfg)
        if baseline is None:
            baseline = calibrate(meas, cfg.model)
        rec = FlightRecord(ac, act, k, unit.flight_start_unix[k])
        ch = {c: v for c, v in meas.items() if c != "t"}
        logs.append(str(write_flight_log(folder / f"{act}-f{k:04d}.mcap", rec, meas["t"], ch)))
        if ratio >= thr:
            break
    unit.ratio = truth_ratio
    unit.flown = len(truth_ratio)
    return {
        "truth": asdict(unit),
        "logs": logs,
        "baseline": baseline.model_dump() if baseline is not None else None,
        "segments": unit.flown,
        "wall_s": time.perf_counter() - w0,
    }


def _sim_job(args: tuple[UnitTruth, FleetSimConfig, str]) -> dict:
    return simulate_unit(*args)


def run_fleet_sim(
    cfg: FleetSimConfig,
    store=None,
    progress: Callable[[float], None] | None = None,
) -> dict:
    """Simulate the fleet into MCAP logs (``cfg.log_dir``), record each unit's baseline and
    ingest every log through ``service.replay.replay_many`` (the replay's code: periods,
    flights, calendar times and alarms) into ``store`` (a ``HealthStore``; None: a temporary
    SQLite store). Returns {"units": [simulate_unit results with the stored "periods" (dicts)
    and "false_alarms"], "wall_s", "ingest_wall_s", "logs"}."""
    from service.monitor import MonitorConfig
    from service.replay import log_order, replay_many
    from service.store import open_store

    w0 = time.perf_counter()
    tmp = tempfile.TemporaryDirectory(prefix="fleet-sim-")
    log_dir = cfg.log_dir or tmp.name
    own = store is None
    if own:
        store = open_store(Path(tmp.name) / "fleet.sqlite")
    try:
        units = draw_units(cfg)
        workers = cfg.workers or min(2, os.cpu_count() or 1)
        jobs = [(u, cfg, log_dir) for u in units]
        results: list[dict] = []
        if workers <= 1 or len(units) <= 1:
            for job in jobs:
                results.append(_sim_job(job))
                if progress:
                    progress(0.5 * len(results) / len(jobs))
        else:
            from service.log.setup import inherit_logging

            with ProcessPoolExecutor(
                workers, mp_context=get_context("spawn"), initializer=inherit_logging
            ) as ex:  # the workers log as this process does
                for r in ex.map(_sim_job, jobs):
                    results.append(r)
                    if progress:
                        progress(0.5 * len(results) / len(jobs))
        for r in results:
            a = r["truth"]["actuator"]
            store.ensure_actuator(a)
            last = store.latest_baseline(a)
            if r["baseline"] is not None and (last is None or last.baseline != r["baseline"]):
                store.add_baseline(a, r["baseline"], f"fleet-sim:{cfg.seed} flight 0")
        logs = log_order([Path(p) for r in results for p in r["logs"]])
        w1 = time.perf_counter()
        done = [0]

        def on_log(p, s, err) -> None:
            if err is not None:
                raise err
            done[0] += 1
            if progress:
                progress(0.5 + 0.5 * done[0] / len(logs))

        replay_many(logs, store, on_log=on_log, monitor_config=MonitorConfig(model=cfg.model))
        ingest = time.perf_counter() - w1
        clear = MonitorConfig().alarms.leak_clear
        for r in results:
            a = r["truth"]["actuator"]
            r["periods"] = [p.to_dict() for p in store.life(a)]
            ratio = r["truth"]["ratio"]
            flight_of = {p["source"]: p["flight"] for p in r["periods"]}  # one log, one flight
            fa = 0
            for ev in store.alarms(a):
                fl = flight_of.get(ev.source)
                true = ratio[fl] if fl is not None and fl < len(ratio) else ratio[-1]
                if ev.kind != "leak" or true < clear:
                    fa += 1
            r["false_alarms"] = fa
    finally:
        if own:
            store.close()
        if cfg.log_dir is None:
            tmp.cleanup()
    return {"units": results, "wall_s": time.perf_counter() - w0, "ingest_wall_s": ingest,
            "logs": len(logs)}  # fmt: skip


def kendall_tau(pred: list[float], true: list[float]) -> float | None:
    """Kendall's tau-b of two orders (inf allowed: "none predicted" / "never"); None below
    three units or when either order is all ties."""
    from scipy.stats import kendalltau

    if len(pred) < 3:
        return None
    big = 1e12
    p = np.where(np.isfinite(pred), pred, big)
    t = np.where(np.isfinite(true), true, big)
    if len(set(p.tolist())) < 2 or len(set(t.tolist())) < 2:
        return None
    return float(kendalltau(p, t).statistic)


def evaluate(
    results: list[dict],
    cfg: FleetSimConfig,
    progress=None,
    learn: Callable | None = None,
    predict: Callable | None = None,
) -> dict:
    """RUL predictions after every ``eval_every``-th flight from the stored history up to it
    (the fleet prior learned from every unit's history up to the same flight, every
    ``prior_every`` flights), on the life axis of flights, scored against the truth:
    alpha-lambda (+-20 %) and relative accuracy at lambda 0.5-0.9 (``metrics.score_unit``),
    the share of 90 % intervals that hold the true RUL from mid-life on (and over all
    predictions before the end of life) and their median width [flights], Kendall's tau of the fleet's order (median RUL,
    ``servowatch fleet``'s key) against the true RUL at each checkpoint with at least three
    units, and the healthy units' largest probability of crossing within the horizon.
    ``learn(histories) -> prior`` (default ``rul.fleet_prior`` on the histories: the fleet
    prior and its life axes) gets every unit's observable (flights, y); ``predict(history, prior, rul_config)`` returns
    ``rul_of_history``'s dict (default) or (median RUL in flights or inf, warning) | None
    (another method, bench/prognostics.py; no interval then)."""
    from service.prognostics.rul import RulConfig, fleet_prior, history_of, rul_of_history
    from service.store.records import Period

    rcfg = RulConfig(
        threshold_ratio=cfg.threshold(), horizon_h=cfg.horizon_h,
        horizon_flights=cfg.horizon_flights, warn_p=cfg.warn_p, n_samples=cfg.n_samples,
        min_periods=cfg.min_history, robust_trend=cfg.robust_trend,
    )  # fmt: skip
    predict = predict or rul_of_history
    hist = {}
    for r in results:
        a = r["truth"]["actuator"]
        hist[a] = history_of(a, [Period.from_dict(p) for p in r["periods"]])
    truths = {r["truth"]["actuator"]: r["truth"] for r in results}
    # per unit: (t_now, median, lo, hi, p_horizon, warning)
    preds: dict[str, list[tuple]] = {a: [] for a in hist}
    taus: list[float] = []
    rows: list[list[tuple]] = []  # per checkpoint: (unit, t_now, median, true RUL)
    max_f = max(int(np.nanmax(h.flight)) for h in hist.values() if len(h.y))
    ks = list(range(cfg.min_history - 1, max_f + 1, max(1, cfg.eval_every)))
    prior = None
    for step, k in enumerate(ks):
        heads = {}
        for a, h in hist.items():
            n = int(np.sum(h.flight <= k))
            if n and (h.flight[n - 1] == k):
                heads[a] = h.head(n)
        if not heads:
            continue
        if prior is None or step % max(1, cfg.prior_every // max(1, cfg.eval_every)) == 0:
            heads_k = hist_heads(hist, k)
            prior = (learn([h.observed() for h in heads_k]) if learn
                     else fleet_prior(heads_k, robust_trend=cfg.robust_trend))  # fmt: skip
        row_p, row_t, row_u = [], [], []
        for a, h in heads.items():
            res = predict(h, prior, rcfg)
            if res is None or (isinstance(res, dict) and res["status"] != "ok"):
                continue
            if isinstance(res, dict):
                med = res["median_flights"]
                med = math.inf if med is None else med
                lo = res["lo_flights"] if res["lo_flights"] is not None else math.inf
                hi = res["hi_flights"] if res["hi_flights"] is not None else math.inf
                ph, warn = res["p_horizon"], bool(res["warning"])
            else:
                med, warn = float(res[0]), bool(res[1])
                lo = hi = ph = None
            t_now = h.t_now()
            preds[a].append((t_now, med, lo, hi, ph, warn))
            eol = truths[a]["eol_flight"]
            if t_now < eol:
                row_p.append(med)
                row_t.append(eol - t_now)
                row_u.append((a, t_now, med, eol - t_now))
        rows.append(row_u)
        tau = kendall_tau(row_p, row_t)
        if tau is not None:
            taus.append(tau)
        if progress:
            progress((step + 1) / len(ks))
    by_law: dict[str, dict[str, list]] = {}
    units = []
    healthy = false_warn = 0
    healthy_p: list[float] = []
    cov_all: list[bool] = []
    for a, p in preds.items():
        tr = truths[a]
        warned = any(x[5] for x in p)
        row = {"actuator": a, "law": tr["law"], "eol_flight": tr["eol_flight"],
               "predictions": len(p), "warned": warned}  # fmt: skip
        eol = tr["eol_flight"]
        ps = [x[4] for x in p if x[4] is not None]
        row["max_p_horizon"] = max(ps) if ps else None  # every unit's (a healthy law's too)
        if tr["law"] == "none":
            healthy += 1
            false_warn += int(warned)
            healthy_p.extend(ps)
        elif p and eol <= tr["flown"] + 1 and p[0][0] < eol:
            before = [x for x in p if x[0] < eol]
            s = score_unit([x[0] for x in before], [x[1] for x in before], eol)
            t_s = before[0][0]
            cov = [x[2] <= eol - x[0] <= x[3] for x in before if x[2] is not None]
            cov_mid = [x[2] <= eol - x[0] <= x[3] for x in before
                       if x[2] is not None and x[0] >= t_s + 0.5 * (eol - t_s)]  # fmt: skip
            width = [x[3] - x[2] for x in before
                     if x[2] is not None and x[0] >= t_s + 0.5 * (eol - t_s)]  # fmt: skip
            cov_all.extend(cov)
            by_law.setdefault(tr["law"], {"acc": [], "ra": [], "ph": [], "cov": [], "width": []})
            by_law[tr["law"]]["width"].extend(width)
            by_law[tr["law"]]["acc"].extend(s.accurate)
            by_law[tr["law"]]["ra"].append(s.relative_accuracy[0])
            by_law[tr["law"]]["ph"].append(s.horizon_frac)
            by_law[tr["law"]]["cov"].extend(cov_mid)
            row.update(accurate=list(s.accurate), ra_05=s.relative_accuracy[0],
                       ph_frac=s.horizon_frac,
                       coverage_mid_pct=100.0 * float(np.mean(cov_mid)) if cov_mid else None,
                       last=[round(x, 2) if math.isfinite(x) else None
                             for x in (before[-1][0], before[-1][1], eol - before[-1][0])])  # fmt: skip
        units.append(row)

    def pct(v: list) -> float | None:
        return 100.0 * float(np.mean(v)) if v else None

    def ra_pct(v: list) -> float | None:
        v = [max(x, 0.0) for x in v]  # a missed prediction (inf) scores 0, not -inf
        return 100.0 * float(np.mean(v)) if v else None

    taus_mid = mid_life_taus(rows, {a: p[0][0] for a, p in preds.items() if p},
                             {a: truths[a]["eol_flight"] for a in preds})  # fmt: skip
    laws = [law for law in by_law if law != "none"]
    acc = [x for law in laws for x in by_law[law]["acc"]]
    ra = [x for law in laws for x in by_law[law]["ra"]]
    ph = [x for law in laws for x in by_law[law]["ph"]]
    cov = [x for law in laws for x in by_law[law]["cov"]]
    width = [x for law in laws for x in by_law[law]["width"]]

    def med(v: list) -> float | None:
        return float(np.median(v)) if v else None

    return {
        "axis": "flights",
        "alpha_lambda_pct": pct(acc),
        "relative_accuracy_pct": ra_pct(ra),
        "prognostic_horizon_pct": pct(ph),
        "interval_coverage_pct": pct(cov),
        "interval_coverage_all_pct": pct(cov_all),
        "interval_width_median_flights": med(width),
        "kendall_tau": float(np.mean(taus)) if taus else None,
        "kendall_tau_min": float(np.min(taus)) if taus else None,
        "kendall_checkpoints": len(taus),
        "kendall_tau_mid": float(np.mean(taus_mid)) if taus_mid else None,
        "kendall_tau_mid_min": float(np.min(taus_mid)) if taus_mid else None,
        "kendall_checkpoints_mid": len(taus_mid),
        "healthy_max_p_horizon": max(healthy_p) if healthy_p else None,
        "scored_units": len(ra),
        "by_law": {
            law: {
                "units": len(v["ra"]),
                "alpha_lambda_pct": pct(v["acc"]),
                "relative_accuracy_pct": ra_pct(v["ra"]),
                "prognostic_horizon_pct": pct(v["ph"]),
                "interval_coverage_pct": pct(v["cov"]),
                "interval_width_median_flights": med(v["width"]),
            }
            for law, v in by_law.items()
            if law != "none"
        },
        "healthy_units": healthy,
        "false_rul_warnings": false_warn,
        "lambdas": list(LAMBDAS),
        "units": units,
    }


def mid_life_taus(
    rows: list[list[tuple]], t_first: dict[str, float], eol: dict[str, float]
) -> list[float]:
    """Kendall's tau at each checkpoint over the units from their mid-life on (the
    predictions the interval coverage counts: t_now >= t_s + (eol - t_s) / 2, t_s the unit's
    first prediction); ``rows`` per checkpoint (unit, t_now, median RUL, true RUL), with
    three or more such units."""
    out = []
    for row in rows:
        sel = [(m, r) for a, t, m, r in row if t >= t_first[a] + 0.5 * (eol[a] - t_first[a])]
        tau = kendall_tau([m for m, _ in sel], [r for _, r in sel])
        if tau is not None:
            out.append(tau)
    return out


def evaluate_store(store, truth: dict, cfg: FleetSimConfig | None = None, **kw) -> dict:
    """``evaluate`` on an already-ingested ``store`` (a ``HealthStore``) against a truth file's
    content (``fleet-sim --truth``: {"seed", "threshold_ratio", "units": [UnitTruth dicts]};
    each unit needs ``actuator``, ``law``, ``eol_flight`` and ``flown``): the scoring alone,
    without simulating or ingesting again. ``cfg`` defaults to the truth's seed and threshold;
    ``kw`` go to ``evaluate``."""
    units = truth.get("units")
    if not isinstance(units, list) or not units:
        raise ValueError("truth: no units")
    have = set(store.actuators())
    results = []
    for u in units:
        for k in ("actuator", "law", "eol_flight", "flown"):
            if k not in u:
                raise ValueError(f"truth: unit without {k!r}")
        a = u["actuator"]
        if a not in have:
            raise ValueError(f"truth: actuator {a!r} is not in the store")
        eol = u["eol_flight"]
        tr = {**u, "eol_flight": math.inf if eol is None else float(eol)}
        results.append({"truth": tr, "periods": [p.to_dict() for p in store.life(a)]})
    if cfg is None:
        cfg = FleetSimConfig(
            actuators=len(units), seed=int(truth.get("seed", 0)),
            threshold_ratio=truth.get("threshold_ratio"),
        )  # fmt: skip
    return evaluate(results, cfg, **kw)


def hist_heads(hist: dict, k: int) -> list:
    """Every unit's history up to flight ``k`` (for the fleet prior)."""
    out = []
    for h in hist.values():
        n = int(np.sum(h.flight <= k))
        if n:
            out.append(h.head(n))
    return out
