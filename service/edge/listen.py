"""``HOST:PORT`` of a server the project runs (the fleet page, the Foxglove feed): loopback
unless explicitly allowed (docs/security.md, "HTTP")."""

from __future__ import annotations

import ipaddress

__all__ = ["check_listen"]


def check_listen(
    text: str,
    *,
    allow_remote: bool = False,
    flag: str = "--listen",
    what: str = "the page",
    allow: str = "--allow-remote",
) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); ValueError naming ``flag`` when it does not parse, or
    when the host is not a loopback address and ``allow_remote`` is False (``what`` names
    the server in the message, ``allow`` the setting that allows it)."""
    host, sep, port_s = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host:
        raise ValueError(f"{flag}: expected HOST:PORT (e.g. 127.0.0.1:8080), got {text!r}")
    try:
        port = int(port_s)
    except ValueError:
        raise ValueError(f"{flag}: port {port_s!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"{flag}: port {port} is out of 0-65535")
    if host == "localhost":
        host = "127.0.0.1"
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        raise ValueError(f"{flag}: {host!r} is not an IP address") from None
    if not ip.is_loopback and not allow_remote:
        raise ValueError(
            f"{flag}: {host} is not a loopback address; {what} has no authentication of "
            "its own, so expose it beyond the host only behind an authenticating TLS proxy "
            f"(docs/security.md) and set {allow}"
        )
    return host, port
