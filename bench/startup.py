"""Start-up of the everyday commands, each in a fresh process (the median of ``--runs``):

    .venv/bin/python bench/startup.py [--runs 5]

Prints one line per figure (seconds, wall clock):
``help``: ``servowatch --help`` to its exit; ``router_listen``: from the spawn of
``servowatch router --listen tcp/127.0.0.1:P`` to a TCP connect to P succeeding;
``status``: ``servowatch status --timeout 0.2`` against that router (no daemon: exit 3) to its
exit, the 0.2 s reply timeout included; ``kernel_from_cache``: a fresh process importing the
monitor and running its first block (the compiled kernels loaded from numba's cache; run
``servowatch warmup`` first); ``import_monitor``: the import alone. The CPU seconds (user +
system) of a figure's process are printed beside it: wall times follow the machine's load
(printed too), CPU times much less. Issue 34's targets: help < 0.5 s, router_listen < 0.5 s,
kernel_from_cache < 1 s.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.restart import servowatch_exe  # noqa: E402
from service.zenoh_util import free_port, loopback  # noqa: E402

_KERNEL = """
import time
t0 = time.perf_counter()
import numpy as np
from service.monitor import MonitorBank
t1 = time.perf_counter()
bank = MonitorBank()
k = bank.index_of("a")
t = 1e-3 * np.arange(1, 11)
ch = np.tile([0.0, 0.0, 0.0, 10e6, 10e6, 20e6, 0.0], (10, 1))
bank.update_arrays(np.full(10, k, np.int64), t, ch)
t2 = time.perf_counter()
print(t1 - t0, t2 - t0, time.process_time())
"""


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _wall(cmd: list[str], ok: tuple[int, ...] = (0,)) -> tuple[float, float]:
    """(wall, CPU user + system) seconds of ``cmd`` run to its exit."""
    c0 = _cpu_children()
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    dt = time.perf_counter() - t0
    if r.returncode not in ok:
        raise RuntimeError(f"{cmd}: exit {r.returncode}: {r.stderr[-500:]}")
    return dt, _cpu_children() - c0


def _router_listen(port: int) -> tuple[float, subprocess.Popen]:
    import socket

    t0 = time.perf_counter()
    p = subprocess.Popen(
        [*servowatch_exe(), "router", "--listen", loopback(port)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    while time.perf_counter() - t0 < 60:
        try:
            socket.create_connection(("127.0.0.1", port), 0.05).close()
            return time.perf_counter() - t0, p
        except OSError:
            time.sleep(0.005)
    p.kill()
    raise TimeoutError("the router never listened")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--json", action="store_true", help="one JSON object instead of lines")
    a = ap.parse_args()
    sw = servowatch_exe()
    figs: dict[str, list[float]] = {
        k: [] for k in ("help", "router_listen", "status", "import_monitor", "kernel_from_cache")
    }
    cpu: dict[str, list[float]] = {k: [] for k in ("help", "status", "kernel_from_cache")}
    for _ in range(a.runs):
        wall, c = _wall([*sw, "--help"])
        figs["help"].append(wall)
        cpu["help"].append(c)
        port = free_port()
        dt, router = _router_listen(port)
        figs["router_listen"].append(dt)
        try:
            wall, c = _wall(
                [*sw, "status", "--timeout", "0.2", "--connect", loopback(port)], ok=(3,)
            )
            figs["status"].append(wall)
            cpu["status"].append(c)
        finally:
            router.terminate()
            router.wait(10)
        out = subprocess.run(
            [sys.executable, "-c", _KERNEL], capture_output=True, text=True, cwd=ROOT, check=True
        ).stdout.split()
        figs["import_monitor"].append(float(out[0]))
        figs["kernel_from_cache"].append(float(out[1]))
        cpu["kernel_from_cache"].append(float(out[2]))
    med = {k: statistics.median(v) for k, v in figs.items()}
    cmed = {k: statistics.median(v) for k, v in cpu.items()}
    load = os.getloadavg()[0]
    if a.json:
        print(json.dumps({"runs": a.runs, "load_1min": load,
                          **{f"{k}_s": round(v, 3) for k, v in med.items()},
                          **{f"{k}_cpu_s": round(v, 3) for k, v in cmed.items()}}))  # fmt: skip
        return
    print(f"load average (1 min) at the end: {load:.1f} on {os.cpu_count()} cores")
    for k, v in med.items():
        c = f"; CPU {cmed[k]:.3f} s" if k in cmed else ""
        print(f"{k:<18} {v:6.3f} s  (median of {a.runs}; max {max(figs[k]):.3f} s{c})")


if __name__ == "__main__":
    main()
