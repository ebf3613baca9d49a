"""WebSocket frames (RFC 6455, section 5.2) read for the live feed's guard
(``service.edge.foxglove_guard``): only their headers, for the limits (:class:`FrameCheck`, the
client's frames) and for the boundaries between the server's frames (:class:`ServerFrames`,
where the guard may put a ping)."""

from __future__ import annotations

__all__ = ["FrameCheck", "ServerFrames"]


class FrameCheck:
    """The client-to-server WebSocket frames of one connection, read for the limits only
    (RFC 6455, section 5.2): :meth:`feed` returns why the connection must be cut, or None.
    ``pending_since`` is the time an unfinished frame or fragmented message started."""

    def __init__(self, max_message_bytes: int) -> None:
        self.max_message = int(max_message_bytes)
        self._hdr = bytearray()
        self._skip = 0  # payload bytes of the current frame still to come
        self._in_msg = False  # a fragmented message is open (its final frame not seen)
        self._msg_len = 0
        self.pending_since: float | None = None
        self.messages = 0

    def _need(self) -> int:
        h = self._hdr
        if len(h) < 2:
            return 2
        ln = h[1] & 0x7F
        return 2 + (2 if ln == 126 else 8 if ln == 127 else 0) + (4 if h[1] & 0x80 else 0)

    def _header(self) -> str | None:
        h = self._hdr
        fin, rsv, op = h[0] & 0x80, h[0] & 0x70, h[0] & 0x0F
        ln = h[1] & 0x7F
        if ln == 126:
            ln = int.from_bytes(h[2:4], "big")
        elif ln == 127:
            ln = int.from_bytes(h[2:10], "big")
        if not h[1] & 0x80:
            return "protocol"  # a client's frames are masked (5.3)
        if rsv:
            return "protocol"  # no extension is negotiated
        if op >= 8:  # control frame: ping, pong, close; never fragmented, <= 125 bytes
            if op > 10 or not fin or ln > 125:
                return "protocol"
        elif op in (1, 2):
            if self._in_msg:
                return "protocol"
            self._msg_len, self._in_msg = ln, not fin
        elif op == 0:
            if not self._in_msg:
                return "protocol"
            self._msg_len += ln
            self._in_msg = not fin
        else:
            return "protocol"
        if op < 8 and self._msg_len > self.max_message:
            return "oversize"
        self._skip = ln
        return None

    def _frame_done(self) -> None:
        self._hdr.clear()
        if not self._in_msg:
            self.pending_since = None
            self.messages += 1

    def feed(self, data: bytes, now: float) -> str | None:
        """Account for ``data`` (``now``: time.monotonic()); a reason to cut, or None."""
        i, n = 0, len(data)
        while i < n:
            if self._skip:
                k = min(self._skip, n - i)
                self._skip -= k
                i += k
                if not self._skip:
                    self._frame_done()
                continue
            if self.pending_since is None:
                self.pending_since = now
            while i < n and len(self._hdr) < self._need():
                self._hdr.append(data[i])
                i += 1
            if len(self._hdr) < self._need():
                return None
            why = self._header()
            if why is not None:
                return why
            if not self._skip:
                self._frame_done()
        return None

    def overdue(self, now: float, limit_s: float) -> bool:
        return self.pending_since is not None and now - self.pending_since > limit_s


class ServerFrames:
    """Where the server-to-client byte stream stands (RFC 6455, section 5.2): inside a frame
    or between two (:attr:`between`), so the guard can put a ping between the SDK's frames.
    Only headers are read; a payload is skipped by its length."""

    def __init__(self) -> None:
        self._hdr = bytearray()
        self._skip = 0
        self._head: bytearray | None = bytearray()  # the HTTP response, until its end

    @property
    def between(self) -> bool:
        return self._head is None and not self._skip and not self._hdr

    def feed(self, data: bytes) -> None:
        i, n = 0, len(data)
        if self._head is not None:  # the server's HTTP response head comes first
            tail = bytes(self._head[-3:])
            end = (tail + data).find(b"\r\n\r\n")
            if end < 0:
                self._head = bytearray((tail + data)[-3:])
                return
            self._head = None
            i = end + 4 - len(tail)
        while i < n:
            if self._skip:
                k = min(self._skip, n - i)
                self._skip -= k
                i += k
                continue
            h = self._hdr
            h.append(data[i])
            i += 1
            if len(h) < 2:
                continue
            ln = h[1] & 0x7F
            need = 2 + (2 if ln == 126 else 8 if ln == 127 else 0) + (4 if h[1] & 0x80 else 0)
            if len(h) < need:
                continue
            if ln == 126:
                ln = int.from_bytes(h[2:4], "big")
            elif ln == 127:
                ln = int.from_bytes(h[2:10], "big")
            self._skip = ln
            h.clear()
