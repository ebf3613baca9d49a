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

import json
import logging
from http import HTTPStatus
from http.server import ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from service.edge.httpguard import REQUEST_S, GuardedHandler, loopback_names
from service.edge.listen import check_listen
from service.edge.web.view import UnknownActuatorError, fleet_view, unit_view
from service.jsonutil import jsonable
from service.store import StoreError, open_store

__all__ = ["STATIC", "check_listen", "make_server", "SECURITY_HEADERS"]

#: ``--access-log``: a line per request, its client, request line, status and size as fields
access_log = logging.getLogger("servowatch.web.access")

STATIC = Path(__file__).resolve().parent / "static"
_FILES = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/static/fleet.js": ("fleet.js", "text/javascript; charset=utf-8"),
    "/static/fleet.css": ("fleet.css", "text/css; charset=utf-8"),
}
STORE_TIMEOUT_S = 5.0  # a store that does not answer within this is a 503 [s]
BACKLOG = 128  # pending connections the kernel queues (a few browsers, scripts, a proxy)
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


def _json_answer(status: int, obj: Any) -> tuple[int, bytes, str]:
    """(status, body, content type) of a JSON answer."""
    return (
        status,
        json.dumps(obj, allow_nan=False, separators=(",", ":")).encode(),
        "application/json",
    )


def _error_answer(status: int, message: str) -> tuple[int, bytes, str]:
    """A JSON error answer naming what was wrong."""
    return _json_answer(status, {"error": message, "status": int(status)})


