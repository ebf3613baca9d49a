"""Benchmark of the degradation monitor (issue 3): accuracy over the scenario set and speed
side by side (this monitor, a plain filterpy UKF calling the model once per sigma point, and
NASA ProgPy 1.9's UnscentedKalmanFilter on the same model as a PrognosticsModel).

    .venv/bin/python bench/estimation.py                 # everything (about 4 min)
    .venv/bin/python bench/estimation.py --healthy-s 60  # shorter false-alarm run
    .venv/bin/python bench/estimation.py --skip-accuracy # speed only
    .venv/bin/python bench/estimation.py --json out.json # also write the figures as JSON
    .venv/bin/python bench/estimation.py --model C5,WH   # process models side by side
    .venv/bin/python bench/estimation.py --model C5,WH --skip-accuracy --clock cpu

The randomized duty-cycle suite is ``python -m evaluation.suite`` (docs/estimation.md).

The truth is the HF bench with the scenarios' seeded sensor noise. ProgPy is optional
(``pip install 'progpy==1.9.*'``, the ``bench`` extra); without it that column reads
"progpy not installed". Speed figures are medians on this machine, one core: wall clock, or
with ``--clock cpu`` the calling thread's CPU time (``time.thread_time``), which time slices
taken by other processes on a shared, loaded machine do not inflate.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluation.scenarios import SCENARIOS, SCENARIOS_WH, bundled_scenario  # noqa: E402
from evaluation.suite import parse_overrides  # noqa: E402
from models import eha_reduced as er  # noqa: E402
from service.monitor import Baseline, Monitor, MonitorBank, MonitorConfig  # noqa: E402
from service.monitor.calibration import measured_run  # noqa: E402
from service.monitor.ukf import ukf_step_batch  # noqa: E402
from service.sim.scenarios import load_scenario  # noqa: E402

CLOCKS = {"wall": time.perf_counter, "cpu": time.thread_time}
_clock = CLOCKS["wall"]  # the speed runs' clock (``--clock``)
_CLOCK_NAME = {time.perf_counter: "wall time", time.thread_time: "thread CPU time"}


# -- accuracy ------------------------------------------------------------------------------
def _one(args) -> dict:
    model, overrides, name, channels, duration, *leak = args
    from service.cli.commands.estimate import evaluate

    sc = bundled_scenario(name, duration, leak[0] if leak else None)
    r = evaluate(sc, MonitorConfig(model=model, channels=channels, **overrides))
    return {k: v for k, v in r.items() if not k.startswith("_")}


def accuracy(
    healthy_s: float,
    workers: int,
    models: tuple[str, ...] = ("C5",),
    overrides: dict | None = None,
) -> list[dict]:
    """Every scenario for every model; the rows of one scenario are adjacent (models side by
    side). ``overrides``: MonitorConfig fields set for every model."""
    jobs = [(n, ch, None) for ch in ("full", "reduced") for n in SCENARIOS]
    jobs.insert(0, ("healthy_noise", "full", healthy_s))
    jobs.insert(4, ("leak_step", "full", None, 4e-13))  # the smallest target: +1x nominal
    jobs[7:7] = [(n, "full", None) for n in SCENARIOS_WH]
    with ProcessPoolExecutor(max_workers=workers) as ex:
        return list(ex.map(_one, [(m, overrides or {}, *j) for j in jobs for m in models]))


def _fmt(v, spec: str) -> str:
    width = int("".join(c for c in spec.split(".")[0] if c.isdigit()) or 0)
    return "-".rjust(width) if v is None else format(v, spec)


def print_accuracy(rows: list[dict]) -> None:
    print(
        '\nAccuracy (truth: HF bench + sensor noise; values at the end of each run; "1s":'
        ' mean over the last second; "rms": over the run after the arming time)'
    )
    hdr = (
        f"{'scenario':<22}{'model':<6}{'ch':<8}{'dur s':>6}{'C_Lk err%':>10}{'C_Lk 1s%':>9}{'C_Lk rms%':>10}{'incr err%':>10}{'1s-mean%':>9}"
        f"{'P_SR err%':>10}{'P_SR rms%':>10}{'P_SR 5% s':>10}{'delay s':>8}{'false':>6}{'NIS in%':>8}"
        f"{'reinit':>7}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(
            f"{r['scenario']:<22}{r['model']:<6}{r['channels']:<8}{r['duration_s']:>6.0f}"
            f"{_fmt(r['c_lk_error_pct'], '+10.1f')}{_fmt(r.get('c_lk_error_settled_pct'), '+9.1f')}"
            f"{_fmt(r.get('c_lk_rms_pct'), '10.1f')}"
            f"{_fmt(r['c_lk_increase_error_pct'], '+10.1f')}"
            f"{_fmt(r['c_lk_increase_error_settled_pct'], '+9.1f')}"
            f"{_fmt(r['p_sr_error_pct'], '+10.2f')}{_fmt(r.get('p_sr_rms_pct'), '10.2f')}"
            f"{_fmt(r['p_sr_settle_s'], '10.3f')}"
            f"{_fmt(r['detection_delay_s'], '8.3f')}{r['false_alarms']:>6d}"
            f"{_fmt(r['nis_in_band_pct'], '8.1f')}{r['counters']['reinit']:>7d}"
        )


# -- speed ---------------------------------------------------------------------------------
def _samples(n: int) -> list[dict]:
    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": n / 1000 + 0.01})
    _, meas = measured_run(sc)
    keys = ("t", "x_cmd", "i", "x_s", "x_j", "p1", "p2")
    cols = [np.asarray(meas[k], float).tolist() for k in keys]
    return [dict(zip(keys, row, strict=True)) for row in zip(*cols, strict=True)][:n]


def speed_monitor(samples: list[dict], model: str = "C5") -> float:
    mon = Monitor(MonitorConfig(model=model))
    dts = []
    pc = _clock
    for s in samples:
        a = pc()
        mon.update(s)
        dts.append(pc() - a)
    return float(np.median(dts[50:]) * 1e6)


def speed_bank(samples: list[dict], n_act: int, rows: bool = False, model: str = "C5") -> float:
    """MonitorBank.update_many (dict outputs) or update_rows (array outputs), per actuator."""
    bank = MonitorBank(MonitorConfig(model=model))
    ids = [f"act{k:03d}" for k in range(n_act)]
    dts = []
    pc = _clock
    call = bank.update_rows if rows else bank.update_many
    for s in samples:
        batch = [(a, s) for a in ids]
        t0 = pc()
        call(batch)
        dts.append(pc() - t0)
    return float(np.median(dts[20:]) * 1e6 / n_act)


def speed_arrays(samples: list[dict], n_act: int, per_call: int = 10, model: str = "C5") -> float:
    """MonitorBank.update_arrays (the daemon's path: samples decoded straight into arrays,
    ``per_call`` consecutive samples of every actuator per call, as a 10-sample message per
    actuator and tick), per actuator and sample."""
    from service.wire.messages import CHANNELS

    bank = MonitorBank(MonitorConfig(model=model))
    rows = [bank.index_of(f"act{k:03d}") for k in range(n_act)]
    t_all = np.array([s["t"] for s in samples])
    ch_all = np.array([[s.get(c, np.nan) for c in CHANNELS] for s in samples], float)
    dts = []
    pc = _clock
    for a in range(0, len(samples) - per_call + 1, per_call):
        ks = np.repeat(np.array(rows, np.int64), per_call)
        t = np.tile(t_all[a : a + per_call], n_act)
        ch = np.tile(ch_all[a : a + per_call], (n_act, 1))
        t0 = pc()
        bank.update_arrays(ks, t, ch)
        dts.append(pc() - t0)
    return float(np.median(dts[5:]) * 1e6 / (n_act * per_call))


def speed_kernel(
    samples: list[dict], n_act: int, model: str = "C5", n_sub: int | None = None
) -> float:
    """The compiled UKF step alone (no sample parsing, no output dicts), per actuator;
    ``n_sub``: integration steps per 1 ms sample instead of the model's own (1 for every
    model: WH takes one ROS2 step, docs/models.md section 7)."""
    bank = MonitorBank(MonitorConfig(model=model))
    ids = [f"act{k:03d}" for k in range(n_act)]
    for s in samples[:2]:
        bank.update_many([(a, s) for a in ids])
    ks = np.arange(n_act)
    x, P = bank.x[ks].copy(), bank.P[ks].copy()
    w = bank.ukf.w
    z = np.tile(np.array([[1.1e-5 / bank._zscale[0], 0.0, 12.4, 8.4, 0.0]]), (n_act, 1))
    mask = np.tile(np.array([[True, True, True, True, False]]), (n_act, 1))
    n_s = max(1, int(np.ceil(1e-3 / bank._cst[0] - 1e-9)))  # substeps at 1 ms (h_max)
    n_s = n_s if n_sub is None else n_sub
    i_in, dt, n_sub = np.full(n_act, 2e-4), np.full(n_act, 1e-3), np.full(n_act, n_s, np.int64)
    y, nis, st = np.zeros((n_act, 5)), np.zeros(n_act), np.zeros(n_act, np.int64)
    dts = []
    for _ in range(300):
        xx, PP = x.copy(), P.copy()
        t0 = _clock()
        ukf_step_batch(
            xx, PP, z, mask, i_in, dt, n_sub, bank._q, bank.R, bank.scale, bank._zscale,
            w.Wm, w.Wc, w.c, bank._prm, y, nis, st,
        )  # fmt: skip
        dts.append(_clock() - t0)
    return float(np.median(dts) * 1e6 / n_act)


def _filter_setup():
    bank = MonitorBank()
    return bank, bank.baseline.reduced_params()


def speed_filterpy(samples: list[dict]) -> float:
    """filterpy's UnscentedKalmanFilter, the numpy model called once per sigma point."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    bank, rp = _filter_setup()
    sc, zs = bank.scale, bank._zscale
    cur = {"i": 0.0}

    def fx(x, dt):
        ev = x * sc
        ev[6], ev[5] = max(ev[6], 0.0), max(ev[5], rp.p_vap)
        out = er.step(ev, cur["i"], dt, rp, 1)
        out[5:] = (x * sc)[5:]
        return out / sc

    def hx(x):
        return er.measure(x * sc, rp)[:4] / zs[:4]

    pts = MerweScaledSigmaPoints(8, alpha=0.5, beta=2.0, kappa=0.0)
    f = UnscentedKalmanFilter(dim_x=8, dim_z=4, dt=1e-3, hx=hx, fx=fx, points=pts)
    s0 = samples[0]
    f.x = np.array([s0["x_s"], 0, s0["x_j"], 0, 1e-3 * (s0["p1"] - s0["p2"]), 20e6, 2e-13, 0]) / sc
    f.P = np.diag((np.array([2e-6, 1e-3, 1e-4, 5e-3, 5e3, 2e6, 2e-13, 2e-4]) / sc) ** 2)
    f.Q = np.diag(bank._q) * 1e-3
    f.R = bank.R[:4, :4]
    dts = []
    for s in samples[1:]:
        z = np.array([s["x_s"], s["x_j"], s["p1"], s["p2"]]) / zs[:4]
        cur["i"] = s["i"]
        t0 = time.perf_counter()
        f.predict()
        f.update(z)
        dts.append(time.perf_counter() - t0)
    return float(np.median(dts) * 1e6)


