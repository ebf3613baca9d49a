"""One member of the randomized estimation suite, as time windows (docs/evaluation.md, "The
duty-cycle suite"): where its C_Lk and P_SR estimates stand against the truth, and what the
jack does meanwhile.

    .venv/bin/python research/suite_member.py --seed 1 --index 11                # WH
    .venv/bin/python research/suite_member.py --seed 1 --index 11 --supply-sensor
    .venv/bin/python research/suite_member.py --seed 1 --index 13 --model C5 --window 1.0
    .venv/bin/python research/suite_member.py --seed 2 --index 17 --png member.png

Per window: mean C_Lk estimate and truth (x nominal), mean P_SR error [%], mean |P12| [MPa],
|v_J| [mm/s] and the largest |x_S| [um] of the truth. Then the longest run of the C_Lk
estimate at or above the leak raise level (its length against the alarm's persistence, peak
and sigma). Last line: the C_Lk increase error and the P_SR error over the last second
(means against the truth at the end). ``--png F``
also draws the run (``plot_member``): C_Lk with its 1-sigma band, P_SR, and
|P12|, |v_J| against the gates that hold C_Lk.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluation.dutycycle import duty_cycle  # noqa: E402
from evaluation.suite import monitor_run, parse_overrides  # noqa: E402
from service.plots import _save, plt  # noqa: E402


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


def plot_member(
    t: np.ndarray,
    est: Mapping[str, np.ndarray],
    truth: Mapping[str, np.ndarray],
    gates: Mapping[str, float],
    alarms: Sequence[tuple[float, str, str]],
    path: str | Path,
    title: str = "",
) -> Path:
    """One monitor run against its truth (docs/evaluation.md, "The duty-cycle suite"):
    C_Lk / nominal with its 1-sigma band and the leak alarm level, P_SR [MPa], |P12| [MPa]
    and |v_J| [mm/s] of the truth with the observability gates (``gates``: p12 [Pa], v_j
    [m/s], leak_raise [x nominal]); alarms as (t, kind, state) lines."""
    c0 = float(truth["c_lk"][0])
    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    c, sd = est["c_lk"] / c0, est["c_lk_sigma"] / c0
    ax[0].fill_between(t, c - sd, c + sd, color="C0", alpha=0.25, lw=0, label="1 sigma")
    ax[0].plot(t, c, "C0", lw=0.8, label="estimate")
    ax[0].plot(t, truth["c_lk"] / c0, "k", lw=1.2, label="truth")
    ax[0].axhline(gates["leak_raise"], color="C3", ls="--", lw=0.8, label="alarm level")
    ax[0].set_ylabel("C_Lk / nominal")
    ax[1].plot(t, est["p_sr"] * 1e-6, "C0", lw=0.8, label="estimate")
    ax[1].plot(t, truth["p_sr"] * 1e-6, "k", lw=1.2, label="truth")
    ax[1].set_ylabel("P_SR [MPa]")
    ax[2].plot(t, np.abs(truth["p12"]) * 1e-6, "C2", lw=0.8)
    ax[2].axhline(gates["p12"] * 1e-6, color="C3", ls="--", lw=0.8, label="C_Lk gate")
    ax[2].set_ylabel("|P12| [MPa]")
    ax[3].plot(t, np.abs(truth["v_j"]) * 1e3, "C2", lw=0.8)
    ax[3].axhline(gates["v_j"] * 1e3, color="C3", ls="--", lw=0.8, label="C_Lk gate")
    ax[3].set_ylabel("|v_J| [mm/s]")
    ax[3].set_xlabel("t [s]")
    for tt, kind, state in alarms:
        for a in ax[:2]:
            a.axvline(tt, color="C3" if state == "raised" else "C1", lw=0.6, alpha=0.7)
        ax[0].text(tt, ax[0].get_ylim()[1], f" {kind} {state}", fontsize=7, va="top")
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend(fontsize=7, loc="upper left")
    fig.suptitle(title)
    return _save(fig, path)


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
