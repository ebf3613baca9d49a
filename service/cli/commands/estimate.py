"""``servowatch estimate``: the HF bench as truth, the monitor offline, truth against estimate.

Runs the scenario on the HF bench, adds the scenario's seeded sensor noise, feeds the monitor
sample by sample (``service.monitor.Monitor``) and scores it: final C_Lk and P_SR against the
truth, alarms (false ones and the detection delay after the true crossing of the raise level)
and the share of samples whose NIS lies in its 95 % chi-square band.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from service.cli.util import check_outputs, emit_json, fail, writing
from service.monitor.model_choice import DEFAULT_MODEL, MONITOR_MODELS
from service.progress import Progress
from service.sim.scenarios import ScenarioError, load_scenario, resolve_scenario

NAME = "estimate"
HELP = "run the HF bench on a scenario and the degradation monitor (UKF) on its signals"

__all__ = ["NAME", "HELP", "add_arguments", "run", "evaluate"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", required=True, help="scenario TOML file (or a bundled name)")
    p.add_argument(
        "--model",
        default=DEFAULT_MODEL,
        help=f"process model of the monitor ({', '.join(MONITOR_MODELS)}; default {DEFAULT_MODEL})",
    )
    p.add_argument("--channels", default="full", choices=("full", "reduced"))
    p.add_argument("--baseline", default=None, help="baseline JSON from `servowatch calibrate`")
    p.add_argument("--duration", type=float, default=None, help="override duration_s [s]")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--png", default=None, help="plot truth, estimate +-1 sigma, residuals")
    p.add_argument("--out", default=None, help="write measurements and outputs to this MCAP")


def _first_cross(t, cond) -> float | None:
    k = np.flatnonzero(cond)
    return float(t[k[0]]) if len(k) else None


def count_false_alarms(events, t, leak_ratio, supply_ratio, alarms) -> int:
    """Alarms raised while the truth is on the healthy side of the clear level: a leak alarm
    with the true C_Lk / baseline below ``leak_clear``, a supply alarm with the true
    P_SR / rated above ``supply_clear``. ``leak_ratio``, ``supply_ratio`` on the grid ``t``."""
    false = 0
    for e in events:
        if e.state != "raised":
            continue
        j = min(int(np.searchsorted(t, e.t)), len(t) - 1)
        if e.kind == "leak" and leak_ratio[j] < alarms.leak_clear:
            false += 1
        if e.kind == "supply" and supply_ratio[j] > alarms.supply_clear:
            false += 1
    return false


def nis_in_band_pct(t, nis, dof, arm_s: float) -> float | None:
    """Share [%] of the samples after the arming time whose NIS lies in its two-sided 95 %
    chi-square band (None when there is none)."""
    sel = (t >= t[0] + arm_s) & (dof > 0)
    if not sel.any():
        return None
    lo, hi = chi2.ppf(0.025, dof[sel]), chi2.ppf(0.975, dof[sel])
    return float(100.0 * np.mean((nis[sel] >= lo) & (nis[sel] <= hi)))


def evaluate(scenario, config=None, baseline=None, *, progress=None, keep_outputs=False) -> dict:
    """Run truth + monitor on ``scenario``; the summary dict of issue 3 item 6 (plus extras).

    With ``keep_outputs`` the dict also holds ``_sim``, ``_meas`` and ``_outs`` (not JSON).
    """
    from service.monitor import Baseline, Monitor, MonitorConfig
    from service.monitor.calibration import measured_run

    config = config or MonitorConfig()
    baseline = baseline or Baseline.default(config.model)
    sim, meas = measured_run(scenario, progress=(lambda f: progress(0.3 * f)) if progress else None)
    mon = Monitor(config, baseline)
    keys = [k for k in ("t", "x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr") if k in meas]
    cols = [np.asarray(meas[k], float).tolist() for k in keys]
    n = len(cols[0])
    outs = [None] * n if keep_outputs else None
    tt = np.full(n, np.nan)
    nis, dof, p_est_all, c_est_all = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    events = []
    last = None
    warm = Monitor(config, baseline)  # compile (or load) the kernels outside the timing
    for j in range(min(n, 3)):
        warm.update({k: c[j] for k, c in zip(keys, cols, strict=True)})
    dts = np.empty(n)
    pc = time.perf_counter
    w0 = pc()
    every = max(1, n // 100)
    for j in range(n):
        s = {k: c[j] for k, c in zip(keys, cols, strict=True)}
        a = pc()
        o = mon.update(s)
        dts[j] = pc() - a
        if o is not None:
            last = o
            tt[j], nis[j], dof[j], p_est_all[j] = o.t, o.res["nis"], o.res["nis_dof"], o.est["p_sr"]
            c_est_all[j] = o.est["c_lk"]
            if o.events:
                events += [e for e in o.events if e.kind in ("leak", "supply")]
            if keep_outputs:
                outs[j] = o
        if progress is not None and j % every == 0:
            progress(0.3 + 0.7 * j / n)
    wall = pc() - w0
    if progress is not None:
        progress(1.0)
    t = sim.t
    good = ~np.isnan(tt)
    tt, nis, dof, p_est_all = tt[good], nis[good], dof[good], p_est_all[good]
    c_est_all = c_est_all[good]
    acfg = config.alarms
    true_leak = sim.c_lk / baseline.c_lk
    true_sup = sim.p_sr / baseline.p_sr_rated
    false_alarms = count_false_alarms(events, t, true_leak, true_sup, acfg)
    delays: dict[str, float | None] = {}
    for kind, cond in (
        ("leak", true_leak >= acfg.leak_raise),
        ("supply", true_sup <= acfg.supply_raise),
    ):
        tc = _first_cross(t, cond)
        if tc is None:
            continue
        raised = [e.t for e in events if e.kind == kind and e.state == "raised" and e.t >= tc - 1]
        delays[kind] = (raised[0] - tc) if raised else None
    finite = [d for d in delays.values() if d is not None]
    detection_delay = max(finite) if finite and len(finite) == len(delays) else None
    in_band = nis_in_band_pct(tt, nis, dof, config.arm_s)
    # supply tracking: time after the last change of the true P_SR from which the estimate
    # stays within 5 % of the truth
    p_settle = None
    steps = np.flatnonzero(np.abs(np.diff(sim.p_sr)) > 1e3)
    if len(steps):
        t_drop = float(t[steps[-1] + 1])
        p_true_all = np.interp(tt, t, sim.p_sr)
        bad = np.flatnonzero((np.abs(p_est_all - p_true_all) > 0.05 * p_true_all) & (tt >= t_drop))
        p_settle = float(tt[bad[-1] + 1] - t_drop) if len(bad) and bad[-1] + 1 < len(tt) else 0.0
        if len(bad) and bad[-1] + 1 >= len(tt):
            p_settle = None
    c_true, p_true = float(sim.c_lk[-1]), float(sim.p_sr[-1])
    c_est, p_est = last.est["c_lk"], last.est["p_sr"]
    inc_true = c_true - baseline.c_lk
    # settled leak estimate: mean over the last second when the true C_Lk is constant there
    last_s = tt >= tt[-1] - 1.0
    c_settled = None
    c_err_settled = None  # the same mean against the true C_Lk, for every scenario
    if np.ptp(np.interp(tt[last_s], t, sim.c_lk)) < 1e-3 * c_true:
        c_mean = float(np.mean(c_est_all[last_s]))
        c_err_settled = 100.0 * (c_mean - c_true) / c_true
        if inc_true >= baseline.c_lk:
            c_settled = 100.0 * ((c_mean - baseline.c_lk) - inc_true) / inc_true
    # whole-run accuracy: RMS of the relative C_Lk and P_SR errors after the arming time
    after = tt >= tt[0] + config.arm_s
    c_true_t, p_true_t = np.interp(tt[after], t, sim.c_lk), np.interp(tt[after], t, sim.p_sr)
    c_rms = float(100.0 * np.sqrt(np.mean((c_est_all[after] / c_true_t - 1.0) ** 2)))
    p_rms = float(100.0 * np.sqrt(np.mean((p_est_all[after] / p_true_t - 1.0) ** 2)))
    out = {
        "scenario": scenario.name,
        "model": config.model,
        "channels": config.channels,
        "duration_s": float(t[-1] - t[0]),
        "wall_s": wall,
        "update_us_median": float(np.median(dts) * 1e6),
        "truth": {"c_lk": c_true, "p_sr": p_true},
        "estimate": {
            "c_lk": c_est,
            "c_lk_sigma": last.est["c_lk_sigma"],
            "p_sr": p_est,
            "p_sr_sigma": last.est["p_sr_sigma"],
        },
        "c_lk_error_pct": 100.0 * (c_est - c_true) / c_true,
        "p_sr_error_pct": 100.0 * (p_est - p_true) / p_true,
        "c_lk_increase_error_pct": (
            100.0 * ((c_est - baseline.c_lk) - inc_true) / inc_true
            if inc_true >= baseline.c_lk
            else None
        ),
        "c_lk_increase_error_settled_pct": c_settled,
        "c_lk_error_settled_pct": c_err_settled,
        "c_lk_rms_pct": c_rms,
        "p_sr_rms_pct": p_rms,
        "alarms": [{"t": e.t, "kind": e.kind, "state": e.state} for e in events],
        "false_alarms": false_alarms,
        "detection_delay_s": detection_delay,
        "detection_delay_by_kind_s": delays,
        "p_sr_settle_s": p_settle,
        "nis_in_band_pct": in_band,
        "counters": dict(mon.counters),
        "baseline": baseline.source,
    }
    if keep_outputs:
        out["_sim"], out["_meas"], out["_outs"] = sim, meas, outs
    return out


def plot(res: dict, path: str | Path, baseline) -> None:
    """Truth vs estimate with the 1-sigma band (C_Lk, P_SR, F_R), innovations, NIS, alarms."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim, outs = res["_sim"], [o for o in res["_outs"] if o is not None]
    t = np.array([o.t for o in outs])

    def col(group, key):
        return np.array([getattr(o, group)[key] for o in outs])

    fig, ax = plt.subplots(5, 1, figsize=(10, 13), sharex=True)
    for a, (key, scale, unit) in zip(
        ax[:3], (("c_lk", 1e-13, "C_Lk [1e-13 m^3/s/Pa]"), ("p_sr", 1e6, "P_SR [MPa]"),
                 ("f_r", 1e3, "F_R [kN]")), strict=True
    ):  # fmt: skip
        m, s = col("est", key) / scale, col("est", key + "_sigma") / scale
        a.plot(sim.t, getattr(sim, key) / scale, "k", lw=1.5, label="truth (HF)")
        a.plot(t, m, "C0", lw=1, label="estimate")
        a.fill_between(t, m - s, m + s, color="C0", alpha=0.3, label="1 sigma")
        a.set_ylabel(unit)
        a.legend(loc="best", fontsize=8)
    for ch, c in (("x_j", "C1"), ("p1", "C2"), ("p2", "C3"), ("x_s", "C4")):
        y = col("res", f"innov_{ch}")
        if np.any(y):
            sd = np.std(y) or 1.0
            ax[3].plot(t, y / sd, c, lw=0.5, label=f"innov {ch} / std")
    ax[3].set_ylabel("normalised innovation")
    ax[3].legend(loc="best", fontsize=8)
    ax[4].semilogy(t, np.maximum(col("res", "nis"), 1e-3), "C0", lw=0.5, label="NIS")
    ax[4].semilogy(t, np.maximum(col("health", "nis_avg"), 1e-3), "C1", lw=1, label="NIS/dof avg")
    ax[4].set_ylabel("NIS")
    ax[4].legend(loc="best", fontsize=8)
    ax[4].set_xlabel("t [s]")
    for e in res["alarms"]:
        for a in ax:
            a.axvline(e["t"], color="r" if e["state"] == "raised" else "g", ls="--", lw=0.8)
    fig.suptitle(
        f"{res['scenario']}: monitor {res['model']} ({res['channels']} channels), "
        "red = alarm raised, green = cleared"
    )
    fig.tight_layout()
    from service.plots import save_png

    try:
        save_png(fig, path, 90)
    finally:
        plt.close(fig)


