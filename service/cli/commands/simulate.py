"""``servowatch simulate``: one closed-loop EHA bench run of a scenario with a chosen valve."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from service.cli.util import check_outputs, emit_json, fail, writing
from service.progress import Progress
from service.sim.scenarios import ScenarioError, load_scenario, resolve_scenario

NAME = "simulate"
HELP = "run the EHA bench on a scenario with one valve model (HF, A, B, C1, C3, C5, WH)"

VALVES = ("HF", "A", "B", "C1", "C3", "C5", "WH")
SIGNALS = (
    "x_cmd",
    "f_r",
    "p_sr",
    "c_lk",
    "i_c",
    "i",
    "x_s",
    "v_s",
    "x_j",
    "v_j",
    "p1",
    "p2",
    "p12",
    "q_j",
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", required=True, help="scenario TOML file (or a bundled name)")
    p.add_argument("--valve", required=True, choices=VALVES, help="fluid-dynamic valve model")
    p.add_argument("--out", default=None, help="write the time histories to this MCAP file")
    p.add_argument("--png", default=None, help="write a plot of the run to this PNG file")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def write_mcap(res, path: str | Path, scenario_name: str) -> Path:
    """Every sample of ``res`` as one JSON message on ``/bench/{valve}/state`` (log_time = t)."""
    from service.log import McapLogger

    topic = f"/bench/{res.valve}/state"
    cols = {k: np.asarray(getattr(res, k), float) for k in SIGNALS}
    with McapLogger(path) as log:
        for k, t in enumerate(res.t):
            log.log(topic, float(t), {name: float(v[k]) for name, v in cols.items()})
    return Path(path)


def warm_up(scenario, valve: str) -> None:
    """Run a few steps first so that ``wall_s`` measures the simulation, not the JIT load."""
    from models.eha import simulate

    short = scenario.model_copy(update={"duration_s": 10 * scenario.step_s})
    simulate(short, valve)


def summary(res, scenario_name: str) -> dict:
    """The JSON summary of one run (issue 2 item 6)."""
    duration = float(res.t[-1] - res.t[0])
    return {
        "valve": res.valve,
        "scenario": scenario_name,
        "duration_s": duration,
        "wall_s": float(res.wall_s),
        "realtime_factor": duration / res.wall_s if res.wall_s > 0 else float("inf"),
        "peak_abs_p12_pa": float(np.max(np.abs(res.p12))),
        "max_abs_v_j_m_s": float(np.max(np.abs(res.v_j))),
        "final_x_j_m": float(res.x_j[-1]),
    }


def run(args: argparse.Namespace) -> int:
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as e:
        return fail(str(e))
    check_outputs(
        [("--out", args.out), ("--png", args.png)],
        [("--scenario", resolve_scenario(args.scenario))],
    )
    from models.eha import simulate
    from service.cli.warmup import ensure

    ensure("models" if args.valve == "HF" else "valves")
    warm_up(scenario, args.valve)
    prog = Progress(f"simulate {args.valve}")
    t0 = time.perf_counter()
    res = simulate(scenario, args.valve, progress=prog)
    prog.done()
    if not np.isfinite(res.wall_s) or res.wall_s <= 0:
        res.wall_s = time.perf_counter() - t0
    out = summary(res, scenario.name)
    if args.out:
        with writing("--out", args.out):
            write_mcap(res, args.out, scenario.name)
    if args.png:
        from service.plots import plot_simulation

        with writing("--png", args.png, so_far=f"--out {args.out} written" if args.out else None):
            plot_simulation(res, args.png, title=f"{scenario.name}: valve {args.valve}")
    if args.json:
        emit_json(out)
        return 0
    print(f"scenario {scenario.name}, valve {args.valve}")
    print(
        f"  simulated {out['duration_s']:.3f} s in {out['wall_s']:.3f} s wall "
        f"({out['realtime_factor']:.0f}x real time)"
    )
    print(f"  peak |P12|   {out['peak_abs_p12_pa'] / 1e6:8.2f} MPa")
    print(f"  max |v_J|    {out['max_abs_v_j_m_s'] * 1e3:8.1f} mm/s")
    print(f"  final x_J    {out['final_x_j_m'] * 1e3:8.2f} mm")
    if args.out:
        print(f"  time histories written to {args.out}")
    if args.png:
        print(f"  plot written to {args.png}")
    return 0
