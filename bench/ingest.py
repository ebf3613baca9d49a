"""Batch ingest benchmark: a fleet history of short logs into a health store.

Writes ``--units`` x ``--flights`` acquisition logs of ``--log-s`` seconds (1 kHz, the HF bench
with the healthy_noise scenario's sensor noise, at a few leak levels; one
``servowatch.flight`` record each), commissions each unit on its flight 0, then times

- ``servowatch replay FOLDER --store S`` (all logs in one process, the figure of issue 31:
  240 logs of 6 s in under 60 s), and the same with ``--jobs 2`` (two worker processes,
  whole actuators each), and
- one ``servowatch replay LOG --store S`` process per log, on ``--per-process`` logs,
  extrapolated to all of them (how the logs were ingested before),

and prints both with their ratio. Run:

    .venv/bin/python bench/ingest.py                    # 6 units x 40 flights x 6 s
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

EXE = str(Path(sys.executable).with_name("servowatch"))


def make_logs(folder: Path, units: int, flights: int, log_s: float) -> list[dict]:
    """The logs (a few distinct leak levels per unit, cycled) and each unit's baseline."""
    from models.scenario import Profile
    from service.log.flightrec import FlightRecord, write_flight_log
    from service.monitor.calibration import calibrate, measured_run
    from service.monitor.model_choice import DEFAULT_MODEL
    from service.sim.scenarios import load_scenario

    base = load_scenario("healthy_noise")
    out = []
    for u in range(units):
        segs = []
        for j, ratio in enumerate((1.0, 1.5, 2.5, 4.0)):
            sens = base.sensors.model_copy(update={"seed": 100 * u + j})
            sc = base.model_copy(update={"duration_s": log_s, "sensors": sens,
                                         "leak": Profile(initial=ratio * 2e-13)})  # fmt: skip
            segs.append(measured_run(sc)[1])
        b = calibrate(segs[0], DEFAULT_MODEL)
        for k in range(flights):
            m = segs[min(k * len(segs) // flights, len(segs) - 1)]
            rec = FlightRecord(f"AC{u:02d}", "eha", k, 1.7e9 + 86400.0 * k)
            ch = {c: v for c, v in m.items() if c != "t"}
            write_flight_log(folder / f"AC{u:02d}-f{k:03d}.mcap", rec, m["t"], ch)
        out.append({"actuator": f"AC{u:02d}/eha", "baseline": b.model_dump()})
    return out


def commission(store: Path, units: list[dict]) -> None:
    from service.store import open_store

    with open_store(store) as st:
        for u in units:
            st.add_baseline(u["actuator"], u["baseline"], "bench/ingest.py flight 0")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=6)
    ap.add_argument("--flights", type=int, default=40)
    ap.add_argument("--log-s", type=float, default=6.0)
    ap.add_argument("--per-process", type=int, default=6, help="logs timed one process each")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-ingest-") as tmp:
        tmp = Path(tmp)
        logs = tmp / "logs"
        logs.mkdir()
        w0 = time.perf_counter()
        units = make_logs(logs, a.units, a.flights, a.log_s)
        gen = time.perf_counter() - w0
        n = len(list(logs.glob("*.mcap")))
        walls = {}
        for jobs in (1, 2):
            s1 = tmp / f"batch{jobs}.sqlite"
            commission(s1, units)
            w0 = time.perf_counter()
            r = subprocess.run([EXE, "replay", str(logs), "--store", str(s1), "--json",
                                "--jobs", str(jobs)], capture_output=True, text=True,
                               check=True)  # fmt: skip
            walls[jobs] = time.perf_counter() - w0
            res = json.loads(r.stdout)
        batch = walls[1]
        s2 = tmp / "single.sqlite"
        commission(s2, units)
        some = sorted(logs.glob("*.mcap"))[: a.per_process]
        w0 = time.perf_counter()
        for p in some:
            subprocess.run([EXE, "replay", str(p), "--store", str(s2), "--json"],
                           capture_output=True, check=True)  # fmt: skip
        single = (time.perf_counter() - w0) / len(some)
    print(f"logs: {n} of {a.log_s:g} s ({a.units} units x {a.flights} flights), "
          f"generated in {gen:.1f} s")  # fmt: skip
    print(f"batch   servowatch replay FOLDER --store: {batch:7.1f} s wall "
          f"({batch / n * 1e3:.0f} ms/log, {res['periods_new']} periods, "
          f"{res['samples']} samples, {len(res['actuators'])} actuators)")  # fmt: skip
    print(f"batch   the same with --jobs 2:           {walls[2]:7.1f} s wall "
          f"({walls[2] / n * 1e3:.0f} ms/log)")  # fmt: skip
    print(f"single  one servowatch replay per log:    {single * n:7.1f} s wall (extrapolated "
          f"from {len(some)} logs, {single:.2f} s/log)")  # fmt: skip
    best = min(walls.values())
    print(f"ratio   single / batch: {single * n / batch:.1f}x; target < 60 s: "
          f"{'met' if best < 60 else 'NOT met'} (best {best:.1f} s); load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")  # fmt: skip
    flights = {k: v["flights"] for k, v in res["actuators"].items()}
    assert set(flights.values()) == {a.flights}, flights
    return 0 if np.isfinite(batch) else 1


if __name__ == "__main__":
    raise SystemExit(main())
