"""``servowatch actuator``: a virtual actuator publishing its sensors on Zenoh."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
import time

from service.cli.util import emit_json, fail

NAME = "actuator"
HELP = "Run a virtual actuator (HF bench paced by the wall clock) publishing on Zenoh."


def add_arguments(p: argparse.ArgumentParser) -> None:
    from service.cli.args import add_zenoh_arguments
    from service.log.setup import add_log_arguments

    p.add_argument("--scenario", default="demo", help="scenario TOML file or bundled name")
    p.add_argument("--aircraft", default="AC001")
    p.add_argument("--actuator", default="elevator_L")
    p.add_argument("--rate", type=float, default=1000.0, help="sample rate [Hz] (default 1000)")
    p.add_argument(
        "--samples-per-msg", type=int, default=10, help="samples per Zenoh message (default 10)"
    )
    p.add_argument(
        "--format",
        choices=("bin", "json"),
        default=None,
        help="wire format (default: service.wire.messages.DEFAULT_FORMAT)",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help="stop after this much simulated time [s] (default: run until killed)",
    )
    p.add_argument("--seed", type=int, default=None, help="sensor-noise seed (default: scenario)")
    p.add_argument(
        "--cache-s",
        type=float,
        default=10.0,
        help="seconds of messages the publisher's cache holds for recovery (default 10)",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary at the end")
    add_log_arguments(p)
    add_zenoh_arguments(p)


def format_counters(c: dict) -> str:
    """The actuator's final counters as words: ``15000 samples in 1500 messages, 1 fault
    applied, 0 refused, 0 late bursts, next seq 15000``."""

    def n(k: str, one: str, many: str) -> str:
        v = c.get(k, 0)
        return f"{v} {one if v == 1 else many}"

    text = (f"{n('samples', 'sample', 'samples')} in {n('messages', 'message', 'messages')}, "
            f"{n('faults_ok', 'fault', 'faults')} applied, {c.get('faults_refused', 0)} refused, "
            f"{n('late', 'late burst', 'late bursts')}")  # fmt: skip
    if "seq_next" in c:
        text += f", next seq {c['seq_next']}"
    return text


def run(args: argparse.Namespace) -> int:

    from service.cli.args import open_zenoh_session, zenoh_config
    from service.log.setup import setup_logging
    from service.sim.actuator import VirtualActuator
    from service.sim.scenarios import ScenarioError, load_scenario
    from service.wire import messages as msgs

    setup_logging("INFO", not args.plain_logs)  # the daemon's format: JSON lines, journald
    try:
        msgs.key(msgs.KEY_MEAS, aircraft=args.aircraft, actuator=args.actuator)
        scenario = load_scenario(args.scenario)
    except (ScenarioError, msgs.MessageError, ValueError) as e:
        return fail(str(e))
    cfg = zenoh_config(args)
    if not args.rate > 0 or args.samples_per_msg < 1:
        return fail("--rate must be > 0 and --samples-per-msg >= 1")
    if not 0 < args.cache_s <= 3600:
        return fail(f"--cache-s: must be in (0, 3600] s, got {args.cache_s}")
    from service.cli.warmup import ensure

    ensure("models", log=True)  # before publishing: a first run compiles (and logs so)
    va = VirtualActuator(scenario, rate_hz=args.rate, t_origin=time.time(), seed=args.seed)
    stop = threading.Event()

    def _stop(signum, frame):
        stop.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    with open_zenoh_session(cfg) as session:
        logging.getLogger("servowatch.actuator").info(
            "actuator %s/%s publishing %s at %g Hz",
            args.aircraft,
            args.actuator,
            msgs.KEY_MEAS.format(aircraft=args.aircraft, actuator=args.actuator),
            args.rate,
        )
        counters = va.serve(
            session,
            args.aircraft,
            args.actuator,
            stop=stop,
            duration_s=args.duration,
            samples_per_msg=args.samples_per_msg,
            fmt=args.format,
            cache_s=args.cache_s,
        )
    counters["seq_next"] = va.seq
    if args.json:
        emit_json(counters)
    else:
        logging.getLogger("servowatch.actuator").info(
            "actuator %s/%s stopped: %s",
            args.aircraft,
            args.actuator,
            format_counters(counters),
            extra={"fields": {"unit": f"{args.aircraft}/{args.actuator}", **counters}},
        )
    return 0
