"""Protobuf rows of the MCAP log: a fixed-layout message per row, written and read as numpy.

A row of F numbers is the proto3 message ``servowatch.<Leaf>`` whose field k + 1 is
``names[k]``, a ``double`` or, for the integer fields, an ``sfixed64``. Both have wire type 1
(8 bytes little-endian), and the writer always writes every field, zeros included (proto3
encoders omit zeros, but every decoder accepts them). So a message has a constant layout,
``tag, value`` per field (a 1-byte tag for fields 1-15, 2 bytes from 16 on), and a block of
rows is one array copy into a template: no per-row Python on either side.

:class:`RowLayout` holds the layout, its numpy views and the schema that goes in the file
(a serialised ``google.protobuf.FileDescriptorSet``, written and parsed here without the
protobuf package). :func:`layout_of_schema` makes the layout from a Schema record, so any
protobuf file with such a message reads through the fast path; a message that does not match
the layout byte for byte (another writer left zeros out, reordered fields, used varints) is
decoded field by field by :func:`decode_message`.

Non-finite values are kept as they are (NaN: a channel that is absent), unlike the JSON rows
of older logs, which wrote ``null``.
"""

from __future__ import annotations

import functools
import re
import struct
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from service.compat.mcap import MESSAGE_HEADER_BYTES

__all__ = [
    "RowLayout",
    "row_layout",
    "layout_of_schema",
    "message_name",
    "file_descriptor_set",
    "source_code_info",
    "parse_file_descriptor_set",
    "decode_message",
    "PROTO_PACKAGE",
]

PROTO_PACKAGE = "servowatch"
_TYPE_DOUBLE, _TYPE_SFIXED64 = 1, 16  # google.protobuf.FieldDescriptorProto.Type
_LABEL_OPTIONAL = 1
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_MSG_OPCODE = 5
_H = MESSAGE_HEADER_BYTES  # 31


# ----------------------------------------------------------------- protobuf wire helpers
def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _key(number: int, wire: int) -> bytes:
    return _varint(number << 3 | wire)


def _len_field(number: int, payload: bytes) -> bytes:
    return _key(number, 2) + _varint(len(payload)) + payload


def _int_field(number: int, v: int) -> bytes:
    return _key(number, 0) + _varint(v)


def _read_varint(b: bytes, pos: int) -> tuple[int, int]:
    v = shift = 0
    while True:
        if pos >= len(b) or shift > 63:
            raise ValueError("truncated or overlong varint")
        c = b[pos]
        pos += 1
        v |= (c & 0x7F) << shift
        if c < 0x80:
            return v, pos
        shift += 7


def _fields(b: bytes) -> Iterable[tuple[int, int, int | bytes]]:
    """(number, wire type, value) of a protobuf message: varints as int, fixed 64/32-bit as
    their little-endian bytes, length-delimited as bytes."""
    pos, n = 0, len(b)
    while pos < n:
        k, pos = _read_varint(b, pos)
        num, wire = k >> 3, k & 7
        if wire == 0:
            v, pos = _read_varint(b, pos)
        elif wire == 1:
            v, pos = b[pos : pos + 8], pos + 8
        elif wire == 5:
            v, pos = b[pos : pos + 4], pos + 4
        elif wire == 2:
            ln, pos = _read_varint(b, pos)
            v, pos = b[pos : pos + ln], pos + ln
        else:
            raise ValueError(f"unsupported wire type {wire}")
        if pos > n:
            raise ValueError("field overruns the message")
        yield num, wire, v


# ----------------------------------------------------------------- schema
def message_name(leaf: str) -> str:
    """``servowatch.Meas`` for the topic leaf ``meas`` (a proto identifier in CamelCase)."""
    parts = [p for p in re.split(r"[^A-Za-z0-9]+", leaf) if p]
    name = "".join(p[:1].upper() + p[1:] for p in parts) or "Row"
    if not name[0].isalpha():
        name = "Row" + name
    return f"{PROTO_PACKAGE}.{name}"


