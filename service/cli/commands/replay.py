"""``servowatch replay``: feed logged runs through the monitor again (service.replay).

One log: the replay's summary (as before). Several logs (files, folders, glob patterns) go
into ``--store`` in one process, in life order (``service.replay.log_order``), with a progress
bar on stderr; each period is stamped with its flight (``--flight``, the log's flight record
or the gap rule, ``--flight-gap-s``) and calendar time (docs/prognostics.md). ``--jobs N``
and ``--cluster`` (a Dask scheduler, or ``local:N``) run the batch's groups of logs on
workers, and this process writes the store (docs/cluster.md).
"""

from __future__ import annotations

import argparse
import sys

from service.cli.util import emit_json, fail, plural

NAME = "replay"
HELP = "replay an MCAP log through the monitor (as fast as possible or paced)"

EXIT_FAILED_LOGS = 1  # a batch: some logs failed (named in `failed`), the others are stored
EXIT_BAD_LOG = 2  # one log: not an MCAP log, unreadable, malformed metadata or flight record
EXIT_CLUSTER = 3  # --cluster: no Dask scheduler reachable (nothing written)
EXIT_STORE = 5  # the store (or --out) failed while being written: disk full, server gone


_UNSET = object()  # --speed not given: max, or 1.0 with --foxglove


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
        "log", nargs="+",
        help="MCAP log(s) of `servowatch run`, an acquisition or the demo: files, folders "
        "(their *.mcap), glob patterns or a rotation set's base name, or fsspec URLs "
        "(file://, s3://, ...: a file, folder or pattern); several need --store",
    )  # fmt: skip
    p.add_argument(
        "--flight", type=int, default=None, metavar="N",
        help="the log's flight (cycle) number, for every actuator in it (one log only; "
        "default: the log's servowatch.flight record, else the gap rule)",
    )  # fmt: skip
    p.add_argument(
        "--start-unix", type=float, default=None, metavar="S",
        help="calendar time of the log's first sample [Unix s] (default: the flight record's, "
        "or the sample time when it is a Unix time)",
    )  # fmt: skip
    p.add_argument(
        "--flight-gap-s", type=float, default=None, metavar="S",
        help="gap rule: a gap longer than this between two periods of a unit starts a new "
        "flight (default 1800)",
    )  # fmt: skip
    p.add_argument(
        "--speed", type=_speed, default=_UNSET, metavar="max|X",
        help="max (default; 1.0 with --foxglove): as fast as possible; X: X times real time",
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
    from service.cli.args import add_foxglove_arguments

    add_foxglove_arguments(p, what="the replay, paced by --speed,", every=10, every_help="10")
    p.add_argument(
        "--foxglove-wait", type=float, default=0.0, metavar="S",
        help="with --foxglove: wait up to S seconds for a viewer to subscribe before starting",
    )  # fmt: skip
    p.add_argument("--config", default=None, help="service TOML (its [monitor] and baseline)")
    p.add_argument(
        "--store", default=None, metavar="PATH|URL",
        help="health store (SQLite path or postgresql:// URL; default: the config's store, "
        "else none): per-actuator baselines from it, operating periods written to it",
    )  # fmt: skip
    p.add_argument(
        "--jobs", type=int, default=None, metavar="N",
        help="several logs: worker processes, each taking whole actuators "
        "(default 1)",
    )  # fmt: skip
    p.add_argument(
        "--cluster", default=None, metavar="tcp://HOST:PORT|local:N",
        help="several logs: run them on the workers of a Dask scheduler at this address, or "
        "on N worker processes of this machine (local:N); the workers must read the logs, "
        "this process writes the store (docs/cluster.md)",
    )  # fmt: skip
    p.add_argument(
        "--task-logs", type=int, default=None, metavar="K",
        help="with --jobs or --cluster: at most K logs per task (default: a whole group of "
        "logs sharing actuators)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def _print_summary(s) -> None:
    from service.log.retention import readable_time

    speed = "n/a" if s.speed is None else f"{s.speed:.1f}x real time"
    print(f"replayed {s.log}: {s.samples} samples of {len(s.actuators)} actuator(s), "
          f"{s.duration_s:.3f} s of data in {s.wall_s:.3f} s ({speed})")  # fmt: skip
    for name, fin in s.final.items():
        est = fin.get("est", {})
        health = fin.get("health", {})
        keys = [k for k in ("c_lk", "p_sr", "f_r") if k in est]
        parts = ", ".join(f"{k}={est[k]:.4g}" for k in keys)
        hp = ", ".join(f"{k}={v:.3g}" for k, v in health.items() if isinstance(v, int | float))
        print(f"  {name} at {readable_time(fin.get('t'))}: {parts}; {hp}")
    print(f"  alarms: {len(s.alarms)}")
    for a in s.alarms[:20]:
        v = a.get("value")
        shown = f"{v:.4g}" if isinstance(v, int | float) else "-"
        print(f"    {readable_time(a.get('t'))}: {a.get('actuator')} {a.get('kind')} "
              f"{a.get('state')} ({shown})")  # fmt: skip
    for name, tc in s.time.items():
        if any(tc.values()):
            print(f"  time checks {name}: " + ", ".join(f"{k} {v}" for k, v in tc.items()))
    if s.corrupt_chunks:
        print(f"  corrupt chunks skipped: {s.corrupt_chunks}")
    if s.source is not None:
        print(f"  periods: {s.periods} closed, {s.periods_new} new in the store ({s.source})")
        for name, st in s.stored.items():
            if st != "new":
                print(f"  {name}: " + ("already stored (a copy, or a longer version of this "
                                       "log)" if st == "stored" else "superseded a shorter "
                                       "ingest of this log"))  # fmt: skip
        for name, v in s.commissioned.items():
            print(f"  {name}: " + (f"baseline version {v}" if v else "commissioned: false"))
    if s.out:
        print(f"  wrote {s.out}")
    for w in s.warnings:
        print(f"  warning: {w}")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from service.config import ConfigError, load_config
    from service.log import rotated_files
    from service.prognostics.life import FLIGHT_GAP_S
    from service.replay import expand_logs
    from service.replay.cluster import expand_urls, is_url

    urls = any(is_url(x) for x in args.log)
    if len(args.log) == 1 and not urls and not any(c in args.log[0] for c in "*?[") \
            and not Path(args.log[0]).is_dir():  # fmt: skip
        if not rotated_files(args.log[0]):
            return fail(f"{args.log[0]}: no such log (nor a rotation set "
                        f"{Path(args.log[0]).stem}-*)")  # fmt: skip
        logs = [Path(args.log[0])]
    else:
        try:
            logs = [u for x in args.log
                    for u in (expand_urls(x) if is_url(x) else expand_logs([x]))]  # fmt: skip
        except FileNotFoundError as e:
            return fail(str(e))
    from service.log.flightrec import MAX_FLIGHT

    if args.flight is not None and (not 0 <= args.flight <= MAX_FLIGHT or len(logs) > 1):
        return fail(f"--flight: an integer in 0..{MAX_FLIGHT}, for one log only")
    if args.start_unix is not None and (len(logs) > 1 or args.start_unix != args.start_unix):
        return fail("--start-unix: a finite number, for one log only")
    try:
        cfg = load_config(args.config) if args.config else None
    except ConfigError as e:
        return fail(str(e))
    from service.cli.warmup import ensure, monitor_group

    ensure(monitor_group(cfg.monitor.model if cfg is not None else "C5"), "log")
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
    from service.daemon.outputs import store_target
    from service.prognostics import PeriodConfig

    store = store_target(args.store or (cfg.store if cfg is not None else None))
    gap = args.flight_gap_s
    if gap is None:
        gap = cfg.prognostics.flight_gap_s if cfg is not None else FLIGHT_GAP_S
    if not gap > 0 or gap != gap:
        return fail("--flight-gap-s must be > 0")
    pc = None
    if cfg is not None:
        pr = cfg.prognostics
        pc = PeriodConfig(silence_s=pr.period_silence_s, window_s=pr.period_window_s)
    from service.cli.util import check_outputs
    from service.replay.cluster import local_path

    inputs = [("LOG", f) for lg in logs if (lp := local_path(lg)) is not None
              for f in (rotated_files(lp) or [lp])]  # fmt: skip
    inputs += [("--config", args.config), ("baseline", cfg.baseline if cfg is not None else None)]
    check_outputs([("--out", args.out), ("--store", store)], inputs)  # before any write
    if args.jobs is None:
        args.jobs = 1
    if args.jobs < 1:
        return fail("--jobs must be >= 1")
    if args.task_logs is not None and args.task_logs < 1:
        return fail("--task-logs must be >= 1")
    pooled = len(logs) > 1 or urls
    if args.cluster and args.jobs > 1:
        return fail("--jobs and --cluster: give one (local:N is N processes of this machine)")
    if args.cluster:
        from service.replay.cluster import check_cluster

        try:
            check_cluster(args.cluster)
        except ValueError as e:
            return fail(str(e))
    pool = None
    if pooled and args.cluster:
        from service.replay.cluster import ClusterError, DaskPool

        try:
            pool = DaskPool(args.cluster)  # before the store: unreachable, nothing written
        except ClusterError as e:
            return fail(str(e), EXIT_CLUSTER)
    try:
        return _run_checked(args, logs, cfg, monitor_config, baseline, store, pc, gap, pool,
                            pooled)  # fmt: skip
    finally:
        if pool is not None:
            pool.close()


def _run_checked(args, logs, cfg, monitor_config, baseline, store, pc, gap, pool,
                 pooled) -> int:  # fmt: skip
    """``run`` once the arguments are checked and the cluster (``pool``) connected."""
    from pathlib import Path

    if store is not None:
        from service.store import StoreError, open_store

        try:
            open_store(store).close()  # fail fast, naming --store
        except StoreError as e:
            return fail(f"--store: {e}")
    if pooled:
        if store is None:
            return fail("several logs, or logs by URL, go into a store: give --store")
        if args.out or args.publish or args.speed is not _UNSET or args.foxglove is not None:
            return fail("--out, --publish, --speed and --foxglove take one local log")
        return _run_many(args, logs, store, monitor_config, baseline, pc, gap, pool)
    if args.speed is _UNSET:
        args.speed = 1.0 if args.foxglove is not None else None
    live = None
    if args.foxglove is not None:
        from service.edge.foxglove_feed import FoxgloveFeed
        from service.edge.listen import check_listen

        try:
            host, port = check_listen(
                args.foxglove, allow_remote=args.foxglove_allow_remote, flag="--foxglove",
                what="the Foxglove server", allow="--foxglove-allow-remote",
            )  # fmt: skip
            live = FoxgloveFeed(host, port, every=args.foxglove_every,
                                name=f"servowatch replay {Path(logs[0]).name}")  # fmt: skip
        except (ValueError, RuntimeError, OSError) as e:
            return fail(str(e))
        print(f"servowatch replay: Foxglove WebSocket server on ws://{host}:{live.port}",
              file=sys.stderr, flush=True)  # fmt: skip
    try:
        return _run(args, logs, cfg, monitor_config, baseline, store, pc, gap, live)
    finally:
        if live is not None:
            live.close()


def _run(args, logs, cfg, monitor_config, baseline, store, pc, gap, live) -> int:
    """``run`` once the inputs are checked; ``live``: a FoxgloveFeed or None."""
    from service.replay import LogError, StoreWriteError, replay

    if live is not None and args.foxglove_wait > 0:
        import time

        from service.log import rotated_files
        from service.replay import log_actuators

        for ac, act in log_actuators(rotated_files(logs[0])):
            live.add_actuator(ac, act)
        end = time.monotonic() + args.foxglove_wait
        while live.status()["subscribed_topics"] == 0 and time.monotonic() < end:
            time.sleep(0.05)
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
            logs[0], speed=args.speed, out=args.out, publish=session,
            monitor_config=monitor_config, baseline=baseline, log_every=args.log_every,
            publish_every=cfg.publish_every if cfg is not None else 10, store=store,
            period_config=pc, flight=args.flight, start_unix=args.start_unix, flight_gap_s=gap,
            live=live,
        )  # fmt: skip
    except StoreWriteError as e:
        return fail(f"{e}; nothing of this log was stored", EXIT_STORE)
    except LogError as e:
        return fail(str(e), EXIT_BAD_LOG)
    except OSError as e:  # the output log (--out): disk full, folder gone
        where = e.filename or args.out or logs[0]
        return fail(f"{where}: {e.strerror or e}", EXIT_STORE)
    except ValueError as e:
        return fail(str(e))
    finally:
        if session is not None:
            session.close()
    if args.json:
        emit_json(s.to_dict())
    else:
        _print_summary(s)
    if s.truncated:
        print(f"servowatch: warning: {logs[0]} was truncated; replayed up to its last "
              "complete chunk", file=sys.stderr)  # fmt: skip
    return 0


def _run_many(args, logs, store, monitor_config, baseline, pc, gap, pool=None) -> int:
    """Several logs into ``store``: in this process, or on ``--jobs`` processes or the
    ``--cluster``'s workers (``pool``, connected) with this process writing the store."""
    import time
    from dataclasses import asdict

    from service.replay import StoreWriteError, log_order, replay_many
    from service.replay.cluster import BatchReport, ProcessPool, is_url

    w0 = time.perf_counter()
    if not any(is_url(p) for p in logs):
        logs = log_order(logs)  # else ordered where the logs are read (on the workers)
    report = BatchReport()
    if pool is None and (args.jobs > 1 or any(is_url(p) for p in logs)):
        pool = ProcessPool(args.jobs)
    from tqdm import tqdm

    bar = tqdm(total=len(logs), desc="replay", unit="log", file=sys.stderr,
               disable=None if not args.json else True)  # fmt: skip
    failed: list[dict] = []
    totals = {"samples": 0, "periods": 0, "periods_new": 0, "alarms": 0, "truncated": 0,
              "corrupt_chunks": 0, "superseded": 0, "already_stored": 0}  # fmt: skip
    units: dict[str, set] = {}
    checks: list[dict] = []  # logs whose samples the time checks refused
    warns: list[str] = []  # each log's warnings (the store's lines among them)
    done: list[str] = []

    def on_log(p, s, err) -> None:
        if err is not None:
            failed.append({"log": str(p), "error": str(err)})
            bar.write(f"servowatch: failed: {err}", file=sys.stderr)
            return
        done.append(str(p))
        totals["samples"] += s.samples
        totals["periods"] += s.periods
        totals["periods_new"] += s.periods_new
        totals["alarms"] += len(s.alarms)
        totals["truncated"] += int(s.truncated)
        totals["corrupt_chunks"] += s.corrupt_chunks
        totals["superseded"] += int("superseded" in s.stored.values())
        totals["already_stored"] += int(bool(s.stored) and set(s.stored.values()) == {"stored"})
        for a, tc in s.time.items():
            if any(tc.values()):
                checks.append({"log": str(p), "actuator": a, **tc})
        for a, fl in s.flights.items():
            units.setdefault(a, set()).update(fl)
        warns.extend(s.warnings)

    try:
        replay_many(logs, store, on_log=on_log, flight_gap_s=gap, monitor_config=monitor_config,
                    baseline=baseline, period_config=pc, pool=pool, report=report,
                    task_logs=args.task_logs, tick=lambda: bar.update(1))  # fmt: skip
    except StoreWriteError as e:
        bar.close()
        return fail(f"{e}; stored so far: {len(done)} of {len(logs)} logs (each whole); run "
                    "the same command again to add the rest", EXIT_STORE)  # fmt: skip
    finally:
        bar.close()
    wall = time.perf_counter() - w0
    out = {"logs": len(logs), "failed": failed, **totals, "time_checks": checks,
           "warnings": warns, "wall_s": wall,
           "actuators": {a: {"flights": len(f), "first": min(f), "last": max(f)}
                         for a, f in sorted(units.items())}}  # fmt: skip
    if pool is not None:
        out["pool"] = report.pool
        out["workers"] = {w: asdict(d) for w, d in sorted(report.workers.items())}
    if args.json:
        emit_json(out)
    else:
        print(f"replayed {plural(len(logs), 'log')} into {store} in {wall:.1f} s: "
              f"{plural(totals['samples'], 'sample')}, {plural(totals['periods_new'], 'new period')}"
              f" of {len(units)} actuator(s)")  # fmt: skip
        if totals["superseded"] or totals["already_stored"]:
            print(f"  {totals['already_stored']} log(s) already stored, {totals['superseded']} "
                  "superseded a shorter ingest of the same log")  # fmt: skip
        for a, d in out["actuators"].items():
            print(f"  {a}: flights {d['first']}-{d['last']} ({d['flights']})")
        for c in checks:
            counts = ", ".join(f"{k} {v}" for k, v in c.items() if k not in ("log", "actuator"))
            print(f"  time checks {c['log']} {c['actuator']}: {counts}")
        if totals["corrupt_chunks"]:
            print(f"  corrupt chunks skipped: {totals['corrupt_chunks']}")
        for w in warns:
            print(f"  warning: {w}")
        if pool is not None:
            print(f"  on {report.pool}:")
            for w, d in sorted(report.workers.items()):
                print(f"    {w}: {d.tasks} task(s), {d.logs} log(s) ({d.failed} failed), "
                      f"{d.samples} samples, busy {d.busy_s:.1f} s")  # fmt: skip
        for f in failed:
            print(f"  failed: {f['error']}")
    return EXIT_FAILED_LOGS if failed else 0