def speed_progpy(samples: list[dict]) -> float | None:
    """ProgPy 1.9's UnscentedKalmanFilter on the same model as a PrognosticsModel."""
    try:
        from progpy import PrognosticsModel
        from progpy.state_estimators import UnscentedKalmanFilter
        from progpy.uncertain_data import MultivariateNormalDist
    except ImportError:
        return None
    bank, rp = _filter_setup()
    sc, zs = bank.scale, bank._zscale
    names = list(er.STATE_NAMES)

    class EHAReduced(PrognosticsModel):
        """The C5 EHA process model of models.eha_reduced (filter units)."""

        inputs = ["i"]
        states = names
        outputs = ["x_s_m", "x_j_m", "p1", "p2"]
        default_parameters = {"process_noise": 0.0, "measurement_noise": 0.0, "x0": {}}

        def next_state(self, x, u, dt):
            v = np.array([x[k] for k in names], float) * sc
            v[6], v[5] = max(v[6], 0.0), max(v[5], rp.p_vap)
            out = er.step(v, float(u["i"]), dt, rp, 1) / sc
            out[5:] = [x["p_sr"], x["c_lk"], x["i_b"]]
            return self.StateContainer(dict(zip(names, out.tolist(), strict=True)))

        def output(self, x):
            v = np.array([x[k] for k in names], float) * sc
            z = er.measure(v, rp)[:4] / zs[:4]
            return self.OutputContainer(dict(zip(self.outputs, z.tolist(), strict=True)))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = EHAReduced()
        s0 = samples[0]
        x0 = np.array([s0["x_s"], 0, s0["x_j"], 0, 1e-3 * (s0["p1"] - s0["p2"]), 20e6, 2e-13, 0])
        cov = np.diag((np.array([2e-6, 1e-3, 1e-4, 5e-3, 5e3, 2e6, 2e-13, 2e-4]) / sc) ** 2)
        xd = MultivariateNormalDist(names, (x0 / sc).tolist(), cov)
        f = UnscentedKalmanFilter(
            m, xd, Q=np.diag(bank._q) * 1e-3, R=bank.R[:4, :4], alpha=0.5, beta=2.0, kappa=0.0,
            t0=s0["t"], dt=1e-3,
        )  # fmt: skip
        dts = []
        for s in samples[1:]:
            u = m.InputContainer({"i": s["i"]})
            z = m.OutputContainer(
                dict(zip(m.outputs, (np.array([s["x_s"], s["x_j"], s["p1"], s["p2"]]) / zs[:4])
                         .tolist(), strict=True))
            )  # fmt: skip
            t0 = time.perf_counter()
            f.estimate(s["t"], u, z)
            dts.append(time.perf_counter() - t0)
    return float(np.median(dts) * 1e6)


