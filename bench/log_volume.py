"""Benchmark: bytes of MCAP log per actuator per hour, for each ``log_every``.

The virtual actuator of ``scenarios/demo.toml`` (the HF bench with sensor noise, the demo's
faults; what ``servowatch actuator`` publishes) at 1 kHz, ``--spm`` samples per message, fed
to ``service.daemon.Daemon`` exactly as ``servowatch run`` builds it (the real monitor, the
in-process MCAP writer, zstd level 1, no store), ``--seconds`` of samples per run; the
closed file's size scaled to an hour. The meas rows (every sample, whatever ``log_every``)
and the est/residual/health rows are logged as the daemon logs them. Deterministic: the
scenario's seed; the byte count does not depend on the machine's load.

    .venv/bin/python bench/log_volume.py [--seconds 60] [--every 1,10,100] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.config import ServiceConfig  # noqa: E402
from service.daemon import Daemon  # noqa: E402
from service.sim.actuator import VirtualActuator  # noqa: E402
from service.sim.scenarios import load_scenario  # noqa: E402
from service.wire import messages as m  # noqa: E402

KEY = "fleet/AC001/elevator_L/meas"


def run(log_every: int, seconds: float, rate: float, spm: int, folder: Path) -> dict:
    """One daemon, ``seconds`` of one actuator: the log's bytes, messages and B/h."""
    sc = load_scenario("demo")
    t0 = time.time() - seconds - 10
    va = VirtualActuator(sc, rate_hz=rate, t_origin=t0, seed=1)
    cfg = ServiceConfig(log_every=log_every, store="off", rotate_bytes=None, rotate_s=None)
    path = folder / f"every{log_every}.mcap"
    d = Daemon(cfg, log_path=path, log_process=False, gather_s=0)  # no worker: fed here
    n = int(seconds * rate)
    while va.seq < n:
        samples = va.produce(min(spm * 50, n - va.seq))
        for j in range(0, len(samples), spm):
            d.submit(KEY, m.encode_meas(samples[j : j + spm]))
        d.process_pending()
    final = d.stop()
    size = path.stat().st_size
    return {
        "log_every": log_every,
        "seconds": seconds,
        "samples": final["samples"],
        "bytes": size,
        "mb_per_hour": size / seconds * 3600 / 1e6,
        "gb_per_day": size / seconds * 86400 / 1e9,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="sample seconds per run")
    ap.add_argument("--every", default="1,10,100", help="log_every values")
    ap.add_argument("--rate", type=float, default=1000.0, help="sample rate [Hz]")
    ap.add_argument("--spm", type=int, default=20, help="samples per message")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for e in (int(x) for x in a.every.split(",")):
            rows.append(run(e, a.seconds, a.rate, a.spm, Path(tmp)))
    if a.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"one actuator at {a.rate:.0f} Hz, {a.seconds:.0f} s of samples per run (demo scenario)")
    print(f"{'log_every':>9} {'samples':>8} {'bytes':>11} {'MB/h':>8} {'GB/day':>7}")
    for r in rows:
        print(f"{r['log_every']:>9} {r['samples']:>8} {r['bytes']:>11} "
              f"{r['mb_per_hour']:>8.0f} {r['gb_per_day']:>7.1f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
