"""A TCP port only the holder of a key can reach: the kernel's TCP-MD5 signature option
(RFC 2385, Linux ``TCP_MD5SIG``), used to keep the Foxglove SDK's private port to its guard
(decision record 0036). A listening socket given a key for a peer address drops every
segment from that address that is not signed with it, so a local process of any user (it
cannot read this process's memory) cannot open a connection: its SYN is never answered.

The SDK's server is Rust code that opens its own socket; :func:`key_listener` finds it among
this process's descriptors by its address and sets the key on a duplicate of it (the
descriptors share the socket). :func:`keyed_socket` makes the guard's client socket, which
signs its segments with the same key.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct

__all__ = ["TCP_MD5SIG", "TCP_MD5SIG_EXT", "new_key", "key_listener", "keyed_socket"]

TCP_MD5SIG = getattr(socket, "TCP_MD5SIG", 14)  # linux/tcp.h
TCP_MD5SIG_EXT = getattr(socket, "TCP_MD5SIG_EXT", 32)  # linux/tcp.h, Linux 4.13
_FLAG_PREFIX = 1  # TCP_MD5SIG_FLAG_PREFIX: the key covers tcpm_prefixlen bits of the address
_KEY_BYTES = 32  # at most TCP_MD5SIG_MAXKEYLEN (80)


def new_key() -> bytes:
    """A fresh random key."""
    return os.urandom(_KEY_BYTES)


def _md5sig(key: bytes, peer: str, prefix: int | None = None) -> bytes:
    """``struct tcp_md5sig`` for the IPv4 ``peer`` (with ``prefix``: the peers of
    ``peer/prefix``): sockaddr_storage (128 bytes), flags, prefix length, key length,
    ifindex, the key (80 bytes)."""
    sa = struct.pack("=HH4s", socket.AF_INET, 0, socket.inet_aton(peer)).ljust(128, b"\0")
    flags = 0 if prefix is None else _FLAG_PREFIX
    return sa + struct.pack("=BBHI", flags, prefix or 0, len(key), 0) + key.ljust(80, b"\0")


def key_listener(port: int, key: bytes, host: str = "127.0.0.1") -> bool:
    """Set ``key`` for every IPv4 peer (``0.0.0.0/0``: a process that binds 127.0.0.2, or
    any other source address, needs it too) on this process's listening TCP socket bound to
    ``host:port``; False when there is none or the kernel refuses (no ``TCP_MD5SIG_EXT``)."""
    done = False
    for name in os.listdir("/proc/self/fd"):
        try:
            if not os.readlink(f"/proc/self/fd/{name}").startswith("socket:"):
                continue
            dup = os.dup(int(name))
        except (OSError, ValueError):
            continue
        try:
            s = socket.socket(fileno=dup)
        except OSError:
            os.close(dup)
            continue
        with s, contextlib.suppress(OSError):
            if (
                s.family == socket.AF_INET
                and s.type == socket.SOCK_STREAM
                and s.getsockname() == (host, port)
                and s.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN)
            ):
                s.setsockopt(socket.IPPROTO_TCP, TCP_MD5SIG_EXT, _md5sig(key, "0.0.0.0", 0))
                done = True
    return done


def keyed_socket(key: bytes, peer: str = "127.0.0.1") -> socket.socket:
    """A non-blocking IPv4 TCP socket that signs its segments to ``peer`` with ``key``."""
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        s.setsockopt(socket.IPPROTO_TCP, TCP_MD5SIG, _md5sig(key, peer))
        s.setblocking(False)
    except OSError:
        s.close()
        raise
    return s
