"""Per-call time of the compiled UKF step ``service.ukf.ukf_one``: the kernel as it was before
the speed-up (frozen copies in ``bench/_ukf_ref.py`` and its model ``bench/_eha_reduced_ref.py``)
and the current one, side by side in one run, on the same inputs.

    .venv/bin/python bench/kernel.py               # about 1 min (mostly compilation)
    .venv/bin/python bench/kernel.py --rounds 60   # more rounds on a noisy machine

Timings, microseconds per ``ukf_one`` call:

* "harness": the kernel issue's loop, the filter state after 200 samples of the healthy
  scenario reset before each of 10^5 calls (same inputs every call), one run each;
* "fixed state": the same loop in short bursts (``--burst`` calls), old and new interleaved
  for ``--rounds`` rounds: best and median burst, and the median of the per-round ratios,
  which is what to compare on a machine whose speed drifts (shared cores);
* "replay 1 kHz": the filter run through ``--replay`` consecutive samples (measured current,
  four channels), the states the service really sees, interleaved the same way.

The last lines show how far the new results are from the old ones (round-off only).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # idle BLAS threads spin on the 2nd core

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "bench"))  # after ROOT: bench/models.py is not the package

import _ukf_ref as ref  # noqa: E402
from estimation import _samples  # noqa: E402

from service import ukf as new  # noqa: E402
from service.monitor import MonitorBank  # noqa: E402

KERNELS = {"old": (ref.ukf_one, ref.workspace), "new": (new.ukf_one, new.workspace)}


def _fixed_loop(kernel, make_ws):
    @njit
    def loop(N, x0, P0, z, mask, q, R, scale, zscale, Wm, Wc, c, prm):
        ws = make_ws(x0.shape[0], z.shape[0])
        y = np.empty(z.shape[0])
        acc = 0.0
        x = x0.copy()
        P = P0.copy()
        for _ in range(N):
            x[:] = x0
            P[:, :] = P0
            nis, st = kernel(
                x, P, z, mask, 2e-4, 1e-3, 1, q, R, scale, zscale, Wm, Wc, c, prm, y, ws
            )
            acc += nis
        return acc, x, P

    return loop


def _replay_loop(kernel, make_ws):
    @njit
    def loop(x0, P0, Z, M, I, dt, q, R, scale, zscale, Wm, Wc, c, prm, X, PP, NIS, ST):
        ws = make_ws(x0.shape[0], Z.shape[1])
        y = np.empty(Z.shape[1])
        x = x0.copy()
        P = P0.copy()
        for j in range(Z.shape[0]):
            nis, st = kernel(
                x, P, Z[j], M[j], I[j], dt, 1, q, R, scale, zscale, Wm, Wc, c, prm, y, ws
            )
            if st == 2:  # as the monitor: restart the covariance, keep the estimates
                P[:, :] = P0
            NIS[j] = nis
            ST[j] = st
            X[j] = x
            PP[j] = P

    return loop


def _rel(a, b) -> float:
    """Largest |a - b| over the steps relative to the largest |b| of the same element
    (first axis: steps), i.e. differences on the scale of each quantity."""
    a = np.asarray(a, float).reshape(len(a), -1)
    b = np.asarray(b, float).reshape(len(b), -1)
    den = np.maximum(np.abs(b).max(axis=0), 1e-300)
    return float(np.max(np.abs(a - b) / den))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--burst", type=int, default=20_000, help="calls per fixed-state burst")
    ap.add_argument("--rounds", type=int, default=30, help="interleaved rounds")
    ap.add_argument("--replay", type=int, default=3000, help="samples in the replay timing")
    ap.add_argument("--harness-n", type=int, default=100_000, help="calls of the harness run")
    a = ap.parse_args()

    samples = _samples(max(a.replay, 200))
    bank = MonitorBank()
    for s in samples[:200]:
        bank.update_many([("a", s)])
    x0, P0 = bank.x[0].copy(), bank.P[0].copy()
    w = bank.ukf.w
    zs = bank._zscale
    z = np.array([1.1e-5 / zs[0], 0.0, 12.4, 8.4, 0.0])
    mask = np.array([True, True, True, True, False])
    cfg = (bank._q, bank.R, bank.scale, zs, w.Wm, w.Wc, w.c, bank._prm)
    fixed_args = (x0, P0, z, mask, *cfg)

    # replay inputs: four measured channels (no P_SR sensor), measured current, 1 ms
    S = samples[: a.replay]
    J = len(S)
    Z = np.array([[s["x_s"], s["x_j"], s["p1"], s["p2"], 0.0] for s in S]) / zs
    Z[:, 4] = 0.0
    M = np.tile(mask, (J, 1))
    I = np.array([s["i"] for s in S])
    bank0 = MonitorBank()
    bank0.update_many([("a", S[0])])
    xr0, Pr0 = bank0.x[0].copy(), bank0.P[0].copy()
    replay_args = (xr0, Pr0, Z, M, I, 1e-3, *cfg)

    def buffers():
        return np.empty((J, 8)), np.empty((J, 8, 8)), np.empty(J), np.empty(J, np.int64)

    fixed = {k: _fixed_loop(*v) for k, v in KERNELS.items()}
    replay = {k: _replay_loop(*v) for k, v in KERNELS.items()}
    out_fixed, out_replay = {}, {}
    for k in KERNELS:  # compile, and keep the results for the comparison
        out_fixed[k] = fixed[k](10, *fixed_args)
        out_replay[k] = buffers()
        replay[k](*replay_args, *out_replay[k])

    harness = {}
    for k in KERNELS:
        t0 = time.perf_counter()
        fixed[k](a.harness_n, *fixed_args)
        harness[k] = (time.perf_counter() - t0) / a.harness_n * 1e6

    t_fixed = {k: [] for k in KERNELS}
    t_replay = {k: [] for k in KERNELS}
    res = buffers()
    for _ in range(a.rounds):
        for k in KERNELS:
            t0 = time.perf_counter()
            fixed[k](a.burst, *fixed_args)
            t_fixed[k].append((time.perf_counter() - t0) / a.burst * 1e6)
            t0 = time.perf_counter()
            replay[k](*replay_args, *res)
            t_replay[k].append((time.perf_counter() - t0) / J * 1e6)

    print(
        f"ukf_one, us per call ({a.rounds} interleaved rounds; harness: one run of {a.harness_n})"
    )
    print(f"{'':16}{'old best':>10}{'old med':>9}{'new best':>10}{'new med':>9}{'old/new':>9}")
    print(f"{'harness':16}{harness['old']:>10.2f}{'':>9}{harness['new']:>10.2f}{'':>9}"
          f"{harness['old'] / harness['new']:>8.2f}x")  # fmt: skip
    for name, t in (("fixed state", t_fixed), ("replay 1 kHz", t_replay)):
        o, n_ = np.array(t["old"]), np.array(t["new"])
        print(
            f"{name:16}{o.min():>10.2f}{np.median(o):>9.2f}{n_.min():>10.2f}{np.median(n_):>9.2f}"
            f"{np.median(o / n_):>8.2f}x"
        )

    _, xo, Po = out_fixed["old"]
    _, xn, Pn = out_fixed["new"]
    Xo, PPo, NISo, STo = out_replay["old"]
    Xn, PPn, NISn, STn = out_replay["new"]
    print("\nnew vs old: largest difference relative to the largest value of each element")
    print(
        f"  fixed state, 1 step: x {_rel(xn[None], xo[None]):.1e}  P {_rel(Pn[None], Po[None]):.1e}"
    )
    print(
        f"  replay, {J} steps:  x {_rel(Xn, Xo):.1e}  P {_rel(PPn, PPo):.1e}  "
        f"NIS {_rel(NISn, NISo):.1e}  status counts old {np.bincount(STo, minlength=3).tolist()} "
        f"new {np.bincount(STn, minlength=3).tolist()}"
    )


if __name__ == "__main__":
    main()
