"""``servowatch replay``: feed a logged run through the monitor again (service.replay)."""

from __future__ import annotations

import argparse
import logging
import sys

from service.cliutil import emit_json, fail

NAME = "replay"
HELP = "replay an MCAP log through the monitor (as fast as possible or paced)"


def _speed(text: str) -> float | None:
    if text.strip().lower() in ("max", "inf", "fast"):
        return None
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"speed: {text!r} is not 'max' or a number") from None
    if not v > 0 or v != v or v == float("inf"):
        raise argparse.ArgumentTypeError(f"speed: {text!r} must be > 0")
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "log", help="MCAP log of `servowatch run` or the demo (or a rotation set's base name)"
    )
    p.add_argument(
        "--speed", type=_speed, default=None, metavar="max|X",
        help="max (default): as fast as possible; X: X times real time",
    )  # fmt: skip
    p.add_argument("--out", default=None, metavar="FILE.mcap", help="write a new log here")
    p.add_argument("--publish", action="store_true", help="republish est/res/health on Zenoh")
    p.add_argument(
        "--connect", action="append", default=None, metavar="ENDPOINT",
        help="Zenoh endpoint for --publish (default tcp/127.0.0.1:7447; repeatable)",
    )  # fmt: skip
    p.add_argument(
        "--log-every", type=int, default=1, metavar="N",
        help="with --out: log est/residual/health every N outputs (default 1 = all)",
    )  # fmt: skip
    p.add_argument("--config", default=None, help="service TOML (its [monitor] and baseline)")
    p.add_argument(
        "--store", default=None, metavar="PATH|URL",
        help="health store (SQLite path or postgresql:// URL; default: the config's store, "
        "else none): per-actuator baselines from it, operating periods written to it",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def _print_summary(s) -> None:
    speed = "n/a" if s.speed is None else f"{s.speed:.1f}x real time"
    print(f"replayed {s.log}: {s.samples} samples of {len(s.actuators)} actuator(s), "
          f"{s.duration_s:.3f} s of data in {s.wall_s:.3f} s ({speed})")  # fmt: skip
    for name, fin in s.final.items():
        est = fin.get("est", {})
        health = fin.get("health", {})
        keys = [k for k in ("c_lk", "p_sr", "f_r") if k in est]
        parts = ", ".join(f"{k}={est[k]:.4g}" for k in keys)
        hp = ", ".join(f"{k}={v:.3g}" for k, v in health.items() if isinstance(v, int | float))
        print(f"  {name} at t={fin.get('t', float('nan')):.3f}: {parts}; {hp}")
    print(f"  alarms: {len(s.alarms)}")
    for a in s.alarms[:20]:
        print(f"    t={a.get('t')}: {a.get('actuator')} {a.get('kind')} {a.get('state')} "
              f"({a.get('value')})")  # fmt: skip
    if s.source is not None:
        print(f"  periods: {s.periods} closed, {s.periods_new} new in the store ({s.source})")
        for name, v in s.commissioned.items():
            print(f"  {name}: " + (f"baseline version {v}" if v else "commissioned: false"))
    if s.out:
        print(f"  wrote {s.out}")
    for w in s.warnings:
        print(f"  warning: {w}")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from service.config import ConfigError, load_config
    from service.replay import replay

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from service.log import rotated_files

    if not rotated_files(args.log):
        return fail(f"{args.log}: no such log (nor a rotation set {Path(args.log).stem}-*)")
    try:
        cfg = load_config(args.config) if args.config else None
    except ConfigError as e:
        return fail(str(e))
    monitor_config = cfg.monitor if cfg is not None else None
    baseline = None
    if cfg is not None and cfg.baseline is not None:
        from service.monitor import Baseline

        try:
            baseline = Baseline.load(cfg.baseline)
        except (OSError, ValueError) as e:
            return fail(f"{cfg.baseline}: cannot read baseline: {e}")
        from service.monitor import BaselineModelError, check_baseline_model

        try:
            check_baseline_model(baseline, cfg.monitor.model, str(cfg.baseline))
        except BaselineModelError as e:
            return fail(str(e))
    from service.daemon.core import store_target
    from service.prognostics import PeriodConfig

    store = store_target(args.store or (cfg.store if cfg is not None else None))
    pc = None
    if cfg is not None:
        pr = cfg.prognostics
        pc = PeriodConfig(silence_s=pr.period_silence_s, window_s=pr.period_window_s)
    if store is not None:
        from service.store import StoreError, open_store

        try:
            open_store(store).close()  # fail fast, naming --store
        except StoreError as e:
            return fail(f"--store: {e}")
    session = None
    if args.publish:
        import zenoh

        from service.zenoh_util import make_config

        try:
            zc = make_config("client", connect=args.connect or ["tcp/127.0.0.1:7447"])
        except ValueError as e:
            return fail(str(e))
        try:
            session = zenoh.open(zc)
        except Exception as e:
            return fail(f"cannot reach a Zenoh router at {args.connect}: {e}", 1)
    try:
        s = replay(
            args.log, speed=args.speed, out=args.out, publish=session,
            monitor_config=monitor_config, baseline=baseline, log_every=args.log_every,
            publish_every=cfg.publish_every if cfg is not None else 10, store=store,
            period_config=pc,
        )  # fmt: skip
    except (OSError, ValueError) as e:
        return fail(str(e))
    finally:
        if session is not None:
            session.close()
    if args.json:
        emit_json(s.to_dict())
    else:
        _print_summary(s)
    if s.truncated:
        print(f"servowatch: warning: {args.log} was truncated; replayed up to its last "
              "complete chunk", file=sys.stderr)  # fmt: skip
    return 0
