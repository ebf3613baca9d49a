"""A guard in front of the Foxglove SDK's WebSocket server: the live feed under the fleet
page's rules (docs/security.md, "HTTP"; decision record 0014).

The SDK's server checks no ``Host`` or ``Origin``, caps nothing and buffers an unfinished
client message without bound. So the SDK listens on a private loopback port (behind TLS with
a certificate made at start and trusted by nobody but this guard, so a browser cannot open
it), and this guard listens on the feed's address. For each client it:

* reads the HTTP upgrade request (at most ``max_head_bytes``, within ``head_s``) and refuses,
  before anything reaches the SDK: a second ``Host`` or ``Origin`` header (400), a ``Host``
  that is not a loopback name of the server (421, as the fleet page; off with
  ``allow_remote``, where a proxy sets it), an ``Origin`` that is neither this server's own
  nor listed in ``allowed_origins`` (403), anything but a WebSocket upgrade (400), a
  connection beyond ``max_connections`` (503);
* then splices the bytes both ways, reading the client's frame headers (RFC 6455): a
  message (all its fragments) longer than ``max_message_bytes``, or a frame or fragmented
  message unfinished after ``message_s``, cuts the connection, as does a malformed frame;
* drops a client that does not read once ``max_backlog_bytes`` wait for it;
* so that no one can lock viewers out (issue 50): a connection still in its handshake
  counts against ``max_pending`` (the oldest is dropped for a new one), not against the
  viewers, and has ``head_s``; one address (one user, for a client on this host) holds at
  most ``max_per_address`` viewer slots;
  the guard pings a viewer that has been silent for ``idle_s``/3 (a browser answers by
  itself) and cuts one silent for ``idle_s``.

The SDK's private port is keyed (``tcpkey``, TCP-MD5): the kernel drops every connection
to it that does not carry the guard's key, so no local process bypasses the guard.

Memory is therefore bounded by ``memory_bound_bytes`` (:meth:`Guard.status`, in ``servowatch
status``), and the SDK sees at most ``max_connections`` clients. The guard reports its
listener: ``ok``, ``out of descriptors`` while accepting fails for want of file descriptors,
``upstream down`` when the SDK's server no longer accepts, ``dead`` when the guard's own loop
or listener is gone; anything but ``ok`` degrades the daemon (``service.daemon.status``).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import shutil
import ssl
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.edge.httpguard import loopback_names
from service.edge.wsframes import FrameCheck, ServerFrames

__all__ = ["GuardLimits", "Guard", "FrameCheck", "ephemeral_tls", "start_guarded"]

log = logging.getLogger("servowatch.foxglove")

_READ_CHUNK = 256 * 1024  # asyncio reads at most this much per callback (selector transport)
_TICK_S = 0.25  # timeouts are checked this often
_PROBE_S = 60.0  # the SDK's listener is probed when no connection reached it for this long [s]
_PROBE_REQUEST = (
    b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    b"Sec-WebSocket-Key: c2Vydm93YXRjaCBwcm9iZQ==\r\nSec-WebSocket-Version: 13\r\n"
    b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
)
_CLOSE_FRAME = bytes([0x88, 0x82, 0, 0, 0, 0, 0x03, 0xE8])  # close 1000, a zero mask
_PING_FRAME = bytes([0x89, 0x00])  # a server's ping, no payload (RFC 6455, 5.5.2)


@dataclass(frozen=True)
class GuardLimits:
    """The live feed's limits (``[foxglove]``, docs/security.md)."""

    max_connections: int = 16  # WebSocket clients at once (beyond: 503)
    allowed_origins: tuple[str, ...] = ()  # browser origins allowed besides the server's own
    max_message_bytes: int = 65536  # a client's message, all fragments [bytes]
    message_s: float = 10.0  # an unfinished frame or message is cut after this [s]
    max_backlog_bytes: int = 1 << 20  # bytes waiting for a client (beyond: dropped) [bytes]
    max_head_bytes: int = 8192  # the HTTP upgrade request [bytes]
    head_s: float = 3.0  # the upgrade request must be complete within this [s]
    allow_remote: bool = False  # no Host check (a proxy in front sets Host)
    idle_s: float = 60.0  # a viewer silent this long is cut (pinged after idle_s / 3) [s]
    max_pending: int = 64  # connections in their handshake at once (beyond: the oldest dropped)
    max_per_address: int = 0  # viewer slots one address holds at most (0: max_connections // 2)

    def __post_init__(self) -> None:
        for name in ("max_connections", "max_message_bytes", "max_backlog_bytes",
                     "max_head_bytes", "max_pending"):  # fmt: skip
            if int(getattr(self, name)) < 1:
                raise ValueError(f"foxglove.{name}: must be >= 1")
        for name in ("message_s", "head_s", "idle_s"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"foxglove.{name}: must be > 0")
        if int(self.max_per_address) < 0:
            raise ValueError("foxglove.max_per_address: must be >= 0")
        if not self.max_per_address:
            object.__setattr__(self, "max_per_address", max(1, self.max_connections // 2))

    def memory_bound_bytes(self) -> int:
        """What the guard buffers at most, over all clients [bytes]: per viewer, the
        backlog to it and to the SDK (each plus one read), and the request head; per
        connection in its handshake, the request head."""
        per = 2 * (self.max_backlog_bytes + _READ_CHUNK) + self.max_head_bytes
        return self.max_connections * per + self.max_pending * self.max_head_bytes


def ephemeral_tls() -> tuple[bytes, bytes] | None:
    """(certificate, PKCS#8 key) in PEM, self-signed for ``localhost``/``127.0.0.1``, made
    with ``openssl`` for this process only; None without ``openssl``."""
    exe = shutil.which("openssl")
    if exe is None:
        return None
    with tempfile.TemporaryDirectory() as d:
        k, c = Path(d) / "k.pem", Path(d) / "c.pem"
        r = subprocess.run(
            [exe, "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
             "-nodes", "-keyout", str(k), "-out", str(c), "-days", "36500",
             "-subj", "/CN=localhost", "-addext", "subjectAltName=IP:127.0.0.1,DNS:localhost"],
            capture_output=True, timeout=30, check=False,
        )  # fmt: skip
        if r.returncode != 0 or not k.exists() or not c.exists():
            log.warning("foxglove guard: openssl failed (%s); the SDK link is plain",
                        r.stderr.decode(errors="replace")[-200:].strip())  # fmt: skip
            return None
        return c.read_bytes(), k.read_bytes()


def _escape(s: str, n: int = 120) -> str:
    """A header value for a log line: printable ASCII only, at most ``n`` characters."""
    return (
        s[:n].encode("ascii", "backslashreplace").decode().replace("\r", "\\r").replace("\n", "\\n")
    )


def _host_name(value: str) -> str:
    """The name part of a ``Host`` header (``name``, ``name:port``, ``[v6]:port``)."""
    v = value.strip().lower()
    if v.startswith("["):
        return v[1 : v.find("]")] if "]" in v else v
    return v.rsplit(":", 1)[0] if v.count(":") == 1 else v


# ---------------------------------------------------------------------------- the splice


class _Upstream(asyncio.Protocol):
    """The guard's connection to the SDK's server, for one client."""

    def __init__(self, client: _Client) -> None:
        self.client = client
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport) -> None:  # type: ignore[override]
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        c = self.client
        if c.transport is None or c.transport.is_closing():
            return
        c.transport.write(data)
        c.server_frames.feed(data)
        if c.transport.get_write_buffer_size() > c.guard.limits.max_backlog_bytes:
            c.cut("slow_client")
        elif c.ping_due:
            c.ping()

    def pause_writing(self) -> None:  # the SDK does not keep up with the client: wait
        if self.client.transport is not None:
            with contextlib.suppress(Exception):
                self.client.transport.pause_reading()

    def resume_writing(self) -> None:
        if self.client.transport is not None:
            with contextlib.suppress(Exception):
                self.client.transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        self.client.close()


class _Client(asyncio.Protocol):
    """One client connection of the guard."""

    def __init__(self, guard: Guard) -> None:
        self.guard = guard
        self.transport: asyncio.Transport | None = None
        self.up: _Upstream | None = None
        self.head = bytearray()
        self.t0 = time.monotonic()
        self.frames = FrameCheck(guard.limits.max_message_bytes)
        self.server_frames = ServerFrames()
        self.upgraded = False
        self.closed = False
        self.peer = "?"
        self.address = "?"  # the peer's IP address (its slots are capped)
        self.last_rx = self.t0  # the client's last bytes (time.monotonic())
        self.last_ping = self.t0
        self.ping_due = False

    # -- asyncio ----------------------------------------------------------------------
    def connection_made(self, transport) -> None:  # type: ignore[override]
        self.transport = transport
        g = self.guard
        peer = transport.get_extra_info("peername")
        self.peer = str(peer)
        self.address = str(peer[0]) if isinstance(peer, tuple) and peer else self.peer
        g.accepted += 1
        if len(g.pending) >= g.limits.max_pending:  # the oldest handshake makes room
            old = min(g.pending, key=lambda c: c.t0)
            g.count(g.refused, "pending_full")
            g.warn("pending_full", "foxglove feed: %d connections in their handshake; "
                   "dropped the oldest, %s", len(g.pending), old.peer)  # fmt: skip
            if old.transport is not None:
                old.transport.abort()
            old.close()
        g.pending.add(self)  # counts against the viewers only once upgraded
        # the client's socket keeps what the kernel holds; the guard's buffers are bounded
        transport.set_write_buffer_limits(high=g.limits.max_backlog_bytes)

    def data_received(self, data: bytes) -> None:
        if self.closed:
            return
        if not self.upgraded:
            self.head += data
            end = self.head.find(b"\r\n\r\n")
            if end < 0:
                if len(self.head) > self.guard.limits.max_head_bytes:
                    self.refuse(431, "Request Header Fields Too Large", "head_size",
                                "request head too large")  # fmt: skip
                return
            if end + 4 > self.guard.limits.max_head_bytes:
                self.refuse(431, "Request Header Fields Too Large", "head_size",
                            "request head too large")  # fmt: skip
                return
            self._upgrade(bytes(self.head), end + 4)
            return
        self.last_rx = now = time.monotonic()
        self.ping_due = False
        why = self.frames.feed(data, now)
        if why is not None:
            self.cut(why)
            return
        if self.up is not None and self.up.transport is not None:
            self.up.transport.write(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.close()

    # -- the upgrade request ------------------------------------------------------------
    def _check(self, head: bytes) -> tuple[int, str, str, str] | None:
        """(status, phrase, counter, log text) of a refusal, or None."""
        lines = head.decode("latin-1").split("\r\n")
        parts = lines[0].split(" ")
        if len(parts) != 3 or parts[0] != "GET" or not parts[2].startswith("HTTP/1."):
            return 400, "Bad Request", "bad_request", "not a GET request"
        hdr: dict[str, list[str]] = {}
        for ln in lines[1:]:
            if not ln:
                continue
            if ":" not in ln:
                return 400, "Bad Request", "bad_request", "a header line without ':'"
            k, v = ln.split(":", 1)
            hdr.setdefault(k.strip().lower(), []).append(v.strip())
        g = self.guard
        hosts, origins = hdr.get("host", []), hdr.get("origin", [])
        if len(hosts) != 1:
            return 400, "Bad Request", "host", f"{len(hosts)} Host headers"
        if len(origins) > 1:
            return 400, "Bad Request", "origin", "more than one Origin header"
        if not g.limits.allow_remote and _host_name(hosts[0]) not in g.names:
            return 421, "Misdirected Request", "host", f"Host {_escape(hosts[0])!s}"
        if origins and not g.origin_ok(origins[0]):
            return 403, "Forbidden", "origin", f"Origin {_escape(origins[0])!s}"
        up = ",".join(hdr.get("upgrade", [])).lower()
        conn = ",".join(hdr.get("connection", [])).lower()
        if "websocket" not in up or "upgrade" not in conn:
            return 400, "Bad Request", "bad_request", "not a WebSocket upgrade"
        return None

    def _upgrade(self, head: bytes, end: int) -> None:
        refusal = self._check(head[:end])
        if refusal is None:
            refusal = self._slot()
        if refusal is not None:
            self.refuse(*refusal)
            return
        g = self.guard
        g.pending.discard(self)
        g.clients.add(self)
        self.upgraded = True
        self.last_rx = self.last_ping = time.monotonic()
        rest = head[end:]
        why = self.frames.feed(rest, time.monotonic()) if rest else None
        if why is not None:
            self.cut(why)
            return
        assert self.transport is not None
        self.transport.pause_reading()
        asyncio.ensure_future(self._connect(head))

    def _slot(self) -> tuple[int, str, str, str] | None:
        """A refusal when no viewer slot is free for this client: all taken (``busy``), or
        its address (a local client: its user, ``peeruid``) holds ``max_per_address``
        already."""
        g, lim = self.guard, self.guard.limits
        if len(g.clients) >= lim.max_connections:
            return 503, "Service Unavailable", "busy", "too many connections"
        if self.transport is not None:  # a local client is counted by its user
            from service.edge.peeruid import peer_uid

            uid = peer_uid(self.transport.get_extra_info("peername"),
                           self.transport.get_extra_info("sockname"))  # fmt: skip
            if uid is not None:
                self.address = f"uid {uid}"
        if sum(1 for c in g.clients if c.address == self.address) >= lim.max_per_address:
            return (503, "Service Unavailable", "per_address",
                    f"{lim.max_per_address} connections from {self.address} already")  # fmt: skip
        return None

    def ping(self) -> None:
        """Ping the client, between two of the SDK's frames (else at the next boundary)."""
        self.ping_due = True
        t = self.transport
        if t is None or t.is_closing() or not self.server_frames.between:
            return
        t.write(_PING_FRAME)
        self.ping_due = False
        self.last_ping = time.monotonic()

    async def _connect(self, head: bytes) -> None:
        g = self.guard
        try:
            _, up = await g.open_upstream(lambda: _Upstream(self))
        except OSError as e:
            g.upstream_failed(e)
            self.refuse(502, "Bad Gateway", "upstream", f"the SDK server: {e}")
            return
        g.upstream_ok()
        if self.closed:
            up.transport.close()  # type: ignore[union-attr]
            return
        self.up = up  # type: ignore[assignment]
        assert up.transport is not None
        up.transport.set_write_buffer_limits(high=g.limits.max_backlog_bytes)
        up.transport.write(head)
        if self.transport is not None:
            self.transport.resume_reading()

    # -- ends -------------------------------------------------------------------------
    def refuse(self, status: int, phrase: str, counter: str, why: str) -> None:
        """Answer the upgrade request with ``status`` and close (counted, logged)."""
        g = self.guard
        g.count(g.refused, counter)
        g.warn(counter, "foxglove feed: refused %s: %s (%d)", self.peer, why, status)
        if self.transport is not None and not self.transport.is_closing():
            body = f"{why}\n".encode("ascii", "backslashreplace")
            self.transport.write(
                f"HTTP/1.1 {status} {phrase}\r\nContent-Type: text/plain\r\n"
                f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode()
                + body
            )
        self.close()

    def cut(self, counter: str) -> None:
        """Drop an upgraded connection at once (its buffers freed), counted and logged."""
        g = self.guard
        g.count(g.cut_counts, counter)
        g.warn("cut:" + counter, "foxglove feed: client %s dropped: %s", self.peer, counter)
        if self.transport is not None:
            self.transport.abort()
        self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.guard.clients.discard(self)
        self.guard.pending.discard(self)
        if self.transport is not None and not self.transport.is_closing():
            self.transport.close()
        if self.up is not None and self.up.transport is not None:
            self.up.transport.abort()

    def buffered(self) -> int:
        n = len(self.head) if not self.upgraded else 0
        if self.transport is not None:
            n += self.transport.get_write_buffer_size()
        if self.up is not None and self.up.transport is not None:
            n += self.up.transport.get_write_buffer_size()
        return n


# ---------------------------------------------------------------------------- the guard


@dataclass
class _Warn:
    last: dict[str, float] = field(default_factory=dict)


class Guard:
    """The guard on ``host:port`` (0: any free port, see :attr:`port`) in front of the SDK's
    server at ``upstream`` (``(host, port)``; ``upstream_cert``: its PEM certificate when it
    speaks TLS). Runs an asyncio loop in a thread of its own: :meth:`start`, :meth:`status`,
    :meth:`close`."""

    def __init__(
        self,
        host: str,
        port: int,
        upstream: tuple[str, int],
        limits: GuardLimits | None = None,
        upstream_cert: bytes | None = None,
        upstream_key: bytes | None = None,
    ) -> None:
        self.host, self.port = host, int(port)
        self.upstream = upstream
        self.upstream_key = upstream_key  # the SDK port's TCP-MD5 key (tcpkey), if keyed
        self.limits = limits or GuardLimits()
        self.names = loopback_names(host)
        self.upstream_ssl: ssl.SSLContext | None = None
        if upstream_cert is not None:
            ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
            ctx.load_verify_locations(cadata=upstream_cert.decode())  # this one certificate
            ctx.check_hostname = False
            self.upstream_ssl = ctx
        self.clients: set[_Client] = set()  # upgraded: the viewers
        self.pending: set[_Client] = set()  # in their handshake
        self.accepted = 0
        self.refused: dict[str, int] = {}
        self.cut_counts: dict[str, int] = {}
        self.accept_errors = 0
        self._accept_failed_at: float | None = None
        self._upstream_error: str | None = None
        self._upstream_ok_at = time.monotonic()  # the last connection that reached the SDK
        self._dead: str | None = None
        self._warn = _Warn()
        self.loop = asyncio.new_event_loop()
        self._server: asyncio.base_events.Server | None = None
        self._thread = threading.Thread(target=self._run, name="foxglove-guard", daemon=True)
        self._started = threading.Event()
        self._start_error: BaseException | None = None

    # -- counters and logs (on the loop's thread) ----------------------------------------
    @staticmethod
    def count(d: dict[str, int], k: str) -> None:
        d[k] = d.get(k, 0) + 1

    def warn(self, key: str, fmt: str, *args: Any) -> None:
        """A warning, at most one per ``key`` every 10 s (a flood costs one line)."""
        now = time.monotonic()
        if now - self._warn.last.get(key, -1e9) >= 10.0:
            self._warn.last[key] = now
            log.warning(fmt, *args)

    def origin_ok(self, origin: str) -> bool:
        """The server's own origin (a loopback name of it at its port) or a listed one."""
        o = origin.strip()
        if o in self.limits.allowed_origins:
            return True
        for scheme in ("http://", "https://"):
            if o.lower().startswith(scheme):
                rest = o[len(scheme) :]
                name = _host_name(rest)
                port = rest.rsplit(":", 1)[-1] if rest.count(":") == 1 or "]:" in rest else ""
                return name in self.names and port == str(self.port)
        return False

    async def open_upstream(self, factory: Any) -> tuple[Any, Any]:
        """A connection to the SDK's server (keyed and over TLS where set up):
        ``loop.create_connection``'s (transport, protocol)."""
        tls = (
            {"ssl": self.upstream_ssl, "server_hostname": "localhost"} if self.upstream_ssl else {}
        )
        if self.upstream_key is None:
            return await self.loop.create_connection(factory, *self.upstream, **tls)
        from service.edge.tcpkey import keyed_socket

        sock = keyed_socket(self.upstream_key, self.upstream[0])
        try:
            await asyncio.wait_for(self.loop.sock_connect(sock, self.upstream), 5.0)
        except BaseException as e:
            sock.close()
            raise e if isinstance(e, OSError) else OSError(f"connect: {e!r}") from None
        return await self.loop.create_connection(factory, sock=sock, **tls)

    def upstream_failed(self, e: OSError) -> None:
        self._upstream_error = f"{type(e).__name__}: {e}"
        self.warn("upstream", "foxglove feed: the SDK's server does not accept: %s", e)

    def upstream_ok(self) -> None:
        self._upstream_error = None
        self._upstream_ok_at = time.monotonic()

    # -- the loop -----------------------------------------------------------------------
    def _exception(self, loop: asyncio.AbstractEventLoop, context: dict) -> None:
        exc = context.get("exception")
        if isinstance(exc, OSError) and exc.errno in (errno.EMFILE, errno.ENFILE,
                                                      errno.ENOBUFS, errno.ENOMEM):  # fmt: skip
            # asyncio retries accept() a second later; meanwhile nobody is let in
            self.accept_errors += 1
            self._accept_failed_at = time.monotonic()
            self.warn("accept", "foxglove feed: cannot accept: %s", exc)
            return
        if isinstance(exc, ConnectionError | ssl.SSLError):
            return  # a client or the SDK went away mid-way: its connection is closed
        log.debug("foxglove guard: %s", context.get("message"))

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.set_exception_handler(self._exception)
        try:
            self._server = self.loop.run_until_complete(
                self.loop.create_server(
                    lambda: _Client(self), self.host, self.port, backlog=128, reuse_address=True
                )
            )
            self.port = int(self._server.sockets[0].getsockname()[1])
        except BaseException as e:
            self._start_error = e
            self._started.set()
            return
        self._started.set()
        tick = self.loop.create_task(self._tick())
        try:
            self.loop.run_forever()
        except BaseException as e:  # noqa: BLE001 (reported as the listener's death)
            self._dead = f"the guard's loop stopped: {type(e).__name__}: {e}"
            log.error("foxglove feed: %s", self._dead)
        finally:
            tick.cancel()
            for c in [*self.clients, *self.pending]:
                c.close()
            self._server.close()
            with contextlib.suppress(Exception):
                self.loop.run_until_complete(asyncio.sleep(0))
            self.loop.close()

    async def _tick(self) -> None:
        lim = self.limits
        while True:
            await asyncio.sleep(_TICK_S)
            now = time.monotonic()
            for c in list(self.pending):
                if now - c.t0 > lim.head_s:
                    self.count(self.refused, "head_timeout")
                    self.warn("head_timeout", "foxglove feed: %s: no request in %.1f s",
                              c.peer, lim.head_s)  # fmt: skip
                    if c.transport is not None:
                        c.transport.abort()
                    c.close()
            for c in list(self.clients):
                if c.frames.overdue(now, lim.message_s):
                    c.cut("message_timeout")
                elif now - c.last_rx > lim.idle_s:
                    c.cut("idle")
                elif now - max(c.last_rx, c.last_ping) > lim.idle_s / 3:
                    c.ping()
            if now - self._upstream_ok_at > _PROBE_S:  # a client's connection is a probe too
                self._upstream_ok_at = now
                await self._probe()

    async def _probe(self) -> None:
        """Does the SDK's server still accept? A whole WebSocket handshake, then a close
        frame (a bare connection would be logged as an error by the SDK)."""
        w = None
        try:
            r = asyncio.StreamReader(limit=2**16, loop=self.loop)
            tr, proto = await asyncio.wait_for(
                self.open_upstream(lambda: asyncio.StreamReaderProtocol(r, loop=self.loop)), 5.0
            )
            w = asyncio.StreamWriter(tr, proto, r, self.loop)
            w.write(_PROBE_REQUEST)
            line = await asyncio.wait_for(r.readline(), 5.0)
            if b" 101 " not in line:
                raise OSError(f"the SDK answered {line[:60]!r}")
            w.write(_CLOSE_FRAME)
            await asyncio.wait_for(w.drain(), 5.0)
        except (OSError, TimeoutError, ssl.SSLError) as e:
            self.upstream_failed(e if isinstance(e, OSError) else OSError(str(e)))
            return
        finally:
            if w is not None:
                w.close()
        self.upstream_ok()

    # -- the API ------------------------------------------------------------------------
    def start(self) -> Guard:
        """Listen (raises what binding raised, e.g. the port in use)."""
        self._thread.start()
        self._started.wait(30)
        if self._start_error is not None:
            raise self._start_error
        log.info("Foxglove feed on ws://%s:%d (guarded; the SDK on %s:%d)", self.host, self.port,
                 *self.upstream)  # fmt: skip
        return self

    def listener(self) -> str:
        """``ok``, or why the feed does not accept connections now."""
        if self._dead is not None:
            return f"dead: {self._dead}"
        if not self._thread.is_alive() or self._server is None or not self._server.is_serving():
            return "dead: the guard's listener is closed"
        t = self._accept_failed_at
        if t is not None and time.monotonic() - t < 10.0:
            return "out of descriptors: accept() fails (EMFILE); raise LimitNOFILE"
        if self._upstream_error is not None:
            return f"upstream down: {self._upstream_error}"
        return "ok"

    def _snapshot(self) -> dict[str, Any]:
        return {
            "connections": len(self.clients),
            "pending": len(self.pending),
            "buffered_bytes": sum(c.buffered() for c in [*self.clients, *self.pending]),
            "refused": dict(self.refused),
            "cut": dict(self.cut_counts),
        }

    def status(self) -> dict[str, Any]:
        """Listener state, connections, refusals and cuts by reason, bytes buffered now and
        the bound on them."""
        snap: dict[str, Any] = {"connections": 0, "buffered_bytes": 0, "refused": {}, "cut": {}}
        if self._thread.is_alive() and not self.loop.is_closed():
            fut = asyncio.run_coroutine_threadsafe(self._async_snapshot(), self.loop)
            with contextlib.suppress(Exception):
                snap = fut.result(2.0)
        lim = self.limits
        return {
            "listener": self.listener(),
            **snap,
            "accepted": self.accepted,
            "accept_errors": self.accept_errors,
            "max_connections": lim.max_connections,
            "max_per_address": lim.max_per_address,
            "max_pending": lim.max_pending,
            "idle_s": lim.idle_s,
            "max_message_bytes": lim.max_message_bytes,
            "max_backlog_bytes": lim.max_backlog_bytes,
            "memory_bound_bytes": lim.memory_bound_bytes(),
            "upstream_tls": self.upstream_ssl is not None,
            "upstream_private": self.upstream_key is not None,
        }

    async def _async_snapshot(self) -> dict[str, Any]:
        return self._snapshot()

    def close(self) -> None:
        """Stop listening and drop every client (idempotent)."""
        if self._thread.is_alive() and not self.loop.is_closed():
            with contextlib.suppress(RuntimeError):
                self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(5)


def start_guarded(
    foxglove: Any, host: str, port: int, limits: GuardLimits | None, **server_kw: Any
) -> tuple[Any, Guard]:
    """The SDK's server (``foxglove.start_server(**server_kw)``) on a private loopback port,
    behind TLS when ``openssl`` is there and keyed (``tcpkey``: only the guard can connect)
    where the kernel has TCP-MD5, and a :class:`Guard` on ``host:port`` in front."""
    from service.edge.tcpkey import key_listener, new_key

    tls = ephemeral_tls()
    kw = dict(server_kw)
    if tls is not None:
        kw.update(tls_cert=tls[0], tls_key=tls[1])
    server = foxglove.start_server(host="127.0.0.1", port=0, **kw)
    key: bytes | None = new_key()
    if not key_listener(int(server.port), key):
        log.warning("foxglove guard: cannot key the SDK's port (no TCP-MD5 in this kernel); "
                    "a local process can reach it past the guard")  # fmt: skip
        key = None
    try:
        guard = Guard(host, port, ("127.0.0.1", int(server.port)), limits,
                      None if tls is None else tls[0], key).start()  # fmt: skip
    except BaseException:
        server.stop()
        raise
    return server, guard
