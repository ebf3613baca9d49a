"""What any monitor could read from a suite member's sensors: an information bound per member
of the duty-cycle suite (docs/evaluation.md, "An information bound on the suite's targets").

    .venv/bin/python -m evaluation.bound --seeds 1-7 --workers 2 --known-plant   # 1 min
    .venv/bin/python -m evaluation.suite --seeds 1-7 --workers 2 --json s.json
    .venv/bin/python -m evaluation.bound --seeds 1-7 --workers 2 --suite-json s.json  # 9 min
    .venv/bin/python -m evaluation.bound --seeds 1-7 --workers 2 --suite-json s.json --png b.png
    .venv/bin/python -m evaluation.bound --seed 5 --only 11,27 --known-plant --channels
    .venv/bin/python -m evaluation.bound --seeds 1-7 --workers 2 --drop i,x_s

The suite's truth is the HF bench with white Gaussian sensor noise added to its outputs
(``service.monitor.calibration.measured_run``: the ECU acts on the true signals, the noise is the
transducers'; ``--drop i,x_s`` leaves out the current and the spool, which follow that
noise-free loop). Two leak profiles are then two noiseless output sets y0, y1, and with the
noise's sigma per channel the detectability of their difference is

    d'^2 = sum over samples and measured channels (i, x_S, x_J, P1, P2) of ((y1 - y0) / sigma)^2

(the Neyman-Pearson likelihood-ratio test between the two profiles detects with probability
Phi(d' - z_alpha) at false-alarm rate alpha). It is an upper bound on what a monitor can do:
the test knows the plant, its other parameters and both profiles exactly, and the monitor
knows none of them. Where the bound says no, no monitor on these sensors can meet the target.

Per leak member:

- ``t_ideal``: the alarm. The truth against the same leak capped at the clear level (2.0x
  nominal, the healthiest profile the alarm may not be raised on), d'^2 accumulated from the
  start; ``t_ideal`` is the first time it reaches ``D_ALARM``^2 (z 3.09: 0.1 % false alarms,
  half the leaks detected), as a delay after the true crossing of the raise level (2.5x),
  the suite's ``delay``. Above 1 s, no monitor meets the 1 s target there.
- ``d_inc``: the settled reading. The truth against the same leak with its increase 10 %
  larger and 10 % smaller (the target's edges), over the whole run (the test also knows the
  leak's shape), the smaller of the two d'. An unbiased reading misses the 10 % band with
  probability at least ``p_miss`` = Phi(-d'+) + Phi(-d'-); ``d_inc`` under 2 means more than
  about 5 %.
- ``sigma%``: the same question with the plant's tolerances unknown (the generator's mass,
  friction, four underlaps, bulk modulus, air, the supply drops' depth, and the external
  load of each run as a free constant per ``LOAD_PIECE_S``), identified
  jointly from the calibration segment and the test: the Cramer-Rao sigma of the increase
  [% of the true increase] from the Fisher matrix of the whitened sensitivities (secants
  across the 10 % band for the leak, over +-``STEP_REL`` for the others). ``sigma_known%`` is
  the same with the tolerances known. Linearised: a guide, not a proof, where the stick-slip
  makes the outputs jump.
- ``dn(1s)``: the alarm's d' within 1 s of the crossing once every difference the unknown
  tolerances could also make is projected out (``projected_dprime``).
- with ``--suite-json`` (the output of ``evaluation/suite.py --json``, same seeds):
  the monitor's ``delay`` and ``inc%`` beside them, and which misses are beyond the bound.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from evaluation.suite import TARGETS, run_jobs, seed_list
from models.scenario import Event, Periodic, Profile, SensorNoise

CHANNELS = (("i", "current_a"), ("x_s", "x_s_m"), ("x_j", "x_j_m"), ("p1", "p_pa"), ("p2", "p_pa"))
D_ALARM = 3.09  # z of a 0.1 % false-alarm rate: an ideal test detects half the leaks there
D_INC = 2.0  # an unbiased reading with d' under 2 misses the 10 % band 5 % of the time or more
INC_EDGE = 0.10  # the target's edge: 10 % of the true increase
STEP_REL = 0.05  # relative half-step of the nuisances' secants: the jack's stick-slip makes the
# outputs jump with a parameter, and a secant over a span like the tolerances' averages that
LOAD_PIECE_S = 0.25  # the external load, unknown to the monitor: a free constant per piece [s]
LOAD_STEP_N = 200.0  # half-step of the load pieces' secants [N]
LEAK_RAISE, LEAK_CLEAR = 2.5, 2.0  # the alarm's levels in nominal C_Lk (AlarmConfig defaults)


def dprime2_series(y0, y1, sensors: SensorNoise) -> np.ndarray:
    """Per-sample contribution to d'^2 of two noiseless output sets (objects with the
    attributes of ``CHANNELS``, same time grid) under the white noise ``sensors`` [1]."""
    out = np.zeros(len(y0.t))
    for ch, field in CHANNELS:
        s = float(getattr(sensors, field))
        if s > 0:
            out += ((np.asarray(getattr(y1, ch)) - np.asarray(getattr(y0, ch))) / s) ** 2
    return out


def first_reaching(t: np.ndarray, d2: np.ndarray, level: float) -> float | None:
    """First time [s] the cumulative sum of ``d2`` reaches ``level``^2; None if never."""
    cum = np.cumsum(d2)
    k = int(np.searchsorted(cum, level**2))
    return float(t[k]) if k < len(t) else None


def miss_probability(d_plus: float, d_minus: float) -> float:
    """Lower bound on the chance an unbiased reading falls outside the band whose edges are
    d_plus and d_minus standard deviations away: Phi(-d+) + Phi(-d-)."""

    def phi_neg(d: float) -> float:
        return 0.5 * math.erfc(d / math.sqrt(2.0))

    return phi_neg(d_plus) + phi_neg(d_minus)


def leak_profile(c0: float, t_l: float, ramp_s: float, ratio: float) -> Profile:
    """The generator's leak (one event: nominal C_Lk ``c0`` to ``ratio`` x ``c0`` from
    ``t_l`` over ``ramp_s``)."""
    return Profile(initial=c0, events=[Event(t=t_l, value=c0 * ratio, ramp_s=ramp_s)])


def capped_ratio_ramp(ratio: float, ramp_s: float, cap: float) -> tuple[float, float]:
    """(value, ramp_s) of the same leak capped at ``cap`` x nominal: the same slope, stopping
    at the cap."""
    if ratio <= cap:
        return ratio, ramp_s
    return cap, ramp_s * (cap - 1.0) / (ratio - 1.0)


def crossing_time(t_l: float, ramp_s: float, ratio: float, level: float) -> float | None:
    """When the generator's leak reaches ``level`` x nominal [s]; None if it never does."""
    if ratio < level:
        return None
    return t_l + ramp_s * (level - 1.0) / (ratio - 1.0)


