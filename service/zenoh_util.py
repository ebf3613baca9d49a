"""Zenoh helpers: loopback-only session configs, free ports, a bounded drop-counting queue.

Every config built here disables multicast scouting and, unless ``allow_remote=True`` is
passed explicitly (deployment configs), accepts only ``tcp/127.0.0.1:<port>``,
``tls/127.0.0.1:<port>`` or unix-socket endpoints (design.md, "Conventions"). A slow subscriber callback stalls the whole session, so
subscribers hand samples to a :class:`BoundedQueue` and count what it drops.
"""

from __future__ import annotations

import collections
import json
import logging
import re
import socket
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Generic, Literal, TypeVar

import zenoh

__all__ = [
    "EndpointError",
    "check_endpoint",
    "make_config",
    "free_port",
    "loopback",
    "BoundedQueue",
    "wait_until",
    "diagnose_link",
    "RECONNECT",
]

#: reconnect settings of every config made here (and of deploy/*.json5): a lost link to a
#: router is retried every 100 ms to 250 ms, so the chain is back within ~0.3 s of the
#: router's return (zenoh's defaults, 1 s doubling to 4 s, took up to 4 s)
RECONNECT: dict[str, Any] = {
    "connect/retry": {"period_init_ms": 100, "period_max_ms": 250, "period_increase_factor": 1.5},
    "listen/retry": {"period_init_ms": 100, "period_max_ms": 250, "period_increase_factor": 1.5},
}

_LOOPBACK_RE = re.compile(r"^(?:tcp|tls)/127\.0\.0\.1:(\d{1,5})$")
_UNIX_RE = re.compile(r"^(unixsock-stream|unix)/.+$")
#: listen protocols that authenticate (a non-loopback listen of any other needs an explicit flag)
_SECURE_LISTEN = ("tls/", "quic/")
_log = logging.getLogger(__name__)

T = TypeVar("T")


class EndpointError(ValueError):
    """An endpoint that is not allowed (not loopback/unix without ``allow_remote``)."""


def check_endpoint(
    endpoint: str,
    *,
    allow_remote: bool = False,
    field: str = "endpoint",
    listen: bool = False,
    allow_plain_listen: bool = False,
) -> str:
    """Return ``endpoint`` if allowed, normalised (``unix/P`` -> ``unixsock-stream/P``).

    Allowed: ``tcp/127.0.0.1:<port>``, ``tls/127.0.0.1:<port>`` (port 0..65535) and unix
    sockets; anything of the form ``<proto>/<address>`` when ``allow_remote`` is true, except
    that a ``listen`` endpoint off loopback that is not ``tls/`` (plain ``tcp/``, ``udp/``,
    ...: anyone on the network may connect unauthenticated) needs ``allow_plain_listen`` as
    well, and is logged as a warning. Raises :class:`EndpointError`.
    """
    if not isinstance(endpoint, str) or "/" not in endpoint:
        raise EndpointError(f"{field}: {endpoint!r} is not <proto>/<address>")
    if endpoint.startswith("unix/"):
        endpoint = "unixsock-stream/" + endpoint[len("unix/") :]
    m = _LOOPBACK_RE.match(endpoint)
    if m:
        if int(m.group(1)) > 65535:
            raise EndpointError(f"{field}: port out of range in {endpoint!r}")
        return endpoint
    if _UNIX_RE.match(endpoint):
        return endpoint
    if allow_remote:
        if listen and not endpoint.startswith(_SECURE_LISTEN):
            if not allow_plain_listen:
                raise EndpointError(
                    f"{field}: {endpoint!r} refused: a plain (not tls/) listen endpoint off "
                    "loopback accepts anyone on the network without authentication; use "
                    "tls/<address>, or pass allow_plain_listen (--allow-plain-listen) explicitly"
                )
            _log.warning(
                "%s: listening on %s without TLS: anyone who reaches it may join unauthenticated",
                field,
                endpoint,
            )
        return endpoint
    raise EndpointError(
        f"{field}: {endpoint!r} refused: only tcp/127.0.0.1:<port>, tls/127.0.0.1:<port> "
        "or unix sockets "
        "(pass allow_remote=True for a deployment config)"
    )


