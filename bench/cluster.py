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
2. The store. The captured store writes of one log (``run_group``: what a worker returns)
   are written by the client into a throwaway PostgreSQL cluster as one unit's flights
   (``--periods`` periods each: a 2 h flight cut in 600 s windows, 12), its history built
   up to each of ``--marks`` flights (0, 1 900 and 7 300: 0, 22 800 and 87 600 periods,
   a unit's five years), and there each contender's write timed, one flight per transaction
   and ``--batch`` per transaction (a task's logs, ``write_logs``): this code's incremental
   path (``write_logs``: a unit whose new flights follow its stored ones is renumbered and
   summarised from its stored last period) and its whole-history renumbering
   (``ingest_logs(incremental=False)``), and with ``--previous DIR`` (a checkout of an
   earlier commit, e.g. ``git archive 4b1a344 | tar -x -C DIR``) that commit's client, run
   by this script in a process of its own, its history built within
   ``--previous-budget-s``.
3. The projection of docs/cluster.md from the figures measured here.

Run:  nice -n 10 .venv/bin/python bench/cluster.py          # 4 units x 12 flights x 20 s
      nice -n 10 .venv/bin/python bench/cluster.py --store-only --previous /tmp/prev
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
CODE = sys.argv[sys.argv.index("--code") + 1] if "--code" in sys.argv else None

from ingest import commission, make_logs  # noqa: E402

if CODE:  # servowatch of another commit (--previous runs this script so), ahead of this one
    sys.path.insert(0, CODE)

PY = sys.executable
ENV = {**os.environ, "PYTHONPATH": CODE or str(ROOT)}

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


def _flights(log: Path, periods: int) -> Callable[[int, float], tuple[Any, Any]]:
    """``flight(k, scale)``: the captured store write of one log (``run_group``: what a
    worker returns) as the unit's flight ``k`` (its flight record's number, 4 flights a
    day), with ``periods`` periods (a 2 h flight cut in 600 s windows: 12) and a source of
    its own; its stream identity that of a log ``scale`` times as long (its blocks repeated:
    the size and shape a longer log's identity has, decision record 0033)."""
    from service.replay import replay_many
    from service.replay.cluster import GroupTask, run_group

    res = run_group(GroupTask([str(log)], "bench", {}, 1800.0, {}, replay_many))
    _, s0, _, call = res.logs[0]
    p0 = call.periods[0]
    idents: dict[float, list] = {}

    def identity(u: Any, scale: float) -> Any:
        if scale == 1:
            return u.identity
        text = u.identity if isinstance(u.identity, str) else u.identity.dumps()
        runs = json.loads(text)
        for r in runs:
            r["blocks"] = r["blocks"] * max(1, round(scale))
        return json.dumps(runs, separators=(",", ":"))

    def flight(k: int, scale: float = 1.0, unit: str | None = None):
        day = 86400.0 * (k // FLIGHTS_PER_DAY) + 3 * 3600.0 * (k % FLIGHTS_PER_DAY)
        dt = [day + 600.0 * j for j in range(periods)]
        ps = [replace(p0, start_t=p0.start_t + d, end_t=p0.end_t + d, flight=k,
                      start_unix=None if p0.start_unix is None else p0.start_unix + d,
                      actuator=unit or p0.actuator) for d in dt]  # fmt: skip
        ids = idents.setdefault(scale, [identity(u, scale) for u in call.units])
        units = [u._replace(source=f"{u.source}-{k}", name=f"f{k:05d}.mcap", identity=i,
                            actuator=unit or u.actuator)
                 for u, i in zip(call.units, ids, strict=True)]  # fmt: skip
        return replace(s0, log=f"f{k:05d}.mcap"), replace(call, units=units, periods=ps,
                                                          alarms=[])  # fmt: skip

    return flight


def _write(hs: Any, done: list, how: str) -> None:
    """The client's write of a task's captured logs: ``write_logs`` (this code's path, or the
    previous commit's), or the whole-history renumbering of every changed unit."""
    from service.replay.cluster import write_logs

    if how.startswith("whole history"):
        hs.ingest_logs([(c.units, c.periods, c.alarms) for _, c in done], done[0][1].gap_s,
                       incremental=False)  # fmt: skip
    else:
        write_logs(hs, done)


def store_rows(
    log: Path,
    marks: list[int],
    periods: int,
    batch: int,
    contenders: list[str],
    budget_s: float,
    scales: dict[str, float] | None = None,
) -> list[dict[str, Any]]:
    """One unit's flights written by the client into a fresh throwaway PostgreSQL: its
    history built up to each of ``marks`` flights (``batch`` flights per transaction, the
    first contender's path, at most ``budget_s`` in all), and there each contender's write
    timed, one flight per transaction and ``batch`` per transaction (where the budget ran
    out first: at the history reached, once). Returns rows of ``{mark, history, contender,
    batch, ms}`` (``history``: the unit's periods before the timed writes; ms of client and
    store per unit-flight, the median of the repeats)."""
    from service.store import open_store
    from service.store.pgtemp import TempCluster

    flight = _flights(log, periods)
    scales = scales or {}
    out: list[dict[str, Any]] = []
    t_end = time.monotonic() + budget_s
    with TempCluster() as pg, open_store(pg.create_database()) as hs:
        k = 0
        for mark in marks:
            if time.monotonic() >= t_end:
                break
            while k < mark and time.monotonic() < t_end:
                n = min(batch, mark - k)
                _write(hs, [flight(j) for j in range(k, k + n)], contenders[0])
                k += n
            for how in contenders:
                if how in scales:  # a longer log's identity: fewer repeats (its bytes)
                    plan = ((20, 2), (batch, 1))
                elif how == "incremental":
                    plan = ((1, 12), (20, 5), (batch, 3))
                else:
                    plan = ((1, 3), (batch, 2))
                for b, reps in plan:
                    ms, hist = [], hs.count_periods()
                    for _ in range(reps):
                        done = [flight(j, scales.get(how, 1.0)) for j in range(k, k + b)]
                        w0 = time.perf_counter()
                        _write(hs, done, how)
                        ms.append((time.perf_counter() - w0) * 1e3 / b)
                        k += b
                    ident = done[0][1].units[0].identity
                    size = len(ident) if isinstance(ident, str) else len(ident.dumps())
                    out.append({"mark": mark, "history": hist, "contender": how, "batch": b,
                                "identity_bytes": size,
                                "ms": sorted(ms)[len(ms) // 2]})  # fmt: skip
    return out


def _writer(job: tuple) -> tuple[float, float, int]:
    """One writer process of ``parallel_writers``: its own unit's flights, ``batch`` per
    transaction, from the barrier time ``t0``; returns its start, end and flights."""
    log, url, unit, batches, batch, periods, scale, t0 = job
    from service.store import open_store

    flight = _flights(Path(log), periods)
    todo = [[flight(k, scale, unit) for k in range(i * batch, (i + 1) * batch)]
            for i in range(batches)]  # fmt: skip
    with open_store(url) as hs:
        _write(hs, [flight(-1, 1.0, unit)], "incremental")  # its first write (whole, empty)
        time.sleep(max(0.0, t0 - time.time()))
        w0 = time.time()
        for done in todo:
            _write(hs, done, "incremental")
        return w0, time.time(), batches * batch


def parallel_writers(
    log: Path, writers: list[int], batches: int, batch: int, periods: int, scale: float
) -> list[dict[str, Any]]:
    """Writers on the workers: ``n`` processes, each its own unit (tasks of disjoint units),
    each task's flights in one transaction, into one throwaway PostgreSQL, at once; the
    flights of all of them over the time from the first start to the last end."""
    import multiprocessing as mp

    from service.store.pgtemp import TempCluster

    out = []
    with TempCluster() as pg:
        for n in writers:
            url = pg.create_database()
            t0 = time.time() + 30.0  # every writer replayed its log and built its flights
            jobs = [(str(log), url, f"W{n}x{w}/eha", batches, batch, periods, scale, t0)
                    for w in range(n)]  # fmt: skip
            with mp.get_context("spawn").Pool(n) as pool:
                res = pool.map(_writer, jobs)
            wall = max(e for _, e, _ in res) - min(s for s, _, _ in res)
            out.append({"writers": n, "flights": sum(f for _, _, f in res), "wall_s": wall})
    return out


def print_store(rows: list[dict[str, Any]], periods: int) -> None:
    print(f"\nPostgreSQL (throwaway), the client writing one unit's flights of {periods} periods "
          "(client and store time per unit-flight, the median of the repeats):")  # fmt: skip
    sizes = {r["contender"]: r.get("identity_bytes") for r in rows}
    print("  stream identity per unit-flight: " + ", ".join(
        f"{c} {b:,} B" for c, b in sizes.items() if b))  # fmt: skip
    print(f"  {'contender':22s} {'flights/tx':>10s} {'history, periods':>17s} "
          f"{'ms/unit-flight':>15s} {'unit-flights/s':>15s}")  # fmt: skip
    for r in sorted(rows, key=lambda r: (r["mark"], r["contender"] != "incremental",
                                         r["contender"], r["batch"])):  # fmt: skip
        print(f"  {r['contender']:22s} {r['batch']:10d} {r['history']:17,d} {r['ms']:15.2f} "
              f"{1e3 / r['ms']:15,.0f}")  # fmt: skip


def throughput(a: argparse.Namespace, tmp: Path) -> tuple[dict, int, float, Path]:
    """The four contenders on the same logs (part 1): ``{name: (wall, summary)}``, logs,
    the scheduler's start time and the first log."""
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
    return rows, n, up, sorted(logs.glob("*.mcap"))[0]


def previous_rows(a: argparse.Namespace, code: str) -> list[dict[str, Any]]:
    """The store rows of the code in ``code`` (a checkout of an earlier commit), run as this
    script in a process of its own (the same module names cannot be imported twice)."""
    r = subprocess.run([PY, __file__, "--store-only", "--json", "--code", code, "--marks",
                        ",".join(map(str, a.marks)), "--periods", str(a.periods), "--batch",
                        str(a.batch), "--pg-budget-s", str(a.previous_budget_s)],
                       env=ENV, capture_output=True, text=True)  # fmt: skip
    if r.returncode != 0:
        raise SystemExit(f"previous code ({code}) failed: {r.stderr.strip()[-800:]}")
    return json.loads(r.stdout)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=4)
    ap.add_argument("--flights", type=int, default=12)
    ap.add_argument("--log-s", type=float, default=20.0)
    ap.add_argument("--store-only", action="store_true", help="only the store writes (part 2)")
    ap.add_argument("--marks", type=lambda t: [int(x) for x in t.split(",")],
                    default=[0, 1900, 7300],
                    help="flights of the unit's history where the writes are timed "
                    "(x12 periods: 0, 22 800, 87 600)")  # fmt: skip
    ap.add_argument("--periods", type=int, default=12, help="periods per flight written")
    ap.add_argument("--batch", type=int, default=100, help="flights per transaction, batched")
    ap.add_argument("--pg-budget-s", type=float, default=300.0,
                    help="time bound of building the history")  # fmt: skip
    ap.add_argument("--identity-s", type=float, default=7200.0,
                    help="the length of log whose stream identity a contender writes "
                    "(the fleet's 2 h flights; the logs written are --log-s long)")  # fmt: skip
    ap.add_argument("--writers", type=lambda t: [int(x) for x in t.split(",")],
                    default=[1, 2], help="writer processes at once (writers on the workers)")  # fmt: skip
    ap.add_argument("--previous", metavar="DIR",
                    help="a checkout of the previous commit: its client writes timed beside")  # fmt: skip
    ap.add_argument("--previous-budget-s", type=float, default=420.0)
    ap.add_argument("--code", metavar="DIR", help=argparse.SUPPRESS)  # import servowatch from DIR
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-cluster-") as tmp:
        tmp = Path(tmp)
        if a.store_only:
            (tmp / "logs").mkdir()
            make_logs(tmp / "logs", 1, 1, a.log_s)
            first, rows = sorted((tmp / "logs").glob("*.mcap"))[0], None
        else:
            rows, n, up, first = throughput(a, tmp)
        long = f"incremental, {a.identity_s / 3600:g} h log"
        how = ["previous commit"] if a.code else ["incremental", long, "whole history"]
        writes = store_rows(first, a.marks, a.periods, a.batch, how, a.pg_budget_s,
                            {long: a.identity_s / a.log_s})  # fmt: skip
        if a.json:
            print(json.dumps(writes))
            return 0
        par = (parallel_writers(first, a.writers, 2, a.batch, a.periods, a.identity_s / a.log_s)
               if a.writers else [])  # fmt: skip
        if a.previous:
            writes += previous_rows(a, a.previous)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    c_us = None
    if rows is not None:
        samples = rows["--jobs 1"][1]["samples"]
        print(f"logs: {n} of {a.log_s:g} s ({a.units} units x {a.flights} flights, {samples} "
              f"samples); dask scheduler + 1 worker up in {up:.1f} s (not timed below)")  # fmt: skip
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
    print_store(writes, a.periods)
    for r in par:
        print(f"  writers on the workers: {r['writers']} process(es), a unit each, "
              f"{a.identity_s / 3600:g} h logs, {a.batch} per transaction: {r['flights']} "
              f"unit-flights in {r['wall_s']:.2f} s = {r['flights'] / r['wall_s']:,.0f}/s")  # fmt: skip
    # projection (docs/cluster.md)
    unit_flights = FLIGHTS_PER_DAY * 365.25 * YEARS
    per_day = AIRCRAFT * UNITS_PER_AC * FLIGHTS_PER_DAY * FLIGHT_H * 3600 * RATE_HZ
    logs_s = AIRCRAFT * unit_flights / 86400  # one log per aircraft and flight
    unit_writes_s = logs_s * UNITS_PER_AC
    print(f"\nfive years of the fleet in one day: the store takes {logs_s:.0f} logs/s = "
          f"{unit_writes_s:.0f} unit-flights/s = {unit_writes_s * a.periods:.0f} periods/s; "
          f"a unit ends at {unit_flights * a.periods:,.0f} periods")  # fmt: skip
    if c_us is not None:
        core_s = per_day * 365.25 * YEARS * c_us * 1e-6
        print(f"  at {c_us:.2f} us/sample (one worker's busy time): the fleet's day is "
              f"{per_day:.3g} samples = {per_day * c_us * 1e-6 / 86400:.1f} workers busy all "
              f"day; five years = {core_s / 3.156e7:.0f} worker-years, in one day "
              f"{core_s / 86400:.0f} workers")  # fmt: skip
    for r in writes:
        if r["batch"] == a.batch and r["mark"] == max(
            x["mark"] for x in writes if x["contender"] == r["contender"]
        ):
            rate = 1e3 / r["ms"]
            verdict = "keeps up" if rate >= unit_writes_s else "does NOT keep up"
            print(f"  one client, {r['contender']}, {a.batch} per transaction at "
                  f"{r['history']:,} periods of history: {rate:,.0f} unit-flights/s, "
                  f"{rate / unit_writes_s:.2f}x the rate: {verdict}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
