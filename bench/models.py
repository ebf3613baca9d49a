"""Benchmark of the physics core: valve-law throughput and the bench's real-time factor.

Prints, side by side in one run:
  * law evaluations per second on N random points (numpy laws A..C5, HF static balance);
  * real-time factor (simulated s / wall s, after JIT warm-up) of ``simulate`` on
    scenarios/paper_bench.toml for HF and each simplified valve at the scenario step, both
    for the integration loop alone (SimResult.wall_s) and for the whole call, with each
    run's NRMSE against the solve_ivp reference; and the simplified valves again at a
    coarser 5e-4 s step;
  * the incremental ``EHAStepper`` driven in 1 ms chunks (as a paced virtual actuator);
  * HF NRMSE against the solve_ivp reference (Radau, rtol 1e-8) in the same run;
  * WH against C5, interleaved run by run on paper_bench at 1e-4 s and at 1 ms: loop time
    per step and the ratio (issue 11: WH at most 3x C5's time per step, >= 300x real time);
  * whether the targets are met: simplified (A-C5) >= 1000x real time, HF >= 20x within 1 %
    NRMSE, WH <= 3x C5 per step and >= 300x real time;
  * with ``--ref-kernel FILE`` (a copy of an earlier models/compiled.py kept outside the
    repo), the integration loop of ``simulate`` with that kernel and with the current one,
    interleaved run by run on paper_bench and on a 3 s hold (the jack stuck most of the
    time): best loop wall and CPU time, speed-up, and the largest state difference between
    the two (relative to each state's range).

Usage: .venv/bin/python bench/models.py [--points N] [--hf-points N] [--repeat R] [--json]
                                        [--ref-kernel FILE] [--ab-only]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from models import eha  # noqa: E402
from models.eha import VALVE_MODELS, EHAStepper, n_substeps, simulate  # noqa: E402
from models.hf_valve import hf_static_p12  # noqa: E402
from models.metrics import nrmse_pct  # noqa: E402
from models.params import simplified_params  # noqa: E402
from models.reference import reference_solution  # noqa: E402
from models.scenario import Profile, Scenario  # noqa: E402
from models.valve_laws import LAW_NAMES, p12  # noqa: E402
from service.sim.scenarios import load_scenario  # noqa: E402

TARGET_SIMPLIFIED_RTF = 1000.0
TARGET_HF_RTF = 20.0
TARGET_HF_NRMSE = 1.0
TARGET_WH_RTF = 300.0
TARGET_WH_COST_VS_C5 = 3.0
C_TYPES = tuple(v for v in VALVE_MODELS if v not in ("HF", "WH"))
COARSE_STEP = 5e-4  # a coarser scenario step for the simplified valves (RK4, 2 substeps)


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def law_throughput(n: int, n_hf: int, repeat: int) -> dict[str, dict[str, float]]:
    sc = load_scenario("paper_bench")
    params = sc.eha_params()
    vp = simplified_params(params)
    rng = np.random.default_rng(0)
    x_s = rng.uniform(-params.x_sm, params.x_sm, n)
    q_j = rng.uniform(-1.5e-4, 1.5e-4, n)  # within +-the no-load capacity
    p_sr = rng.uniform(5e6, 20e6, n)
    out: dict[str, dict[str, float]] = {}
    for law in LAW_NAMES:
        dt = _best(lambda law=law: p12(law, x_s, q_j, p_sr, vp), repeat)
        out[law] = {"points": n, "seconds": dt, "evals_per_s": n / dt}
    xs, qj, ps = x_s[:n_hf], q_j[:n_hf], p_sr[:n_hf]
    dt = _best(lambda: hf_static_p12(xs, qj, ps, params), max(1, repeat // 2))
    out["HF static"] = {"points": n_hf, "seconds": dt, "evals_per_s": n_hf / dt}
    return out


def bench_rtf(repeat: int, step_s: float | None = None) -> dict[str, dict[str, float]]:
    sc = load_scenario("paper_bench")
    if step_s is not None:
        sc = sc.model_copy(update={"step_s": step_s})
    dur = sc.n_steps() * sc.step_s
    out: dict[str, dict[str, float]] = {}
    valves = VALVE_MODELS if step_s is None else [v for v in VALVE_MODELS if v != "HF"]
    for valve in valves:
        t0 = time.perf_counter()
        simulate(sc, valve)  # warm-up (JIT compile or cache load)
        first = time.perf_counter() - t0
        loop, call, cpu = float("inf"), float("inf"), float("inf")
        for _ in range(repeat):
            t0 = time.perf_counter()
            c0 = time.process_time()
            r = simulate(sc, valve)
            cpu = min(cpu, time.process_time() - c0)
            call = min(call, time.perf_counter() - t0)
            loop = min(loop, r.wall_s)
        ref = reference_solution(sc, valve)
        out[valve] = {
            "substeps": n_substeps(sc.eha_params(), valve, sc.step_s),
            "nrmse_x_j_pct": nrmse_pct(r.x_j, ref.x_j),
            "nrmse_p12_pct": nrmse_pct(r.p12, ref.p12),
            "call_cpu_s": cpu,
            "step_s": sc.step_s,
            "sim_s": dur,
            "first_call_s": first,
            "loop_wall_s": loop,
            "call_wall_s": call,
            "rtf_loop": dur / loop,
            "rtf_call": dur / call,
        }
    return out


def wh_vs_c5(repeat: int) -> dict[str, dict[str, float]]:
    """Loop wall time per step of WH and C5, interleaved run by run (best of ``repeat``), on
    paper_bench at its 1e-4 s step and at the monitor's 1 ms step."""
    out: dict[str, dict[str, float]] = {}
    base = load_scenario("paper_bench")
    for step in (1e-4, 1e-3):
        sc = base.model_copy(update={"step_s": step})
        n = sc.n_steps()
        for v in ("C5", "WH"):
            simulate(sc, v)  # warm-up
        best = {"C5": float("inf"), "WH": float("inf")}
        for _ in range(max(repeat, 7)):
            for v in ("C5", "WH"):
                best[v] = min(best[v], simulate(sc, v).wall_s)
        out[f"{step:g}"] = {
            "step_s": step,
            "c5_us_per_step": 1e6 * best["C5"] / n,
            "wh_us_per_step": 1e6 * best["WH"] / n,
            "wh_over_c5": best["WH"] / best["C5"],
            "c5_rtf": sc.duration_s / best["C5"],
            "wh_rtf": sc.duration_s / best["WH"],
            "wh_substeps": n_substeps(sc.eha_params(), "WH", step),
        }
    return out


