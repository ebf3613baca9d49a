"""``servowatch characteristic``: P12-x_S curves parameterised by Q_J (seed Figs. 2, 8-11;
WH: the steady state of docs/models.md eq. 7)."""

from __future__ import annotations

import argparse

import numpy as np

from models.params import EHAParams, simplified_params
from models.valve_laws import LAW_NAMES, p12
from service.cli.util import check_outputs, emit_json, finite_float, float_list, writing

NAME = "characteristic"
HELP = "P12-x_S valve characteristic of one model, parameterised by the jack flow Q_J"

MODELS = (*LAW_NAMES, "HF", "WH")
DEFAULT_Q_J = (-1e-4, -5e-5, 0.0, 5e-5, 1e-4)  # m^3/s


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, choices=MODELS, help="valve model")
    p.add_argument("--p-sr", type=finite_float, default=None, help="P_SR [Pa] (default rated)")
    p.add_argument("--c-lk", type=finite_float, default=None, help="C_Lk [m^3/s/Pa]")
    p.add_argument("--x-s", type=float_list, default=None, help="spool positions [m], V1,V2,...")
    p.add_argument("--q-j", type=float_list, default=None, help="jack flows [m^3/s], V1,V2,...")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--png", default=None, help="write the curves to this PNG file")


def characteristic(
    model: str,
    x_s: np.ndarray,
    q_j: np.ndarray,
    p_sr: float,
    params: EHAParams,
) -> np.ndarray:
    """P12 [Pa] on the grid (len(q_j), len(x_s)) for ``model`` at supply ``p_sr``."""
    xs, qj = np.meshgrid(np.asarray(x_s, float), np.asarray(q_j, float))
    if model == "HF":
        from models.hf_valve import hf_static_p12

        return hf_static_p12(xs, qj, p_sr, params)
    if model == "WH":
        from models.params import wh_params
        from models.wh_valve import wh_static_p12

        return wh_static_p12(xs, qj, p_sr, wh_params(params))
    return p12(model, xs, qj, p_sr, simplified_params(params))


def run(args: argparse.Namespace) -> int:
    check_outputs([("--png", args.png)])
    base = EHAParams()
    params = base if args.c_lk is None else base.with_overrides(c_lk=args.c_lk)
    if args.c_lk is not None and args.c_lk < 0:
        from service.cli.util import fail

        return fail("--c-lk must be >= 0")
    p_sr = base.p_sr if args.p_sr is None else args.p_sr
    if p_sr <= 0:
        from service.cli.util import fail

        return fail("--p-sr must be > 0 Pa")
    x_s = np.asarray(
        args.x_s if args.x_s is not None else np.linspace(-params.x_sm, params.x_sm, 201)
    )
    q_j = np.asarray(args.q_j if args.q_j is not None else DEFAULT_Q_J)
    curves = characteristic(args.model, x_s, q_j, p_sr, params)
    vp = simplified_params(params)
    info = {
        "p_sr": p_sr,
        "c_lk": params.c_lk,
        "g_pq": vp.g_pq,
        "x_ss": vp.x_ss,
        "g_p": p_sr / vp.x_ss,
        "g_q": p_sr / vp.x_ss / vp.g_pq,
        "p_vap": vp.p_vap,
    }
    if args.png:
        from service.plots import plot_characteristic

        with writing("--png", args.png):
            plot_characteristic(x_s, q_j, curves, args.model, p_sr, args.png)
    if args.json:
        emit_json({"model": args.model, "params": info, "x_s": x_s, "q_j": q_j, "p12": curves})
        return 0
    print(f"model {args.model}: P_SR = {p_sr / 1e6:.2f} MPa, C_Lk = {params.c_lk:.3g} m^3/s/Pa")
    idx = np.linspace(0, len(x_s) - 1, min(len(x_s), 11)).round().astype(int)
    header = "x_S [mm]  " + "".join(f"{q * 6e4:>+10.2f}" for q in q_j)
    print("P12 [MPa] by Q_J [L/min]")
    print(header)
    for i in idx:
        print(
            f"{x_s[i] * 1e3:>8.3f}  "
            + "".join(f"{curves[k, i] / 1e6:>10.3f}" for k in range(len(q_j)))
        )
    if args.png:
        print(f"plot written to {args.png}")
    return 0
