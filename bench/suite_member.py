"""One member of the randomized estimation suite, as time windows (docs/estimation.md, "WH on
the duty-cycle suite"): where its C_Lk and P_SR estimates stand against the truth, and what the
jack does meanwhile.

    .venv/bin/python bench/suite_member.py --seed 1 --index 11                # WH
    .venv/bin/python bench/suite_member.py --seed 1 --index 11 --supply-sensor
    .venv/bin/python bench/suite_member.py --seed 1 --index 13 --model C5 --window 1.0
    .venv/bin/python bench/suite_member.py --seed 2 --index 17 --png member.png

Per window: mean C_Lk estimate and truth (x nominal), mean P_SR error [%], mean |P12| [MPa],
|v_J| [mm/s] and the largest |x_S| [um] of the truth. Then the longest run of the C_Lk
estimate at or above the leak raise level (its length against the alarm's persistence, peak
and sigma). Last line: the C_Lk increase error and the P_SR error over the last second
(means against the truth at the end). ``--png F``
also draws the run (``service.plots.plot_member``): C_Lk with its 1-sigma band, P_SR, and
|P12|, |v_J| against the gates that hold C_Lk.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.estimation_suite import monitor_run, parse_overrides  # noqa: E402
from models.dutycycle import duty_cycle  # noqa: E402


def above_raise(t: np.ndarray, ratio: np.ndarray, sigma: np.ndarray, raise_at: float,
                hold_s: float) -> str:  # fmt: skip
    """The longest run of samples whose C_Lk estimate (``ratio``, x baseline) is at or above
    the leak raise level: its time from first to last sample (what the alarm's persistence
    ``hold_s`` [s] is measured against), peak and sigma range (x baseline)."""
    on = np.concatenate(([0], (ratio >= raise_at).astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(on))
    if len(edges) == 0:
        return f"C_Lk never at or above the leak raise level ({raise_at:g}x)"
    starts, ends = edges[::2], edges[1::2] - 1  # inclusive sample ranges
    k = int(np.argmax(t[ends] - t[starts]))
    a, b = int(starts[k]), int(ends[k])
    return (f"longest run at or above the leak raise level ({raise_at:g}x): "
            f"{1e3 * (t[b] - t[a]):.0f} ms from {t[a]:.3f} s (persistence {1e3 * hold_s:.0f} ms), "
            f"peak {np.max(ratio[a:b + 1]):.2f}x, sigma {np.min(sigma[a:b + 1]):.2f}"
            f"-{np.max(sigma[a:b + 1]):.2f}x")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--index", type=int, required=True, help="member of the suite")
    ap.add_argument("--model", default="WH")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--supply-sensor", action="store_true", help="the plant also measures P_SR")
    ap.add_argument("--window", type=float, default=0.5, help="window length [s]")
    ap.add_argument("--png", default=None, metavar="F", help="also draw the run to this PNG")
    a = ap.parse_args(argv)
    if not a.window > 0:
        ap.error("--window must be positive")
    from service.monitor import EST_KEYS

    dc = duty_cycle(a.seed, a.index)
    overrides = parse_overrides(ap, a.model, a.set)
    sim, rows, base, cfg, _ = monitor_run(dc, False, a.model, overrides, a.supply_sensor)
    t = rows.t
    c = rows.est[:, EST_KEYS.index("c_lk")]
    p = rows.est[:, EST_KEYS.index("p_sr")]

    def truth(y):
        return np.interp(t, sim.t, y)

    c0 = float(sim.c_lk[0])
    c_t, p_t = truth(sim.c_lk), truth(sim.p_sr)
    p12, v_j, x_s = truth(sim.p1 - sim.p2), truth(sim.v_j), truth(sim.x_s)
    print(f"{dc.test.name}: {dc.kind}" + (f", leak {dc.leak_shape} {dc.leak_ratio:.2f}x" if
          dc.leak_shape else "") + f"; model {a.model}, supply sensor {a.supply_sensor}")  # fmt: skip
    print(f"baseline x_SS {base.x_ss * 1e6:.2f} um, G_PQ {base.g_pq:.3e}, P_R {base.p_r / 1e6:.3f}"
          f" MPa, x_0 {base.x_0 * 1e6:+.3f} um, skew {base.skew:+.2e}")  # fmt: skip
    print("     t  C_est/c0  C_true/c0  P_SR err%  |P12| MPa  |v_J| mm/s  max|x_S| um")
    for lo in np.arange(t[0], t[-1], a.window):
        s = (t >= lo) & (t < lo + a.window)
        if not s.any():
            continue
        print(f"{lo:6.2f} {np.mean(c[s]) / base.c_lk:9.3f} {np.mean(c_t[s]) / c0:10.3f}"
              f" {100 * np.mean(p[s] / p_t[s] - 1):+10.2f} {np.mean(np.abs(p12[s])) / 1e6:10.2f}"
              f" {1e3 * np.mean(np.abs(v_j[s])):11.2f} {1e6 * np.max(np.abs(x_s[s])):12.1f}")  # fmt: skip
    print(above_raise(t, c / base.c_lk, rows.est[:, EST_KEYS.index("c_lk_sigma")] / base.c_lk,
                      cfg.alarms.leak_raise, cfg.alarms.hold_s))  # fmt: skip
    last = t >= t[-1] - 1.0
    inc_true = float(sim.c_lk[-1]) - c0
    p_err = 100.0 * (float(np.mean(p[last])) / float(sim.p_sr[-1]) - 1.0)
    inc = (
        f"{100.0 * ((float(np.mean(c[last])) - base.c_lk) - inc_true) / inc_true:+.1f} %"
        if dc.leak_shape
        else "- (no leak)"
    )
    print(f"last second: C_Lk increase error {inc}, P_SR error {p_err:+.2f} %")
    if a.png:
        from service.plots import plot_member

        est = {k: rows.est[:, EST_KEYS.index(k)] for k in ("c_lk", "c_lk_sigma", "p_sr")}
        alarms = [(e.t, e.kind, e.state) for evs in rows.events for e in evs]
        gates = {
            "p12": cfg.c_lk_gate_p12 * base.p_sr_rated,
            "v_j": cfg.c_lk_gate_v,
            "leak_raise": cfg.alarms.leak_raise,
        }
        tr = {"c_lk": c_t, "p_sr": p_t, "p12": p12, "v_j": v_j}
        title = f"{dc.test.name} ({dc.kind}), model {a.model}"
        print(f"wrote {plot_member(t, est, tr, gates, alarms, a.png, title)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