def file_descriptor_set(message: str, names: tuple[str, ...], ints: tuple[bool, ...]) -> bytes:
    """The serialised FileDescriptorSet of one proto3 message ``package.Name`` whose field
    k + 1 is ``names[k]`` (``sfixed64`` where ``ints[k]``, else ``double``)."""
    package, short = message.rsplit(".", 1)
    fields = b"".join(
        _len_field(
            2,
            _len_field(1, n.encode())
            + _int_field(3, k + 1)
            + _int_field(4, _LABEL_OPTIONAL)
            + _int_field(5, _TYPE_SFIXED64 if i else _TYPE_DOUBLE)
            + _len_field(10, n.encode()),  # json_name: the field name itself
        )
        for k, (n, i) in enumerate(zip(names, ints, strict=True))
    )
    file = (
        _len_field(1, f"{package}/{short}.proto".encode())
        + _len_field(2, package.encode())
        + _len_field(4, _len_field(1, short.encode()) + fields)
        + _len_field(9, source_code_info(names))
        + _len_field(12, b"proto3")
    )
    return _len_field(1, file)


def _packed(values: Iterable[int]) -> bytes:
    return b"".join(_varint(v) for v in values)


def source_code_info(names: Iterable[str], types: Iterable[int] | None = None) -> bytes:
    """A ``SourceCodeInfo`` whose field comments give each field's unit
    (``service.log.units``): the leading comment of field k of the file's first message (path
    4, 0, 2, k), as a ``.proto`` file's ``// [unit]`` comment would be kept."""
    from service.log.units import unit_of

    locs = b""
    for k, n in enumerate(names):
        u = unit_of(n)
        if u is None:
            continue
        loc = (
            _len_field(1, _packed((4, 0, 2, k)))
            + _len_field(2, _packed((k + 1, 2, 40)))  # line, column, end column (synthetic)
            + _len_field(3, f" [{u}]\n".encode())
        )
        locs += _len_field(1, loc)
    return locs


class ProtoField(NamedTuple):
    name: str
    number: int
    type: int  # FieldDescriptorProto.Type
    repeated: bool


def parse_file_descriptor_set(data: bytes) -> dict[str, list[ProtoField]]:
    """Full message name -> its fields (top-level messages of every file of the set)."""
    out: dict[str, list[ProtoField]] = {}
    for num, _w, file in _fields(data):
        if num != 1 or not isinstance(file, bytes):
            continue
        package, msgs = "", []
        for fn, _fw, fv in _fields(file):
            if fn == 2 and isinstance(fv, bytes):
                package = fv.decode()
            elif fn == 4 and isinstance(fv, bytes):
                msgs.append(fv)
        for mb in msgs:
            name, fields = "", []
            for mn, _mw, mv in _fields(mb):
                if mn == 1 and isinstance(mv, bytes):
                    name = mv.decode()
                elif mn == 2 and isinstance(mv, bytes):
                    f = {1: b"", 3: 0, 4: _LABEL_OPTIONAL, 5: 0}
                    for a, _aw, av in _fields(mv):
                        if a in f:
                            f[a] = av
                    fields.append(ProtoField(f[1].decode(), int(f[3]), int(f[5]), f[4] == 3))
            out[f"{package}.{name}" if package else name] = fields
    return out


