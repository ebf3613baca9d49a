"""Baseline identification from a healthy run (issue 3, deliverable 2).

The C-type laws are secant approximations of the valve: at null the HF valve has twice their
pressure gain (physics.md section 3). A monitor built on nominal C-type parameters would read
that mismatch as a fault, so its effective parameters are identified first on healthy data:

1. P_R (return, absolute) from the mean of (P1 + P2) / 2 - P_SR / 2 (the chamber-pressure sum
   of a matched four-land valve is P_S + P_R for any flow and leakage, physics.md section 3).
2. Near null every C-law reads P12 (1 + G_PQ C_Lk) = (P_SR / x_SS) x_S - G_PQ A v_J
   (physics.md section 2), linear in a = 1 / x_SS and G_PQ once C_Lk is fixed at nominal:
   P12 = a P_SR x_S - G_PQ (A v_J + C_Lk P12). Least squares on smoothed x_S, P12 and the
   smoothed derivative of x_J gives the effective pressure gain and G_PQ.
   WH (docs/models.md eq. 7, linearised at null with all four lands open by x_SS) reads the
   same form with twice the pressure gain, P12 (1 + G_PQ C_Lk) = (2 P_SR / x_SS) x_S -
   G_PQ A v_J (the tangent gain of the real valve), so its x_SS is 2 / a; G_PQ and x_SS
   then give its land coefficient K_o = sqrt(2 P_SR) / (x_SS G_PQ) = a sqrt(P_SR / 2).
3. Only 1/G_PQ + C_Lk is identifiable at null, so C_Lk stays at nominal and the residual bias
   of the monitor's C_Lk estimate on the same healthy data is moved into 1/G_PQ, keeping the
   flow gain P_SR / (x_SS G_PQ) fixed (a few fixed passes), so that a healthy plant reads
   C_Lk = nominal and a leak reads as an increase.
   WH carries the lands' laminar clearance leak apart (``Baseline.c_land``, the valve's
   design value): it does not grow as the supply drops, as the orifices' coefficient does.
4. WH, where the run holds the jack under two loads or more: x_0 and the lands' null
   pressure coefficient from the holds (``hold_fit``), so that the law reads nominal C_Lk
   at a hold, where the monitor reads it (the passes of step 3 average over the motion).

``measured_run`` makes the "recorded log" from a scenario: the HF bench with the scenario's
sensor noise added (seeded).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.signal import savgol_filter

from models.eha import SimResult, simulate
from models.scenario import Scenario
from service.monitor import DEFAULT_MODEL, EST_KEYS, Baseline, MeasurementNoise, MonitorConfig

__all__ = [
    "measured_run",
    "identify_baseline",
    "identify_noise",
    "calibrate",
    "run_monitor",
    "bank_rows",
    "meas_channels",
    "SAMPLE_KEYS",
    "hold_windows",
    "hold_reading",
    "hold_fit",
]

SAMPLE_KEYS: tuple[str, ...] = ("t", "x_cmd", "i", "x_s", "x_j", "p1", "p2")


def measured_run(
    scenario: Scenario,
    *,
    valve: str = "HF",
    with_supply_sensor: bool = False,
    progress: Callable[[float], None] | None = None,
) -> tuple[SimResult, dict[str, NDArray]]:
    """Run the bench on ``scenario`` at the sensors' rate and add its seeded sensor noise.

    Returns the noiseless truth and the measured signals t, x_cmd, i, x_s, x_j, p1, p2
    (and p_sr when ``with_supply_sensor``).
    """
    sn = scenario.sensors
    out_every = max(1, int(round(1.0 / (sn.rate_hz * scenario.step_s))))
    n = scenario.n_steps() // out_every + 1
    rng = np.random.default_rng(sn.seed)
    # drawn before the run, in the order the channels have always been drawn (i, x_S, x_J,
    # P1, P2, then P_SR): a seed gives the same draws whether or not the ECU reads x_J's
    noise = {
        ch: s * rng.standard_normal(n) if s > 0 else None
        for ch, s in (("i", sn.current_a), ("x_s", sn.x_s_m), ("x_j", sn.x_j_m),
                      ("p1", sn.p_pa), ("p2", sn.p_pa))
    }  # fmt: skip
    fb = noise["x_j"] if sn.ecu_noisy_x_j else None
    sim = simulate(scenario, valve, out_every=out_every, progress=progress, x_fb_noise=fb)

    def noisy(ch: str, y: NDArray) -> NDArray:
        return y + noise[ch] if noise[ch] is not None else y.copy()

    meas = {
        "t": sim.t.copy(),
        "x_cmd": sim.x_cmd.copy(),
        "i": noisy("i", sim.i),
        "x_s": noisy("x_s", sim.x_s),
        "x_j": noisy("x_j", sim.x_j),
        "p1": noisy("p1", sim.p1),
        "p2": noisy("p2", sim.p2),
    }
    if with_supply_sensor:
        s = sn.p_sr_pa
        meas["p_sr"] = sim.p_sr + s * rng.standard_normal(n) if s > 0 else sim.p_sr.copy()
    return sim, meas


def _smoothing_window(t: NDArray) -> int:
    """Samples in the 0.2 s Savitzky-Golay window of the calibration (odd, at least 5)."""
    return max(5, int(round(0.2 / float(np.median(np.diff(t))))) | 1)


def _jack_speed(meas: dict[str, NDArray], win: int, dt: float) -> NDArray:
    """dx_J/dt [m/s] from the Savitzky-Golay window ``win`` (cubic) of the measured x_J."""
    return savgol_filter(np.asarray(meas["x_j"], float), win, 3, deriv=1, delta=dt)


NULL_FIT_SPREAD = 0.1  # fit x_0 when P12 at rest spans more than this share of P_SR (5-95 %)
NULL_FIT_V = 0.5e-3  # "at rest": smoothed |v_J| below this [m/s]


def identify_baseline(
    meas: dict[str, NDArray], law: str = DEFAULT_MODEL, p_sr_rated: float | None = None
) -> Baseline:
    """Steps 1-2 of the module docstring: P_R, effective x_SS and G_PQ by least squares."""
    nom = Baseline.nominal(law)
    p_sr = float(p_sr_rated or nom.p_sr_rated)
    t = np.asarray(meas["t"], float)
    dt = float(np.median(np.diff(t)))
    win = _smoothing_window(t)
    p1, p2 = np.asarray(meas["p1"], float), np.asarray(meas["p2"], float)
    p_r = float(np.mean(0.5 * (p1 + p2)) - 0.5 * p_sr)
    skew = 0.0
    if law == "WH":
        # WH keeps the return pressure (a line pressure, known) and reads the chamber
        # pressures' offset from mid-supply as a supply/return underlap skew, which scales
        # with P_SR as land mismatch does (an offset in P_R would not):
        # (P_k - P_R) / P_SR = f = k^2 / (1 + k^2), k = (1 + skew) / (1 - skew)
        f = float(np.clip((p_r + 0.5 * p_sr - nom.p_r) / p_sr, 0.05, 0.95))
        k = math.sqrt(f / (1.0 - f))
        skew, p_r = (k - 1.0) / (k + 1.0), nom.p_r
    x_s = savgol_filter(np.asarray(meas["x_s"], float), win, 3)
    p12 = savgol_filter(p1 - p2, win, 3)
    v_j = _jack_speed(meas, win, dt)
    keep = np.abs(x_s) < 0.7 * nom.x_ss
    keep[: win * 2] = False  # start-up transient
    keep[-win:] = False
    # the hydraulic null x_0: at rest (v_J ~ 0) the null relation is the line
    # x_S = x_0 + P12 (1/G_PQ + C_Lk) / K_q, whose offset is seen only if the run holds P12
    # at different levels (two loads); otherwise x_0 = 0
    rest = keep & (np.abs(v_j) < NULL_FIT_V)
    x_0 = 0.0
    if rest.sum() > 100 and np.ptp(np.percentile(p12[rest], [5, 95])) > NULL_FIT_SPREAD * p_sr:
        x_0 = float(np.polyfit(p12[rest], x_s[rest], 1)[1])
    A = np.stack([p_sr * (x_s - x_0), -(nom.area * v_j + nom.c_lk * p12)], axis=1)[keep]
    coef, *_ = np.linalg.lstsq(A, p12[keep], rcond=None)
    a, g_pq = float(coef[0]), float(coef[1])
    if not (a > 0 and g_pq > 0):
        raise ValueError(
            f"calibration failed: the healthy run does not excite the valve near null ({coef})"
        )
    x_ss = (2.0 if law == "WH" else 1.0) / a  # WH: the tangent null gain 2 P_SR / x_SS
    if law == "WH" and nom.c_land > 0.0:
        # 1/G_PQ is the lands' whole null pressure coefficient; WH carries the laminar
        # clearance share apart (c_land, supply-independent), so its orifices keep the
        # rest, at the same flow gain 2 P_SR / (x_SS G_PQ)
        # (docs/estimation.md, "Land clearance leak (WH)")
        inv_orifice = 1.0 / g_pq - nom.c_land
        if not inv_orifice > 0.0:
            raise ValueError(
                f"calibration failed: the valve's null pressure coefficient 1/G_PQ = "
                f"{1.0 / g_pq:.3e} does not exceed the lands' clearance leak c_land = "
                f"{nom.c_land:.3e} m^3/(s Pa)"
            )
        g_orifice = 1.0 / inv_orifice
        x_ss, g_pq = x_ss * g_pq / g_orifice, g_orifice
    return nom.model_copy(
        update={"x_ss": x_ss, "g_pq": g_pq, "p_r": p_r, "p_sr_rated": p_sr, "x_0": x_0,
                "skew": skew, "source": "lsq"}
    )  # fmt: skip


def noise_sigma(y: NDArray) -> float:
    """1-sigma of the white noise on a signal sampled much faster than it moves: the second
    difference of white noise has variance 6 sigma^2; median absolute deviation (robust to
    the few samples where the signal itself bends sharply)."""
    d2 = np.diff(np.asarray(y, float), 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


# model mismatch the filter's default chamber-pressure noise carries above the bundled 50 kPa
# transducers (55 kPa assumed: sqrt(55^2 - 50^2) = 23 kPa)
_P_MISMATCH_PA = float(np.sqrt(55e3**2 - 50e3**2))


def identify_noise(meas: dict[str, NDArray]) -> MeasurementNoise:
    """The filter's measurement noise from a healthy run: each sensor's white noise
    (``noise_sigma``), plus the default model-mismatch share on the chamber pressures."""
    d = MeasurementNoise()
    p = float(np.hypot(noise_sigma(np.concatenate([meas["p1"], meas["p2"]])), _P_MISMATCH_PA))
    p_sr = float(np.hypot(noise_sigma(meas["p_sr"]), _P_MISMATCH_PA)) if "p_sr" in meas else p
    return MeasurementNoise(
        x_s_m=max(noise_sigma(meas["x_s"]), 1e-3 * d.x_s_m),
        x_j_m=max(noise_sigma(meas["x_j"]), 1e-3 * d.x_j_m),
        p_pa=p,
        p_sr_pa=p_sr,
    )


def run_monitor(
    meas: dict[str, NDArray],
    config: MonitorConfig | None = None,
    baseline: Baseline | None = None,
    progress: Callable[[float], None] | None = None,
):
    """Feed the measured arrays sample by sample to a ``Monitor``; returns (outputs, monitor)."""
    from service.monitor import Monitor

    mon = Monitor(config, baseline)
    keys = [k for k in ("t", "x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr") if k in meas]
    cols = [np.asarray(meas[k], float).tolist() for k in keys]
    n = len(cols[0])
    outs = []
    step = max(1, n // 50)
    for j in range(n):
        outs.append(mon.update({k: c[j] for k, c in zip(keys, cols, strict=True)}))
        if progress is not None and j % step == 0:
            progress(j / n)
    return outs, mon


def meas_channels(meas: dict[str, NDArray]) -> NDArray:
    """The measured arrays as ``MonitorBank.update_arrays`` takes them: (n, 7) in
    ``service.wire.messages.CHANNELS`` order, NaN where a channel is absent."""
    from models.channels import SENSORS as CHANNELS

    ch = np.full((len(meas["t"]), len(CHANNELS)), np.nan)
    for j, c in enumerate(CHANNELS):
        if c in meas:
            ch[:, j] = meas[c]
    return ch


def bank_rows(meas: dict[str, NDArray], config: MonitorConfig, baseline: Baseline):
    """The output rows of one actuator fed ``meas`` in one ``MonitorBank.update_arrays`` call
    (the same numbers as ``run_monitor``, ``tests/test_monitor_block.py``; about 10x faster)."""
    from service.monitor import MonitorBank

    t = np.asarray(meas["t"], float)
    ch = meas_channels(meas)
    bank = MonitorBank(config, baseline, capacity=1)
    k = bank.index_of("calibration/unit")
    return bank.update_arrays(np.full(len(t), k, np.int64), t, ch)


def calibrate(
    meas: dict[str, NDArray],
    law: str | None = None,
    config: MonitorConfig | None = None,
    passes: int = 2,
    settle_s: float = 1.0,
    holds: bool = True,
) -> Baseline:
    """Identify a baseline from healthy measurements (all steps of the docstring).

    ``law`` is the process model the baseline is for; by default ``config.model`` (DEFAULT_MODEL
    when neither is given). ``holds``: on WH, finish with ``hold_fit`` (step 4)."""
    cfg = config or MonitorConfig()
    law = law or cfg.model
    cfg = cfg.model_copy(update={"model": law})
    base = identify_baseline(meas, law)
    t = np.asarray(meas["t"], float)
    p12_m = savgol_filter(
        np.asarray(meas["p1"], float) - np.asarray(meas["p2"], float), _smoothing_window(t), 2
    )
    for _ in range(passes):
        rows = bank_rows(meas, cfg, base)
        sel = rows.t >= t[0] + settle_s
        c_all = rows.est[sel, EST_KEYS.index("c_lk")]
        c_est = float(np.mean(c_all))
        p_sr_est = float(np.mean(rows.est[sel, EST_KEYS.index("p_sr")]))
        # null refinement: a null error dx_0 is a flow error K_x dx_0, read as a leak
        # K_x dx_0 / P12; on a run that holds P12 at two levels (x_0 fitted) the monitor's
        # own C_Lk bias against 1/P12 gives dx_0 (slope) and the 1/G_PQ bias (intercept)
        # (WH only: on C5 it halved the suite's median C_Lk increase error but one member's
        # filter then diverged, 48 re-initialisations; docs/estimation.md)
        x_0 = base.x_0
        if base.x_0 != 0.0 and law == "WH":
            p12_s = np.interp(rows.t[sel], t, p12_m)
            use = np.abs(p12_s) > NULL_FIT_SPREAD * 0.5 * base.p_sr_rated
            if use.sum() > 100:
                inv = 1.0 / p12_s[use]
                slope, icpt = np.polyfit(inv, c_all[use] - base.c_lk, 1)
                k_x = 2.0 * base.p_sr_rated / (base.x_ss * base.g_pq)  # WH null flow gain
                x_0 = base.x_0 + float(slope) / k_x
                c_est = base.c_lk + float(icpt)
        inv_g = 1.0 / base.g_pq + (c_est - base.c_lk)
        # the P_SR estimate is clipped at rated: only correct P_R when it reads low. Not for
        # WH: its P_SR is read through its own orifice law, not the chamber-pressure sum, so
        # the correction would feed WH's model error back into P_R
        p_r = base.p_r + (0.0 if law == "WH" else 0.5 * min(p_sr_est - base.p_sr_rated, 0.0))
        g_new = 1.0 / max(inv_g, 1e-14)
        # keep the flow gain P_SR / (x_SS G_PQ) fixed: only the sum 1/G_PQ + C_Lk moves
        x_ss = base.x_ss * base.g_pq / g_new
        base = base.model_copy(update={"g_pq": g_new, "x_ss": x_ss, "p_r": p_r, "x_0": x_0})
    if law == "WH" and holds:
        base = hold_fit(meas, base)
    return base.model_copy(update={"source": "calibrated"})


HOLD_SETTLE_S = 0.3  # a hold: the command has not moved for this long [s] ...
HOLD_DP12 = 0.05  # ... |dP12/dt| (smoothed) below this share of P_SR per second ...
HOLD_MIN_S = 0.3  # ... for at least this long [s]
HOLD_FIT_MAX_DX0 = 0.05  # hold_fit moves x_0 by at most this share of x_SS ...
HOLD_FIT_MAX_DXSS = 0.2  # ... and x_SS by at most this share of itself


def hold_windows(meas: dict[str, NDArray], p_sr: float) -> list[tuple[float, float, float]]:
    """Mean (x_S, P1, P2) [m, Pa, Pa] of each hold of a run: the position command still for
    HOLD_SETTLE_S, the smoothed jack speed below NULL_FIT_V and P12 steady (HOLD_DP12), for
    at least HOLD_MIN_S."""
    t = np.asarray(meas["t"], float)
    dt = float(np.median(np.diff(t)))
    win = _smoothing_window(t)
    p1, p2 = np.asarray(meas["p1"], float), np.asarray(meas["p2"], float)
    v_j = _jack_speed(meas, win, dt)
    dp12 = savgol_filter(p1 - p2, win, 3, deriv=1, delta=dt)
    x_cmd = np.asarray(meas["x_cmd"], float)
    moved = np.concatenate(([True], np.abs(np.diff(x_cmd)) > 1e-9))
    last_move = np.maximum.accumulate(np.where(moved, np.arange(len(t)), 0))
    ok = (t - t[last_move] >= HOLD_SETTLE_S) & (np.abs(v_j) < NULL_FIT_V)
    ok &= np.abs(dp12) < HOLD_DP12 * p_sr
    ok[:win] = False
    ok[-win:] = False
    x_s = np.asarray(meas["x_s"], float)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], ok.astype(np.int8), [0]))))
    return [
        (float(np.mean(x_s[a:b])), float(np.mean(p1[a:b])), float(np.mean(p2[a:b])))
        for a, b in zip(edges[::2], edges[1::2], strict=True)
        if t[b - 1] - t[a] >= HOLD_MIN_S
    ]


def hold_reading(base: Baseline, x_s: float, p1: float, p2: float, p_sr: float) -> float:
    """C_Lk [m^3/(s Pa)] the WH law of ``base`` reads at a hold (x_S, P1, P2 absolute, at
    supply P_SR): both chamber balances of docs/models.md eq. 5 with v_J = 0 and steady
    pressures, Q1 - Q2 = C_Lk P12 = Q4 - Q3, averaged."""
    from models.eha_reduced_wh import land_flows

    rp = base.reduced_params()
    q1, q2, q3, q4 = land_flows(x_s - rp.x_0, p1, p2, p_sr, rp)
    return float(((q1 - q2) - (q3 - q4)) / (2.0 * (p1 - p2)))


def hold_fit(meas: dict[str, NDArray], base: Baseline) -> Baseline:
    """WH: the hydraulic null x_0 and the lands' null pressure coefficient (x_SS, with G_PQ
    moving so that the flow gain P_SR / (x_SS G_PQ) stays) such that the law reads the
    baseline C_Lk at every hold of the healthy run (least squares, ``hold_reading``): the
    monitor reads C_Lk at holds, where slow motion with stick-slip reads it differently
    (docs/estimation.md, "Calibrating where the monitor reads"). Only where the run holds
    P12 at two levels at least NULL_FIT_SPREAD of P_SR apart, and only a fit within
    HOLD_FIT_MAX_DX0 and HOLD_FIT_MAX_DXSS of ``base``; otherwise ``base``."""
    from scipy.optimize import least_squares

    p_sr = base.p_sr_rated
    holds = [h for h in hold_windows(meas, p_sr) if abs(h[1] - h[2]) > 0.5 * NULL_FIT_SPREAD * p_sr]
    if len(holds) < 2 or np.ptp([h[1] - h[2] for h in holds]) < NULL_FIT_SPREAD * p_sr:
        return base
    flow = base.x_ss * base.g_pq  # x_SS G_PQ: the flow gain's denominator, kept

    def moved(v: NDArray) -> Baseline:  # v = (dx_0 [um], relative change of x_SS)
        x_ss = base.x_ss * (1.0 + v[1])
        return base.model_copy(
            update={"x_0": base.x_0 + v[0] * 1e-6, "x_ss": x_ss, "g_pq": flow / x_ss}
        )

    def residuals(v: NDArray) -> list[float]:
        b = moved(v)
        return [(hold_reading(b, *h, p_sr) - b.c_lk) / b.c_lk for h in holds]

    sol = least_squares(residuals, [0.0, 0.0], x_scale=[0.1, 0.01])
    # a fit that moves the null by more than HOLD_FIT_MAX_DX0 or x_SS by more than
    # HOLD_FIT_MAX_DXSS is not a refinement of the passes' baseline: keep that one
    if not (
        sol.success
        and abs(sol.x[0]) * 1e-6 <= HOLD_FIT_MAX_DX0 * base.x_ss
        and abs(sol.x[1]) <= HOLD_FIT_MAX_DXSS
    ):
        return base
    return moved(sol.x)
