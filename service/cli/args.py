"""Command-line arguments shared by the service commands: Zenoh endpoints and the config."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the config pulls in the monitor (numba): imported when used
    from service.config import ServiceConfig

__all__ = [
    "add_zenoh_arguments",
    "add_tls_arguments",
    "tls_overrides",
    "service_config_from_args",
    "zenoh_config",
    "open_zenoh_session",
]


def add_tls_arguments(parser: argparse.ArgumentParser) -> None:
    """``--tls-root-ca``, ``--tls-cert``, ``--tls-key``: file paths (never a secret itself)."""
    g = parser.add_argument_group("TLS (paths; override [zenoh.tls] and SERVOWATCH_ZENOH__TLS__*)")
    g.add_argument("--tls-root-ca", metavar="FILE.pem", default=None, help="station CA certificate")
    g.add_argument(
        "--tls-cert", metavar="FILE.pem", default=None, help="this identity's certificate"
    )
    g.add_argument("--tls-key", metavar="FILE.pem", default=None, help="its private key (a path)")


def tls_overrides(args: argparse.Namespace, zenoh: dict[str, Any]) -> dict[str, Any]:
    """``zenoh`` (a ``ZenohSettings.model_dump()``) with the ``--tls-*`` flags applied."""
    tls = dict(zenoh.get("tls") or {})
    for name in ("root_ca", "cert", "key"):
        v = getattr(args, f"tls_{name}", None)
        if v is not None:
            tls[name] = v
    return {**zenoh, "tls": tls}


def add_serve_arguments(
    parser: argparse.ArgumentParser, flag: str, serves: str, note: str = ""
) -> None:
    """``--FLAG HOST:PORT`` (help: ``serves``, then ``note`` and the loopback rule in
    parentheses) and ``--FLAG-allow-remote``, of a server a command runs."""
    parser.add_argument(
        f"--{flag}", default=None, metavar="HOST:PORT",
        help=f"{serves} ({note}loopback unless --{flag}-allow-remote)",
    )  # fmt: skip
    parser.add_argument(
        f"--{flag}-allow-remote", action="store_true",
        help=f"allow a non-loopback --{flag} host (only behind an authenticating TLS proxy)",
    )  # fmt: skip


def add_foxglove_arguments(
    parser: argparse.ArgumentParser, *, what: str, every: int | None, every_help: str
) -> None:
    """``--foxglove HOST:PORT``, ``--foxglove-allow-remote`` and ``--foxglove-every N`` of
    the commands that serve ``what`` live to Foxglove (run, replay)."""
    add_serve_arguments(
        parser, "foxglove", f"serve {what} live over the Foxglove WebSocket protocol"
    )
    parser.add_argument(
        "--foxglove-every", type=int, default=every, metavar="N",
        help=f"send one row in N per topic to Foxglove (default: {every_help}; events all; "
        "1 = every row)",
    )  # fmt: skip


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config``, ``--connect``, ``--listen``, ``--mode`` shared by the service commands."""
    parser.add_argument(
        "--config",
        help="service TOML file (default: $SERVOWATCH_CONFIG, ~/.config/servowatch/"
        "servowatch.toml, /etc/servowatch/servowatch.toml; SERVOWATCH_* overrides apply)",
    )
    parser.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable; "
        "replaces the config's)",
    )
    parser.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on (repeatable; replaces the config's)",
    )
    parser.add_argument(
        "--mode",
        choices=("peer", "client", "router"),
        default=None,
        help="Zenoh mode (default: the config's; a peer with nothing to "
        "listen on runs as a client)",
    )
    add_tls_arguments(parser)


def service_config_from_args(args: argparse.Namespace) -> ServiceConfig:
    """``load_config`` of the config file the search finds (``service.paths.find_config``:
    ``--config``, ``$SERVOWATCH_CONFIG``, the user's, the system's) with the command line's
    Zenoh overrides applied."""
    from service.config import ConfigError, ZenohSettings, load_config
    from service.paths import find_config

    path, _where = find_config(getattr(args, "config", None))  # flag, env, user, system
    cfg = load_config(path)
    z = cfg.zenoh.model_dump()
    if getattr(args, "connect", None):
        z["connect"] = list(args.connect)
    if getattr(args, "listen", None):
        z["listen"] = list(args.listen)
    if getattr(args, "mode", None):
        z["mode"] = args.mode
    elif z["mode"] == "peer" and not z["listen"] and z["connect"]:
        z["mode"] = "client"
    z = tls_overrides(args, z)
    try:
        zs = ZenohSettings.model_validate(z)
    except ValueError as e:  # pydantic.ValidationError: name the field, skip the URL
        errs = getattr(e, "errors", None)
        if errs is None:
            raise
        err = errs()[0]
        loc = ".".join(str(x) for x in err["loc"])
        raise ConfigError(err["msg"], f"zenoh.{loc}", "command line") from None
    return cfg.model_copy(update={"zenoh": zs})


def zenoh_config(
    args: argparse.Namespace, then: Callable[[ServiceConfig], ServiceConfig] | None = None
) -> ServiceConfig:
    """The config of a Zenoh command (:func:`service_config_from_args`, then ``then`` on it):
    a bad file, field or override is a ``CommandError`` (one line, exit 2)."""
    from service.cli.util import CommandError
    from service.config import ConfigError

    try:
        cfg = service_config_from_args(args)
        return cfg if then is None else then(cfg)
    except (ConfigError, ValueError) as e:
        raise CommandError(str(e)) from None


def open_zenoh_session(cfg: ServiceConfig) -> Any:
    """``cfg.zenoh.open_session()``; an unreachable or refusing router is a ``CommandError``
    with the session error's exit code (``EXIT_UNREACHABLE``, ``EXIT_REFUSED``)."""
    from service.cli.util import CommandError
    from service.config import SessionError

    try:
        return cfg.zenoh.open_session()
    except SessionError as e:
        raise CommandError(str(e), e.exit_code) from None
