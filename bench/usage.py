"""Usage per period (docs/prognostics.md, "Usage"): its accuracy against the HF bench's truth
on bundled scenarios, and what it costs the monitor, side by side in one run.

Accuracy: each scenario's measured run (HF bench, seeded sensor noise) through
``MonitorBank.update_arrays`` and one period (``periods_of_rows``); each usage figure against
the same figure of the truth (the bench's v_J, A (P1 - P2), P_SR and x_J through the same
thresholds and hysteresis, on the same sample intervals). Beside the travel from the
estimator's v_J, the travel from a Savitzky-Golay derivative of the measured x_J (window 51
samples, quadratic), the alternative that docs/decisions/0017-usage-from-the-estimated-v-j.md
weighed.

Speed: ``update_arrays`` per actuator and sample with the usage rates on and off
(``MonitorBank.usage.enabled``), on the same blocks, the two alternating for ``--repeats``
rounds (median of each block's time, best round).

    .venv/bin/python bench/usage.py [--scenarios healthy_noise est_large_steps ...]
                                    [--actuators 20] [--samples 2000] [--repeats 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.monitor import Baseline, MonitorBank, MonitorConfig  # noqa: E402
from service.monitor.calibration import bank_rows, meas_channels, measured_run  # noqa: E402
from service.monitor.usage import usage_rows  # noqa: E402
from service.monitor.usage_config import N_USAGE, UsageConfig, new_state  # noqa: E402
from service.prognostics.indicators import periods_of_rows  # noqa: E402
from service.sim.scenarios import load_scenario  # noqa: E402

SCENARIOS = ("healthy_noise", "est_large_steps", "est_load_reversal", "leak_step",
             "scenarios/suite/s10_load_reversal_moving.toml", "scenarios/suite/s18_square_wave.toml")  # fmt: skip
FIGURES = ("usage_travel_m", "usage_load_travel_j", "usage_load2_travel_n2m",
           "usage_reversals", "usage_loaded_s", "usage_pressurised_s")  # fmt: skip


def _truth(sim, sel, t, base: Baseline, op_max_dt: float = 0.1) -> dict[str, float]:
    """The usage figures of the bench's true signals at the output rows ``sel``."""
    n = len(sel)
    X = np.zeros((n, 8))
    X[:, 2], X[:, 3], X[:, 5] = sim.x_j[sel], sim.v_j[sel], sim.p_sr[sel]
    z = np.zeros((n, 5))
    z[:, 2], z[:, 3] = sim.p1[sel], sim.p2[sel]
    out = np.zeros((n, N_USAGE))
    usage_rows(np.zeros(n, np.int64), np.ones(n, np.bool_), True, X, np.ones((1, 8)),
               np.ones((1, 5)), 3, 2, 5, z, np.ones((n, 5), np.bool_), 2, 3,
               UsageConfig().row(base.area, base.p_sr_rated)[None, :], new_state(1), out)  # fmt: skip
    dt = np.diff(t, prepend=t[0])
    w = np.where(dt <= op_max_dt, dt, 0.0)
    return {"usage_travel_m": float(w @ out[:, 0]), "usage_load_travel_j": float(w @ out[:, 1]),
            "usage_load2_travel_n2m": float(w @ out[:, 2]), "usage_loaded_s": float(w @ out[:, 3]),
            "usage_pressurised_s": float(w @ out[:, 4]),
            "usage_reversals": float(out[:, 5].sum())}  # fmt: skip


def accuracy(name: str) -> dict:
    from scipy.signal import savgol_filter

    sc = load_scenario(name)
    sim, meas = measured_run(sc)
    cfg = MonitorConfig()
    base = Baseline.default(cfg.model)
    rows = bank_rows(meas, cfg, base)
    (p,) = periods_of_rows("bench/usage", base.c_lk, "bench", rows.t, rows.est, rows.health,
                           rows.res, usage=rows.usage)  # fmt: skip
    truth = _truth(sim, rows.index, rows.t, base)
    got = {f: getattr(p, f) for f in FIGURES}
    dt = np.diff(rows.t, prepend=rows.t[0])
    v_sg = savgol_filter(np.asarray(meas["x_j"])[rows.index], 51, 2, deriv=1, delta=1e-3)
    return {"scenario": Path(name).stem, "duration_s": sc.duration_s, "usage": got, "truth": truth,
            "travel_savgol_m": float(np.sum(np.abs(v_sg) * dt))}  # fmt: skip


