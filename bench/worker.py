"""Benchmark: the daemon's pipeline in one process, without Zenoh: CPU per sample of each stage.

``service.daemon.Daemon`` as ``servowatch run`` builds it (the real monitor, the MCAP log
process), fed pre-encoded binary messages (the virtual actuator's HF run, 10 samples per
message, as ``bench/service.py``'s generator sends them) through ``Daemon.submit`` in ticks
of ``--tick`` messages (default N/2: 5 ms of N actuators at 1 kHz), then
``process_pending`` per tick, as fast as it goes. Printed: CPU time per sample of the
worker's stages (intake: decode and acceptance; monitor: the bank's update with its step
threads; outputs: the meas log records, the fan-out, commit), of the monitor's step threads,
and of the log process; the floor of each part with no transport and no contention from
other processes of the bench. ``--compare-tree PATH`` runs every row again on another checkout's
``service`` package, side by side.

    .venv/bin/python bench/worker.py --actuators 20,100 --model WH --compare-tree ../main
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

ROOT = Path(__file__).resolve().parent.parent
if sys.path and Path(sys.path[0]).resolve() == ROOT / "bench":
    sys.path.pop(0)  # bench/service.py is not the service package (PYTHONPATH names the tree)


def _proc_cpu(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        txt = f.read()
    fields = txt[txt.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _threads_cpu(prefix: str) -> float:
    """CPU seconds of this process's threads whose name starts with ``prefix``."""
    import threading

    ids = {t.native_id for t in threading.enumerate() if t.name.startswith(prefix)}
    total = 0.0
    for tid in ids:
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                txt = f.read()
        except OSError:
            continue
        fields = txt[txt.rindex(")") + 2 :].split()
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def _run(args: argparse.Namespace) -> dict:
    """One row, in this process (the checkout on sys.path first)."""
    from service.config import ServiceConfig
    from service.daemon import Daemon
    from service.sim.actuator import VirtualActuator
    from service.sim.scenarios import load_scenario
    from service.wire import messages as m

    rate, spm = 1000.0, 10
    n_per = int(args.seconds * rate)
    base = VirtualActuator(load_scenario("demo"), rate_hz=rate).produce(n_per)
    keys = [m.KEY_MEAS.format(aircraft=f"AC{a // 4:03d}", actuator=f"act{a % 4}")
            for a in range(args.n)]  # fmt: skip
    msgs = []
    for j in range(0, n_per, spm):
        p = m.encode_meas([dict(base[k], seq=k, t=1.7e9 + k / rate) for k in range(j, j + spm)])
        msgs += [(key, p) for key in keys]
    tmp = tempfile.mkdtemp(prefix="servowatch-bench-")
    cfg = ServiceConfig(monitor={"model": args.model}, station="bench", rotate_bytes=None,
                        rotate_s=None, silence_s=1e9, store="off")  # fmt: skip
    d = Daemon(cfg, log_path=Path(tmp) / "w.mcap")
    d.monitor.warm_up()
    stages = {"intake": 0.0, "monitor": 0.0, "outputs": 0.0}
    tick = args.tick or max(1, args.n // 2)

    def timed(name, fn):
        def f(*a):
            t0 = time.thread_time()
            try:
                return fn(*a)
            finally:
                stages[name] += time.thread_time() - t0

        return f

    nw = len(msgs) // 10  # the first tenth warms up, untimed
    k = 0
    while k < nw:
        for key, p in msgs[k : k + tick]:
            d.submit(key, p)
        k += tick
        d.process_pending()
    d.intake.take = timed("intake", d.intake.take)
    d.monitor.run = timed("monitor", d.monitor.run)
    d.outputs.write = timed("outputs", d.outputs.write)
    lp = d.outputs.logger._proc.pid
    l0, s0 = _proc_cpu(lp), _threads_cpu("monitor-step")
    c0 = time.thread_time()
    samples = 0
    while k < len(msgs):
        for key, p in msgs[k : k + tick]:
            d.submit(key, p)
        k += tick
        samples += d.process_pending()
    worker = time.thread_time() - c0
    steps = _threads_cpu("monitor-step") - s0
    d.outputs.logger.commit()
    time.sleep(1.0)  # the log process writes what it was sent
    logc = _proc_cpu(lp) - l0
    st = d.stop()

    def us(x):
        return 1e6 * x / samples

    return {
        "code": args.code,
        "actuators": args.n,
        "tick_msgs": tick,
        "samples": samples,
        "bad": st["bad"],
        "intake": us(stages["intake"]),
        "monitor": us(stages["monitor"]),
        "outputs": us(stages["outputs"]),
        "worker": us(worker),
        "steps": us(steps),
        "log": us(logc),
        "loadavg": os.getloadavg(),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--actuators", default="20,100", help="comma-separated N")
    p.add_argument("--model", default="WH")
    p.add_argument("--seconds", type=float, default=3.0, help="of samples per actuator")
    p.add_argument("--tick", type=int, default=0, help="messages per tick (default N/2)")
    p.add_argument("--compare-tree", default=None)
    p.add_argument("--json", action="store_true")
    p.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a child: one row
    p.add_argument("--n", type=int, default=20, help=argparse.SUPPRESS)
    p.add_argument("--code", default="this", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.one:
        print(json.dumps(_run(args)), flush=True)
        return 0
    rows = []
    trees = [None] if args.compare_tree is None else [None, args.compare_tree]
    for n in [int(x) for x in args.actuators.split(",")]:
        for tree in trees:
            root = Path(tree).resolve() if tree else ROOT
            cmd = [sys.executable, str(Path(__file__).resolve()), "--one", "--n", str(n),
                   "--model", args.model, "--seconds", str(args.seconds), "--tick",
                   str(args.tick), "--code", root.name if tree else "this"]  # fmt: skip
            env = {**os.environ, "PYTHONPATH": str(root)}
            r = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
            if r.returncode != 0:
                print(f"failed ({root}):\n{r.stderr[-2000:]}", file=sys.stderr)
                continue
            rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
            print("  " + json.dumps(rows[-1]), file=sys.stderr, flush=True)
    print(f"servowatch worker benchmark ({os.cpu_count()} CPUs), model {args.model}, "
          f"10 samples/message, no Zenoh")  # fmt: skip
    print(f"{'code':>10} {'act':>4} {'tick':>4} {'intake':>7} {'monitor':>7} {'outputs':>7} "
          f"{'worker':>7} {'steps':>6} {'log proc':>8} {'total':>6}  load avg")  # fmt: skip
    for r in rows:
        total = r["worker"] + r["steps"] + r["log"]
        print(f"{r['code'][:10]:>10} {r['actuators']:>4} {r['tick_msgs']:>4} {r['intake']:>7.2f} "
              f"{r['monitor']:>7.2f} {r['outputs']:>7.2f} {r['worker']:>7.2f} {r['steps']:>6.2f} "
              f"{r['log']:>8.2f} {total:>6.1f}  "
              + "/".join(f"{x:.1f}" for x in r["loadavg"]))  # fmt: skip
    print("CPU time per sample [us]: the worker thread's stages (intake = decode and acceptance, "
          "monitor = the bank's update in this thread, outputs = meas log records, fan-out, "
          "commit), the worker as a whole, the monitor's step threads, the MCAP log process; "
          "total = worker + steps + log")  # fmt: skip
    if args.json:
        print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
