"""The user of a loopback TCP peer (Linux): for a connection from this host, the uid that owns
the peer's socket, read from ``/proc/net/tcp`` (or ``tcp6``). The live feed's guard counts a
local client's slots by its user rather than by its address, which every local process
shares (127.0.0.1), so one local user cannot hold every slot (decision record 0036)."""

from __future__ import annotations

import ipaddress
import socket

__all__ = ["peer_uid"]


def _hex_addr(ip: str, port: int) -> str:
    """``/proc/net/tcp``'s spelling of ``ip:port`` (the address in host byte order words)."""
    a = ipaddress.ip_address(ip)
    b = a.packed
    words = [b[i : i + 4][::-1] for i in range(0, len(b), 4)]  # each 32-bit word, host order
    return "".join(w.hex().upper() for w in words) + f":{port:04X}"


def peer_uid(peer: tuple, local: tuple) -> int | None:
    """The uid owning the socket at ``peer`` connected to ``local`` (both ``(ip, port, ...)``
    as asyncio gives them), or None when the peer is not on this host or cannot be found."""
    try:
        ip = ipaddress.ip_address(peer[0])
    except (ValueError, IndexError, TypeError):
        return None
    if not ip.is_loopback and ip.version == 4:
        return None
    v6 = ":" in str(peer[0])
    want = (_hex_addr(peer[0], int(peer[1])), _hex_addr(local[0], int(local[1])))
    try:
        with open("/proc/net/tcp6" if v6 else "/proc/net/tcp", encoding="ascii") as f:
            next(f, None)
            for line in f:
                cols = line.split()
                if len(cols) > 7 and (cols[1], cols[2]) == want:
                    return int(cols[7])
    except OSError:
        return None
    return None


if __name__ == "__main__":  # a quick check: a loopback connection's own uid
    import os

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    c = socket.create_connection(srv.getsockname())
    s, addr = srv.accept()
    print(peer_uid(addr, s.getsockname()), os.getuid())
