"""An independent acceptance fleet for the prognostics, held apart from ``fleet-sim`` (issue 31):
its own wear laws and parameter ranges, its own schedule, a few seconds of log per flight, and
the user's path only: ``servowatch calibrate --log <flight 0> --store S`` (the actuator named by
the log), ``servowatch replay <folder> --store S``, then the RUL of the stored histories after
each flight, scored with the same metrics as ``fleet-sim --evaluate``. Nothing in the RUL is
tuned on this fleet.

Wear laws (true C_Lk ratio against the unit's cumulative operating hours h, or cycles):

- ``none``: 1 (healthy);
- ``quadratic``: 1 + a h + b h^2;
- ``two_rate``: 1 + a h, then four to eight times faster after a knee;
- ``sqrt_then_exp``: 1 + a sqrt(h) + c (exp(g h) - 1) (early running-in, late runaway);
- ``cycles``: linear in the number of actuator cycles, which differ per flight (x 0.3-2);
- ``usage``: linear in the load-weighted jack travel, hours x load x amplitude of each flight.

Each unit flies its operator's profile (a mean load x 0.7-1.3 of 4 kN and a mean command
amplitude x 0.8-1.2), and each flight's load (x 0.7-1.3) and amplitude (x 0.7-1.3) vary
about it; every log is made at its flight's load and amplitude.

    .venv/bin/python -m tests.acceptance_fleet --seed 101 --units 8 --flights 30 --json

``--work DIR`` keeps the logs, the store (``DIR/acceptance.sqlite``) and the truth
(``DIR/truth.json``, the format of ``fleet-sim --truth``); ``--score-only`` then scores the
stored histories again without generating or ingesting (``fleetsim.evaluate_store``).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import numpy as np

LAWS = ("none", "two_rate", "usage", "quadratic", "sqrt_then_exp", "cycles")
C_LK0 = 2e-13


def draw(seed: int, units: int, flights: int, thr: float) -> list[dict]:
    """The hidden truth: per unit its law, per flight hours, cycles, calendar start and the
    true ratio; the end of life on the flights axis (flight k at k + 1)."""
    rng = np.random.default_rng(seed)
    out = []
    n = 5 * flights
    for i in range(units):
        law = LAWS[i % len(LAWS)]
        base_h = rng.uniform(0.6, 4.0)
        hours = base_h * rng.uniform(0.7, 1.3, n)
        cyc = rng.uniform(0.3, 2.0, n)
        p_load, p_amp = rng.uniform(0.7, 1.3), rng.uniform(0.8, 1.2)
        load = p_load * rng.uniform(0.7, 1.3, n)
        amp = p_amp * rng.uniform(0.7, 1.3, n)
        load[0] = amp[0] = 1.0  # flight 0: the calibration run
        h = np.concatenate(([0.0], np.cumsum(hours)[:-1]))
        c = np.concatenate(([0.0], np.cumsum(cyc)[:-1]))
        life = rng.uniform(0.5, 1.3) * float(np.sum(hours[:flights]))  # hours to the threshold
        x = h / life  # 1 at the end of life (hours laws)
        par: dict[str, float] = {"life": life}
        if law == "none":
            r = np.ones(n)
        elif law == "quadratic":
            f = rng.uniform(0.1, 0.6)  # share of the linear term at the end of life
            par["f"] = f
            r = 1 + (thr - 1) * (f * x + (1 - f) * x**2)
        elif law == "two_rate":
            knee = rng.uniform(0.3, 0.6)
            k = rng.uniform(4.0, 8.0)
            par.update(knee=knee, k=k)
            at_knee = knee / (knee + k * (1 - knee))
            r = 1 + (thr - 1) * np.where(x < knee, x / knee * at_knee,
                                         at_knee + (x - knee) / (1 - knee) * (1 - at_knee))  # fmt: skip
        elif law == "sqrt_then_exp":
            g = rng.uniform(2.0, 3.5)
            a = rng.uniform(0.5, 1.5)
            cc = (thr - 1 - a) / math.expm1(g)
            par.update(g=g, a=a, cc=cc)
            r = 1 + a * np.sqrt(x) + cc * np.expm1(g * x)
        elif law == "usage":
            inc = hours * load * amp
            par["life"] = rng.uniform(0.5, 1.3) * float(np.sum(inc[:flights]))
            r = 1 + (thr - 1) * np.concatenate(([0.0], np.cumsum(inc)[:-1])) / par["life"]
        else:  # cycles
            par["life"] = rng.uniform(0.5, 1.3) * float(np.sum(cyc[:flights]))  # in cycles
            xc = c / par["life"]
            r = 1 + (thr - 1) * xc
        per_day = rng.choice([1, 2, 4])
        starts, day = [], 0
        while len(starts) < n:
            if rng.uniform() >= 0.3:
                starts += [1.75e9 + 86400.0 * day + 5400.0 * j for j in range(per_day)]
            day += 1
        above = np.flatnonzero(r >= thr)
        eol = math.inf
        if law != "none" and len(above) and above[0] > 0:
            j = int(above[0])
            eol = j + (thr - r[j - 1]) / (r[j] - r[j - 1])
        out.append({
            "actuator": f"ACC{seed % 1000:03d}{i:02d}/spoiler", "index": i, "law": law,
            "ratio_schedule": r.tolist(), "start_unix": starts[:n], "eol_flight": eol,
            "noise": float(rng.uniform(0.7, 1.6)), "load": float(p_load), "amp": float(p_amp),
            "flight_load": load.tolist(), "flight_amp": amp.tolist(),
            "log_s": float(rng.uniform(1.5, 3.0)),
            "base_h": float(base_h), "hours": hours.tolist(), "cycles": cyc.tolist(),
            "params": {k: float(v) for k, v in par.items()},
        })  # fmt: skip
    return out


def increments(u: dict) -> np.ndarray:
    """Damage of each flight of unit ``u`` (a ``draw`` entry): operating hours, actuator
    cycles (``cycles``), load-weighted travel hours x load x amplitude (``usage``)."""
    if u["law"] == "cycles":
        return np.asarray(u["cycles"], float)
    h = np.asarray(u["hours"], float)
    if u["law"] == "usage":
        return h * np.asarray(u["flight_load"], float) * np.asarray(u["flight_amp"], float)
    return h


def ratio_of(u: dict, d: float | np.ndarray, thr: float) -> np.ndarray:
    """True ratio of unit ``u`` (a ``draw`` entry) at damage ``d`` (``increments`` summed;
    the law of ``draw``, for oracles)."""
    x = np.asarray(d, float) / u["params"]["life"]
    p, law = u["params"], u["law"]
    if law == "none":
        return np.ones_like(x)
    if law in ("quadratic",):
        return 1 + (thr - 1) * (p["f"] * x + (1 - p["f"]) * x**2)
    if law == "two_rate":
        knee, k = p["knee"], p["k"]
        at = knee / (knee + k * (1 - knee))
        return 1 + (thr - 1) * np.where(x < knee, x / knee * at,
                                        at + (x - knee) / (1 - knee) * (1 - at))  # fmt: skip
    if law == "sqrt_then_exp":
        return 1 + p["a"] * np.sqrt(x) + p["cc"] * np.expm1(p["g"] * x)
    return 1 + (thr - 1) * x


def write_logs(units: list[dict], flights: int, thr: float, folder: Path, seed: int) -> None:
    """One log per unit and flight (flight record, a few seconds of the HF bench); a unit stops
    after the flight that reaches the threshold. Sets each unit's ``flown`` and ``ratio``."""
    from models.scenario import Profile
    from service.log.flightrec import FlightRecord, write_flight_log
    from service.monitor.calibration import measured_run
    from service.sim.scenarios import load_scenario

    base = load_scenario("healthy_noise")
    for u in units:
        ac, act = u["actuator"].split("/")
        u["ratio"] = []
        for k in range(flights):
            ratio = float(u["ratio_schedule"][k])
            s = base.sensors
            sens = s.model_copy(update={
                "seed": int(np.random.SeedSequence([seed, u["index"], k, 7]).generate_state(1)[0]),
                **{f: getattr(s, f) * u["noise"] for f in ("x_s_m", "x_j_m", "p_pa", "current_a")},
            })  # fmt: skip
            sc = base.model_copy(update={
                "duration_s": 4.0 if k == 0 else u["log_s"], "sensors": sens,
                "leak": Profile(initial=ratio * C_LK0),
                "load": Profile(initial=4000.0 * u["flight_load"][k]),
                "command": base.command.model_copy(update={"periodic": [
                    q.model_copy(update={"amplitude": q.amplitude * u["flight_amp"][k]})
                    for q in base.command.periodic]}),
            })  # fmt: skip
            meas = measured_run(sc)[1]
            rec = FlightRecord(ac, act, k, u["start_unix"][k])
            ch = {c: v for c, v in meas.items() if c != "t"}
            write_flight_log(folder / f"{ac}_{act}_{k:03d}.mcap", rec, meas["t"], ch)
            u["ratio"].append(ratio)
            if ratio >= thr:
                break
        u["flown"] = len(u["ratio"])