def whitened(sim, sensors: SensorNoise) -> np.ndarray:
    """The measured channels of a noiseless run over their noise sigma: (n, channels)."""
    cols = [
        np.asarray(getattr(sim, ch)) / float(getattr(sensors, f))
        for ch, f in CHANNELS
        if float(getattr(sensors, f)) > 0
    ]
    return np.stack(cols, axis=1)


def without(sensors: SensorNoise, drop: tuple[str, ...]) -> SensorNoise:
    """``sensors`` with the channels ``drop`` (names of ``CHANNELS``; ``p`` for P1 and P2,
    which share one noise figure) taken out of the bound (their sigma set to 0)."""
    fields = {f for ch, f in CHANNELS if ch in drop or (ch in ("p1", "p2") and "p" in drop)}
    unknown = set(drop) - {ch for ch, _ in CHANNELS} - {"p"}
    if unknown:
        raise ValueError(f"unknown channel(s) {sorted(unknown)}; expected i, x_s, x_j, p")
    return sensors.model_copy(update={f: 0.0 for f in fields})


def measured_names(sensors: SensorNoise) -> list[str]:
    """The channels of ``whitened``, in its column order."""
    return [ch for ch, f in CHANNELS if float(getattr(sensors, f)) > 0]


def _steps(params: dict[str, float], name: str, h: float) -> tuple[float, float]:
    """(down, up) values of plant parameter ``name`` for a difference of relative size
    ``h``, one-sided where the plant's own check (Coulomb F_d <= breakaway F_s) forbids a
    side."""
    v = params[name]
    d = abs(v) * h
    lo, hi = v - d, v + d
    if name == "f_d" and hi > params["f_s"]:
        hi = v
    if name == "f_s" and lo < params["f_d"]:
        lo = v
    return lo, hi