def write_mcap(res: dict, path: str | Path) -> None:
    """Measurements, truth and monitor outputs, one JSON message per sample and topic."""
    from service.log import McapLogger

    sim, meas, outs = res["_sim"], res["_meas"], res["_outs"]
    base = f"/estimate/{res['scenario']}"
    keys = list(meas)
    with McapLogger(path) as log:
        for j, o in enumerate(outs):
            t = float(sim.t[j])
            log.log(f"{base}/meas", t, {k: float(meas[k][j]) for k in keys})
            log.log(
                f"{base}/truth",
                t,
                {"c_lk": float(sim.c_lk[j]), "p_sr": float(sim.p_sr[j]), "f_r": float(sim.f_r[j])},
            )
            if o is None:
                continue
            log.log(f"{base}/est", t, o.est)
            log.log(f"{base}/residual", t, o.res)
            log.log(f"{base}/health", t, o.health)


def run(args: argparse.Namespace) -> int:
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as e:
        return fail(str(e))
    check_outputs(
        [("--png", args.png), ("--out", args.out)],
        [("--scenario", resolve_scenario(args.scenario)), ("--baseline", args.baseline)],
    )
    from service.cli.warmup import ensure, monitor_group
    from service.monitor import Baseline, BaselineModelError, MonitorConfig, check_baseline_model

    if args.model not in MONITOR_MODELS:
        return fail(f"unknown model {args.model!r}; expected one of {', '.join(MONITOR_MODELS)}")
    ensure("models", monitor_group(args.model))
    if args.duration is not None:
        if args.duration <= 0:
            return fail("--duration must be positive")
        scenario = scenario.model_copy(update={"duration_s": float(args.duration)})
    try:
        baseline = Baseline.load(args.baseline) if args.baseline else Baseline.default(args.model)
    except (OSError, ValueError) as e:
        return fail(f"{args.baseline}: cannot read baseline: {e}")
    try:
        check_baseline_model(baseline, args.model, f"{args.baseline}")
    except BaselineModelError as e:
        return fail(str(e))
    config = MonitorConfig(model=args.model, channels=args.channels)
    prog = Progress(f"estimate {scenario.name}")
    res = evaluate(scenario, config, baseline, progress=prog, keep_outputs=True)
    prog.done()
    if args.png:
        with writing("--png", args.png):
            plot(res, args.png, baseline)
    if args.out:
        with writing("--out", args.out, so_far=f"--png {args.png} written" if args.png else None):
            write_mcap(res, args.out)
    summary = {k: v for k, v in res.items() if not k.startswith("_")}
    if args.json:
        emit_json(summary)
        return 0
    tr, es = summary["truth"], summary["estimate"]
    print(
        f"scenario {summary['scenario']}, model {summary['model']}, {summary['channels']} channels"
    )
    print(f"  {summary['duration_s']:.2f} s simulated, monitor {summary['wall_s']:.2f} s wall, "
          f"median update {summary['update_us_median']:.0f} us")  # fmt: skip
    print(f"  C_Lk  truth {tr['c_lk']:.3e}  estimate {es['c_lk']:.3e} +- {es['c_lk_sigma']:.1e}"
          f"  ({summary['c_lk_error_pct']:+.1f} %)")  # fmt: skip
    print(f"  P_SR  truth {tr['p_sr'] / 1e6:.3f} MPa  estimate {es['p_sr'] / 1e6:.3f} +- "
          f"{es['p_sr_sigma'] / 1e6:.3f} MPa  ({summary['p_sr_error_pct']:+.2f} %)")  # fmt: skip
    for a in summary["alarms"]:
        print(f"  alarm {a['kind']} {a['state']} at {a['t']:.3f} s")
    d = summary["detection_delay_s"]
    delay = "-" if d is None else f"{d:.3f} s"
    print(f"  false alarms {summary['false_alarms']}, detection delay {delay}, "
          f"NIS in 95 % band {summary['nis_in_band_pct']:.1f} %")  # fmt: skip
    if args.png:
        print(f"  plot written to {args.png}")
    if args.out:
        print(f"  log written to {args.out}")
    return 0
