"""What every HTTP endpoint of servowatch does before its routes (docs/security.md, "HTTP"):
a Host header that names the server (DNS rebinding), a bounded wait for a request's first
byte and a bounded time for the whole request, however slowly it trickles in. The fleet page
(``service.edge.web.server``) and the daemon's metrics endpoint (``service.edge.metrics``) share it."""

from __future__ import annotations

import contextlib
import socket
import threading
from http.server import BaseHTTPRequestHandler

__all__ = ["IDLE_S", "REQUEST_S", "GuardedHandler", "loopback_names"]

IDLE_S = 30.0  # a kept-alive connection with no new request is closed after this long [s]
REQUEST_S = 10.0  # a request, from its first byte to its answer, must be done within this [s]


def loopback_names(host: str) -> frozenset[str]:
    """The Host names a loopback server bound to ``host`` answers to."""
    return frozenset({"localhost", "127.0.0.1", "::1", host.lower()})


class GuardedHandler(BaseHTTPRequestHandler):
    """A request handler with the endpoint rules: ``allowed_hosts`` (None: any Host),
    ``timeout`` (the idle wait, s) and ``request_s`` (the whole request, s)."""

    timeout = IDLE_S  # socket timeout: the wait for a request's first byte [s]
    request_s = REQUEST_S  # the whole request and its answer, however slowly it trickles [s]
    allowed_hosts: frozenset[str] | None = None  # Host header names; None = any

    def handle_one_request(self) -> None:
        """One request within ``request_s`` in total: the socket timeout bounds each read, so
        a client sending a byte now and then would otherwise hold the connection (and its
        thread) forever. At the deadline the socket is shut down and the connection ends."""
        try:
            if not self.rfile.peek(1):  # the idle wait (socket timeout); b"": closed
                self.close_connection = True
                return
        except (TimeoutError, OSError):
            self.close_connection = True
            return

        def expire() -> None:
            self.close_connection = True
            with contextlib.suppress(OSError):
                self.connection.shutdown(socket.SHUT_RDWR)

        timer = threading.Timer(self.request_s, expire)
        timer.daemon = True
        timer.start()
        try:
            super().handle_one_request()
        finally:
            timer.cancel()

    def _host_ok(self) -> bool:
        """The Host header names this server (DNS rebinding: a page of another origin that
        resolves its name to 127.0.0.1 must not read what the server serves)."""
        if self.allowed_hosts is None:
            return True
        host = (self.headers.get("Host") or "").strip().lower()
        if host.startswith("["):
            name = host[1 : host.find("]")] if "]" in host else host
        else:
            name = host.rsplit(":", 1)[0] if host.count(":") == 1 else host
        return name in self.allowed_hosts
