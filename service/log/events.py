"""Events in the log as protobuf rows (issue 54, decision 0043): ``servowatch.Event``, so
the stock protobuf decoder reads every topic of a log.

An event (an alarm raised or cleared, a daemon's silent/resumed/restart/released, a group
event) is the proto3 message::

    message Event {
      double t = 1;       // [s (Unix time)] sample time of the event
      string kind = 2;    // leak, supply, nis, silent, resumed, restart, released, ...
      string state = 3;   // raised or cleared; empty for a service event
      double value = 4;   // the indicator that crossed (a ratio), the gap [s], ...; NaN: none
      double wall = 5;    // [s (Unix time)] the daemon's clock when it logged it; NaN: none
      string detail = 6;  // whatever else the event carries, as JSON; empty: nothing
    }

every field written (a fixed order; strings length-delimited). :func:`encode_event` makes the
bytes from an event dict, :class:`EventCodec` reads them back as the dict the older JSON
events gave (the readers pick it by the schema's name; JSON events of older logs keep
reading as JSON).
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np

from service.log.rows import _fields, _key, _len_field, _varint, source_code_info

__all__ = [
    "EVENT_MESSAGE",
    "EVENT_FIELDS",
    "EventCodec",
    "EventLayout",
    "decode_event",
    "encode_event",
    "event_schema",
]

EVENT_MESSAGE = "servowatch.Event"
_DOUBLE, _STRING = 1, 9  # FieldDescriptorProto.Type
#: the fields of ``servowatch.Event``: (name, number, type)
EVENT_FIELDS: tuple[tuple[str, int, int], ...] = (
    ("t", 1, _DOUBLE),
    ("kind", 2, _STRING),
    ("state", 3, _STRING),
    ("value", 4, _DOUBLE),
    ("wall", 5, _DOUBLE),
    ("detail", 6, _STRING),
)
_NAMES = tuple(f[0] for f in EVENT_FIELDS)
_KNOWN = frozenset(_NAMES)
_D = struct.Struct("<d")


def event_schema() -> bytes:
    """The FileDescriptorSet of ``servowatch.Event`` (each field's unit as its comment)."""
    package, short = EVENT_MESSAGE.rsplit(".", 1)
    fields = b"".join(
        _len_field(
            2,
            _len_field(1, n.encode())
            + _key(3, 0) + _varint(num)
            + _key(4, 0) + _varint(1)  # LABEL_OPTIONAL
            + _key(5, 0) + _varint(ty)
            + _len_field(10, n.encode()),
        )
        for n, num, ty in EVENT_FIELDS
    )  # fmt: skip
    file = (
        _len_field(1, f"{package}/{short}.proto".encode())
        + _len_field(2, package.encode())
        + _len_field(4, _len_field(1, short.encode()) + fields)
        + _len_field(9, source_code_info(_NAMES))
        + _len_field(12, b"proto3")
    )
    return _len_field(1, file)


class EventLayout:
    """What a channel of events is, as a ``RowLayout`` is for rows: ``message`` (the full
    message name) and ``schema`` (its FileDescriptorSet); the live feed advertises it."""

    message = EVENT_MESSAGE

    @property
    def schema(self) -> bytes:
        return event_schema()


def _number(v: Any) -> float | None:
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, int | float | np.integer | np.floating):
        return float(v)
    return None


def encode_event(d: Mapping[str, Any]) -> bytes:
    """``servowatch.Event`` bytes of an event dict (keys t, kind, state, value, wall; a
    non-numeric value and any other key go to ``detail`` as JSON)."""
    from service.jsonutil import jsonable

    extra = {str(k): v for k, v in d.items() if k not in _KNOWN}
    value = _number(d.get("value"))
    if value is None and d.get("value") is not None:
        extra["value"] = d["value"]
    t = _number(d.get("t"))
    wall = _number(d.get("wall"))
    detail = json.dumps(jsonable(extra), separators=(",", ":")) if extra else ""
    out = bytearray()
    out += b"\x09" + _D.pack(math.nan if t is None else t)
    out += _len_field(2, str(d.get("kind") or "").encode())
    out += _len_field(3, str(d.get("state") or "").encode())
    out += b"\x21" + _D.pack(math.nan if value is None else value)
    out += b"\x29" + _D.pack(math.nan if wall is None else wall)
    out += _len_field(6, detail.encode())
    return bytes(out)


def decode_event(data: bytes) -> dict[str, Any]:
    """An event dict from ``servowatch.Event`` bytes (any proto3 encoding of it): t, kind,
    state (None when empty), value and wall (None for NaN), and the keys of ``detail``."""
    v: dict[str, Any] = {"t": 0.0, "kind": "", "state": "", "value": 0.0, "wall": 0.0, "detail": ""}
    for num, wire, x in _fields(data):
        if num in (1, 4, 5) and wire == 1:
            v[_NAMES[num - 1]] = _D.unpack(x)[0]
        elif num in (2, 3, 6) and wire == 2:
            v[_NAMES[num - 1]] = bytes(x).decode("utf-8", "replace")
    out: dict[str, Any] = {
        "t": v["t"],
        "kind": v["kind"],
        "state": v["state"] or None,
        "value": None if v["value"] != v["value"] else v["value"],
        "wall": None if v["wall"] != v["wall"] else v["wall"],
    }
    if v["detail"]:
        try:
            extra = json.loads(v["detail"])
        except ValueError:
            extra = {"detail": v["detail"]}
        if isinstance(extra, dict):
            out.update(extra)
    return out


class EventCodec:
    """The readers' codec of a ``servowatch.Event`` channel (as a ``RowLayout`` is for rows):
    ``decode_one`` gives the field values (strings as text), ``decode_block`` the numeric
    fields as float (strings NaN, like the JSON events' strings)."""

    names = _NAMES

    def as_dict(self, data: bytes) -> dict[str, Any]:
        """The event as :func:`read_log` yields it (:func:`decode_event`)."""
        return decode_event(data)

    def decode_one(self, data: bytes) -> list[Any]:
        d = decode_event(data)
        return [d.get(n) if n != "detail" else _detail_of(d) for n in _NAMES]

    def decode_block(self, buf: np.ndarray, offs: np.ndarray, lens: np.ndarray) -> np.ndarray:
        vals = np.full((len(offs), len(_NAMES)), np.nan)
        raw = buf.tobytes() if hasattr(buf, "tobytes") else bytes(buf)
        for k, (o, n) in enumerate(zip(offs.tolist(), lens.tolist(), strict=True)):
            try:
                d = decode_event(raw[o : o + n])
            except ValueError:
                continue
            for f, name in ((0, "t"), (3, "value"), (4, "wall")):
                x = d.get(name)
                vals[k, f] = x if isinstance(x, float) else np.nan
        return vals


def _detail_of(d: Mapping[str, Any]) -> str | None:
    extra = {k: v for k, v in d.items() if k not in _KNOWN}
    return json.dumps(extra) if extra else None