def run(seed: int, units: int, flights: int, work: Path, robust_trend: bool = False) -> dict:
    """Generate, ingest through the CLI, evaluate; the metrics of ``fleet-sim --evaluate``
    (``robust_trend``: the RUL's opt-in trend model and Student-t readings)."""
    from service.cli import main
    from service.prognostics.rul import default_threshold_ratio

    thr = default_threshold_ratio()
    truth = draw(seed, units, flights, thr)
    logs = work / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    write_logs(truth, flights, thr, logs, seed)
    store = work / "acceptance.sqlite"
    for u in truth:
        ac, act = u["actuator"].split("/")
        f0 = logs / f"{ac}_{act}_000.mcap"
        if main(["calibrate", "--log", str(f0), "--store", str(store), "--json"]) != 0:
            raise RuntimeError(f"calibrate failed on {f0}")
    if main(["replay", str(logs), "--store", str(store), "--json"]) != 0:
        raise RuntimeError("replay failed")
    tr = {
        "seed": seed,
        "threshold_ratio": thr,
        "flights": flights,
        "units": [{k: v for k, v in u.items() if k != "ratio_schedule"} for u in truth],
    }
    (work / "truth.json").write_text(json.dumps(tr, default=_plain) + "\n")
    return score(work, robust_trend)


