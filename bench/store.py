"""Health-store benchmark: build a fleet store and time the fleet query on both backends.

Builds N actuators x Y years of operating periods (F flights a day, one period per flight)
with bulk inserts (``add_periods``: executemany on SQLite, COPY on PostgreSQL), then times
``HealthStore.fleet_summary()`` and ``servowatch fleet --json`` as a whole command (a new
process: interpreter start, import, open, query, JSON out), and beside them the fleet page's
two requests to a running ``servowatch web`` (``/api/fleet``, the whole ranked fleet, and
``/api/unit``, one unit's full history). PostgreSQL runs in a throwaway
cluster (``service.store.pgtemp``) when its server binaries are installed.

    .venv/bin/python bench/store.py                       # 1000 actuators x 5 years, both
    .venv/bin/python bench/store.py --actuators 100 --years 1 --backend sqlite
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from service.store import Period, open_store  # noqa: E402
from service.store.pgtemp import ClusterUnavailableError, TempCluster  # noqa: E402


def fleet_periods(i: int, years: float, per_day: int, rng: np.random.Generator) -> list[Period]:
    """One actuator's periods: a random wear law on the C_Lk ratio with noise."""
    n = int(round(years * 365 * per_day))
    k = np.arange(n)
    start = k * (86400.0 / per_day) + rng.uniform(0, 600)
    op = rng.uniform(1.5, 3.0, n) * 3600.0
    law = i % 4
    life = n * rng.uniform(0.8, 3.0)
    if law == 0:
        ratio = np.ones(n)
    elif law == 1:
        ratio = 1.0 + 2.0 * k / life
    elif law == 2:
        ratio = np.exp(math.log(3.0) * k / life)
    else:
        ratio = 1.0 + np.where(k > n // 2, 0.5 + 1.5 * (k - n // 2) / life, 0.0)
    ratio = ratio * (1 + 0.02 * rng.standard_normal(n))
    c_nom = 2e-13
    name = f"AC{i // 8:03d}/act{i % 8}"
    src = "bench"
    return [
        Period(
            actuator=name,
            start_t=float(start[j]),
            end_t=float(start[j] + op[j]),
            op_time_s=float(op[j]),
            samples=int(op[j] * 100),
            flight=int(j),
            c_lk_mean=float(c_nom * ratio[j]),
            c_lk_sigma=float(c_nom * 0.02),
            c_lk_ratio=float(ratio[j]),
            observable_samples=int(op[j] * 60),
            p_sr_mean=2.1e7,
            p_sr_min=2.05e7,
            i_b_mean=1e-4,
            nis_mean=1.0,
            nis_in_band=0.95,
            alarms=int(ratio[j] > 2.5),
            bad_samples=0,
            dropped=0,
            source=src,
        )
        for j in range(n)
    ]


def build(url: str, n_act: int, years: float, per_day: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    gen_s = 0.0
    total = 0
    with open_store(url) as s:
        for i in range(n_act):
            g = time.perf_counter()
            ps = fleet_periods(i, years, per_day, rng)
            gen_s += time.perf_counter() - g
            total += s.add_periods(ps)
            if i % 4 == 1:
                s.add_baseline(ps[0].actuator, {"c_lk": 2e-13, "law": "C5"}, "bench", {})
            if i % 3 == 0:
                med = float(rng.uniform(50, 5000))
                s.put_rul(ps[0].actuator, {"median_h": med, "lo_h": 0.6 * med, "hi_h": 1.6 * med})
            if (i + 1) % max(1, n_act // 10) == 0:
                el = time.perf_counter() - t0
                print(f"  {i + 1}/{n_act} actuators, {total} periods, {el:.0f} s", flush=True)
    wall = time.perf_counter() - t0
    return {"periods": total, "build_s": wall, "generate_s": gen_s, "insert_s": wall - gen_s}


def time_queries(url: str, reps: int) -> dict:
    with open_store(url, create=False) as s:
        t = time.perf_counter()
        rows = s.fleet_summary()
        first = time.perf_counter() - t
        times = []
        for _ in range(reps):
            t = time.perf_counter()
            s.fleet_summary()
            times.append(time.perf_counter() - t)
    cli = []
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for _ in range(max(3, reps // 2)):
        t = time.perf_counter()
        r = subprocess.run(
            [sys.executable, "-m", "service.cli", "fleet", "--store", url, "--json"],
            cwd=ROOT, env=env, capture_output=True, check=False,
        )  # fmt: skip
        cli.append(time.perf_counter() - t)
        if r.returncode != 0:
            raise RuntimeError(r.stderr.decode())
        n = json.loads(r.stdout)["actuators"]
    web = time_web(url, reps, rows[0]["actuator"])
    return {
        **web,
        "actuators": len(rows),
        "fleet_summary_first_s": first,
        "fleet_summary_median_s": statistics.median(times),
        "fleet_summary_max_s": max(times),
        "fleet_cli_median_s": statistics.median(cli),
        "fleet_cli_max_s": max(cli),
        "fleet_cli_actuators": n,
    }


def time_web(url: str, reps: int, unit: str) -> dict:
    """Median and max wall time of GET /api/fleet and /api/unit?name=UNIT (the unit with the
    first name, a full history) on a ``servowatch web`` process serving ``url``."""
    import urllib.parse
    import urllib.request

    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli", "web", "--store", url, "--listen", "127.0.0.1:0",
         "--refresh", "0"],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        base = proc.stdout.readline().split()[1].rstrip("/")
        out: dict = {}
        for name, path in (
            ("web_fleet", "/api/fleet"),
            ("web_unit", "/api/unit?name=" + urllib.parse.quote(unit, safe="")),
        ):
            times, size = [], 0
            for _ in range(reps + 1):  # the first warms the imports up
                t = time.perf_counter()
                with urllib.request.urlopen(base + path, timeout=60) as r:
                    size = len(r.read())
                times.append(time.perf_counter() - t)
            out[f"{name}_median_s"] = statistics.median(times[1:])
            out[f"{name}_max_s"] = max(times[1:])
            out[f"{name}_bytes"] = size
        return out
    finally:
        proc.terminate()
        proc.wait(10)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--actuators", type=int, default=1000)
    ap.add_argument("--years", type=float, default=5.0)
    ap.add_argument("--flights-per-day", type=int, default=4)
    ap.add_argument("--backend", choices=("both", "sqlite", "postgresql"), default="both")
    ap.add_argument("--reps", type=int, default=7, help="timed fleet queries per backend")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true", help="print one JSON object at the end")
    a = ap.parse_args()
    # SIGTERM unwinds like Ctrl-C, so the throwaway cluster and the files are removed
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    if a.actuators < 1 or a.years <= 0 or a.flights_per_day < 1:
        ap.error("--actuators, --years and --flights-per-day must be positive")
    out: dict = {
        "actuators": a.actuators,
        "years": a.years,
        "flights_per_day": a.flights_per_day,
        "expected_periods": a.actuators * int(round(a.years * 365 * a.flights_per_day)),
    }
    tmp = Path(tempfile.mkdtemp(prefix="servowatch-bench-store-"))
    try:
        if a.backend in ("both", "sqlite"):
            path = tmp / "health.sqlite"
            print(f"SQLite {path}: building", flush=True)
            res = build(str(path), a.actuators, a.years, a.flights_per_day, a.seed)
            res["size_mb"] = sum(f.stat().st_size for f in tmp.glob("health.sqlite*")) / 1e6
            res.update(time_queries(str(path), a.reps))
            out["sqlite"] = res
            print(json.dumps(res, indent=1), flush=True)
        if a.backend in ("both", "postgresql"):
            try:
                cluster = TempCluster(settings={"shared_buffers": "512MB"})
                cluster.start()
            except ClusterUnavailableError as e:
                out["postgresql"] = {"skipped": str(e)}
                print(f"PostgreSQL skipped: {e}")
            else:
                try:
                    url = cluster.create_database("bench")
                    print(f"PostgreSQL {url}: building", flush=True)
                    res = build(url, a.actuators, a.years, a.flights_per_day, a.seed)
                    res.update(time_queries(url, a.reps))
                    out["postgresql"] = res
                    print(json.dumps(res, indent=1), flush=True)
                finally:
                    cluster.stop()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for b in ("sqlite", "postgresql"):
        r = out.get(b, {})
        if "fleet_summary_median_s" in r:
            print(
                f"{b:<10}: {r['periods']} periods built in {r['build_s']:.0f} s; "
                f"fleet_summary() median {r['fleet_summary_median_s'] * 1e3:.1f} ms "
                f"(first {r['fleet_summary_first_s'] * 1e3:.1f} ms), "
                f"`servowatch fleet --json` median {r['fleet_cli_median_s'] * 1e3:.0f} ms; "
                f"page GET /api/fleet median {r['web_fleet_median_s'] * 1e3:.0f} ms "
                f"({r['web_fleet_bytes'] / 1e6:.2f} MB), /api/unit median "
                f"{r['web_unit_median_s'] * 1e3:.0f} ms ({r['web_unit_bytes'] / 1e6:.2f} MB)"
            )
    if a.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
