"""Replay speed of one actuator at 1 kHz, stage by stage (target: >= 200x real time).

Logs ``--seconds`` of the HF bench (leak_step scenario, lengthened to ``--seconds``; 1 kHz
samples, the daemon's meas topic, fields and metadata, one chunk per second as the daemon's
1 s flush makes) with
``McapLogger.log_block``, as the daemon does, then times side by side
in one run (best of ``--repeats``, numba kernels warm):

* reading the log per message (``read_log``, a dict per sample) and as column blocks
  (``read_blocks``, what the replay uses);
* ``service.replay.replay`` without an output log (read + monitor + summary), of the meas
  log and of logs as the daemon writes them, whose chunks also hold the est/residual/health
  outputs of every sample (``log_every = 1``, the default) or of one in 10;
* ``replay`` writing a new log with every est/residual/health (``--out``), and with them
  decimated to one output in 10 (``--log-every 10``; meas and events always logged).

    .venv/bin/python bench/replay.py [--seconds 20] [--repeats 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from models.eha import simulate  # noqa: E402
from service.log import McapLogger, read_blocks, read_log  # noqa: E402
from service.log.proclog import MEAS_LOG_FIELDS  # noqa: E402
from service.monitor import Baseline, MonitorBank, MonitorConfig  # noqa: E402
from service.replay import replay  # noqa: E402
from service.sim.scenarios import load_scenario  # noqa: E402
from service.wire.messages import CHANNELS, mcap_topic  # noqa: E402


def write_live_log(path: Path, seconds: float) -> tuple[int, float]:
    """The daemon's meas log of one actuator (1 kHz HF bench, sensor noise); (n, duration)."""
    sc = load_scenario("leak_step")
    sc = sc.model_copy(update={"duration_s": max(sc.duration_s, seconds)})
    r = simulate(sc, "HF", out_every=10)
    n = min(len(r.t), int(seconds * 1000) + 1)
    rng = np.random.default_rng(1)
    cols = [np.asarray(getattr(r, c)[:n], float) for c in CHANNELS]
    cols[CHANNELS.index("x_j")] = cols[CHANNELS.index("x_j")] + rng.normal(0, 5e-6, n)
    cols[CHANNELS.index("p1")] = cols[CHANNELS.index("p1")] + rng.normal(0, 50e3, n)
    t = np.asarray(r.t[:n], float)
    vals = np.column_stack([*cols, np.arange(n), t])
    topic = mcap_topic("AC001", "elevator_L", "meas")
    cfg = MonitorConfig()
    md = {  # as the daemon's log: replay rebuilds its monitors from this
        "source": "bench",
        "monitor_config": cfg.model_dump_json(),
        "baseline": Baseline.default(cfg.model).model_dump_json(),
    }
    with McapLogger(path, background_flush=False, metadata=md) as lg:
        for a in range(0, n, 100):  # 10 messages of 10 samples per daemon tick
            lg.log_block(
                topic, t[a : a + 100], MEAS_LOG_FIELDS, vals[a : a + 100], int_fields=("seq",)
            )
            if (a + 100) % 1000 == 0:
                lg.flush()  # one chunk per second of data, as the daemon's 1 s flush
    return n, float(t[-1] - t[0])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="logged duration [s]")
    ap.add_argument("--repeats", type=int, default=7, help="best of N rounds per stage")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    res: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as d:
        live = Path(d) / "live.mcap"
        n, duration = write_live_log(live, args.seconds)
        warm = Path(d) / "warm.mcap"  # compile (or load the numba caches) before timing
        write_live_log(warm, 0.05)
        replay(warm, out=Path(d) / "warm-out.mcap")

        # the daemon's own log also holds est/residual/health (and events) in the same chunks:
        # a replay reads them past; written here by a replay, which has the daemon's layout
        full1 = Path(d) / "daemon-log-every-1.mcap"
        full10 = Path(d) / "daemon-log-every-10.mcap"
        replay(live, out=full1)
        replay(live, out=full10, log_every=10)
        blocks = list(read_blocks(live))  # the samples in memory, for the monitor alone
        t_all = np.concatenate([b.values[:, b.names.index("t")] for b in blocks])
        ch_all = np.column_stack(
            [np.concatenate([b.values[:, b.names.index(c)] for b in blocks]) for c in CHANNELS]
        )

        def monitor_alone() -> None:
            cfg = MonitorConfig()
            bank = MonitorBank(cfg, Baseline.default(cfg.model))
            k = bank.index_of("AC001/elevator_L")
            bank.update_arrays(np.full(len(t_all), k, np.int64), t_all, ch_all)

        stages = {
            "read_log": lambda: sum(1 for _ in read_log(live)),
            "read_blocks": lambda: sum(len(b.t) for b in read_blocks(live)),
            "monitor": monitor_alone,
            "replay": lambda: replay(live),
            "replay_daemon1": lambda: replay(full1),
            "replay_daemon10": lambda: replay(full10),
            "replay_out": lambda: replay(live, out=Path(d) / "out.mcap"),
            "replay_out_every10": lambda: replay(live, out=Path(d) / "o10.mcap", log_every=10),
        }
        # rounds interleave the stages, so a drift of the shared machine's speed hits all alike
        walls: dict[str, list[float]] = {key: [] for key in stages}
        for _ in range(args.repeats):
            for key, fn in stages.items():
                t0 = time.perf_counter()
                fn()
                walls[key].append(time.perf_counter() - t0)
        for key in stages:
            wall = min(walls[key])
            res[key + "_us_per_sample"] = wall / n * 1e6
            res[key + "_x_real_time"] = duration / wall
        s = replay(live)
        res["final_c_lk"] = s.final["AC001/elevator_L"]["est"]["c_lk"]
    res["samples"] = n
    res["duration_s"] = duration
    if args.json:
        print(json.dumps(res))
        return 0
    print(
        f"Replay of one actuator at 1 kHz, {duration:.1f} s of data ({n} samples), best of "
        f"{args.repeats}; target 200x real time"
    )
    print(f"  {'stage':<56}{'us/sample':>10}{'x real time':>13}")
    for label, key in (
        ("read_log: a dict per message", "read_log"),
        ("read_blocks: column blocks (the replay's reader)", "read_blocks"),
        ("monitor alone: update_arrays on the samples in memory", "monitor"),
        ("replay LOG: read + monitor + summary", "replay"),
        ("replay of a daemon log (every est/res/health in it)", "replay_daemon1"),
        ("replay of a daemon log (log_every 10)", "replay_daemon10"),
        ("replay LOG --out: + every est/residual/health logged", "replay_out"),
        ("replay LOG --out --log-every 10", "replay_out_every10"),
    ):
        print(f"  {label:<56}{res[key + '_us_per_sample']:>10.2f}"
              f"{res[key + '_x_real_time']:>13.1f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
