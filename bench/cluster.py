"""Cluster benchmark (issue 53): ``replay --cluster`` on 1 and 2 Dask workers against
``replay --jobs 1`` and ``--jobs 2``, side by side in one run, and the client's store writes
into PostgreSQL as a unit's history grows.

1. Throughput. Writes ``--units`` x ``--flights`` logs of ``--log-s`` seconds (1 kHz, the HF
   bench as ``bench/ingest.py`` makes them, one flight record each; units commissioned on
   flight 0), starts a ``dask scheduler`` and ``dask worker`` processes on 127.0.0.1 (their
   start is not timed: a cluster is a standing service) and times ``servowatch replay FOLDER
   --store S`` with ``--jobs 1``, ``--jobs 2``, ``--cluster`` on one worker and on two, each
   into a fresh commissioned SQLite store (the four stores must agree). The per-sample cost
   is the workers' busy time over their samples (the summary's ``workers``).
2. The store. The captured store writes of one log (``run_group``: what a worker returns) are
   written by the client (``HealthStore.ingest_log``, as ``replay --cluster`` does) into a
   throwaway PostgreSQL cluster, as one unit's flights ``--pg-flights`` times with
   ``--periods`` periods each (a 2 h flight cut in 600 s windows: 12), timing each write as
   the unit's history grows.
3. The projection of docs/cluster.md from the figures measured here.

Run:  nice -n 10 .venv/bin/python bench/cluster.py          # 4 units x 12 flights x 20 s
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from ingest import commission, make_logs  # noqa: E402

PY = sys.executable
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}

# the fleet of issue 53
AIRCRAFT, UNITS_PER_AC, FLIGHTS_PER_DAY, FLIGHT_H, RATE_HZ, YEARS = 500, 20, 4, 2.0, 1000, 5


def start_dask(folder: Path, workers: int) -> tuple[str, list[subprocess.Popen]]:
    """A scheduler and ``workers`` worker processes on 127.0.0.1, dashboards off."""
    sf = folder / "scheduler.json"
    dask = [PY, "-m", "dask"]
    procs = [subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--dashboard-address", "127.0.0.1:0",
                               "--scheduler-file", str(sf)], env=ENV,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]  # fmt: skip
    end = time.monotonic() + 60
    while not sf.exists() and time.monotonic() < end:
        time.sleep(0.1)
    addr = json.loads(sf.read_text())["address"]
    for k in range(workers):
        procs.append(add_worker(sf, k))
    wait_workers(addr, workers)
    return addr, procs


def add_worker(sf: Path, k: int) -> subprocess.Popen:
    return subprocess.Popen([PY, "-m", "dask", "worker", "--scheduler-file", str(sf), "--name",
                             f"w{k}", "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny",
                             "--no-dashboard", "--dashboard-address", "127.0.0.1:0"], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip


def wait_workers(addr: str, n: int) -> None:
    from distributed import Client

    with Client(addr, timeout="30s") as c:
        c.wait_for_workers(n, timeout=120)


def replay(logs: Path, store: Path, *opt: str) -> tuple[float, dict]:
    w0 = time.perf_counter()
    r = subprocess.run([PY, "-m", "service.cli", "replay", str(logs), "--store", str(store),
                        "--json", *opt], env=ENV, capture_output=True, text=True)  # fmt: skip
    wall = time.perf_counter() - w0
    if r.returncode != 0:
        raise SystemExit(f"replay {' '.join(opt)} failed: {r.stderr.strip()[-500:]}")
    return wall, json.loads(r.stdout)


def fleet_rows(store: Path) -> list:
    from service.store import open_store

    with open_store(store, read_only=True) as s:
        return [{k: v for k, v in d.items() if not k.endswith("updated_s")}
                for d in s.fleet_summary()]  # fmt: skip


def store_writes(
    log: Path, flights: int, periods: int, batch: int, budget_s: float
) -> list[tuple[int, int, float]]:
    """(flight, periods of the unit stored before it, ms of client and store time per
    flight) for one unit's ``flights`` written into a fresh PostgreSQL database, ``batch``
    flights per transaction (``write_logs`` of ``batch`` captured logs: a task's)."""
    from service.replay import replay_many
    from service.replay.cluster import GroupTask, run_group, write_logs
    from service.store import open_store
    from service.store.pgtemp import TempCluster

    res = run_group(GroupTask([str(log)], "bench", {}, 1800.0, {}, replay_many))
    _, s0, _, call = res.logs[0]
    p0 = call.periods[0]

    def flight(k: int):
        day = 86400.0 * (k // FLIGHTS_PER_DAY) + 3 * 3600.0 * (k % FLIGHTS_PER_DAY)
        dt = [day + 600.0 * j for j in range(periods)]
        ps = [replace(p0, start_t=p0.start_t + d, end_t=p0.end_t + d,
                      start_unix=None if p0.start_unix is None else p0.start_unix + d)
              for d in dt]  # fmt: skip
        units = [u._replace(source=f"{u.source}-{k}", name=f"f{k:05d}.mcap") for u in call.units]
        return replace(s0, log=f"f{k:05d}.mcap"), replace(call, units=units, periods=ps,
                                                          alarms=[])  # fmt: skip

    out = []
    with TempCluster() as pg:
        url = pg.create_database()
        with open_store(url) as hs:
            t_end = time.monotonic() + budget_s
            for k in range(0, flights, batch):
                done = [flight(j) for j in range(k, min(k + batch, flights))]
                w0 = time.perf_counter()
                write_logs(hs, done)
                ms = (time.perf_counter() - w0) * 1e3 / len(done)
                out.append((k, k * periods, ms))
                if time.monotonic() > t_end:
                    break
    return out


def print_writes(title: str, writes: list[tuple[int, int, float]]) -> None:
    print(title)
    step = max(1, len(writes) // 6)
    for i in list(range(0, len(writes), step)) + [len(writes) - 1]:
        near = sorted(m for _, _, m in writes[max(0, i - 2) : i + 3])
        k, hist, _ = writes[i]
        print(f"  at flight {k:5d} ({hist:7d} periods stored): {near[len(near) // 2]:8.2f} ms "
              "per flight")  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=4)
    ap.add_argument("--flights", type=int, default=12)
    ap.add_argument("--log-s", type=float, default=20.0)
    ap.add_argument("--pg-flights", type=int, default=2000, help="flights written to PostgreSQL")
    ap.add_argument("--periods", type=int, default=12, help="periods per flight written")
    ap.add_argument("--batch", type=int, default=100, help="flights per transaction, batched")
    ap.add_argument("--pg-budget-s", type=float, default=90.0, help="time bound of each write run")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-cluster-") as tmp:
        tmp = Path(tmp)
        logs = tmp / "logs"
        logs.mkdir()
        units = make_logs(logs, a.units, a.flights, a.log_s)
        n = len(list(logs.glob("*.mcap")))
        (tmp / "dask").mkdir()
        w0 = time.perf_counter()
        addr, procs = start_dask(tmp / "dask", 1)
        up = time.perf_counter() - w0
        rows: dict[str, tuple[float, dict]] = {}
        ref = None
        try:
            for name, opt in (("--jobs 1", ["--jobs", "1"]), ("--jobs 2", ["--jobs", "2"]),
                              ("--cluster, 1 worker", ["--cluster", addr]),
                              ("--cluster, 2 workers", ["--cluster", addr])):  # fmt: skip
                if name.endswith("2 workers"):
                    procs.append(add_worker(tmp / "dask" / "scheduler.json", 1))
                    wait_workers(addr, 2)
                st = tmp / f"{len(rows)}.sqlite"
                commission(st, units)
                rows[name] = replay(logs, st, *opt)
                fr = fleet_rows(st)
                assert ref is None or fr == ref, f"{name}: another store than --jobs 1"
                ref = fr
        finally:
            for p in reversed(procs):  # the workers, then the scheduler
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        first = sorted(logs.glob("*.mcap"))[0]
        one = store_writes(first, a.pg_flights, a.periods, 1, a.pg_budget_s)
        many = store_writes(first, a.pg_flights, a.periods, a.batch, a.pg_budget_s)
    samples = rows["--jobs 1"][1]["samples"]
    print(f"logs: {n} of {a.log_s:g} s ({a.units} units x {a.flights} flights, {samples} "
          f"samples); dask scheduler + 1 worker up in {up:.1f} s (not timed below); load "
          f"average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")  # fmt: skip
    print(f"{'contender':22s} {'wall s':>7s} {'logs/s':>7s} {'Msamples/s':>11s} "
          f"{'us/sample (workers busy)':>25s}")  # fmt: skip
    cost = {}
    for name, (wall, res) in rows.items():
        w = res.get("workers", {})
        busy = sum(d["busy_s"] for d in w.values())
        cost[name] = busy / samples * 1e6 if busy else float("nan")
        print(f"{name:22s} {wall:7.1f} {n / wall:7.2f} {samples / wall / 1e6:11.3f} "
              f"{cost[name]:25.2f}   {len(w)} worker(s)")  # fmt: skip
    c_us = cost["--cluster, 1 worker"]
    print_writes(
        f"\nPostgreSQL, the client writing one unit's flights ({a.periods} periods "
        "each) as its history grows, one flight per transaction:",
        one,
    )
    print_writes(
        f"the same, {a.batch} flights per transaction (write_logs of a task's logs):", many
    )
    # projection (docs/cluster.md)
    unit_flights = FLIGHTS_PER_DAY * 365.25 * YEARS
    per_day = AIRCRAFT * UNITS_PER_AC * FLIGHTS_PER_DAY * FLIGHT_H * 3600 * RATE_HZ
    core_s = per_day * 365.25 * YEARS * c_us * 1e-6
    logs_s = AIRCRAFT * unit_flights / 86400  # one log per aircraft and flight
    unit_writes_s = logs_s * UNITS_PER_AC
    print(f"\nprojection at {c_us:.2f} us/sample (one worker's busy time): the fleet's day is "
          f"{per_day:.3g} samples = {per_day * c_us * 1e-6 / 86400:.1f} workers busy all day; "
          f"five years = {core_s / 3.156e7:.0f} worker-years, in one day "
          f"{core_s / 86400:.0f} workers")  # fmt: skip
    print(f"  in one day the store takes {logs_s:.0f} logs/s = {unit_writes_s:.0f} unit "
          f"writes/s = {unit_writes_s * a.periods:.0f} periods/s")  # fmt: skip
    for title, w in (
        ("one flight per transaction", one),
        (f"{a.batch} flights per transaction", many),
    ):
        head = sorted(m for _, _, m in w[:5])[len(w[:5]) // 2]
        tail = sorted(m for _, _, m in w[-5:])[len(w[-5:]) // 2]
        print(f"  one client, {title}: {1e3 / head:.0f} unit-flights/s on an empty history, "
              f"{1e3 / tail:.0f}/s at {w[-1][1]} periods of history "
              f"({w[-1][0]} of the {unit_flights:.0f} flights of a unit's {YEARS} years)")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
