"""``servowatch web``: the fleet health page over HTTP, read only, on loopback by default.

It logs as the daemon does (``service.log.setup``: JSON lines on stderr, ``--plain-logs`` for
text, journald under systemd): ``serving http://HOST:PORT/ from STORE`` once it listens, with
the fields ``url`` and ``store`` (with ``--listen 127.0.0.1:0`` the port is a free one, read
it there), a line per request with ``--access-log``, ``web stopped`` at the end; it serves
until SIGINT or SIGTERM and exits 0. Nothing goes to stdout but ``--snapshot``'s ``wrote F``. Exit 2: bad arguments, a non-loopback address without
``--allow-remote``, or a store that cannot be opened; 3: the address is in use.

With ``--connect`` (or ``--config``, a service TOML with a ``[zenoh]`` table) the page also
shows which daemon monitors each unit, live, from the daemons' status queryables; the session
only queries (the read-only ``dashboard`` role of docs/security.md is enough). A router that
does not answer does not stop the page: the live strip says so, and the session is retried
every refresh period.
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading

from service.cli.util import check_outputs, fail, writing

NAME = "web"
HELP = "serve the fleet health page (ranked RUL, trends, alarms) over HTTP, read only"

DEFAULT_LISTEN = "127.0.0.1:8080"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from service.store.cli import add_store_argument

    add_store_argument(p)
    p.add_argument(
        "--listen", default=DEFAULT_LISTEN, metavar="HOST:PORT",
        help=f"address to serve on (default {DEFAULT_LISTEN}; port 0 picks a free one)",
    )  # fmt: skip
    p.add_argument(
        "--allow-remote", action="store_true",
        help="allow a non-loopback --listen address (only behind an authenticating TLS proxy)",
    )  # fmt: skip
    p.add_argument(
        "--refresh", type=float, default=10.0, metavar="S",
        help="seconds between the page's reloads of the fleet (default 10; 0 = never)",
    )  # fmt: skip
    p.add_argument("--access-log", action="store_true", help="log every request (a log line)")
    p.add_argument(
        "--connect", action="append", default=None, metavar="ENDPOINT",
        help="Zenoh router to ask the daemons' live status through, e.g. tcp/127.0.0.1:7447 "
        "(repeatable); without it and --config the page shows the store only",
    )  # fmt: skip
    p.add_argument(
        "--config", default=None, metavar="F.toml",
        help="service TOML whose [zenoh] table opens the live-status session "
        "(e.g. deploy/secure/dashboard.toml)",
    )  # fmt: skip
    from service.cli.args import add_tls_arguments
    from service.log.setup import add_log_arguments

    add_tls_arguments(p)
    add_log_arguments(p)
    p.add_argument(
        "--snapshot", default=None, metavar="F.png",
        help="serve on a free loopback port, take a PNG of the page with headless Chromium "
        "into F.png and exit (no --listen needed)",
    )  # fmt: skip
    p.add_argument(
        "--unit", default=None, metavar="AIRCRAFT/ACTUATOR",
        help="with --snapshot: open this unit's history on the page",
    )  # fmt: skip


def _open_live(args: argparse.Namespace, refresh_s: float):
    """A started ``LiveStatus`` whose session comes from ``--connect``/``--config``/
    ``--tls-*``, or the exit code 2 with the error printed when those do not parse. The
    session itself is opened (and retried) by the status thread."""
    from service.cli.args import service_config_from_args
    from service.config import ConfigError
    from service.edge.web.live import LiveStatus

    zargs = argparse.Namespace(**{**vars(args), "listen": None, "mode": None})  # HTTP --listen
    try:
        cfg = service_config_from_args(zargs)
    except (ConfigError, ValueError) as e:
        return None, fail(str(e))
    return LiveStatus(cfg.zenoh.open_session, period_s=refresh_s if refresh_s > 0 else 5.0), 0


def _snapshot(srv, url: str, out: str, unit: str | None) -> int:
    """Serve in a thread, take the picture, stop."""
    from urllib.parse import quote

    from service.edge.web.browser import BrowserError, screenshot

    worker = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
    worker.start()
    try:
        page = url + (f"#unit={quote(unit, safe='')}" if unit else "")
        with writing("--snapshot", out):
            path = screenshot(page, out)
    except BrowserError as e:
        return fail(f"--snapshot: {e}", 1)
    finally:
        srv.shutdown()
        srv.server_close()
    print(f"wrote {path}")
    return 0


def run(args: argparse.Namespace) -> int:
    from service.edge.web.server import check_listen, make_server
    from service.log.setup import setup_command_logging, setup_logging
    from service.store import StoreError, default_store
    from service.store.cli import open_store_arg

    if args.snapshot:  # a one-shot command
        setup_command_logging()
    else:  # a service: the daemon's log format
        setup_logging("INFO", not args.plain_logs)
    log = logging.getLogger("servowatch.web")
    if not 0 <= args.refresh <= 3600:
        return fail(f"--refresh: expected 0-3600 s, got {args.refresh:g}")
    if args.unit is not None and args.snapshot is None:
        return fail("--unit: only with --snapshot (on the live page, click the unit)")
    try:
        host, port = check_listen(
            "127.0.0.1:0" if args.snapshot else args.listen, allow_remote=args.allow_remote
        )
    except ValueError as e:
        return fail(str(e))
    target = args.store if args.store is not None else default_store()
    check_outputs([("--snapshot", args.snapshot)], [("--store", target)])
    try:
        with open_store_arg(args, create=False, read_only=True) as store:
            where = store.where
    except StoreError as e:
        return fail(str(e))
    stop = threading.Event()
    if not args.snapshot:  # before anything is started, so a SIGTERM always cleans up

        def _stop(*_: object) -> None:
            stop.set()

        signal.signal(signal.SIGTERM, _stop)
        signal.signal(signal.SIGINT, _stop)
    live = None
    if args.connect or args.config:
        live, code = _open_live(args, args.refresh)
        if live is None:
            return code
    shown_listen = f"{host}:{port}"
    try:
        srv = make_server(
            str(target), host, port, refresh_s=args.refresh, access_log=args.access_log,
            live=live, allow_remote=args.allow_remote,
        )  # fmt: skip
    except OSError as e:
        return fail(f"--listen: cannot listen on {shown_listen}: {e}", 3)
    h, p = srv.server_address[:2]
    shown = f"[{h}]" if ":" in h else h
    url = f"http://{shown}:{p}/"
    if live is not None:
        live.start()
    try:
        if args.snapshot:
            return _snapshot(srv, url, args.snapshot, args.unit)
        log.info("serving %s from %s%s", url, where, " (live status on)" if live else "",
                 extra={"fields": {"url": url, "store": str(where), "live": live is not None}})  # fmt: skip
        worker = threading.Thread(
            target=srv.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True
        )
        worker.start()
        while not stop.wait(0.5):
            pass
        srv.shutdown()
    finally:
        srv.server_close()
        if live is not None:
            live.close()
    log.info("web stopped", extra={"fields": {"url": url}})
    return 0