def _plain(v):
    return v.item() if hasattr(v, "item") else str(v)


def score(work: Path, robust_trend: bool = False) -> dict:
    """The metrics of ``fleet-sim --evaluate`` on the store and truth kept in ``work``
    (``robust_trend``: the RUL's opt-in trend model and Student-t readings)."""
    from service.replay.fleetsim import FleetSimConfig, evaluate_store
    from service.store import open_store

    tr = json.loads((work / "truth.json").read_text())
    units, flights, seed = len(tr["units"]), tr["flights"], tr["seed"]
    cfg = FleetSimConfig(actuators=units, flights=flights, seed=seed,
                         threshold_ratio=tr["threshold_ratio"], robust_trend=robust_trend)  # fmt: skip
    with open_store(work / "acceptance.sqlite") as st:
        ev = evaluate_store(st, tr, cfg)
    ev["fleet"] = {"seed": seed, "units": units, "flights": flights,
                   "laws": [u["law"] for u in tr["units"]]}  # fmt: skip
    return ev


def main_cli() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=101)
    ap.add_argument("--units", type=int, default=8)
    ap.add_argument("--flights", type=int, default=30)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--work", default=None, metavar="DIR", help="keep logs, store and truth")
    ap.add_argument("--score-only", action="store_true", help="score the store kept in --work")
    ap.add_argument("--robust-trend", action="store_true",
                    help="the RUL's opt-in trend model and Student-t readings")  # fmt: skip
    a = ap.parse_args()
    import contextlib
    import io

    if a.score_only and a.work is None:
        ap.error("--score-only needs --work")
    with (
        tempfile.TemporaryDirectory(prefix="acceptance-") as tmp,
        contextlib.redirect_stdout(io.StringIO()),
    ):
        work = Path(a.work) if a.work else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        ev = (score(work, a.robust_trend) if a.score_only
              else run(a.seed, a.units, a.flights, work, a.robust_trend))  # fmt: skip
    keys = ("alpha_lambda_pct", "interval_coverage_pct", "interval_coverage_all_pct",
            "interval_width_median_flights",
            "kendall_tau", "kendall_tau_min", "kendall_tau_mid", "healthy_max_p_horizon",
            "relative_accuracy_pct",
            "scored_units", "healthy_units")  # fmt: skip
    if a.json:
        print(json.dumps({k: ev[k] for k in (*keys, "by_law", "fleet")}, default=str))
    else:
        for k in keys:
            print(f"{k:<28} {ev[k]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main_cli())
