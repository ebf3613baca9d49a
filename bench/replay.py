"""Replay speed of one actuator at 1 kHz, stage by stage (target: >= 200x real time).

Logs ``--seconds`` of the HF bench (leak_step scenario, 1 kHz samples) with McapLogger, then
times, side by side: reading the log (read_log), reading + writing a new log with one
est/residual/health message per sample (the replay's I/O without the monitor, outputs faked
from the inputs), and the full ``service.replay.replay``. Prints x real time for each.

    .venv/bin/python bench/replay.py [--seconds 4] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from models.eha import simulate  # noqa: E402
from service.mcaplog import McapLogger, read_log  # noqa: E402
from service.messages import mcap_topic  # noqa: E402
from service.replay import replay  # noqa: E402
from service.scenarios import load_scenario  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=4.0, help="logged duration [s] (<= 4)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    sc = load_scenario("leak_step")
    r = simulate(sc, "HF", out_every=10)
    n = min(len(r.t), int(args.seconds * 1000) + 1)
    topic = mcap_topic("AC001", "elevator_L", "meas")
    res: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as d:
        live = Path(d) / "live.mcap"
        t0 = time.perf_counter()
        with McapLogger(live) as lg:
            for k in range(n):
                row = {"seq": k, "t": float(r.t[k])}
                for c in ("x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr"):
                    row[c] = float(getattr(r, c)[k])
                lg.log(topic, row["t"], row)
        res["log_write_us_per_sample"] = (time.perf_counter() - t0) / n * 1e6
        duration = float(r.t[n - 1] - r.t[0])

        t0 = time.perf_counter()
        m = sum(1 for _ in read_log(live))
        wall = time.perf_counter() - t0
        assert m == n
        res["read_only_x_real_time"] = duration / wall
        res["read_only_us_per_sample"] = wall / n * 1e6

        t0 = time.perf_counter()
        with McapLogger(Path(d) / "io.mcap") as out:
            for tp, t, msg in read_log(live):
                out.log(tp, t, msg)
                fake = {k: v for k, v in msg.items() if k != "seq"}
                out.log("/fleet/AC001/elevator_L/est", t, fake)
                out.log("/fleet/AC001/elevator_L/residual", t, fake)
                out.log("/fleet/AC001/elevator_L/health", t, fake)
        wall = time.perf_counter() - t0
        res["io_only_x_real_time"] = duration / wall
        res["io_only_us_per_sample"] = wall / n * 1e6

        warm = Path(d) / "warm.mcap"  # numba compiles (or loads its cache) on first use
        with McapLogger(warm) as lg:
            for _tp, t, msg in read_log(live):
                lg.log(topic, t, msg)
                if msg["seq"] >= 20:
                    break
        replay(warm, out=Path(d) / "warm-out.mcap")

        s = replay(live, out=Path(d) / "replay.mcap")
        res["replay_out_x_real_time"] = s.speed or float("nan")
        res["replay_out_us_per_sample"] = s.wall_s / n * 1e6
        s = replay(live)
        res["replay_x_real_time"] = s.speed or float("nan")
        res["replay_us_per_sample"] = s.wall_s / n * 1e6
        res["monitor_share_us_per_sample"] = (
            res["replay_us_per_sample"] - res["read_only_us_per_sample"]
        )
    res["samples"] = n
    res["duration_s"] = duration
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"Replay of one actuator at 1 kHz, {duration:.1f} s of data ({n} samples); target 200x")
    print(f"  {'stage':<44}{'us/sample':>10}{'x real time':>13}")
    for label, key in (
        ("read_log only", "read_only"),
        ("read_log + write meas/est/res/health (I/O)", "io_only"),
        ("replay(): read + monitor + write new log", "replay_out"),
        ("replay(): read + monitor, no output log", "replay"),
    ):
        print(f"  {label:<44}{res[key + '_us_per_sample']:>10.1f}"
              f"{res[key + '_x_real_time']:>13.1f}")  # fmt: skip
    print(f"  monitor (service.monitor) share: about {res['monitor_share_us_per_sample']:.0f} "
          "us/sample")  # fmt: skip
    print(f"  log write (McapLogger.log, meas): {res['log_write_us_per_sample']:.1f} us/sample")
    return 0


if __name__ == "__main__":
    sys.exit(main())
