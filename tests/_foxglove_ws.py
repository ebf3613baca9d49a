"""A minimal Foxglove WebSocket client for the tests, written from the specifications (no
Foxglove code): RFC 6455 (handshake, masked client frames, ping/pong, fragments) and
``foxglove.websocket.v1`` (offered with its current name ``foxglove.sdk.v1``, the same
protocol, which foxglove-sdk >= 0.9 servers require in the handshake) (JSON ``serverInfo``/``advertise``/``unadvertise`` from the server,
``subscribe``/``unsubscribe`` from the client, binary ``messageData``: opcode 0x01, uint32
subscription id, uint64 receive timestamp [ns], payload; all little-endian)."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import socket
import struct
import time
from dataclasses import dataclass, field
from typing import Any

SUBPROTOCOLS = ("foxglove.websocket.v1", "foxglove.sdk.v1")
OFFER = ", ".join(SUBPROTOCOLS)


def client_frame(opcode: int, data: bytes, fin: bool = True, length: int | None = None) -> bytes:
    """A masked client frame of ``data`` (``fin``: the message's last; ``length``: the length
    its header announces, by default ``len(data)``)."""
    n = len(data) if length is None else length
    head = bytes([(0x80 if fin else 0) | opcode])
    if n < 126:
        head += bytes([0x80 | n])
    elif n < 1 << 16:
        head += bytes([0x80 | 126]) + struct.pack(">H", n)
    else:
        head += bytes([0x80 | 127]) + struct.pack(">Q", n)
    mask = os.urandom(4)
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data))


@dataclass
class MessageData:
    subscription: int
    timestamp_ns: int
    payload: bytes


@dataclass
class FoxgloveClient:
    host: str
    port: int
    sock: socket.socket | None = None
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  # id -> advertise entry
    server_info: dict[str, Any] | None = None
    subprotocol: str | None = None
    _buf: bytes = b""

    # -- RFC 6455 -----------------------------------------------------------------------
    def connect(self, timeout: float = 10.0, rcvbuf: int | None = None) -> FoxgloveClient:
        """Handshake; ``rcvbuf``: the socket's receive buffer size (a small one fills fast)."""
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if rcvbuf is not None:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, int(rcvbuf))
        s.settimeout(timeout)
        s.connect((self.host, self.port))
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: {self.host}:{self.port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {OFFER}\r\n\r\n"
            ).encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = s.recv(4096)
            if not chunk:
                raise ConnectionError("closed during the handshake")
            head += chunk
        head, self._buf = head.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        if " 101 " not in lines[0] + " ":
            raise ConnectionError(f"handshake refused: {lines[0]}")
        hdr = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:])}
        self.subprotocol = hdr.get("sec-websocket-protocol")
        if self.subprotocol not in SUBPROTOCOLS:
            raise ConnectionError(f"subprotocol not agreed: {hdr}")
        self.sock = s
        return self

    def _read(self, n: int) -> bytes:
        while len(self._buf) < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("connection closed")
            self._buf += chunk
        out, self._buf = self._buf[:n], self._buf[n:]
        return out

    def _send_frame(self, opcode: int, data: bytes) -> None:
        self.sock.sendall(client_frame(opcode, data))

    def _frame(self) -> tuple[int, bytes]:
        """One whole message (fragments joined; pings answered): (opcode, data)."""
        parts: list[bytes] = []
        first = None
        while True:
            b0, b1 = self._read(2)
            fin, op = b0 & 0x80, b0 & 0x0F
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._read(8))[0]
            mask = self._read(4) if b1 & 0x80 else None
            data = self._read(n)
            if mask is not None:
                data = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
            if op == 0x9:  # ping
                self._send_frame(0xA, data)
                continue
            if op == 0xA:
                continue
            if op == 0x8:
                raise ConnectionError("closed by the server")
            if op != 0:
                first = op
            parts.append(data)
            if fin:
                return first, b"".join(parts)

    # -- foxglove.websocket.v1 -------------------------------------------------------------
    def recv(self, timeout: float = 10.0) -> dict[str, Any] | MessageData:
        """The next server message: a JSON dict (advertise etc. also update ``channels``) or
        a :class:`MessageData`."""
        self.sock.settimeout(timeout)
        op, data = self._frame()
        if op == 0x1:
            msg = json.loads(data)
            kind = msg.get("op")
            if kind == "serverInfo":
                self.server_info = msg
            elif kind == "advertise":
                for ch in msg["channels"]:
                    self.channels[int(ch["id"])] = ch
            elif kind == "unadvertise":
                for cid in msg["channelIds"]:
                    self.channels.pop(int(cid), None)
            return msg
        if op == 0x2 and data[:1] == b"\x01":
            sub, ts = struct.unpack_from("<IQ", data, 1)
            return MessageData(sub, ts, data[13:])
        return {"op": f"binary opcode {data[:1].hex()}"}

    def send_json(self, msg: dict[str, Any]) -> None:
        self._send_frame(0x1, json.dumps(msg).encode())

    def subscribe(self, subs: dict[int, int]) -> None:
        """``{subscription id: channel id}``."""
        self.send_json({"op": "subscribe", "subscriptions": [
            {"id": s, "channelId": c} for s, c in subs.items()]})  # fmt: skip

    def unsubscribe(self, ids: list[int]) -> None:
        self.send_json({"op": "unsubscribe", "subscriptionIds": list(ids)})

    def channel_of(self, topic: str) -> dict[str, Any] | None:
        return next((c for c in self.channels.values() if c["topic"] == topic), None)

    def wait_channel(self, topic: str, timeout: float = 60.0) -> dict[str, Any]:
        """Read until ``topic`` is advertised (messages in between are discarded)."""
        self.wait_topics({topic}, timeout)
        return self.channel_of(topic)

    def wait_topics(self, topics: set[str], timeout: float = 60.0) -> None:
        """Read until all of ``topics`` are advertised (messages in between are discarded)."""
        end = time.monotonic() + timeout
        while not set(topics) <= self.topics():
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"{topics} not advertised; have {sorted(self.topics())}")
            with contextlib.suppress(TimeoutError):
                self.recv(timeout=min(1.0, left))

    def topics(self) -> set[str]:
        return {c["topic"] for c in self.channels.values()}

    def close(self) -> None:
        if self.sock is not None:
            with contextlib.suppress(OSError):
                self._send_frame(0x8, struct.pack(">H", 1000))
            self.sock.close()
            self.sock = None