def load_bump(load: Profile, t0: float, t1: float, force_n: float) -> Profile:
    """``load`` plus ``force_n`` [N] on [t0, t1): one half-period of a square wave."""
    bump = Periodic(kind="square", amplitude=force_n, freq_hz=0.5 / (t1 - t0), t_start=t0, t_end=t1)
    return load.model_copy(update={"periodic": [*load.periodic, bump]})


def nuisance_jacobians(
    dc, h: float = STEP_REL, load_piece_s: float = LOAD_PIECE_S, drop: tuple[str, ...] = ()
):
    """Whitened sensitivities of the test run and of the calibration run to every unknown of
    the plant: the generator's tolerances (per unit of relative change, central secants of
    relative size ``h``), the supply drops' depth where there are any, and the external load
    of each run as an unknown constant per ``load_piece_s`` [per N; 0: the loads known]:
    (J_test (n,c,m), J_cal (n_cal,c,m), names). A column that belongs to one run is zero in
    the other."""
    from models.eha import simulate

    sc, cal = dc.test, dc.calibration
    tols = sorted(dc.params)

    def run(scn, params: dict, supply: float = 1.0, load: Profile | None = None) -> np.ndarray:
        upd: dict = {"params": params}
        if load is not None:
            upd["load"] = load
        if scn is sc and supply != 1.0:
            p0 = sc.supply.initial
            upd["supply"] = Profile(
                initial=p0,
                events=[
                    Event(t=e.t, value=p0 - supply * (p0 - e.value), ramp_s=e.ramp_s)
                    for e in sc.supply.events
                ],
            )
        out_every = max(1, int(round(1.0 / (scn.sensors.rate_hz * scn.step_s))))
        sim = simulate(scn.model_copy(update=upd), "HF", out_every=out_every)
        return whitened(sim, without(scn.sensors, drop))

    j_test, j_cal, names = [], [], []
    for n in tols:
        lo, hi = _steps(dc.params, n, h)
        p_lo, p_hi = {**dc.params, n: lo}, {**dc.params, n: hi}
        scale = (hi - lo) / abs(dc.params[n])  # relative: J per unit of relative change
        j_test.append((run(sc, p_hi) - run(sc, p_lo)) / scale)
        j_cal.append((run(cal, p_hi) - run(cal, p_lo)) / scale)
        names.append(n)
    zero_t, zero_c = np.zeros_like(j_test[0]), np.zeros_like(j_cal[0])
    if sc.supply.events:
        j_test.append((run(sc, dc.params, 1 + h) - run(sc, dc.params, 1 - h)) / (2 * h))
        j_cal.append(zero_c)
        names.append("supply drop")
    if load_piece_s > 0:
        for scn, label in ((sc, "test"), (cal, "cal")):
            edges = np.arange(0.0, scn.duration_s, load_piece_s)
            for t0 in edges:
                t1 = min(t0 + load_piece_s, scn.duration_s)
                up = run(scn, dc.params, load=load_bump(scn.load, t0, t1, LOAD_STEP_N))
                down = run(scn, dc.params, load=load_bump(scn.load, t0, t1, -LOAD_STEP_N))
                col = (up - down) / (2 * LOAD_STEP_N)
                j_test.append(col if scn is sc else zero_t)
                j_cal.append(col if scn is cal else zero_c)
                names.append(f"load {label} {t0:.2f} s")
    return np.stack(j_test, -1), np.stack(j_cal, -1), names