# ----------------------------------------------------------------- layout
class RowLayout:
    """The fixed layout of a row message (see the module docstring).

    ``names``/``ints``: the fields and which are ``sfixed64``; ``message``: the full message
    name; ``schema``: its FileDescriptorSet; ``size``: bytes of one message; ``numbers``: the
    field numbers (1..F for the layouts this module writes)."""

    def __init__(
        self,
        message: str,
        names: tuple[str, ...],
        ints: tuple[bool, ...],
        numbers: tuple[int, ...] | None = None,
    ):
        self.message = message
        self.names = names
        self.ints = ints
        self.isint = np.array(ints, bool)
        self._int_cols = [k for k, i in enumerate(ints) if i]
        self.numbers = numbers if numbers is not None else tuple(range(1, len(names) + 1))
        tags = [_key(n, 1) for n in self.numbers]
        self.schema = file_descriptor_set(message, names, ints)
        tmpl = bytearray()
        voff = []
        for tag in tags:
            tmpl += tag
            voff.append(len(tmpl))
            tmpl += bytes(8)
        self.size = len(tmpl)
        self.template = np.frombuffer(bytes(tmpl), np.uint8)
        self.value_offsets = np.array(voff, np.int64)
        #: byte positions of the F values (8 bytes each) in a message, as one index array
        self.value_bytes = (self.value_offsets[:, None] + np.arange(8)).reshape(-1)
        self.tag_bytes = np.setdiff1d(np.arange(self.size), self.value_bytes)
        # the values as runs of equal stride (fields 1-15: 9 bytes, 16-2047: 10 bytes)
        runs: list[tuple[int, int, int, int]] = []  # (first field, count, offset, stride)
        k = 0
        while k < len(tags):
            j = k + 1
            while j < len(tags) and len(tags[j]) == len(tags[k]):
                j += 1
            runs.append((k, j - k, int(voff[k]), len(tags[k]) + 8))
            k = j
        self._runs = runs
        rec = bytearray(struct.pack("<BQHIQQ", _MSG_OPCODE, 22 + self.size, 0, 0, 0, 0)) + bytes(
            tmpl
        )
        self.record_size = len(rec)
        self.record_template = np.frombuffer(bytes(rec), np.uint8)
        self._struct = struct.Struct(
            "<"
            + "".join(
                ("B" if len(t) == 1 else "H") + ("q" if i else "d")
                for t, i in zip(tags, ints, strict=True)
            )  # fmt: skip
        )
        self._tags = [t[0] if len(t) == 1 else int.from_bytes(t, "little") for t in tags]

    def __repr__(self) -> str:
        return f"RowLayout({self.message}, {len(self.names)} fields, {self.size} bytes)"

    # ------------------------------------------------------------- writing
    def _words(self, vals: np.ndarray) -> np.ndarray:
        """(n, F) 8-byte words: the doubles, and the integer fields as int64 (truncated)."""
        if not self._int_cols:
            return vals
        w = vals.copy()
        wi = w.view(np.int64)
        for k in self._int_cols:
            c = vals[:, k]
            if len(c) and not (c.min() >= -(2.0**63) and c.max() < 2.0**63):  # NaN fails too
                raise ValueError(f"integer field {self.names[k]!r} must be finite and within int64")
            wi[:, k] = c
        return w

    def _fill(self, out: np.ndarray, base: int, words: np.ndarray) -> None:
        """Write ``words`` (n, F) into the rows of ``out`` (n, stride uint8) at ``base``."""
        n, stride = out.shape
        wb = words.view(np.uint8).reshape(n, -1, 8)
        for k, cnt, off, step in self._runs:
            dst = np.ndarray((n, cnt, 8), np.uint8, out, base + off, (stride, step, 1))
            dst[...] = wb[:, k : k + cnt]

    def encode(self, vals: np.ndarray) -> np.ndarray:
        """The messages of the rows of ``vals`` (n, F) as an (n, size) uint8 array."""
        vals = np.ascontiguousarray(vals, np.float64)
        out = np.empty((len(vals), self.size), np.uint8)
        out[...] = self.template
        if len(vals):
            self._fill(out, 0, np.ascontiguousarray(self._words(vals)))
        return out

    def records(
        self,
        vals: np.ndarray,
        channel_id: int | np.ndarray,
        seqs: np.ndarray,
        log_times: np.ndarray,
    ) -> np.ndarray:
        """MCAP Message records of the rows of ``vals`` (n, F) on channel(s) ``channel_id``
        (one, or one per row) with sequence numbers ``seqs`` and log = publish times
        ``log_times`` [ns] (n,): an (n, record_size) uint8 array."""
        vals = np.ascontiguousarray(vals, np.float64)
        n = len(vals)
        rs = self.record_size
        out = np.empty((n, rs), np.uint8)
        out[...] = self.record_template
        if n:
            np.ndarray((n,), "<u2", out, 9, (rs,))[...] = channel_id
            np.ndarray((n,), "<u4", out, 11, (rs,))[...] = seqs
            np.ndarray((n,), "<u8", out, 15, (rs,))[...] = log_times
            np.ndarray((n,), "<u8", out, 23, (rs,))[...] = log_times
            self._fill(out, _H, np.ascontiguousarray(self._words(vals)))
        return out

    def set_channels(
        self, recs: np.ndarray, channel_id: int | np.ndarray, seqs: np.ndarray
    ) -> None:
        """Set the channel(s) and sequence numbers of records made by :meth:`records`."""
        n, rs = recs.shape
        if n:
            np.ndarray((n,), "<u2", recs, 9, (rs,))[...] = channel_id
            np.ndarray((n,), "<u4", recs, 11, (rs,))[...] = seqs

    # ------------------------------------------------------------- reading
    def decode_block(
        self, buf: np.ndarray, offs: np.ndarray, lens: np.ndarray
    ) -> np.ndarray | None:
        """The rows of the messages at ``buf[offs[k] : offs[k] + lens[k]]`` as (n, F)
        float64 (integer fields converted), or None when some message is not in this layout
        byte for byte (the caller then decodes them one by one)."""
        n = len(offs)
        if n == 0:
            return np.empty((0, len(self.names)))
        if not (lens == self.size).all():
            return None
        if self.tag_bytes.size:
            tb = buf[offs[:, None] + self.tag_bytes]
            if not (tb == self.template[self.tag_bytes]).all():
                return None
        raw = buf[offs[:, None] + self.value_bytes]  # (n, 8F), contiguous
        vals = raw.view("<f8").reshape(n, len(self.names)).astype(np.float64, copy=False)
        if self.isint.any():
            vals = vals.copy()
            vals[:, self.isint] = raw.view("<i8").reshape(n, -1)[:, self.isint]
        return vals

    def decode_one(self, data: bytes) -> list[float | int]:
        """One message as the field values in ``names`` order (see :func:`decode_message`)."""
        if len(data) == self.size:
            v = self._struct.unpack(data)
            if list(v[0::2]) == self._tags:
                return list(v[1::2])
        return decode_message(self, data)


