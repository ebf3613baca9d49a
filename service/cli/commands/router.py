"""``servowatch router``: a Zenoh router as a Python session in router mode.

There is no zenohd on PyPI; ``zenoh.open`` with ``mode: router`` routes between the peers and
clients that connect to it. Multicast scouting is off; by default it listens on loopback only.
A secure station (docs/security.md) starts it with ``--config deploy/secure/router.json5``:
mutual TLS on every link and access-control rules keyed on certificate common names; the
``--tls-*`` flags give the file paths (never a secret itself). ``RUST_LOG`` set in the
environment turns Zenoh's own log on (``zenoh::net::routing::interceptor::access_control=trace``
logs every access decision, refusals included; costly, for an audit; those lines are Zenoh's
own format, the only ones not in servowatch's).

It logs as the daemon does (``service.log.setup``: JSON lines on stderr, ``--plain-logs``
for text, journald under systemd): ``router ZID listening on ENDPOINTS`` once it listens
(fields ``zid``, ``listen``), ``router stopped`` at the end. Nothing goes to stdout.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import threading

from service.cli.util import fail

NAME = "router"
HELP = "run a Zenoh router (Python session in router mode) until SIGINT/SIGTERM"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--listen", action="append", default=None, metavar="ENDPOINT",
        help="endpoint to listen on (default tcp/127.0.0.1:7447; repeatable)",
    )  # fmt: skip
    p.add_argument(
        "--connect", action="append", default=[], metavar="ENDPOINT",
        help="another router to connect to (repeatable)",
    )  # fmt: skip
    p.add_argument(
        "--config", default=None, metavar="FILE.json5",
        help="a Zenoh JSON5 config (e.g. deploy/loopback/router.json5); --listen/--connect override it",
    )  # fmt: skip
    p.add_argument(
        "--allow-remote", action="store_true",
        help="accept endpoints other than tcp|tls/127.0.0.1 and unix sockets (from the flags "
        "and from --config alike)",
    )  # fmt: skip
    p.add_argument(
        "--allow-plain-listen", action="store_true",
        help="with --allow-remote: accept a non-loopback listen endpoint without TLS (tcp/...; "
        "unauthenticated, logged as a warning)",
    )  # fmt: skip
    from service.cli.args import add_tls_arguments
    from service.log.setup import add_log_arguments

    add_tls_arguments(p)
    add_log_arguments(p)


def _tls(cfg, args: argparse.Namespace) -> None:
    """The ``--tls-*`` paths into ``cfg`` (listen and router-to-router connect identity)."""
    base = "transport/link/tls/"
    for flag, keys in (
        ("tls_root_ca", ("root_ca_certificate",)),
        ("tls_cert", ("listen_certificate", "connect_certificate")),
        ("tls_key", ("listen_private_key", "connect_private_key")),
    ):
        v = getattr(args, flag, None)
        if v is not None:
            from pathlib import Path

            if not Path(v).is_file():
                raise ValueError(f"--{flag.replace('_', '-')}: no such file: {v}")
            for k in keys:
                cfg.insert_json5(base + k, json.dumps(str(v)))
    if getattr(args, "tls_cert", None) is not None:
        cfg.insert_json5(base + "enable_mtls", "true")


def _config(args: argparse.Namespace):
    import zenoh

    from service.zenoh_util import make_config

    if args.config is None:
        listen = args.listen or ["tcp/127.0.0.1:7447"]
        cfg = make_config(
            "router", listen, args.connect, allow_remote=args.allow_remote,
            allow_plain_listen=args.allow_plain_listen,
        )  # fmt: skip
        _tls(cfg, args)
        return cfg, listen
    cfg = zenoh.Config.from_file(args.config)
    cfg.insert_json5("mode", '"router"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if args.listen:
        cfg.insert_json5("listen/endpoints", json.dumps(args.listen))
    if args.connect:
        cfg.insert_json5("connect/endpoints", json.dumps(args.connect))
    _tls(cfg, args)
    listen = _endpoints(cfg, "listen")
    connect = _endpoints(cfg, "connect")
    _check(args, listen, connect)
    cfg.insert_json5("listen/endpoints", json.dumps(listen))
    return cfg, listen


def _endpoints(cfg, what: str) -> list[str]:
    """The router's ``listen`` or ``connect`` endpoints in ``cfg``: a per-mode table (Zenoh's
    default listen is ``tcp/[::]:7447``, every interface) resolves to its ``router`` entry."""
    v = json.loads(cfg.get_json(f"{what}/endpoints"))
    if isinstance(v, dict):
        v = v.get("router", [])
    if not isinstance(v, list) or not all(isinstance(e, str) for e in v):
        raise ValueError(f"{what}/endpoints: expected a list of endpoints, got {v!r}")
    return v


def _check(args: argparse.Namespace, listen: list[str], connect: list[str]) -> None:
    """The loopback rule (``service.zenoh_util.check_endpoint``) on the final endpoints,
    whether they came from the flags or from ``--config``."""
    from service.zenoh_util import check_endpoint

    src = f" ({args.config})" if args.config else ""
    for what, eps in (("listen", listen), ("connect", connect)):
        for k, e in enumerate(eps):
            check_endpoint(
                e, allow_remote=args.allow_remote, field=f"{what}/endpoints[{k}]{src}",
                listen=what == "listen", allow_plain_listen=args.allow_plain_listen,
            )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    import os

    import zenoh

    from service.log.setup import setup_logging
    from service.zenoh_util import EndpointError

    setup_logging("INFO", not args.plain_logs)
    log = logging.getLogger("servowatch.router")
    if os.environ.get("RUST_LOG"):
        zenoh.init_log_from_env_or("error")

    try:
        cfg, listen = _config(args)
    except (EndpointError, ValueError, OSError) as e:
        return fail(str(e))
    except zenoh.ZError as e:
        return fail(f"{args.config}: invalid Zenoh config: {e}")
    stop = threading.Event()

    def _stop(signum, _frame):
        stop.set()

    old = {s: signal.signal(s, _stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            session = zenoh.open(cfg)
        except zenoh.ZError as e:
            return fail(f"cannot start the router on {listen}: {e}", 1)
        with session:
            zid = str(session.zid())
            log.info("router %s listening on %s", zid, ", ".join(map(str, listen)),
                     extra={"fields": {"zid": zid, "listen": [str(e) for e in listen]}})  # fmt: skip
            while not stop.wait(0.5):
                pass
        log.info("router stopped", extra={"fields": {"zid": zid}})
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    return 0