def crb_scale(j_k: np.ndarray, j_test: np.ndarray, j_cal: np.ndarray) -> tuple[float, float]:
    """Cramer-Rao sigma of the leak's scale k [1]: (nuisances known, nuisances unknown and
    identified jointly from the calibration and the test runs), from the Fisher matrix
    F = J^T J of the whitened sensitivities (a pseudo-inverse: an unknown the data do
    not see at all is no nuisance)."""
    a = np.concatenate([j_k.reshape(-1, 1), j_test.reshape(-1, j_test.shape[-1])], axis=1)
    f = a.T @ a
    m = j_cal.reshape(-1, j_cal.shape[-1])
    f[1:, 1:] += m.T @ m
    return float(1.0 / np.sqrt(f[0, 0])), float(np.sqrt(np.linalg.pinv(f, hermitian=True)[0, 0]))


def projected_dprime(delta: np.ndarray, j_test: np.ndarray, j_cal: np.ndarray) -> float:
    """d' of a difference ``delta`` (whitened, (n,c)) once the nuisance directions are
    projected out: a profile the unknowns can mimic is not told apart by any test
    (d'^2 = |delta|^2 - b^T G^-1 b, b = J^T delta, G = J^T J + J_cal^T J_cal)."""
    j = j_test.reshape(-1, j_test.shape[-1])
    m = j_cal.reshape(-1, j_cal.shape[-1])
    d = delta.reshape(-1)
    b = j.T @ d
    g = j.T @ j + m.T @ m
    return float(np.sqrt(max(d @ d - b @ np.linalg.pinv(g, hermitian=True) @ b, 0.0)))


def member_bound(
    seed: int,
    index: int,
    nuisance: bool = True,
    load_piece_s: float = LOAD_PIECE_S,
    drop: tuple[str, ...] = (),
) -> dict:
    """The bound of the module docstring for member ``index`` of suite ``seed``."""
    from evaluation.dutycycle import duty_cycle
    from models.eha import simulate

    dc = duty_cycle(seed, index)
    row: dict = {"name": dc.test.name, "kind": dc.kind, "leak_ratio": dc.leak_ratio}
    if dc.leak_t is None:
        return row
    sc = dc.test
    sn = without(sc.sensors, drop)
    out_every = max(1, int(round(1.0 / (sn.rate_hz * sc.step_s))))
    c0 = float(sc.leak.initial)
    t_l, t_end = dc.leak_t
    ramp = t_end - t_l
    r = dc.leak_ratio

    def run(ratio: float, ramp_s: float):
        return simulate(
            sc.model_copy(update={"leak": leak_profile(c0, t_l, ramp_s, ratio)}),
            "HF",
            out_every=out_every,
        )

    truth = run(r, ramp)
    t = truth.t
    y_true = whitened(truth, sn)
    y_edge = [whitened(run(1.0 + k * (r - 1.0), ramp), sn) for k in (1 + INC_EDGE, 1 - INC_EDGE)]
    d_side = [float(np.linalg.norm(y - y_true)) for y in y_edge]
    names = measured_names(sn)
    per = np.linalg.norm(y_edge[1] - y_true, axis=0).tolist()
    row["d_inc_by_channel"] = dict(zip(names, per, strict=True))
    row.update(
        {
            "d_inc": min(d_side),
            "d_inc_plus": d_side[0],
            "d_inc_minus": d_side[1],
            "p_miss": miss_probability(*d_side),
        }
    )
    jac = None
    if nuisance:
        jac = nuisance_jacobians(dc, load_piece_s=load_piece_s, drop=drop)
        j_k = (y_edge[0] - y_edge[1]) / (2.0 * INC_EDGE)  # the secant across the target band
        s_known, s_unknown = crb_scale(j_k, *jac[:2])
        row["sigma_known%"] = 100.0 * s_known
        row["sigma%"] = 100.0 * s_unknown
        row["p_miss_nuis"] = miss_probability(INC_EDGE / s_unknown, INC_EDGE / s_unknown)
        row["nuisances"] = [n for n in jac[2] if not n.startswith("load ")]
        row["load_pieces"] = len(jac[2]) - len(row["nuisances"])
    t_cross = crossing_time(t_l, ramp, r, LEAK_RAISE)
    if t_cross is not None:
        delta = whitened(run(*capped_ratio_ramp(r, ramp, LEAK_CLEAR)), sn) - y_true
        d2 = np.sum(delta**2, axis=1)
        t_id = first_reaching(t, d2, D_ALARM)
        upto = t <= t_cross + TARGETS["delay"]
        w = (t > t_cross) & upto
        row["t_cross"] = t_cross
        row["t_ideal"] = None if t_id is None else t_id - t_cross
        row["d_alarm_1s"] = float(np.sqrt(d2[upto].sum()))
        per = np.linalg.norm(delta[upto], axis=0).tolist()
        row["d_alarm_1s_by_channel"] = dict(zip(names, per, strict=True))
        row["p12_1s_mpa"] = float(np.mean(np.abs(truth.p12[w]))) / 1e6
        if jac is not None:
            row["d_alarm_1s_nuis"] = projected_dprime(delta[upto], jac[0][upto], jac[1])
    return row


