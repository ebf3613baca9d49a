"""WH's filter model (models/eha_reduced_wh.py) against the HF bench at the monitor's 1 ms
step, with its integrator: one ROS2 step per sample (the monitor's), the classic RK4 scheme
the filter used before at 3 substeps (``step_rk4``, below its stability limit off mid stroke)
and RK4 at 20 substeps (the fine-step reference). docs/models.md section 7.

    .venv/bin/python bench/wh_integrator.py                  # paper bench + scenarios/suite
    .venv/bin/python bench/wh_integrator.py --only paper_bench,s22_end_stop

Each run closes the loop as the bench does (the ECU law on the model's own x_J, the torque
motor's lag), with the scenario's load, supply and leak as inputs and the plant's nominal
WH baseline (``Baseline.nominal("WH", params)``). Printed per scenario: NRMSE % against HF
(x_J, v_J, P12, x_S; physics.md section 5) for ROS2 and for RK4 x3, and ROS2's NRMSE % against
the fine reference (its integration error alone); then the worst and median of each column.
The filter model has no end stops: scenarios that reach them (s22) measure that, not the
integrator.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from models import eha_reduced_wh as erw  # noqa: E402
from models.eha import simulate  # noqa: E402
from models.metrics import nrmse_pct  # noqa: E402
from service.monitor import Baseline  # noqa: E402
from service.sim.scenarios import load_scenario  # noqa: E402

H = 1e-3  # the monitor's sample step [s]
SIGNALS = ("x_j", "v_j", "p12", "x_s")


def closed_loop(sc, sim, scheme: str) -> dict[str, np.ndarray]:
    """The WH filter model run closed loop at 1 ms on the HF run ``sim``'s inputs (sampled
    every 1 ms): ``scheme`` "ros2" (1 step), "rk4" (3 substeps) or "fine" (RK4, 20)."""
    p = sc.eha_params()
    base = Baseline.nominal("WH", p)
    rp = base.reduced_params()
    prm = erw.param_vector(rp, base.v_c, base.beta)
    n = len(sim.t)
    x = np.array(
        [sim.x_s[0], sim.v_s[0], sim.x_j[0], sim.v_j[0], sim.f_r[0], sim.p_sr[0],
         sim.c_lk[0], 0.0, sim.p1[0], sim.p2[0]]
    )  # fmt: skip
    cur = sim.i[0]
    a_tm = 1.0 - math.exp(-H / p.tau_tm)
    out = {k: np.empty(n) for k in SIGNALS}
    buf = np.empty(10)
    for k in range(n):
        out["x_j"][k], out["v_j"][k], out["x_s"][k] = x[2], x[3], x[0]
        out["p12"][k] = max(x[8], rp.p_vap) - max(x[9], rp.p_vap)
        if k == n - 1:
            break
        x[4], x[5], x[6] = sim.f_r[k], sim.p_sr[k], sim.c_lk[k]
        i_c = min(max(p.k_p * (sim.x_cmd[k] - x[2]), -p.i_max), p.i_max)
        cur += a_tm * (i_c - cur)  # torque motor: exact first-order lag over the step
        if scheme == "ros2":
            erw.step_nb(x, cur, H, 1, prm, buf)
            x = buf.copy()
        else:
            x = erw.step_rk4(x, cur, H, rp, 3 if scheme == "rk4" else 20, base.v_c, base.beta)
    return out


def scenario_rows(path: str) -> dict:
    sc = load_scenario(path)
    sim = simulate(sc, "HF", out_every=max(1, round(H / sc.step_s)))
    hf = {"x_j": sim.x_j, "v_j": sim.v_j, "p12": sim.p1 - sim.p2, "x_s": sim.x_s}
    runs = {s: closed_loop(sc, sim, s) for s in ("ros2", "rk4", "fine")}
    row = {"scenario": sc.name}
    for s in ("ros2", "rk4"):
        with np.errstate(all="ignore"):
            row[s] = {k: nrmse_pct(runs[s][k], hf[k]) for k in SIGNALS}
    row["ros2_vs_fine"] = {k: nrmse_pct(runs["ros2"][k], runs["fine"][k]) for k in SIGNALS}
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default=None, help="comma-separated scenario names or paths")
    a = ap.parse_args(argv)
    root = Path(__file__).resolve().parent.parent / "scenarios"
    paths = ["paper_bench"] + sorted(str(f) for f in (root / "suite").glob("*.toml"))
    if a.only:
        want = {w.strip() for w in a.only.split(",")}
        paths = [q for q in paths if Path(q).stem in want or q in want]
    cols = [(s, k) for s in ("ros2", "rk4", "ros2_vs_fine") for k in SIGNALS]
    print("NRMSE % at 1 ms, closed loop: WH filter model (ROS2, 1 step; RK4, 3 substeps) "
          "against HF, and ROS2 against RK4 at 20 substeps")  # fmt: skip
    hdr = f"{'scenario':<28}" + "".join(f"{s[:4] + ' ' + k:>11}" for s, k in cols)
    print(hdr + "\n" + "-" * len(hdr))
    rows = []
    for q in paths:
        r = scenario_rows(q)
        rows.append(r)
        print(f"{r['scenario']:<28}" + "".join(f"{r[s][k]:11.2f}" for s, k in cols), flush=True)
    for name, fn in (("worst", np.max), ("median", np.median)):
        vals = [fn([r[s][k] for r in rows]) for s, k in cols]
        print(f"{name:<28}" + "".join(f"{v:11.2f}" for v in vals))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