class _Handler(GuardedHandler):
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
            access_log.info("%s " + format, self.address_string(), *args,
                            extra={"fields": {"client": self.address_string()}})  # fmt: skip

    def log_request(self, code: int | str = "-", size: int | str = "-") -> None:
        if self.access_log:
            try:
                status: int | str = int(code)
            except ValueError:
                status = str(code)
            line = getattr(self, "requestline", "")
            access_log.info("%s %s %s %s", self.address_string(), line, status, size,
                            extra={"fields": {"client": self.address_string(), "request": line,
                                              "status": status, "size": str(size)}})  # fmt: skip

    def _send(self, status: int, body: bytes, ctype: str) -> None:
        head_only = self.command == "HEAD"
        try:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            for k, v in SECURITY_HEADERS.items():
                self.send_header(k, v)
            if status == HTTPStatus.METHOD_NOT_ALLOWED:
                self.send_header("Allow", "GET, HEAD")
            if self.close_connection:
                self.send_header("Connection", "close")
            self.end_headers()
            if not head_only:
                self.wfile.write(body)
        except (ConnectionError, TimeoutError):  # the client went away: nothing to answer
            self.close_connection = True

    def _error(self, status: int, message: str) -> None:
        self._send(*_error_answer(status, message))

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """The base class's errors (a malformed request line, an unknown method, headers too
        long) as JSON with the security headers; an unknown method is a 405."""
        self.close_connection = True
        if code == HTTPStatus.NOT_IMPLEMENTED:
            code = HTTPStatus.METHOD_NOT_ALLOWED
            message = f"{self.command}: the page is read only"
        if not hasattr(self, "command") or self.command is None:
            self.command = ""
        if getattr(self, "request_version", "HTTP/0.9") == "HTTP/0.9":
            self.request_version = (
                "HTTP/1.0"  # an unparsed request: answer with headers all the same
            )
        self._error(code, message or HTTPStatus(code).phrase)

    def _body_length(self) -> int | None:
        """The request body's Content-Length (0 without one); None when it is not a
        non-negative integer, or the body is chunked: the connection cannot be reused."""
        if self.headers.get("Transfer-Encoding"):
            return None
        text = self.headers.get("Content-Length")
        if text is None:
            return 0
        try:
            n = int(text)
        except ValueError:
            return None
        return n if n >= 0 else None

    # -- routes -----------------------------------------------------------------------------
    def _answer(self) -> tuple[int, bytes, str]:
        """(status, body, content type) of a GET (HEAD) request."""
        url = urlsplit(self.path)
        path = url.path
        err = _error_answer

        def ok(obj: Any) -> tuple[int, bytes, str]:
            return _json_answer(HTTPStatus.OK, obj)

        if len(self.headers.get_all("Host") or ()) > 1:  # which one a proxy reads is anyone's guess
            self.close_connection = True
            return err(HTTPStatus.BAD_REQUEST, "Host: more than one Host header")
        if not self._host_ok():
            return err(HTTPStatus.MISDIRECTED_REQUEST, "Host: not this server's name")
        if path in _FILES:
            name, ctype = _FILES[path]
            body = (STATIC / name).read_bytes()
            if name == "index.html":
                body = body.replace(b"{{REFRESH_S}}", f"{self.refresh_s:g}".encode())
            return HTTPStatus.OK, body, ctype
        if path == "/api/live":
            return ok(
                jsonable(self.live.snapshot() if self.live is not None else {"enabled": False})
            )
        if path not in ("/api/fleet", "/api/unit", "/healthz"):
            return err(HTTPStatus.NOT_FOUND, f"no such page: {path}")
        query = parse_qs(url.query, keep_blank_values=True)
        try:
            store = open_store(self.store_target, read_only=True, timeout_s=STORE_TIMEOUT_S)
        except StoreError as e:
            return err(HTTPStatus.SERVICE_UNAVAILABLE, str(e))
        try:
            with store:
                if path == "/healthz":
                    store.schema_version()
                    return ok({"ok": True, "store": store.where})
                if path == "/api/fleet":
                    return ok(fleet_view(store))
                names = query.get("name", [])
                if len(names) != 1:
                    return err(HTTPStatus.BAD_REQUEST, "name: expected one ?name=AIRCRAFT/ACTUATOR")
                return ok(unit_view(store, names[0]))
        except ValueError as e:
            return err(HTTPStatus.BAD_REQUEST, str(e))
        except UnknownActuatorError as e:
            return err(HTTPStatus.NOT_FOUND, f"name: no actuator {e.args[0]!r} in the store")
        except Exception as e:  # a store failing mid-request (connection lost, file removed)
            return err(HTTPStatus.SERVICE_UNAVAILABLE, f"store: {type(e).__name__}: {e}")

    def do_GET(self) -> None:
        if self._body_length() != 0:  # a body on a read: never parse it as the next request
            self.close_connection = True
        self._send(*self._answer())

    do_HEAD = do_GET

    def _refuse(self) -> None:
        # drain a small body so the connection stays usable, then refuse: the page is read only
        n = self._body_length()
        if n is not None and n <= 1 << 20:
            self.rfile.read(n)
        else:
            self.close_connection = True
        self._error(HTTPStatus.METHOD_NOT_ALLOWED, f"{self.command}: the page is read only")

    do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_TRACE = do_CONNECT = _refuse


class _Server(ThreadingHTTPServer):
    request_queue_size = BACKLOG  # the listen backlog (socketserver's default is 5)


def make_server(
    store_target: str,
    host: str = "127.0.0.1",
    port: int = 8080,
    *,
    refresh_s: float = 10.0,
    access_log: bool = False,
    live: Any = None,
    allow_remote: bool = False,
    request_s: float = REQUEST_S,
) -> ThreadingHTTPServer:
    """A bound (not yet serving) server of the page on ``host:port`` (port 0: any free one;
    ``server.server_address`` tells which) over the store at ``store_target``; ``live``, a
    started ``LiveStatus``, adds the daemons' live status. Unless ``allow_remote``, a request
    whose Host header is not a loopback name of this server is answered 421; a request with
    more than one Host header is a 400. Each request must be done within ``request_s`` [s];
    the kernel queues up to :data:`BACKLOG` pending connections."""
    handler = type(
        "FleetPageHandler",
        (_Handler,),
        {
            "store_target": store_target,
            "refresh_s": float(refresh_s),
            "access_log": access_log,
            "live": live,
            "allowed_hosts": None if allow_remote else loopback_names(host),
            "request_s": float(request_s),
        },
    )
    cls = _Server
    if ":" in host:

        class _V6(_Server):
            import socket as _socket

            address_family = _socket.AF_INET6

        cls = _V6
    srv = cls((host, port), handler)
    srv.daemon_threads = True
    return srv
