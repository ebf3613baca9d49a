"""C_Lk read at a hold near the |P12| observability gate, with the gate judged on each
sample's own measured P1 - P2 against its 50 ms low-pass over the samples before
(docs/estimation.md, "Observability gate": the selection bias of a gate on noisy data).

    .venv/bin/python research/gate_bias.py
    .venv/bin/python research/gate_bias.py --seed 3 --index 12 --p12 0.9,1.0,1.1,1.2,1.5 --noise-seeds 3

The plant, its sensor noise and the monitor's baseline are those of suite member (seed,
index), calibrated on its own healthy segment as ``evaluation/suite.py`` does; the test
run holds the jack at mid stroke for ``--duration`` s under the load that gives each |P12|.
Printed per |P12| and noise seed: the mean C_Lk estimate over the last 2 s (x the baseline)
with the per-sample gate (``c_lk_gate_p12_tau_s`` = 0) and with the low-passed gate (the
default).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluation.dutycycle import duty_cycle  # noqa: E402
from models.params import EHAParams  # noqa: E402
from models.scenario import Profile  # noqa: E402


def floats(text: str) -> list[float]:
    """Comma-separated numbers."""
    return [float(v) for v in text.split(",") if v.strip()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=3, help="suite seed of the plant")
    ap.add_argument("--index", type=int, default=12, help="suite member of the plant")
    ap.add_argument("--p12", type=floats, default=[0.9, 1.0, 1.1, 1.2, 1.5], help="[MPa]")
    ap.add_argument("--noise-seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=4.0, help="hold length [s] (>= 2.5)")
    a = ap.parse_args(argv)
    if a.duration < 2.5:
        ap.error("--duration: at least 2.5 s (the figure is the mean over the last 2 s)")
    if a.noise_seeds < 1:
        ap.error("--noise-seeds: at least 1")

    from service.monitor import EST_KEYS, MonitorConfig
    from service.monitor.calibration import bank_rows, calibrate, identify_noise, measured_run

    c_col = EST_KEYS.index("c_lk")
    dc = duty_cycle(a.seed, a.index)
    _, mc = measured_run(dc.calibration)
    cfg = MonitorConfig(model="WH").model_copy(update={"noise": identify_noise(mc)})
    base = calibrate(mc, config=cfg)
    per_sample = cfg.model_copy(update={"c_lk_gate_p12_tau_s": 0.0})
    area = EHAParams().with_overrides(**dc.params).area
    gate = cfg.c_lk_gate_p12 * base.p_sr_rated
    print(f"plant of dc{a.seed}_{a.index:03d} (noise x{dc.noise_scale:.2f}), WH, gate |P12| > "
          f"{gate / 1e6:.2f} MPa, low-pass {cfg.c_lk_gate_p12_tau_s * 1e3:.0f} ms")  # fmt: skip
    print(f"{'|P12| MPa':>10}{'noise seed':>11}{'per sample':>12}{'low-passed':>12}")
    n_last = int(round(2.0 * dc.calibration.sensors.rate_hz))
    for p12 in a.p12:
        for seed in range(1, a.noise_seeds + 1):
            scen = dc.calibration.model_copy(
                update={
                    "name": "hold",
                    "duration_s": a.duration,
                    "command": Profile(initial=0.0),
                    "load": Profile(initial=p12 * 1e6 * area),
                    "sensors": dc.calibration.sensors.model_copy(update={"seed": seed}),
                }
            )
            _, meas = measured_run(scen)
            vals = [
                float(np.mean(bank_rows(meas, c, base).est[-n_last:, c_col])) / base.c_lk
                for c in (per_sample, cfg)
            ]
            print(f"{p12:>10.2f}{seed:>11d}{vals[0]:>12.3f}{vals[1]:>12.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