def _load_kernel(path: str):
    # registered under its file stem: numba's on-disk cache re-imports the module by name
    name = os.path.splitext(os.path.basename(path))[0]
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def _timed_simulate(sc, valve: str, kernel) -> tuple[float, float, np.ndarray]:
    """simulate() with ``kernel`` in place of models.compiled: (loop wall, CPU, states)."""
    saved = eha.kern
    eha.kern = kernel
    try:
        c0 = time.process_time()
        r = simulate(sc, valve)
        cpu = time.process_time() - c0
    finally:
        eha.kern = saved
    return r.wall_s, cpu, np.stack([r.i, r.x_s, r.v_s, r.x_j, r.v_j, r.p1, r.p2], axis=1)


HOLD = Scenario(
    name="hold_3s",
    description="step to 20 mm, then held: the jack sticks (Karnopp) from about 0.4 s",
    duration_s=3.0,
    command=Profile(initial=0.02),
)


def bench_kernel_ab(ref_path: str, repeat: int, sc: Scenario) -> dict[str, dict[str, float]]:
    """Loop RTF of the reference kernel file and of the current models.compiled, side by
    side (interleaved, best of ``repeat``) on scenario ``sc`` at its step."""
    dur = sc.n_steps() * sc.step_s
    kernels = {"ref": _load_kernel(ref_path), "new": eha.kern}
    out: dict[str, dict[str, float]] = {}
    for valve in VALVE_MODELS:
        if valve not in kernels["ref"].MODEL_IDS:  # a model newer than the reference kernel
            continue
        states = {k: _timed_simulate(sc, valve, m)[2] for k, m in kernels.items()}  # warm-up
        best = {k: [float("inf"), float("inf")] for k in kernels}
        for _ in range(repeat):
            for k, m in kernels.items():
                wall, cpu, _ = _timed_simulate(sc, valve, m)
                best[k] = [min(best[k][0], wall), min(best[k][1], cpu)]
        scale = np.max(np.abs(states["ref"]), axis=0)
        scale[scale == 0] = 1.0
        dev = float(np.max(np.abs(states["new"] - states["ref"]) / scale))
        out[valve] = {
            "ref_loop_wall_s": best["ref"][0],
            "new_loop_wall_s": best["new"][0],
            "ref_call_cpu_s": best["ref"][1],
            "new_call_cpu_s": best["new"][1],
            "ref_rtf_loop": dur / best["ref"][0],
            "new_rtf_loop": dur / best["new"][0],
            "speedup_loop": best["ref"][0] / best["new"][0],
            "max_state_diff_rel_range": dev,
        }
    return out