def _job(args: tuple[int, int, bool, tuple[str, ...], float]) -> dict:
    seed, index, nuisance, drop, piece = args
    return member_bound(seed, index, nuisance, drop=drop, load_piece_s=piece)


def _f(v, spec: str, width: int) -> str:
    return ("-" if v is None else format(v, spec)).rjust(width)


def reading_out_of_reach(r: dict) -> bool:
    """The settled reading of leak row ``r`` is within reach of the noise: d' of the 10 %
    edges under ``D_INC`` with the plant known, or the Cramer-Rao sigma past 10 % / D_INC
    with it unknown (where computed)."""
    return r["d_inc"] < D_INC or r.get("sigma%", 0.0) > 100.0 * INC_EDGE / D_INC


def alarm_out_of_reach(r: dict) -> bool:
    """No test on the sensors raises alarm row ``r`` within the target: the ideal test comes
    later (or never), or with the plant unknown its d' within 1 s is under ``D_ALARM``."""
    ideal = r.get("t_ideal")
    nuis = r.get("d_alarm_1s_nuis")
    return ideal is None or ideal > TARGETS["delay"] or (nuis is not None and nuis < D_ALARM)


def judge(rows: list[dict], monitor: dict[str, dict]) -> None:
    """Add the monitor's figures (rows of ``evaluation/suite.py --json``, by name) and
    whether each of its misses is beyond the bound (the known plant's, and where computed the
    one with the plant's tolerances unknown)."""
    for r in rows:
        m = monitor.get(r["name"])
        if m is None or "d_inc" not in r:
            continue
        r["inc%"], r["delay"] = m.get("inc%"), m.get("delay")
        inc_miss = r["inc%"] is not None and abs(r["inc%"]) > TARGETS["inc%"]
        late = r["delay"] is not None and not r["delay"] <= TARGETS["delay"]
        r["inc_beyond"] = bool(inc_miss and reading_out_of_reach(r))
        r["alarm_beyond"] = bool(late and alarm_out_of_reach(r))
        r["misses"] = [k for k, v in (("inc%", inc_miss), ("delay", late)) if v]


