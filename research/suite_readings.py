"""Where the monitor's settled C_Lk reading errs on the duty-cycle suite, by operating point
(docs/decisions/0005-information-bound.md).

    .venv/bin/python research/suite_readings.py --seeds 1,2,3,4,5 --workers 2   # about 2 min
    .venv/bin/python research/suite_readings.py --seeds 1 --suite 4 --json r.json --png r.png

Every member of each suite seed (``evaluation.dutycycle``), calibrated on its own healthy segment
and run as ``evaluation/suite.py`` runs it (``monitor_run``). Per member, ``err`` is the
error of the last-second mean C_Lk reading in units of the plant's own nominal C_Lk: the
estimated minus the true increase over the baseline (so for a leak member err = inc% x the
true increase / 100, and on a plant with no leak err = bias% / 100). Beside it, the last
second's mean true P12 [MPa] and |v_J| [mm/s], and the supply at the end as a share of rated.

Then err's mean, standard deviation and RMS binned by |P12|, by the final supply and by fault
kind, and in each |P12| bin the RMS of err x |P12| [nominal x MPa]: a constant flow error
dQ read as a leak gives err = dQ / (C_Lk,nom P12), so err x |P12| is the same in every bin
when the reading's error is such a flow error (a null offset dx_0 is dQ = K_q dx_0).
``--png F`` draws err against |P12| with +-(the RMS of err x |P12|) / |P12|.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.plots import _axes, _save, plt  # noqa: E402

P12_BINS_MPA = (0.0, 1.0, 2.0, 4.0, 6.0, np.inf)
SUPPLY_BINS = (0.0, 0.7, 0.9, 1.1)


def reading(
    seed: int,
    index: int,
    model: str = "WH",
    overrides: dict | None = None,
    noise: float = 1.0,
    nominal: bool = False,
    datasheet: bool = False,
    frictionless: bool = False,
) -> dict:
    """One member's settled C_Lk reading error and the operating point it was read at
    (``overrides``: MonitorConfig fields, as ``--set``; ``noise``: the sensors' noise times
    this, ``evaluation.dutycycle.scale_noise``; ``nominal``: the plant without tolerances,
    ``evaluation.dutycycle.nominal_plant``; ``datasheet``: the monitor on the datasheet baseline,
    not calibrated; ``frictionless``: a nominal plant without Coulomb or breakaway friction,
    and the baseline without them too)."""
    from evaluation.dutycycle import duty_cycle, nominal_plant, scale_noise
    from evaluation.suite import gate_open, monitor_run
    from service.monitor import EST_KEYS

    dc = scale_noise(duty_cycle(seed, index), noise)  # noise 1: the member as drawn
    if nominal or frictionless:
        dc = nominal_plant(dc, frictionless=frictionless)
    sim, rows, base, cfg, _ = monitor_run(
        dc,
        model=model,
        overrides=overrides,
        plant_friction=frictionless,  # the baseline takes the plant's F_d = F_s = 0
        datasheet_baseline=datasheet,
    )
    c0 = float(sim.c_lk[0])
    last = rows.t >= rows.t[-1] - 1.0
    c_mean = float(np.mean(rows.est[last, EST_KEYS.index("c_lk")]))
    inc_true = float(sim.c_lk[-1]) - c0
    st = sim.t >= sim.t[-1] - 1.0
    gate = gate_open(
        sim.v_j, np.asarray(sim.x_s) - base.x_0, sim.p1 - sim.p2,
        cfg.c_lk_gate_v, base.x_u, cfg.c_lk_gate_p12 * base.p_sr_rated,
    )  # fmt: skip
    dt = float(np.median(np.diff(sim.t)))
    c_end = float(sim.c_lk[-1])
    moving = np.flatnonzero(np.abs(np.asarray(sim.c_lk) - c_end) > 1e-3 * c_end)
    settled = sim.t > sim.t[moving[-1]] if len(moving) else None
    return {
        "name": dc.test.name,
        "kind": dc.kind,
        "leak_ratio": dc.leak_ratio,
        "err": ((c_mean - base.c_lk) - inc_true) / c0,
        "p12_mpa": float(np.mean(sim.p1[st] - sim.p2[st])) / 1e6,
        "v_j_mm_s": float(np.mean(np.abs(sim.v_j[st]))) * 1e3,
        "supply": float(sim.p_sr[-1] / sim.p_sr[0]),
        # seconds the true signals pass the C_Lk gate after the leak last changed (leak
        # members) and within the last second, the reading's window
        "obs_settled_s": None if settled is None else float(gate[settled].sum() * dt),
        "obs_last_s": float(gate[st].sum() * dt),
    }


def _obs(r: dict) -> str:
    """A row's gate-open seconds after the leak settled / in the last second."""
    settled = r.get("obs_settled_s")
    return f"{'-' if settled is None else f'{settled:.2f}'} / {r.get('obs_last_s', 0.0):.2f} s"