def speed_models(n: int, fleet: int, models: tuple[str, ...], repeats: int = 3) -> dict:
    """The monitor's own paths for each process model, side by side: each repeat times every
    model in turn (interleaved, so that load on the shared machine hits them alike); the
    best of ``repeats``, per model and path [us per actuator and sample]."""
    samples = _samples(n)
    paths = {
        "monitor_single_us": lambda m: speed_monitor(samples, m),
        f"monitor_bank{fleet}_rows_us_per_actuator": lambda m: speed_bank(
            samples, fleet, rows=True, model=m
        ),
        f"monitor_bank{fleet}_arrays_us_per_actuator": lambda m: speed_arrays(
            samples, fleet, model=m
        ),
        f"kernel{fleet}_us_per_actuator": lambda m: speed_kernel(samples, fleet, m),
    }
    vals: dict = {m: {k: [] for k in paths} for m in models}
    for _ in range(repeats):
        for k, fn in paths.items():
            for m in models:
                vals[m][k].append(fn(m))
    return {m: {k: min(v) for k, v in d.items()} for m, d in vals.items()}


def print_speed_models(sp: dict, fleet: int) -> None:
    models = list(sp)
    print(f"\nSpeed per process model (median {_CLOCK_NAME[_clock]} per actuator and sample, "
          "best of runs)")  # fmt: skip
    print(f"  {'path':<52}" + "".join(f"{m:>10}" for m in models) + (
        f"{models[-1] + ' / ' + models[0]:>12}" if len(models) > 1 else ""))  # fmt: skip
    for k in sp[models[0]]:
        v = [sp[m][k] for m in models]
        ratio = f"{v[-1] / v[0]:11.2f}x" if len(models) > 1 else ""
        print(f"  {k:<52}" + "".join(f"{x:10.1f}" for x in v) + ratio)
    arr = f"monitor_bank{fleet}_arrays_us_per_actuator"
    print("  actuators per core at 1 kHz, update_arrays: " + ", ".join(
        f"{m} {1e3 / sp[m][arr]:.1f}" for m in models))  # fmt: skip
    if "C5" in models:
        for m in models:
            if m != "C5":
                print(f"  update_arrays {m} / C5: {sp[m][arr] / sp['C5'][arr]:.2f}x "
                      "(issue 41's target for WH: at most 2x)")  # fmt: skip


