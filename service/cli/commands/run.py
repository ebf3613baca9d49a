"""``servowatch run``: the monitoring daemon (Zenoh in and out, MCAP log, status)."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
import time

from service.cli.util import check_outputs, emit_json, fail
from service.log.setup import PlainFormatter, add_log_arguments, setup_logging

NAME = "run"
HELP = "Run the monitoring daemon: subscribe, monitor each actuator, publish, log to MCAP."

__all__ = ["PlainFormatter", "setup_logging", "NAME", "HELP", "add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    from service.cli.args import add_zenoh_arguments

    add_zenoh_arguments(p)
    p.add_argument("--log", default=None, help="MCAP file to write (default: log_dir/...)")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help="stop after this long [s] (default: until SIGTERM/SIGINT)",
    )
    p.add_argument(
        "--no-rotate", action="store_true", help="write exactly --log (no size/time rotation)"
    )
    p.add_argument(
        "--store", default=None, metavar="PATH|URL",
        help="health store (SQLite path or postgresql:// URL; 'off': none); default: the "
        "config's store, else $SERVOWATCH_STORE or servowatch-data/health.sqlite",
    )  # fmt: skip
    from service.cli.args import add_foxglove_arguments, add_serve_arguments

    add_foxglove_arguments(p, what="the channels (overrides [foxglove] listen)", every=None,
                           every_help="[foxglove] every, 10")  # fmt: skip
    add_serve_arguments(p, "metrics", "serve OpenMetrics for Prometheus on "
                        "http://HOST:PORT/metrics", "overrides [metrics] listen; ")  # fmt: skip
    add_log_arguments(p)
    p.add_argument("--json", action="store_true", help="print the final status as JSON")


def _serve_override(
    cfg, name: str, settings, what: str, listen: str | None, allow_remote: bool,
    fields: dict, refusal: str,
):  # fmt: skip
    """``cfg`` with its ``[name]`` section (a ``settings``) set from ``--name HOST:PORT``,
    ``--name-allow-remote`` and ``fields`` (more of the section's fields from flags; None:
    not given); ``refusal``: the ConfigError's message when neither ``--name`` nor the
    section is there to apply them to."""
    from service.config import ConfigError
    from service.edge.listen import check_listen

    fields = {k: v for k, v in fields.items() if v is not None}
    if listen is None and not allow_remote and not fields:
        return cfg
    section = getattr(cfg, name)
    if listen is None and section is None:
        raise ConfigError(refusal, None, None)
    d = section.model_dump() if section is not None else {}
    if listen is not None:
        check_listen(
            listen, allow_remote=allow_remote or bool(d.get("allow_remote")),
            flag=f"--{name}", what=what, allow=f"--{name}-allow-remote",
        )  # fmt: skip
        d["listen"] = listen
    if allow_remote:
        d["allow_remote"] = True
    d.update(fields)
    return cfg.model_copy(update={name: settings.model_validate(d)})


def foxglove_override(cfg, listen: str | None, allow_remote: bool, every: int | None = None):
    """``cfg`` with ``--foxglove HOST:PORT``, ``--foxglove-allow-remote`` and
    ``--foxglove-every`` applied."""
    from service.config import FoxgloveSettings

    return _serve_override(
        cfg, "foxglove", FoxgloveSettings, "the Foxglove server", listen, allow_remote,
        {"every": every}, "--foxglove-* options need --foxglove or [foxglove]",
    )  # fmt: skip


def metrics_override(cfg, listen: str | None, allow_remote: bool):
    """``cfg`` with ``--metrics HOST:PORT`` and ``--metrics-allow-remote`` applied."""
    from service.config import MetricsSettings

    return _serve_override(
        cfg, "metrics", MetricsSettings, "the metrics endpoint", listen, allow_remote, {},
        "--metrics-allow-remote needs --metrics or [metrics]",
    )  # fmt: skip


def _check_identity(cfg) -> None:
    """Warn when the daemon's certificate is not ``monitor.<station>.<shard>``: the secure
    station's rules let each daemon identity hold only its own status and tokens, so another
    identity's would be refused silently (docs/security.md)."""
    if cfg.zenoh.tls.cert is None:
        return
    from service.zenoh_util import certificate_cn

    want = f"monitor.{cfg.station}.{cfg.shard}"
    cn = certificate_cn(cfg.zenoh.tls.cert)
    if cn != want:
        logging.getLogger("servowatch.daemon").warning(
            "certificate %s names %r, not %r: the secure station's rules let a daemon hold "
            "only its own identity's status and group tokens", cfg.zenoh.tls.cert, cn, want,
        )  # fmt: skip