def _job(args: tuple[int, int, str, dict, float, bool, bool, bool]) -> dict:
    return reading(*args)


def increase_misses(rows: list[dict], limit: float = 0.10) -> list[tuple[str, float]]:
    """(member, increase error) of the leak members whose settled C_Lk increase errs by more
    than ``limit`` of the true increase (issue 10's target; err / (leak x - 1))."""
    out = []
    for r in rows:
        if r["leak_ratio"] > 1.0:
            inc = r["err"] / (r["leak_ratio"] - 1.0)
            if abs(inc) > limit:
                out.append((r["name"], inc))
    return out


def binned(rows: list[dict]) -> list[tuple[str, str, int, float, float, float, float | None]]:
    """(group, bin, n, mean, sd, rms of err, rms of err x |P12| or None) per non-empty bin."""
    err = np.array([r["err"] for r in rows])
    p12 = np.abs([r["p12_mpa"] for r in rows])
    sup = np.array([r["supply"] for r in rows])
    out = []

    def add(group: str, label: str, sel: np.ndarray, flow: bool) -> None:
        if sel.any():
            e = err[sel]
            fl = float(np.sqrt(np.mean((e * p12[sel]) ** 2))) if flow else None
            out.append((group, label, int(sel.sum()), float(e.mean()), float(e.std()),
                        float(np.sqrt(np.mean(e**2))), fl))  # fmt: skip

    for lo, hi in zip(P12_BINS_MPA[:-1], P12_BINS_MPA[1:], strict=True):
        add("|P12| MPa", f"{lo:g}-{hi:g}", (p12 >= lo) & (p12 < hi), True)
    for lo, hi in zip(SUPPLY_BINS[:-1], SUPPLY_BINS[1:], strict=True):
        add("supply/rated", f"{lo:g}-{hi:g}", (sup >= lo) & (sup < hi), False)
    for kind in dict.fromkeys(r["kind"] for r in rows):
        add("kind", kind, np.array([r["kind"] == kind for r in rows]), False)
    add("all", "-", np.ones(len(rows), bool), True)
    return out


def plot_readings(
    rows: Sequence[Mapping[str, object]], flow: float, path: str | Path, title: str = ""
) -> Path:
    """Settled C_Lk reading errors of suite members (docs/decisions/0005-information-bound.md): err [nominal C_Lk] against the last second's |P12| [MPa], one dot a
    member, coloured by the supply at the end (share of rated), with +-``flow`` / |P12|, the
    error a constant flow error of ``flow`` [nominal x MPa] gives."""
    p12 = np.abs([float(r["p12_mpa"]) for r in rows])
    err = np.array([float(r["err"]) for r in rows])
    sup = np.array([float(r["supply"]) for r in rows])
    fig, ax = plt.subplots(figsize=(8, 5))
    sc = ax.scatter(p12, err, c=sup, cmap="viridis", vmin=0.5, vmax=1.0, s=14)
    fig.colorbar(sc, ax=ax, label="supply at the end / rated")
    x = np.linspace(0.5, max(float(p12.max()), 1.0), 200)
    for sign in (1.0, -1.0):
        ax.plot(x, sign * flow / x, "C3", ls="--", lw=0.8,
                label=f"+-{flow:.2f} / |P12| (a constant flow error)" if sign > 0 else None)  # fmt: skip
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_ylim(-0.8, 0.8)
    _axes(
        ax, "|P12| over the last second [MPa]", "settled C_Lk error [nominal C_Lk]", "upper right"
    )
    ax.set_title(title)
    return _save(fig, path)