def print_rows(rows: list[dict]) -> None:
    print(
        f"{'member':<10} {'kind':<12} {'ratio':>5} {'d_inc':>6} {'sig%':>5} {'inc%':>6}"
        f" {'d(1s)':>6} {'dn(1s)':>6} {'ideal':>7} {'delay':>7} {'P12':>5}  beyond the bound"
    )
    for r in rows:
        if "d_inc" not in r:
            continue
        beyond = [k for k in ("inc", "alarm") if r.get(f"{k}_beyond")]
        print(
            f"{r['name']:<10} {r['kind']:<12} {r['leak_ratio']:5.2f}"
            f" {_f(r['d_inc'], '.1f', 6)} {_f(r.get('sigma%'), '.2f', 5)}"
            f" {_f(r.get('inc%'), '+.1f', 6)} {_f(r.get('d_alarm_1s'), '.1f', 6)}"
            f" {_f(r.get('d_alarm_1s_nuis'), '.1f', 6)}"
            f" {_f(r.get('t_ideal'), '.3f', 7)} {_f(r.get('delay'), '.3f', 7)}"
            f" {_f(r.get('p12_1s_mpa'), '.2f', 5)}  {', '.join(beyond)}"
        )


def print_channels(rows: list[dict]) -> None:
    """Each leak member's d' per measured channel: the settled reading's lower edge (-10 %)
    and, above the raise level, the alarm's first second."""
    print("\nd' per channel (settled -10 % edge | alarm within 1 s)")
    for r in rows:
        if "d_inc_by_channel" not in r:
            continue
        inc = " ".join(f"{k} {v:.1f}" for k, v in r["d_inc_by_channel"].items())
        al = r.get("d_alarm_1s_by_channel")
        al = " ".join(f"{k} {v:.1f}" for k, v in al.items()) if al else "-"
        print(f"{r['name']:<10} {inc} | {al}")


def summary(rows: list[dict]) -> dict:
    """Figures over the leak members: the bound's extremes, how many members it rules out,
    and of the monitor's misses (with ``judge``) how many are beyond it."""
    leaks = [r for r in rows if "d_inc" in r]
    alarms = [r for r in leaks if "t_cross" in r]

    def worst(key: str, rs: list[dict], fn=min):
        vals = [r[key] for r in rs if r.get(key) is not None]
        return fn(vals) if vals else None

    s = {
        "leak_members": len(leaks),
        "d_inc_min": worst("d_inc", leaks),
        "sigma%_max": worst("sigma%", leaks, max),
        "inc_bound_low": sum(reading_out_of_reach(r) for r in leaks),
        "alarm_members": len(alarms),
        "t_ideal_max": worst("t_ideal", alarms, max),
        "d_alarm_1s_min": worst("d_alarm_1s", alarms),
        "d_alarm_1s_nuis_min": worst("d_alarm_1s_nuis", alarms),
        "alarm_beyond_1s": [r["name"] for r in alarms if alarm_out_of_reach(r)],
    }
    if any("misses" in r for r in leaks):
        inc = [r for r in leaks if "inc%" in r.get("misses", [])]
        late = [r for r in leaks if "delay" in r.get("misses", [])]
        s.update(
            {
                "inc_misses": len(inc),
                "inc_misses_beyond": [r["name"] for r in inc if r["inc_beyond"]],
                "late_alarms": len(late),
                "late_alarms_beyond": [r["name"] for r in late if r["alarm_beyond"]],
            }
        )
    return s