def log_files_line(paths: list[str]) -> None:
    """The daemon's last line (its counts are in ``daemon stopped``): the file it logged to
    last, and how many of the files it wrote are kept and how many retention deleted (a
    station running for months writes hundreds; not every name)."""
    from pathlib import Path

    from service.cli.util import plural

    kept = [p for p in paths if Path(p).exists()]
    gone = len(paths) - len(kept)
    last = paths[-1] if paths else "-"
    logging.getLogger("servowatch.daemon").info(
        "logged to %s (%s of this run kept%s)", last, plural(len(kept), "file"),
        f", {gone} deleted by retention" if gone else "",
        extra={"fields": {"log_file": last, "kept_files": len(kept), "deleted_files": gone}},
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:

    from service.cli.args import open_zenoh_session, zenoh_config
    from service.daemon import EXIT_LOG_FAILURE, Daemon

    def overrides(cfg):
        cfg = foxglove_override(cfg, args.foxglove, args.foxglove_allow_remote, args.foxglove_every)
        return metrics_override(cfg, args.metrics, args.metrics_allow_remote)

    cfg = zenoh_config(args, overrides)
    from service.store import default_store

    store = args.store or cfg.store or default_store()
    cfg = cfg.model_copy(update={"store": store})
    check_outputs(
        [("--log", args.log), ("--store", None if store == "off" else store)],
        [("--config", args.config), ("baseline", cfg.baseline)],
    )
    if args.no_rotate:
        cfg = cfg.model_copy(update={"rotate_bytes": None, "rotate_s": None})
    setup_logging(cfg.log_level, not args.plain_logs)
    _check_identity(cfg)
    from service.cli.warmup import ensure, monitor_group
    from service.daemon.systemd import extending_start

    # before the session: a first run compiles (and says so), telling systemd meanwhile that
    # the start goes on (EXTEND_TIMEOUT_USEC; READY=1 comes once the daemon has started)
    with extending_start("starting: compiling the kernels (a first run takes minutes)"):
        ensure(monitor_group(cfg.monitor.model), "log", log=True)
    stop = threading.Event()

    def _stop(signum, frame):
        logging.getLogger("servowatch.daemon").info("signal %d: stopping", signum)
        stop.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    session = open_zenoh_session(cfg)
    try:
        daemon = Daemon(cfg, log_path=args.log)
    except Exception as e:  # bad baseline, unwritable log directory, ...
        session.close()
        return fail(f"cannot start the daemon: {e}")
    with session:
        daemon.start(session)
        t_end = None if args.duration is None else time.monotonic() + args.duration
        while not stop.is_set():
            left = None if t_end is None else t_end - time.monotonic()
            if left is not None and left <= 0:
                break
            stop.wait(0.5 if left is None else min(0.5, left))
        final = daemon.stop()
    log = logging.getLogger("servowatch.daemon")
    if args.json:
        emit_json(final)
    else:
        log_files_line(final["log"])
    if final["log_failure"]:
        log.error("the MCAP log failed: %s", final["log_failure"],
                  extra={"fields": {"log_failure": str(final["log_failure"])}})  # fmt: skip
        return EXIT_LOG_FAILURE
    return 0