def print_kernel_ab(ab: dict[str, dict[str, float]], ref_path: str, sc: Scenario) -> None:
    print(f"\nIntegration loop, reference kernel {ref_path} vs current models/compiled.py")
    print(f"  {sc.name}: {sc.description}")
    print(f"  {sc.duration_s:g} s at step {sc.step_s:g} s, interleaved, best of runs; loop =")
    print("  SimResult.wall_s, cpu = process time of the whole simulate(); diff = max |new - ref|")
    print("  / state range")
    print(f"  {'valve':<6} {'ref loop s':>10} {'new loop s':>10} {'ref RTF':>8} {'new RTF':>8} "
          f"{'speed-up':>8} {'ref cpu s':>9} {'new cpu s':>9} {'diff':>8}")  # fmt: skip
    for v, d in ab.items():
        print(
            f"  {v:<6} {d['ref_loop_wall_s']:>10.5f} {d['new_loop_wall_s']:>10.5f} "
            f"{d['ref_rtf_loop']:>7.0f}x {d['new_rtf_loop']:>7.0f}x {d['speedup_loop']:>7.2f}x "
            f"{d['ref_call_cpu_s']:>9.5f} {d['new_call_cpu_s']:>9.5f} "
            f"{d['max_state_diff_rel_range']:>8.1e}"
        )


def stepper_rtf(valve: str, sim_s: float = 1.0) -> float:
    """EHAStepper advanced in 10-step (1 ms) chunks with signals() read each chunk."""
    sc = load_scenario("paper_bench")
    st = EHAStepper(sc.eha_params(), valve, step_s=1e-4)
    st.advance(10, 0.0, 0.0, 20e6, 2e-13)
    n = int(round(sim_s / 1e-3))
    t0 = time.perf_counter()
    for k in range(n):
        st.advance(10, 0.02 if k > 0 else 0.0, 0.0, 20e6, 2e-13)
        st.signals()
    return sim_s / (time.perf_counter() - t0)