def make_config(
    mode: Literal["peer", "client", "router"] = "peer",
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    *,
    allow_remote: bool = False,
    allow_plain_listen: bool = False,
    extra: Mapping[str, Any] | None = None,
) -> zenoh.Config:
    """A :class:`zenoh.Config` with multicast scouting off and only the given endpoints.

    ``listen`` replaces zenoh's default listeners (which bind every interface); an empty
    ``listen`` means the session listens nowhere (fine for clients and peers that connect to
    a router). Reconnection after a lost link follows :data:`RECONNECT`. ``extra`` maps config paths to JSON-serialisable values inserted last (it may
    not re-enable multicast scouting).
    """
    if mode not in ("peer", "client", "router"):
        raise ValueError(f"mode: {mode!r} is not peer, client or router")
    if isinstance(listen, str) or isinstance(connect, str):
        raise TypeError("listen and connect are sequences of endpoints, not strings")
    lst = [
        check_endpoint(
            e, allow_remote=allow_remote, field="listen", listen=True,
            allow_plain_listen=allow_plain_listen,
        )
        for e in listen
    ]  # fmt: skip
    con = [check_endpoint(e, allow_remote=allow_remote, field="connect") for e in connect]
    if mode == "client" and not con:
        raise ValueError("connect: a client needs at least one endpoint to connect to")
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps(lst))
    cfg.insert_json5("connect/endpoints", json.dumps(con))
    for path, value in RECONNECT.items():
        cfg.insert_json5(path, json.dumps(value))
    for path, value in (extra or {}).items():
        if path.startswith("scouting/multicast") and value not in (False, {"enabled": False}):
            raise ValueError(f"{path}: multicast scouting stays off")
        cfg.insert_json5(path, json.dumps(value))
    return cfg


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (for tests and demos)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def loopback(port: int) -> str:
    """The endpoint string ``tcp/127.0.0.1:<port>``."""
    return f"tcp/127.0.0.1:{int(port)}"


class BoundedQueue(Generic[T]):
    """A thread-safe bounded FIFO that drops the oldest item when full and counts drops.

    ``put`` never blocks (safe in a Zenoh callback); ``get_batch`` waits up to ``timeout``
    for at least one item and returns up to ``max_items``.
    """

    def __init__(self, maxlen: int = 10000):
        if maxlen < 1:
            raise ValueError("maxlen must be >= 1")
        self.maxlen = maxlen
        self._dq: collections.deque[T] = collections.deque()
        self._cv = threading.Condition()
        self.dropped = 0
        self.put_count = 0
        self.high_water = 0

    def put(self, item: T) -> None:
        """Append ``item``; if full, drop the oldest and count it."""
        with self._cv:
            if len(self._dq) >= self.maxlen:
                self._dq.popleft()
                self.dropped += 1
            self._dq.append(item)
            self.put_count += 1
            n = len(self._dq)
            if n > self.high_water:
                self.high_water = n
            self._cv.notify()

    def get_batch(self, max_items: int = 1000, timeout: float | None = None) -> list[T]:
        """Up to ``max_items`` items in FIFO order; ``[]`` if none arrived within ``timeout``."""
        with self._cv:
            if not self._dq and not self._cv.wait_for(lambda: bool(self._dq), timeout):
                return []
            n = min(max_items, len(self._dq))
            return [self._dq.popleft() for _ in range(n)]

    def __len__(self) -> int:
        return len(self._dq)


def wait_until(pred: Callable[[], bool], timeout: float = 5.0, interval: float = 0.01) -> bool:
    """Poll ``pred`` until it is true or ``timeout`` [s] passes; return its last value."""
    deadline = time.monotonic() + timeout
    while True:
        if pred():
            return True
        if time.monotonic() >= deadline:
            return bool(pred())
        time.sleep(interval)


#: TLS alerts and verification failures -> what they mean for a servowatch operator
_TLS_REASONS = {
    "CERTIFICATE_REQUIRED": "the router requires a client certificate and none was presented "
    "(set [zenoh.tls] cert and key)",
    "DECRYPT_ERROR": "the router rejected the client certificate (not signed by the station CA)",
    "BAD_CERTIFICATE": "the router rejected the client certificate",
    "UNKNOWN_CA": "the router rejected the client certificate (unknown CA)",
    # TLS has one alert for both: rustls sends it for a not-yet-valid certificate too
    "CERTIFICATE_EXPIRED": "a certificate has expired or is not yet valid (check its validity "
    "dates and the clocks)",
    "CERTIFICATE_REVOKED": "the client certificate is revoked",
    "CERTIFICATE_VERIFY_FAILED": "the router's certificate is not trusted by tls.root_ca",
    "WRONG_VERSION_NUMBER": "the endpoint does not speak TLS (a tcp/ listener?)",
}


