"""A daemon's status reply, checked before ``servowatch status`` or the fleet page read it.

Any monitor identity can answer the status query on its own key (the router lets each
daemon's certificate reply only on ``monitor/<STATION>/<SHARD>/status``), so a reply is input
like any other. :func:`check_reply` checks every field the readers use, one by one: a field
of the wrong type is left out and named in ``bad_fields``, a unit entry the readers cannot
use (its names not of the station's grammar, ``service.names``, a counter missing, a
field of the wrong type) is left out and named in ``bad_units``, and the rest is shown
(issue 50: one field never discards the whole daemon). Only a reply that is no JSON object,
too large, or without a valid ``station``/``shard`` is a marker ``{"malformed": why,
"error": ...}``. The daemon's name is the **key's**, which the router ties to the replier's
certificate: a reply whose ``station``/``shard`` say otherwise is kept but marked
``name_mismatch`` (what it claims), and its units and its ``unmonitored`` list are not
believed (:func:`believed`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

from service.names import is_name, name_problem

__all__ = [
    "check_reply", "name_of_key", "believed", "query_status", "MAX_REPLY_BYTES",
    "MAX_BAD_LISTED", "STATUS_SELECTOR",
]  # fmt: skip

#: every daemon's status queryable
STATUS_SELECTOR = "monitor/*/*/status"

#: a reply larger than this is refused unread [bytes] (a station's status is far smaller)
MAX_REPLY_BYTES = 16 << 20

#: bad units named at most (their total is ``bad_units_total``)
MAX_BAD_LISTED = 20


def name_of_key(key: str) -> str | None:
    """``station/shard`` of ``monitor/<station>/<shard>/status``, None for another key."""
    p = str(key).split("/")
    if len(p) == 4 and p[0] == "monitor" and p[3] == "status" and all(map(is_name, p[1:3])):
        return f"{p[1]}/{p[2]}"
    return None


def _num(v: Any) -> bool:
    return v is None or (
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
    )


def _int(v: Any) -> bool:
    return v is None or (isinstance(v, int) and not isinstance(v, bool))


def _str(v: Any) -> bool:
    return v is None or _text(v)


def _text(v: Any) -> bool:
    """A string, not None (what a list's items must be: ``members: [null]`` is not one)."""
    return isinstance(v, str) and len(v) <= 4096


def _bool(v: Any) -> bool:
    return v is None or isinstance(v, bool)


def _name(v: Any) -> bool:
    return is_name(v)


def _list_of(pred: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda v: v is None or (isinstance(v, list) and all(pred(x) for x in v))


def _dict_of(pred: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda v: (
        v is None
        or (isinstance(v, dict) and all(isinstance(k, str) and pred(x) for k, x in v.items()))
    )


def _alarm(v: Any) -> bool:
    return (
        isinstance(v, dict) and _text(v.get("kind")) and _str(v.get("actuator"))
        and _num(v.get("value"))
    )  # fmt: skip


_TOP: dict[str, Callable[[Any], bool]] = {
    "station": _name, "shard": _name, "state": _str, "model": _str, "pid": _int,
    "uptime_s": _num, "samples": _num, "dropped": _num, "bad": _num, "missed": _num,
    "errors": _num, "log_failure": _str, "feed_failure": _str,
    "latency_ms": _dict_of(_num), "age_ms": _dict_of(_num),
    "silent": _list_of(_text), "alarms": _list_of(_alarm), "unknown": _dict_of(_num),
    "actuators": lambda v: isinstance(v, dict), "group": lambda v: v is None or isinstance(v, dict),
    "foxglove": lambda v: v is None or isinstance(v, dict),
}  # fmt: skip

_UNIT: dict[str, Callable[[Any], bool]] = {
    "aircraft": _name, "actuator": _name, "samples": _num, "dropped": _num, "gaps": _num,
    "bad": lambda v: _num(v) or _dict_of(_num)(v), "missed": _num, "silent": _bool, "commissioned": _bool,
    "baseline_version": _num, "est": _dict_of(_num), "health": _dict_of(lambda x: True),
    "alarms": _list_of(_alarm), "bad_total": _num, "nis_in_band": _num,
    "periods": _num, "last_ratio": _num, "rul": lambda v: v is None or (
        isinstance(v, dict) and _num(v.get("median_h")) and _str(v.get("status"))
        and _num(v.get("median")) and _num(v.get("median_flights"))
        and _num(v.get("median_days")) and _num(v.get("periods"))),
    "c_lk_pooled": lambda v: v is None or _dict_of(_num)(v),
}  # fmt: skip

#: what every unit entry of a daemon's status has (the readers index these)
_UNIT_REQUIRED = ("aircraft", "actuator", "samples", "dropped", "gaps", "bad")

_GROUP: dict[str, Callable[[Any], bool]] = {
    "name": _str, "me": _str, "joined": _bool, "members": _list_of(_text),
    "takeovers": _num, "released": _num, "held_units": _num, "unmonitored_s": _num,
    "unmonitored": _dict_of(lambda u: isinstance(u, dict) and _str(u.get("owner"))),
    "released_units": _list_of(_text), "foreign_tokens": _num, "foreign_outputs": _num,
}  # fmt: skip

_GUARD: dict[str, Callable[[Any], bool]] = {
    "listener": _str, "connections": _num, "max_connections": _num, "buffered_bytes": _num,
    "memory_bound_bytes": _num,
}  # fmt: skip

_FOXGLOVE: dict[str, Callable[[Any], bool]] = {
    "listen": _str, "subscribed_topics": _num, "sent": _num, "dropped": _num,
    "guard": lambda v: v is None or isinstance(v, dict),
}  # fmt: skip


def _keep(obj: dict, spec: dict[str, Callable[[Any], bool]], where: str, bad: list[str]) -> dict:
    """``obj`` without the fields of ``spec`` that fail their check (each named in ``bad``)."""
    out = dict(obj)
    for k, pred in spec.items():
        if k in out and not pred(out[k]):
            del out[k]
            bad.append(f"{where}{k}")
    return out


def _unit_problem(name: str, a: Any) -> str | None:
    """Why a unit entry cannot be shown, or None."""
    if not isinstance(a, dict):
        return f"not a unit entry ({type(a).__name__})"
    missing = [k for k in _UNIT_REQUIRED if k not in a]
    if missing:
        return f"{missing[0]}: missing"
    for k in ("aircraft", "actuator"):
        why = name_problem(a[k])
        if why is not None:
            return f"{k}: {why}"
    for k, pred in _UNIT.items():
        if k in a and not pred(a[k]):
            return f"{k}: wrong type"
    return None


def _sift(st: dict) -> dict:
    """A reply with its bad fields and units left out and named (``bad_fields``,
    ``bad_units``, ``bad_units_total``)."""
    bad: list[str] = []
    out = _keep(st, _TOP, "", bad)
    units, bad_units, n_bad = {}, {}, 0
    for name, a in (out.get("actuators") or {}).items():
        why = _unit_problem(name, a)
        if why is None:
            units[name] = a
            continue
        n_bad += 1
        if len(bad_units) < MAX_BAD_LISTED:
            bad_units[name[:80]] = why[:200]
    if "actuators" in out:
        out["actuators"] = units
    for k, spec in (("group", _GROUP), ("foxglove", _FOXGLOVE)):
        if isinstance(out.get(k), dict):
            out[k] = _keep(out[k], spec, f"{k}.", bad)
    fx = out.get("foxglove")
    if isinstance(fx, dict) and isinstance(fx.get("guard"), dict):
        fx["guard"] = _keep(fx["guard"], _GUARD, "foxglove.guard.", bad)
    if bad:
        out["bad_fields"] = bad
    if n_bad:
        out["bad_units"], out["bad_units_total"] = bad_units, n_bad
    return out


def _why(st: Any) -> str | None:
    """Why a reply cannot be read at all (not an object, no valid name), or None."""
    if not isinstance(st, dict):
        return f"not a JSON object ({type(st).__name__})"
    for k in ("station", "shard"):
        if k not in st:
            return f"{k}: missing"
        if not is_name(st[k]):
            return f"{k}: {name_problem(st[k])}"
    return None


def check_reply(key: str, payload: bytes) -> dict[str, Any]:
    """The status of the reply ``payload`` on ``key`` with its bad fields and units left
    out and named, or a ``malformed`` marker; a name that differs from the key's is marked
    ``name_mismatch``."""
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
                st = _sift(st)
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