def speed(n: int, fleet: int, repeats: int = 3) -> dict:
    """Median time per update, best of ``repeats`` runs for each contender (the machine is
    shared; the best run is the least disturbed one, as ``timeit`` does)."""
    samples = _samples(n)

    def best(fn, *a, **kw):
        vals = [fn(*a, **kw) for _ in range(repeats)]
        return None if vals[0] is None else min(vals)

    out = {
        "monitor_single_us": best(speed_monitor, samples),
        f"monitor_bank{fleet}_us_per_actuator": best(speed_bank, samples, fleet),
        f"monitor_bank{fleet}_rows_us_per_actuator": best(speed_bank, samples, fleet, rows=True),
        f"monitor_bank{fleet}_arrays_us_per_actuator": best(speed_arrays, samples, fleet),
        f"kernel{fleet}_us_per_actuator": best(speed_kernel, samples, fleet),
        "filterpy_per_sigma_point_us": best(speed_filterpy, samples[: min(n, 1000)]),
        "progpy_ukf_us": best(speed_progpy, samples[: min(n, 300)]),
        "repeats": repeats,
    }
    return out


def print_speed(sp: dict, fleet: int) -> None:
    print(
        f"\nSpeed per update (median wall time, best of {sp['repeats']} runs, one core, "
        "8 states, 4 channels, 1 kHz data)"
    )
    mono = sp["monitor_single_us"]
    bank = sp[f"monitor_bank{fleet}_us_per_actuator"]
    rows_ = sp[f"monitor_bank{fleet}_rows_us_per_actuator"]
    arr = sp[f"monitor_bank{fleet}_arrays_us_per_actuator"]
    rows = [
        ("servowatch Monitor, one actuator", mono),
        (f"servowatch MonitorBank.update_many, {fleet} actuators (per actuator)", bank),
        (f"servowatch MonitorBank.update_rows, {fleet} actuators (per actuator)", rows_),
        (f"servowatch MonitorBank.update_arrays, {fleet} actuators (per actuator)", arr),
        (f"compiled UKF kernel alone, {fleet} actuators (per actuator)", sp[f"kernel{fleet}_us_per_actuator"]),
        ("filterpy UKF, model called per sigma point", sp["filterpy_per_sigma_point_us"]),
        ("ProgPy 1.9 UnscentedKalmanFilter (PrognosticsModel)", sp["progpy_ukf_us"]),
    ]  # fmt: skip
    for label, v in rows:
        print(f"  {label:<62}" + ("progpy not installed" if v is None else f"{v:10.1f} us"))
    pp = sp["progpy_ukf_us"]
    if pp is not None:
        print(f"  ProgPy / Monitor (one actuator)        {pp / mono:8.1f} x   (target >= 20 x)")
        print(f"  ProgPy / MonitorBank (per actuator)    {pp / bank:8.1f} x")
        print(f"  ProgPy / MonitorBank rows (per act.)   {pp / rows_:8.1f} x")
    print(
        f"  filterpy / Monitor (one actuator)      {sp['filterpy_per_sigma_point_us'] / mono:8.1f} x"
    )
    print(
        f"  actuators per core at 1 kHz (target >= 50): {1e3 / arr:6.1f} update_arrays, "
        f"{1e3 / rows_:6.1f} update_rows, {1e3 / bank:6.1f} update_many, "
        f"{1e3 / mono:6.1f} one Monitor each"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--healthy-s", type=float, default=600.0, help="false-alarm run length [s]")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--fleet", type=int, default=50, help="actuators in the MonitorBank")
    ap.add_argument("--n", type=int, default=2000, help="samples for the speed runs")
    ap.add_argument("--workers", type=int, default=max(1, min(2, os.cpu_count() or 1)))
    ap.add_argument("--json", default=None, help="write every figure to this JSON file")
    ap.add_argument(
        "--clock",
        choices=sorted(CLOCKS),
        default="wall",
        help="the speed runs' clock: wall time, or the thread's CPU time (a loaded machine)",
    )
    ap.add_argument(
        "--model",
        default="C5",
        help="process model(s) of the monitor, comma-separated (e.g. C5,WH: side by side)",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="override a MonitorConfig field for every model (numbers only), e.g. --set "
        "process.p_sr=5e5",
    )
    args = ap.parse_args(argv)
    global _clock
    _clock = CLOCKS[args.clock]
    models = tuple(m.strip() for m in args.model.split(",") if m.strip())
    overrides = {}
    for m in models:  # the same overrides, checked against every model's config
        overrides = parse_overrides(ap, m, args.set)
    for m in models:
        print(f"baseline {m}: {Baseline.default(m).source}")
    out: dict = {}
    if not args.skip_speed:  # first, while nothing else runs
        if models == ("C5",):
            out["speed"] = speed(args.n, args.fleet)
            print_speed(out["speed"], args.fleet)
        else:
            out["speed_models"] = speed_models(args.n, args.fleet, models)
            print_speed_models(out["speed_models"], args.fleet)
    if not args.skip_accuracy:
        t0 = time.perf_counter()
        out["accuracy"] = accuracy(args.healthy_s, args.workers, models, overrides)
        print_accuracy(out["accuracy"])
        print(f"(accuracy runs: {time.perf_counter() - t0:.0f} s wall)")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