@functools.lru_cache(maxsize=256)
def row_layout(leaf: str, names: tuple[str, ...], ints: frozenset[str] = frozenset()) -> RowLayout:
    """The layout the writer gives rows of ``names`` on a topic ending in ``leaf``; names
    must be distinct proto identifiers."""
    for n in names:
        if not _IDENT.match(n):
            raise ValueError(
                f"field name {n!r} is not a protobuf identifier ([A-Za-z_][A-Za-z0-9_]*)"
            )
    if len(set(names)) != len(names):
        raise ValueError(f"duplicate field names in {names}")
    return RowLayout(message_name(leaf), names, tuple(n in ints for n in names))


_SIGNED = {3, 5, 14}  # int64, int32, enum: two's complement varints
_ZIGZAG = {17, 18}  # sint32, sint64


def decode_message(layout: RowLayout, data: bytes) -> list[float | int]:
    """Any protobuf encoding of a message of ``layout``'s fields (omitted fields are zero,
    as proto3 defines; unknown fields ignored; the last occurrence wins), as values in
    ``names`` order: ints for integer fields, floats else. Raises ValueError on bad wire
    data."""
    types = getattr(layout, "types", None) or tuple(
        _TYPE_SFIXED64 if i else _TYPE_DOUBLE for i in layout.ints
    )
    pos = {num: k for k, num in enumerate(layout.numbers)}
    out: list[float | int] = [0 if i else 0.0 for i in layout.ints]
    for num, wire, v in _fields(data):
        k = pos.get(num)
        if k is None:
            continue
        ty = types[k]
        if wire == 1:
            x = struct.unpack("<d" if ty == 1 else "<q" if ty == 16 else "<Q", v)[0]
        elif wire == 5:
            x = struct.unpack("<f" if ty == 2 else "<i" if ty == 15 else "<I", v)[0]
        elif wire == 0:
            x = int(v)  # type: ignore[arg-type]
            if ty in _ZIGZAG:
                x = (x >> 1) ^ -(x & 1)
            elif ty in _SIGNED and x >= 1 << 63:
                x -= 1 << 64
            elif ty == 8:
                x = int(bool(x))
        else:
            continue
        out[k] = int(x) if layout.ints[k] else float(x)
    return out


_NUMERIC = {1, 2, 3, 4, 5, 6, 7, 8, 13, 14, 15, 16, 17, 18}
_INTEGER = _NUMERIC - {1, 2}


def layout_of_schema(name: str, encoding: str, data: bytes) -> RowLayout | None:
    """The layout of the message ``name`` of a protobuf Schema record whose fields are all
    numeric scalars (None otherwise: strings, nested messages, repeated fields or a schema
    that is not protobuf). Its fast path matches the messages this module writes."""
    if encoding != "protobuf":
        return None
    try:
        fields = parse_file_descriptor_set(data).get(name)
    except (ValueError, UnicodeDecodeError, IndexError):
        return None
    if not fields or any(f.repeated or f.type not in _NUMERIC for f in fields):
        return None
    names = tuple(f.name for f in fields)
    if len(set(names)) != len(names):
        return None
    lay = RowLayout(
        name,
        names,
        tuple(f.type in _INTEGER for f in fields),
        tuple(f.number for f in fields),
    )
    lay.types = tuple(f.type for f in fields)  # type: ignore[attr-defined]
    if any(t not in (_TYPE_DOUBLE, _TYPE_SFIXED64) for t in lay.types):  # type: ignore[attr-defined]
        lay.size = -1  # no fixed layout: every message goes through decode_message
    return lay