def print_summary(s: dict) -> None:
    g = lambda k, spec: "-" if s.get(k) is None else format(s[k], spec)  # noqa: E731
    print(
        f"\nleak members: {s['leak_members']}; settled reading: d' of the 10 % edges at least"
        f" {g('d_inc_min', '.1f')} (plant known), Cramer-Rao sigma of the increase at most"
        f" {g('sigma%_max', '.2f')} % (tolerances unknown); members where an unbiased reading"
        f" would miss 10 % more than 5 % of the time: {s['inc_bound_low']}"
    )
    b = s["alarm_beyond_1s"]
    print(
        f"alarm members (leak above {LEAK_RAISE}x): {s['alarm_members']}; ideal test (d'"
        f" {D_ALARM}) at most {g('t_ideal_max', '+.3f')} s after the crossing; d' within 1 s at"
        f" least {g('d_alarm_1s_min', '.1f')} (plant known), {g('d_alarm_1s_nuis_min', '.1f')}"
        f" (tolerances unknown); no test detects within 1 s: {len(b)}"
        + (f" ({', '.join(b)})" if b else "")
    )
    if "inc_misses" in s:
        for key, label in (("inc_misses", "C_Lk increase misses"), ("late_alarms", "late alarms")):
            beyond = s[f"{key}_beyond"]
            print(
                f"monitor's {label}: {s[key]}, beyond the bound: {len(beyond)}"
                + (f" ({', '.join(beyond)})" if beyond else "")
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=seed_list, default=None, help="1-7 or 1,3,8")
    ap.add_argument("--seed", type=int, default=1, help="one suite seed (unless --seeds)")
    ap.add_argument("--suite", type=int, default=30, help="members per seed")
    ap.add_argument("--only", default=None, help="member indices, 3,7 (one seed)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--suite-json", default=None, help="evaluation/suite.py --json output")
    ap.add_argument("--json", default=None, help="write the rows and summary here")
    ap.add_argument(
        "--png", default=None, help="draw the monitor against the bound (needs --suite-json)"
    )
    ap.add_argument("--channels", action="store_true", help="also print d' per channel")
    ap.add_argument(
        "--drop",
        default="",
        metavar="CH,CH",
        help="leave these channels out of the bound (i, x_s, x_j, p), e.g. --drop i,x_s",
    )
    ap.add_argument(
        "--load-piece",
        type=float,
        default=LOAD_PIECE_S,
        metavar="S",
        help=f"the unknown load's piece length [s] (default {LOAD_PIECE_S}; 0: the load known)",
    )
    ap.add_argument(
        "--known-plant",
        action="store_true",
        help="skip the bound with the plant's tolerances unknown (about 10x faster)",
    )
    a = ap.parse_args(argv)
    seeds = a.seeds or [a.seed]
    if a.only is not None:
        try:
            idx = sorted({int(x) for x in a.only.split(",")})
        except ValueError:
            ap.error(f"--only {a.only!r}: expected member indices such as 3,7")
        if len(seeds) != 1 or any(not 0 <= k < a.suite for k in idx):
            ap.error("--only takes indices within --suite, with one seed")
    else:
        idx = list(range(a.suite))
    if a.suite < 1 or a.workers < 1:
        ap.error("--suite and --workers must be at least 1")
    if not a.load_piece >= 0:
        ap.error(f"--load-piece {a.load_piece}: expected a length >= 0 [s]")
    if a.png and not a.suite_json:
        ap.error("--png draws the monitor's figures: give --suite-json too")
    monitor: dict[str, dict] = {}
    if a.suite_json:
        try:
            data = json.loads(Path(a.suite_json).read_text())
            for v in data["seeds"].values():
                monitor.update({m["name"]: m for m in v["rows"]})
        except (OSError, ValueError, KeyError, TypeError) as exc:
            ap.error(f"--suite-json {a.suite_json}: {exc}")
    t0 = time.perf_counter()
    drop = tuple(c for c in a.drop.split(",") if c)
    try:
        without(SensorNoise(), drop)
    except ValueError as exc:
        ap.error(f"--drop {a.drop!r}: {exc}")
    jobs = [(s, k, not a.known_plant, drop, a.load_piece) for s in seeds for k in idx]
    print(f"{len(jobs)} members, {a.workers} worker(s) ...", flush=True)
    rows = run_jobs(_job, jobs, a.workers)
    if monitor:
        judge(rows, monitor)
    print_rows(rows)
    if a.channels:
        print_channels(rows)
    s = summary(rows)
    print_summary(s)
    print(f"\n{len(jobs)} members in {time.perf_counter() - t0:.1f} s")
    if a.png:
        from evaluation.plots import plot_bound

        plot_bound(rows, a.png, f"suite seeds {','.join(map(str, seeds))}: monitor and bound")
        print(f"wrote {a.png}")
    if a.json:
        Path(a.json).write_text(json.dumps({"rows": rows, "summary": s}, indent=1))
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