def hf_accuracy() -> dict[str, float]:
    sc = load_scenario("paper_bench")
    r = simulate(sc, "HF")
    t0 = time.perf_counter()
    ref = reference_solution(sc, "HF")
    t_ref = time.perf_counter() - t0
    out = {
        f"nrmse_{k}_pct": nrmse_pct(getattr(r, k), getattr(ref, k))
        for k in ("x_j", "v_j", "p12", "x_s")
    }
    out["reference_wall_s"] = t_ref
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000, help="points per simplified law")
    ap.add_argument("--hf-points", type=int, default=1_000_000, help="points for HF static")
    ap.add_argument("--repeat", type=int, default=5, help="repeats (best time kept)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead")
    ap.add_argument(
        "--ref-kernel",
        metavar="FILE",
        help="an earlier models/compiled.py (copied outside the repo) to time side by side",
    )
    ap.add_argument("--ab-only", action="store_true", help="with --ref-kernel: only that table")
    a = ap.parse_args(argv)

    ab_scenarios = {"paper_bench": load_scenario("paper_bench"), "hold_3s": HOLD}
    ab = (
        {k: bench_kernel_ab(a.ref_kernel, a.repeat, sc) for k, sc in ab_scenarios.items()}
        if a.ref_kernel
        else None
    )
    if a.ab_only:
        if ab is None:
            ap.error("--ab-only needs --ref-kernel")
        if a.json:
            print(json.dumps({"kernel_ab": ab, "load_average": os.getloadavg()}, indent=2))
        else:
            for k, sc in ab_scenarios.items():
                print_kernel_ab(ab[k], a.ref_kernel, sc)
        return 0

    laws = law_throughput(a.points, a.hf_points, a.repeat)
    rtf = bench_rtf(a.repeat)
    rtf_coarse = bench_rtf(a.repeat, COARSE_STEP)
    step = {v: stepper_rtf(v) for v in ("HF", "C5", "WH")}
    wh = wh_vs_c5(a.repeat)
    acc = hf_accuracy()
    simp_min = min(rtf[v]["rtf_loop"] for v in C_TYPES)
    coarse_min = min(rtf_coarse[v]["rtf_loop"] for v in C_TYPES)
    coarse_nrmse = max(
        max(rtf_coarse[v]["nrmse_x_j_pct"], rtf_coarse[v]["nrmse_p12_pct"]) for v in C_TYPES
    )
    wh_bench = wh["0.0001"]
    targets = {
        "simplified_rtf>=1000": simp_min >= TARGET_SIMPLIFIED_RTF,
        "simplified_coarse_rtf>=1000": coarse_min >= TARGET_SIMPLIFIED_RTF,
        "simplified_coarse_nrmse<1%": coarse_nrmse < 1.0,
        "hf_rtf>=20": rtf["HF"]["rtf_loop"] >= TARGET_HF_RTF,
        "hf_nrmse<1%": max(acc["nrmse_x_j_pct"], acc["nrmse_p12_pct"]) < TARGET_HF_NRMSE,
        "wh_cost<=3x_c5": wh_bench["wh_over_c5"] <= TARGET_WH_COST_VS_C5,
        "wh_rtf>=300": wh_bench["wh_rtf"] >= TARGET_WH_RTF,
    }
    report = {
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count()},
        "law_throughput": laws,
        "bench_rtf": rtf,
        "bench_rtf_coarse_step": rtf_coarse,
        "load_average": os.getloadavg(),
        "stepper_rtf_1ms_chunks": step,
        "wh_vs_c5": wh,
        "hf_vs_reference": acc,
        "targets_met": targets,
    }
    if ab is not None:
        report["kernel_ab"] = ab
    if a.json:
        print(json.dumps(report, indent=2))
        return 0
    print("Valve-law throughput (numpy, vectorised)")
    print(f"  {'law':<10} {'points':>9} {'seconds':>9} {'evals/s':>12}")
    for k, v in laws.items():
        print(f"  {k:<10} {v['points']:>9d} {v['seconds']:>9.4f} {v['evals_per_s']:>12.3e}")
    print("\nClosed-loop bench on paper_bench (1.0 s simulated), real-time factor (best of runs)")
    print("  RTF loop = 1 s / integration wall time; RTF call = whole simulate() incl. outputs;")
    print("  NRMSE % against the Radau rtol 1e-8 reference on the same scenario")
    hdr = f"  {'valve':<6} {'step':>7} {'sub':>3} {'1st call':>9} {'loop s':>9} {'cpu s':>9}"
    print(hdr + f" {'RTF loop':>9} {'RTF call':>9} {'NRMSE xJ':>9} {'NRMSE P12':>9}")
    for tab in (rtf, rtf_coarse):
        for v, d in tab.items():
            print(
                f"  {v:<6} {d['step_s']:>7.0e} {d['substeps']:>3d} {d['first_call_s']:>8.2f}s "
                f"{d['loop_wall_s']:>9.5f} {d['call_cpu_s']:>9.5f} {d['rtf_loop']:>8.0f}x "
                f"{d['rtf_call']:>8.0f}x {d['nrmse_x_j_pct']:>9.4f} {d['nrmse_p12_pct']:>9.4f}"
            )
    print("\nEHAStepper in 1 ms chunks (advance(10) + signals()):")
    for v, x in step.items():
        print(f"  {v:<6} {x:>9.0f}x real time")
    print("\nWH against C5 on paper_bench, loop time per step, interleaved (best of runs):")
    print(f"  {'step':>7} {'sub':>3} {'C5 us':>8} {'WH us':>8} {'WH/C5':>6} {'C5 RTF':>8} "
          f"{'WH RTF':>8}")  # fmt: skip
    for d in wh.values():
        print(
            f"  {d['step_s']:>7.0e} {d['wh_substeps']:>3d} {d['c5_us_per_step']:>8.4f} "
            f"{d['wh_us_per_step']:>8.4f} {d['wh_over_c5']:>5.2f}x {d['c5_rtf']:>7.0f}x "
            f"{d['wh_rtf']:>7.0f}x"
        )
    print("\nHF fixed-step vs solve_ivp Radau rtol 1e-8 (NRMSE %, physics.md section 5):")
    print(
        "  x_J {nrmse_x_j_pct:.4f}  v_J {nrmse_v_j_pct:.4f}  P12 {nrmse_p12_pct:.4f}  "
        "x_S {nrmse_x_s_pct:.4f}   (reference solve {reference_wall_s:.1f} s)".format(**acc)
    )
    if ab is not None:
        for k, sc in ab_scenarios.items():
            print_kernel_ab(ab[k], a.ref_kernel, sc)
    la = os.getloadavg()
    print(f"\nTargets (load average {la[0]:.1f} on {os.cpu_count()} CPUs while measuring):")
    print(f"  simplified (A-C5) >= {TARGET_SIMPLIFIED_RTF:.0f}x real time, RK4 (min {simp_min:.0f}x): "
          f"{'MET' if targets['simplified_rtf>=1000'] else 'NOT MET'}")  # fmt: skip
    print(f"  simplified >= {TARGET_SIMPLIFIED_RTF:.0f}x at step {COARSE_STEP:.0e} s (min "
          f"{coarse_min:.0f}x, NRMSE max {coarse_nrmse:.2f} %): "
          f"{'MET' if targets['simplified_coarse_rtf>=1000'] else 'NOT MET'}")  # fmt: skip
    print(f"  WH <= {TARGET_WH_COST_VS_C5:.0f}x C5 per step at 1e-4 s "
          f"({wh_bench['wh_over_c5']:.2f}x): "
          f"{'MET' if targets['wh_cost<=3x_c5'] else 'NOT MET'}")  # fmt: skip
    print(f"  WH >= {TARGET_WH_RTF:.0f}x real time at 1e-4 s ({wh_bench['wh_rtf']:.0f}x): "
          f"{'MET' if targets['wh_rtf>=300'] else 'NOT MET'}")  # fmt: skip
    print(f"  HF >= {TARGET_HF_RTF:.0f}x real time ({rtf['HF']['rtf_loop']:.0f}x): "
          f"{'MET' if targets['hf_rtf>=20'] else 'NOT MET'}")  # fmt: skip
    print(f"  HF NRMSE < {TARGET_HF_NRMSE:.0f} % on x_J and P12: "
          f"{'MET' if targets['hf_nrmse<1%'] else 'NOT MET'}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
