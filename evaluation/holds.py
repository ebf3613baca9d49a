"""The C_Lk a monitor's valve law reads at the HF plant's static holds (docs/evaluation.md,
"The laws at the HF plant's static holds"; docs/estimation.md, "Stiction in the WH process model").

    .venv/bin/python -m evaluation.holds                       # a few seconds
    .venv/bin/python -m evaluation.holds --supply 1,0.7 --leak 1,5 --load 4000
    .venv/bin/python -m evaluation.holds --baseline wh.json     # a saved WH baseline
    .venv/bin/python -m evaluation.holds --calibrated-seeds 8   # a few seconds

A hold: the HF valve (``models.hf_valve.hf_static_pressures``) at the spool position where,
with the jack still, its static P12 carries the load (P12 = F_R / A) at supply P_SR and
leak C_Lk. The C_Lk each law reads there, with its default baseline (or ``--baseline``):

* WH: both chamber balances of the four-land law, ``service.monitor.calibration.hold_reading``;
* a C-type law: the C_Lk at which the law, at v_J = 0 and the same x_S and P_SR, gives the
  measured P12 (the laws are monotone in C_Lk; solved by bracketing).

Printed as the reading's error in % of the true C_Lk. This is the static part of the
monitor's error; the filter's reading adds the dynamics (friction, chamber transients).

``--calibrated-seeds N`` adds N columns ``s1`` .. ``sN``: WH calibrated (``servowatch
calibrate``, ``service.monitor.calibration.calibrate``) on the bundled healthy run with sensor-noise
seed 1..N, so the table shows how far one run's calibration moves the law from the datasheet
values (docs/estimation.md, "WH's default baseline: the datasheet values").
"""

from __future__ import annotations

import argparse
import sys

from scipy.optimize import brentq

from models.eha_reduced import p12_state
from models.hf_valve import hf_static_hold
from models.params import EHAParams
from service.monitor import Baseline
from service.monitor.calibration import hold_reading
from service.monitor.config import MONITOR_MODELS


def law_reading(base: Baseline, x_s: float, p1: float, p2: float, p_sr: float) -> float:
    """C_Lk [m^3/(s Pa)] that ``base``'s law reads at a hold (x_S, absolute P1, P2, P_SR)."""
    if base.law == "WH":
        return hold_reading(base, x_s, p1, p2, p_sr)
    rp = base.reduced_params()
    p12 = p1 - p2

    def gap(c: float) -> float:
        return float(p12_state(x_s, 0.0, p_sr, c, rp)) - p12

    return brentq(gap, 0.0, 1e-10, xtol=1e-20)


def table(
    bases: dict[str, Baseline], supplies: list[float], leaks: list[float], loads: list[float]
) -> list[dict]:
    """One row per (supply share of rated, leak multiple of nominal, load [N]): the hold and
    the reading error [% of the true C_Lk] of each baseline's law (keyed by model)."""
    plant = EHAParams()
    rows = []
    for s in supplies:
        for k in leaks:
            for f in loads:
                c = k * plant.c_lk
                x_s, p1, p2 = hf_static_hold(f / plant.area, s * plant.p_sr, plant, c)
                row = {"supply": s, "leak": k, "load_n": f, "x_s_um": x_s * 1e6}
                row["p12_mpa"] = (p1 - p2) / 1e6
                for m, b in bases.items():
                    row[m] = 100.0 * (law_reading(b, x_s, p1, p2, s * plant.p_sr) / c - 1.0)
                rows.append(row)
    return rows


def calibrated_wh(seed: int) -> Baseline:
    """WH calibrated on ``healthy_noise`` with sensor-noise seed ``seed``."""
    from service.monitor.calibration import calibrate, measured_run
    from service.sim.scenarios import load_scenario

    sc = load_scenario("healthy_noise")
    sc = sc.model_copy(update={"sensors": sc.sensors.model_copy(update={"seed": seed})})
    _, meas = measured_run(sc)
    return calibrate(meas, law="WH")


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers, got {text!r}"
        ) from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default="WH,C5", help="comma-separated process models")
    ap.add_argument("--supply", type=_floats, default=[1.0, 0.7], help="shares of rated P_SR")
    ap.add_argument("--leak", type=_floats, default=[1, 2, 3, 5], help="multiples of nominal C_Lk")
    ap.add_argument("--load", type=_floats, default=[4000.0, 2000.0], help="loads F_R [N]")
    ap.add_argument("--baseline", default=None, help="a saved baseline JSON for its own law")
    ap.add_argument(
        "--calibrated-seeds",
        type=int,
        default=0,
        metavar="N",
        help="add WH calibrated on healthy_noise with sensor-noise seeds 1..N",
    )
    a = ap.parse_args(argv)
    models = [m.strip() for m in a.models.split(",") if m.strip()]
    bad = [m for m in models if m not in MONITOR_MODELS]
    if bad:
        ap.error(f"--models: unknown {bad}; expected some of {MONITOR_MODELS}")
    if any(s <= 0 for s in a.supply) or any(k <= 0 for k in a.leak):
        ap.error("--supply and --leak must be positive")
    if a.calibrated_seeds < 0:
        ap.error("--calibrated-seeds must be >= 0")
    if any(f == 0 for f in a.load):
        ap.error("--load: a hold needs a load (P12 = 0 carries no leak flow)")
    bases = {m: Baseline.default(m) for m in models}
    if a.baseline:
        try:
            b = Baseline.load(a.baseline)
        except (OSError, ValueError) as e:
            ap.error(f"--baseline: {e}")
        if b.law in bases:
            bases[b.law] = b
    seed_cols = [f"s{seed}" for seed in range(1, a.calibrated_seeds + 1)]
    for seed, col in enumerate(seed_cols, start=1):
        print(f"calibrating WH on healthy_noise, sensor seed {seed}", file=sys.stderr)
        bases[col] = calibrated_wh(seed)
    cols = list(bases)
    rows = table(bases, a.supply, a.leak, a.load)
    print("C_Lk read at the HF plant's static holds, error in % of the true C_Lk")
    for m, b in bases.items():
        print(f"  {m}: baseline {b.source}")
    head = f"{'supply':>6} {'leak':>5} {'load N':>7} {'x_S um':>7} {'P12 MPa':>7}"
    print(head + "".join(f" {m:>7}" for m in cols))
    for r in rows:
        line = f"{r['supply']:6.2f} {r['leak']:5.2f} {r['load_n']:7.0f} {r['x_s_um']:7.3f}"
        line += f" {r['p12_mpa']:7.2f}" + "".join(f" {r[m]:+7.2f}" for m in cols)
        print(line)
    cal = [r[c] for r in rows for c in seed_cols]
    if cal:
        print(f"calibrated s1..s{a.calibrated_seeds}: {min(cal):+.2f} .. {max(cal):+.2f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