def _err(a: float, b: float) -> str:
    if b == 0:
        return f"{a:.3g} vs 0"
    return f"{100 * (a / b - 1):+6.2f} %"


def print_accuracy(rows: list[dict]) -> None:
    print("usage per period against the HF bench's truth (one period per scenario):")
    print(f"  {'scenario':24s} {'travel':>18s} {'|F| travel':>18s} {'F^2 travel':>10s} "
          f"{'reversals':>10s} {'loaded s':>16s} {'pressurised s':>14s} {'savgol travel':>14s}")  # fmt: skip
    for r in rows:
        u, t = r["usage"], r["truth"]
        print(
            f"  {r['scenario']:24s} "
            f"{u['usage_travel_m'] * 1e3:7.2f} mm {_err(u['usage_travel_m'], t['usage_travel_m']):>8s} "
            f"{u['usage_load_travel_j']:7.1f} J {_err(u['usage_load_travel_j'], t['usage_load_travel_j']):>8s} "
            f"{_err(u['usage_load2_travel_n2m'], t['usage_load2_travel_n2m']):>10s} "
            f"{u['usage_reversals']:4.0f} / {t['usage_reversals']:<3.0f} "
            f"{u['usage_loaded_s']:6.3f} / {t['usage_loaded_s']:<6.3f} "
            f"{u['usage_pressurised_s']:6.3f} / {t['usage_pressurised_s']:<6.3f} "
            f"{_err(r['travel_savgol_m'], t['usage_travel_m']):>14s}"
        )  # fmt: skip


def speed(n_act: int, n: int, repeats: int, per_call: int = 10) -> dict:
    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": n / 1000 + 0.01})
    _, meas = measured_run(sc)
    t_all = np.asarray(meas["t"], float)[:n]
    ch_all = meas_channels(meas)[:n]
    res: dict[str, list[float]] = {"on": [], "off": []}
    for r in range(repeats):
        for mode in ("on", "off") if r % 2 == 0 else ("off", "on"):
            bank = MonitorBank(MonitorConfig())
            bank.usage.enabled = mode == "on"
            rows = [bank.index_of(f"act{k:03d}") for k in range(n_act)]
            ks = np.repeat(np.array(rows, np.int64), per_call)
            dts = []
            pc = time.perf_counter
            for a in range(0, n - per_call + 1, per_call):
                t = np.tile(t_all[a : a + per_call], n_act)
                ch = np.tile(ch_all[a : a + per_call], (n_act, 1))
                t0 = pc()
                bank.update_arrays(ks, t, ch)
                dts.append(pc() - t0)
            res[mode].append(float(np.median(dts[5:]) * 1e6 / (n_act * per_call)))
    on, off = min(res["on"]), min(res["off"])
    # the usage kernel alone on the last block's rows (the same call as in rows_of), best of 200
    bank.usage.enabled = True
    sb = bank.step_arrays(ks, t, ch)
    kern = []
    for _ in range(200):
        t0 = pc()
        bank.usage.rates(sb.ks, sb.so.acc, True, sb.so.SX, bank.mr, sb.sm.z, sb.sm.mask)
        kern.append(pc() - t0)
    return {"us_per_sample_kernel": float(min(kern) * 1e6 / len(ks)),"actuators": n_act, "samples": n, "per_call": per_call, "repeats": repeats,
            "us_per_sample_on": on, "us_per_sample_off": off,
            "overhead_pct": 100 * (on / off - 1), "rounds": res}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--actuators", type=int, default=20)
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    acc = [accuracy(s) for s in a.scenarios]
    sp = speed(a.actuators, a.samples, a.repeats)
    if a.json:
        print(json.dumps({"accuracy": acc, "speed": sp}, indent=1))
        return 0
    print_accuracy(acc)
    print(
        f"update_arrays, WH, {sp['actuators']} actuators x {sp['per_call']} samples per call "
        f"(best of {sp['repeats']} alternating rounds): usage on {sp['us_per_sample_on']:.2f} "
        f"us, off {sp['us_per_sample_off']:.2f} us per actuator and sample "
        f"({sp['overhead_pct']:+.1f} %); the usage kernel alone (with its call): "
        f"{sp['us_per_sample_kernel']:.3f} us per sample"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