def certificate_cn(cert: str | Path) -> str | None:
    """The subject common name of the certificate file ``cert`` (None: unreadable, none)."""
    import ssl

    try:
        info = ssl._ssl._test_decode_cert(str(cert))  # the stdlib's PEM decoder, no CA check
    except (OSError, ValueError, ssl.SSLError, AttributeError):
        return None
    for rdn in info.get("subject", ()):
        for k, v in rdn:
            if k == "commonName":
                return str(v)
    return None


def certificate_validity(cert: str | Path, now: float | None = None) -> str:
    """Why the certificate file ``cert`` is not valid at ``now`` (Unix time; default: now):
    "not yet valid (from ...)", "expired (on ...)", or "" when it is valid or unreadable."""
    import ssl

    try:
        info = ssl._ssl._test_decode_cert(str(cert))  # the stdlib's PEM decoder, no CA check
        not_before = ssl.cert_time_to_seconds(info["notBefore"])
        not_after = ssl.cert_time_to_seconds(info["notAfter"])
    except (OSError, ValueError, KeyError, ssl.SSLError, AttributeError):
        return ""
    now = time.time() if now is None else now
    if now < not_before:
        return f"not yet valid (from {info['notBefore']})"
    if now > not_after:
        return f"expired (on {info['notAfter']})"
    return ""


def diagnose_link(
    endpoint: str,
    root_ca: str | Path | None = None,
    cert: str | Path | None = None,
    key: str | Path | None = None,
    timeout: float = 2.0,
) -> tuple[Literal["ok", "refused", "unreachable"], str]:
    """Why a Zenoh link to ``endpoint`` fails: one TCP (and for ``tls/``, TLS) handshake.

    Zenoh reports only "unable to connect"; this probe tells an absent router
    (``unreachable``: connection refused, timeout, bad address) from a refusal at the TLS
    handshake (``refused``: no client certificate, a certificate from another CA, a router
    certificate that ``root_ca`` does not trust). The probe sends no Zenoh message, holds no
    secret beyond what the Zenoh link itself loads, and is used only after a failed open.
    """
    import ssl

    proto, _, addr = endpoint.partition("/")
    if proto not in ("tcp", "tls"):
        return "unreachable", f"cannot probe a {proto}/ endpoint"
    host, _, port = addr.rpartition(":")
    host = host.strip("[]")
    try:
        sock = socket.create_connection((host, int(port)), timeout=timeout)
    except (OSError, ValueError) as e:
        return "unreachable", f"no router there ({getattr(e, 'strerror', None) or e})"
    with sock:
        if proto == "tcp":
            return "ok", "TCP connection accepted"
        try:
            ctx = ssl.create_default_context(cafile=None if root_ca is None else str(root_ca))
            if cert is not None and key is not None:
                ctx.load_cert_chain(str(cert), str(key))
        except (OSError, ssl.SSLError) as e:
            return "refused", f"cannot load the TLS files: {e}"
        try:
            with ctx.wrap_socket(sock, server_hostname=host) as ts:
                ts.settimeout(min(timeout, 0.5))
                try:  # TLS 1.3: a rejected client certificate shows at the first read
                    ts.recv(1)
                except TimeoutError:
                    return "ok", "TLS handshake accepted"
                return "ok", "TLS handshake accepted"
        except ssl.SSLError as e:
            reason = str(getattr(e, "reason", "") or "")
            for k, text in _TLS_REASONS.items():
                if k in reason:
                    if k == "CERTIFICATE_EXPIRED" and cert is not None:
                        why = certificate_validity(cert)
                        text = f"this identity's certificate {cert} is {why}" if why else text
                    return "refused", f"{text} [{reason}]"
            return "refused", f"TLS handshake failed: {reason or e}"
        except OSError as e:
            return "unreachable", f"connection lost during the TLS handshake ({e})"
