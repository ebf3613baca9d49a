"""Read-only HTTP server of the fleet page (docs/dashboard.md).

Routes (GET and HEAD only; any other method is answered 405):

- ``/``: the page (``static/index.html``), ``/static/fleet.js``, ``/static/fleet.css``;
- ``/api/fleet``: ``view.fleet_view`` of the store;
- ``/api/unit?name=AIRCRAFT/ACTUATOR``: ``view.unit_view`` (400 on a bad name, 404 on an
  unknown one);
- ``/api/live``: the daemons' live status (``live.LiveStatus``) when the server was given a
  Zenoh session, else ``{"enabled": false}``;
- ``/healthz``: ``{"ok": true, "store": ...}`` when the store answers, 503 otherwise.

The store is opened per request (``open_store(create=False)``), so the page follows a store
that daemons and ``servowatch rul`` write meanwhile, on SQLite and PostgreSQL alike, and a
store that goes away is a 503 with its error, not a dead server. The server binds to loopback
unless told otherwise (docs/security.md, "HTTP"); the page loads nothing from elsewhere and
its Content-Security-Policy says so.
"""

from __future__ import annotations

import ipaddress
import json
import sys
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from service.jsonutil import jsonable
from service.store import StoreError, open_store
from service.web.view import UnknownActuatorError, fleet_view, unit_view

__all__ = ["STATIC", "check_listen", "make_server", "SECURITY_HEADERS"]

STATIC = Path(__file__).resolve().parent / "static"
_FILES = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/static/fleet.js": ("fleet.js", "text/javascript; charset=utf-8"),
    "/static/fleet.css": ("fleet.css", "text/css; charset=utf-8"),
}
SECURITY_HEADERS: dict[str, str] = {
    "Content-Security-Policy": (
        "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
        "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
    "Cache-Control": "no-store",
}


def check_listen(text: str, *, allow_remote: bool = False) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); ValueError naming ``--listen`` when it does not parse,
    or when the host is not a loopback address and ``allow_remote`` is False."""
    host, sep, port_s = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host:
        raise ValueError(f"--listen: expected HOST:PORT (e.g. 127.0.0.1:8080), got {text!r}")
    try:
        port = int(port_s)
    except ValueError:
        raise ValueError(f"--listen: port {port_s!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"--listen: port {port} is out of 0-65535")
    if host == "localhost":
        host = "127.0.0.1"
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        raise ValueError(f"--listen: {host!r} is not an IP address") from None
    if not ip.is_loopback and not allow_remote:
        raise ValueError(
            f"--listen: {host} is not a loopback address; the page has no authentication of "
            "its own, so expose it beyond the host only behind an authenticating TLS proxy "
            "(docs/security.md) and pass --allow-remote"
        )
    return host, port


class _Handler(BaseHTTPRequestHandler):
    server_version = "servowatch-web"
    sys_version = ""
    protocol_version = "HTTP/1.1"
    # set by make_server on a subclass
    store_target: str = ""
    refresh_s: float = 10.0
    access_log: bool = False
    live: Any = None  # a LiveStatus, or None

    # -- plumbing ---------------------------------------------------------------------------
    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (the base's name)
        if self.access_log:
            sys.stderr.write(f"servowatch web: {self.address_string()} {format % args}\n")

    def _send(self, status: int, body: bytes, ctype: str, head_only: bool = False) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        for k, v in SECURITY_HEADERS.items():
            self.send_header(k, v)
        if status == HTTPStatus.METHOD_NOT_ALLOWED:
            self.send_header("Allow", "GET, HEAD")
        self.end_headers()
        if not head_only:
            self.wfile.write(body)

    def _json(self, status: int, obj: Any, head_only: bool = False) -> None:
        body = json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()
        self._send(status, body, "application/json", head_only)

    def _error(self, status: int, message: str, head_only: bool = False) -> None:
        self._json(status, {"error": message, "status": int(status)}, head_only)

    # -- routes -----------------------------------------------------------------------------
    def _route(self, head_only: bool) -> None:
        url = urlsplit(self.path)
        path = url.path
        if path in _FILES:
            name, ctype = _FILES[path]
            body = (STATIC / name).read_bytes()
            if name == "index.html":
                body = body.replace(b"{{REFRESH_S}}", f"{self.refresh_s:g}".encode())
            self._send(HTTPStatus.OK, body, ctype, head_only)
            return
        if path == "/api/live":
            live = self.live.snapshot() if self.live is not None else {"enabled": False}
            self._json(HTTPStatus.OK, jsonable(live), head_only)
            return
        if path not in ("/api/fleet", "/api/unit", "/healthz"):
            self._error(HTTPStatus.NOT_FOUND, f"no such page: {path}", head_only)
            return
        query = parse_qs(url.query, keep_blank_values=True)
        try:
            store = open_store(self.store_target, create=False)
        except StoreError as e:
            self._error(HTTPStatus.SERVICE_UNAVAILABLE, str(e), head_only)
            return
        try:
            with store:
                if path == "/healthz":
                    store.schema_version()
                    self._json(HTTPStatus.OK, {"ok": True, "store": store.where}, head_only)
                elif path == "/api/fleet":
                    self._json(HTTPStatus.OK, fleet_view(store), head_only)
                else:
                    names = query.get("name", [])
                    if len(names) != 1:
                        self._error(
                            HTTPStatus.BAD_REQUEST,
                            "name: expected one ?name=AIRCRAFT/ACTUATOR",
                            head_only,
                        )
                        return
                    self._json(HTTPStatus.OK, unit_view(store, names[0]), head_only)
        except ValueError as e:
            self._error(HTTPStatus.BAD_REQUEST, str(e), head_only)
        except UnknownActuatorError as e:
            self._error(
                HTTPStatus.NOT_FOUND, f"name: no actuator {e.args[0]!r} in the store", head_only
            )
        except Exception as e:  # a store failing mid-request (connection lost, file removed)
            self._error(
                HTTPStatus.SERVICE_UNAVAILABLE, f"store: {type(e).__name__}: {e}", head_only
            )

    def do_GET(self) -> None:
        self._route(head_only=False)

    def do_HEAD(self) -> None:
        self._route(head_only=True)

    def _refuse(self) -> None:
        # drain a body so the connection stays usable, then refuse: the page is read only
        n = int(self.headers.get("Content-Length") or 0)
        if 0 < n <= 1 << 20:
            self.rfile.read(n)
        else:
            self.close_connection = True
        self._error(HTTPStatus.METHOD_NOT_ALLOWED, f"{self.command}: the page is read only")

    do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _refuse


def make_server(
    store_target: str,
    host: str = "127.0.0.1",
    port: int = 8080,
    *,
    refresh_s: float = 10.0,
    access_log: bool = False,
    live: Any = None,
) -> ThreadingHTTPServer:
    """A bound (not yet serving) server of the page on ``host:port`` (port 0: any free one;
    ``server.server_address`` tells which) over the store at ``store_target``; ``live``, a
    started ``LiveStatus``, adds the daemons' live status."""
    handler = type(
        "FleetPageHandler",
        (_Handler,),
        {
            "store_target": store_target,
            "refresh_s": float(refresh_s),
            "access_log": access_log,
            "live": live,
        },
    )
    cls = ThreadingHTTPServer
    if ":" in host:

        class _V6(ThreadingHTTPServer):
            import socket as _socket

            address_family = _socket.AF_INET6

        cls = _V6
    srv = cls((host, port), handler)
    srv.daemon_threads = True
    return srv