def main(argv: list[str] | None = None) -> int:
    from evaluation.suite import noise_factor, parse_overrides, run_jobs

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="1", help="comma-separated suite seeds")
    ap.add_argument("--suite", type=int, default=30, help="members per seed")
    ap.add_argument("--model", default="WH")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="override a MonitorConfig field, as evaluation/suite.py --set",
    )
    ap.add_argument(
        "--noise-scale",
        type=noise_factor,
        default=1.0,
        metavar="F",
        help="every sensor's noise times F, as evaluation/suite.py --noise-scale",
    )
    ap.add_argument(
        "--nominal-plant",
        action="store_true",
        help="every plant at the datasheet values, no tolerances (a diagnostic)",
    )
    ap.add_argument(
        "--datasheet-baseline",
        action="store_true",
        help="the monitor on the datasheet baseline, not calibrated (a diagnostic; with "
        "--nominal-plant WH's parameters are then exact)",
    )
    ap.add_argument(
        "--frictionless",
        action="store_true",
        help="every plant nominal and without Coulomb or breakaway friction, and the "
        "monitor's baseline without them too (a diagnostic)",
    )
    ap.add_argument("--json", default=None, help="write the rows and the bins to this file")
    ap.add_argument("--png", default=None, metavar="F", help="also draw err against |P12|")
    a = ap.parse_args(argv)
    try:
        seeds = [int(s) for s in a.seeds.split(",")]
    except ValueError:
        ap.error(f"--seeds: comma-separated integers, not {a.seeds!r}")
    if a.suite < 1:
        ap.error("--suite: at least 1 member")
    overrides = parse_overrides(ap, a.model, a.set)
    jobs = [
        (
            s,
            i,
            a.model,
            overrides,
            a.noise_scale,
            a.nominal_plant,
            a.datasheet_baseline,
            a.frictionless,
        )
        for s in seeds
        for i in range(a.suite)
    ]
    w0 = time.perf_counter()
    rows = run_jobs(_job, jobs, a.workers)
    opts = f", noise x{a.noise_scale:g}" if a.noise_scale != 1.0 else ""
    opts += ", nominal plants" if a.nominal_plant or a.frictionless else ""
    opts += ", no Coulomb or breakaway friction" if a.frictionless else ""
    opts += ", datasheet baseline" if a.datasheet_baseline else ""
    print(f"seeds {a.seeds}, {len(rows)} members, model {a.model}{opts}, "
          f"{time.perf_counter() - w0:.0f} s wall")  # fmt: skip
    print(f"{'member':<10} {'kind':<12} {'leak x':>6} {'err':>7} {'P12 MPa':>8} "
          f"{'|v_J| mm/s':>10} {'supply':>7}")  # fmt: skip
    for r in rows:
        print(f"{r['name']:<10} {r['kind']:<12} {r['leak_ratio']:>6.2f} {r['err']:>+7.3f} "
              f"{r['p12_mpa']:>+8.2f} {r['v_j_mm_s']:>10.1f} {r['supply']:>7.2f}")  # fmt: skip
    bins = binned(rows)
    print("\nerr: settled C_Lk reading error in units of nominal C_Lk")
    print(
        f"{'group':<13} {'bin':<12} {'n':>4} {'mean':>7} {'sd':>6} {'rms':>6} {'rms err x |P12|':>16}"
    )
    for g, label, n, mean, sd, rms, fl in bins:
        fls = f"{fl:>16.3f}" if fl is not None else f"{'-':>16}"
        print(f"{g:<13} {label:<12} {n:>4d} {mean:>+7.3f} {sd:>6.3f} {rms:>6.3f} {fls}")
    miss = increase_misses(rows)
    n_leak = sum(r["leak_ratio"] > 1.0 for r in rows)
    by_name = {r["name"]: r for r in rows}
    print(f"\nC_Lk increase misses (error above 10 % of the true increase): {len(miss)} of "
          f"{n_leak} leak members; gate-open seconds of the true signals after the leak "
          "settled / in the last second:"
          + "".join(f"\n  {m} {e:+.1%}  {_obs(by_name[m])}" for m, e in miss))  # fmt: skip
    if a.png:
        flow = next(b[6] for b in bins if b[0] == "all")
        title = f"settled C_Lk reading, seeds {a.seeds}, {len(rows)} members, {a.model}"
        print(f"wrote {plot_readings(rows, flow, a.png, title)}")
    if a.json:
        keys = ("group", "bin", "n", "mean", "sd", "rms", "rms_flow")
        Path(a.json).write_text(
            json.dumps(
                {"rows": rows, "bins": [dict(zip(keys, b, strict=True)) for b in bins]}, indent=1
            )
            + "\n"  # fmt: skip
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
