"""A daemon's status reply, checked before ``servowatch status`` or the fleet page read it.

Any monitor identity can answer the status query on its own key (the router lets each
daemon's certificate reply only on ``monitor/<STATION>/<SHARD>/status``), so a reply is input
like any other: :func:`check_reply` returns the reply's JSON when every field the readers use
has its type, else a marker ``{"malformed": why, "error": ...}`` naming the first bad
field; the readers count and show those as such. The daemon's name is the **key's**, which
the router ties to the replier's certificate: a reply whose ``station``/``shard`` say
otherwise is kept but marked ``name_mismatch`` (what it claims), and its units and its
``unmonitored`` list are not believed (:func:`believed`).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from typing import Any

__all__ = [
    "check_reply", "name_of_key", "believed", "query_status", "MAX_REPLY_BYTES",
    "STATUS_SELECTOR",
]  # fmt: skip

#: every daemon's status queryable
STATUS_SELECTOR = "monitor/*/*/status"

#: a reply larger than this is refused unread [bytes] (a station's status is far smaller)
MAX_REPLY_BYTES = 16 << 20

_NAME = re.compile(r"^[A-Za-z0-9_.\-]{1,128}$")


def name_of_key(key: str) -> str | None:
    """``station/shard`` of ``monitor/<station>/<shard>/status``, None for another key."""
    p = str(key).split("/")
    if len(p) == 4 and p[0] == "monitor" and p[3] == "status" and all(map(_NAME.match, p[1:3])):
        return f"{p[1]}/{p[2]}"
    return None


def _num(v: Any) -> bool:
    return v is None or (
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
    )


def _int(v: Any) -> bool:
    return v is None or (isinstance(v, int) and not isinstance(v, bool))


def _str(v: Any) -> bool:
    return v is None or (isinstance(v, str) and len(v) <= 4096)


def _bool(v: Any) -> bool:
    return v is None or isinstance(v, bool)


def _name(v: Any) -> bool:
    return isinstance(v, str) and bool(_NAME.match(v))


def _list_of(pred: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda v: v is None or (isinstance(v, list) and all(pred(x) for x in v))


def _dict_of(pred: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda v: (
        v is None
        or (isinstance(v, dict) and all(isinstance(k, str) and pred(x) for k, x in v.items()))
    )


def _alarm(v: Any) -> bool:
    return isinstance(v, dict) and _str(v.get("kind")) and _str(v.get("actuator"))


_TOP: dict[str, Callable[[Any], bool]] = {
    "station": _name, "shard": _name, "state": _str, "model": _str, "pid": _int,
    "uptime_s": _num, "samples": _num, "dropped": _num, "bad": _num, "missed": _num,
    "errors": _num, "log_failure": _str, "feed_failure": _str,
    "latency_ms": _dict_of(_num), "age_ms": _dict_of(_num),
    "silent": _list_of(_str), "alarms": _list_of(_alarm), "unknown": _dict_of(_num),
    "actuators": lambda v: isinstance(v, dict), "group": lambda v: v is None or isinstance(v, dict),
    "foxglove": lambda v: v is None or isinstance(v, dict),
}  # fmt: skip

_UNIT: dict[str, Callable[[Any], bool]] = {
    "aircraft": _name, "actuator": _name, "samples": _num, "dropped": _num, "gaps": _num,
    "bad": lambda v: _num(v) or _dict_of(_num)(v), "missed": _num, "silent": _bool, "commissioned": _bool,
    "baseline_version": _num, "est": _dict_of(_num), "health": _dict_of(lambda x: True),
    "alarms": _list_of(lambda x: isinstance(x, dict) and _str(x.get("kind"))),
    "periods": _num, "rul": lambda v: v is None or (isinstance(v, dict) and _num(v.get("median_h"))),
}  # fmt: skip

#: what every unit entry of a daemon's status has (the readers index these)
_UNIT_REQUIRED = ("aircraft", "actuator", "samples", "dropped", "gaps", "bad")

_GROUP: dict[str, Callable[[Any], bool]] = {
    "name": _str, "me": _str, "joined": _bool, "members": _list_of(_str),
    "takeovers": _num, "released": _num, "held_units": _num, "unmonitored_s": _num,
    "unmonitored": _dict_of(lambda u: isinstance(u, dict) and _str(u.get("owner"))),
    "released_units": _list_of(_str),
}  # fmt: skip

_GUARD: dict[str, Callable[[Any], bool]] = {
    "listener": _str, "connections": _num, "max_connections": _num, "buffered_bytes": _num,
    "memory_bound_bytes": _num,
}  # fmt: skip

_FOXGLOVE: dict[str, Callable[[Any], bool]] = {
    "listen": _str, "subscribed_topics": _num, "sent": _num, "dropped": _num,
    "guard": lambda v: v is None or (isinstance(v, dict) and _check(v, _GUARD, "") is None),
}  # fmt: skip


def _check(obj: dict, spec: dict[str, Callable[[Any], bool]], where: str) -> str | None:
    for k, pred in spec.items():
        if k in obj and not pred(obj[k]):
            return f"{where}{k}"
    return None


def _why(st: Any) -> str | None:
    """The first field of a reply the readers cannot use, or None."""
    if not isinstance(st, dict):
        return f"not a JSON object ({type(st).__name__})"
    for k in ("station", "shard"):
        if k not in st:
            return f"{k}: missing"
    bad = _check(st, _TOP, "")
    if bad:
        return f"{bad}: wrong type"
    for name, a in (st.get("actuators") or {}).items():
        if not isinstance(a, dict) or not all(k in a for k in _UNIT_REQUIRED):
            return f"actuators.{name[:60]!r}: not a unit entry"
        bad = _check(a, _UNIT, f"actuators.{name[:60]!r}.")
        if bad:
            return f"{bad}: wrong type"
    if st.get("group") is not None:
        bad = _check(st["group"], _GROUP, "group.")
        if bad:
            return f"{bad}: wrong type"
    if st.get("foxglove") is not None:
        bad = _check(st["foxglove"], _FOXGLOVE, "foxglove.")
        if bad:
            return f"{bad}: wrong type"
    return None


def check_reply(key: str, payload: bytes) -> dict[str, Any]:
    """The status of the reply ``payload`` on ``key``, or a ``malformed`` marker; a name
    that differs from the key's is marked ``name_mismatch``."""
    if len(payload) > MAX_REPLY_BYTES:
        why = f"larger than {MAX_REPLY_BYTES} bytes"
    else:
        try:
            st = json.loads(payload)
        except (ValueError, RecursionError) as e:
            why = f"not JSON ({type(e).__name__})"
        else:
            why = _why(st)
            if why is None:
                own = name_of_key(key)
                claimed = f"{st['station']}/{st['shard']}"
                if own is not None and claimed != own:
                    st = {**st, "name_mismatch": claimed}
                return st
    return {"malformed": why, "error": f"malformed reply: {why}"}


def believed(key: str, st: dict[str, Any]) -> bool:
    """Whether the readers take a reply's units and ``unmonitored`` list: a well-formed
    reply whose name is its key's."""
    return (
        isinstance(st, dict)
        and "malformed" not in st
        and "name_mismatch" not in st
        and ("error" not in st)
    )


def query_status(session, timeout: float = 2.0, selector: str = STATUS_SELECTOR) -> dict:
    """``{key: status dict}`` of every daemon that answered within ``timeout``; each reply
    checked (``service.edge.status.check_reply``): a malformed one is a ``malformed``
    marker, one whose name is not its key's is marked ``name_mismatch``."""
    out: dict[str, dict] = {}
    for reply in session.get(selector, timeout=timeout):
        if reply.ok is None:
            continue
        key = str(reply.ok.key_expr)
        out[key] = check_reply(key, reply.ok.payload.to_bytes())
    return out
