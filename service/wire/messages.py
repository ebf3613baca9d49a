"""Wire messages of the monitoring service: sensor samples in, fault commands, key expressions.

A measurement message carries 1..N consecutive samples of ONE actuator; the key names the
actuator (``fleet/{aircraft}/{actuator}/meas``), so the payload is actuator-agnostic.
Two encodings are accepted and auto-detected on receipt (docs/messages.md):

* ``bin`` (default, chosen by measurement in ``bench/codec.py``): an 8-byte header
  ``b"SW"``, version ``1``, kind ``ord("M")``, sample count ``n`` (uint32 little-endian),
  then ``n`` packed little-endian records of 73 bytes:
  ``seq`` int64, ``t`` float64, ``mask`` uint8 (bit k set = channel k present, channels in
  the order of :data:`CHANNELS`), 7 x float64 channel values (ignored where absent).
* ``json``: ``{"v": 1, "samples": [{"seq": 0, "t": 0.001, "x_cmd": 0.02, "p1": null, ...}]}``
  or one bare sample object. Absent keys and ``null`` mean a missing channel.

:class:`MeasSample` (pydantic) is the documented schema. :func:`decode_meas` validates with a
hand-written check that applies the same rules (tests hold the two to the same verdicts),
because pydantic per sample costs more than a 20 kHz aggregate stream can afford.
"""

from __future__ import annotations

import functools
import json
import math
import struct
from collections.abc import Mapping, Sequence
from typing import Any, Literal, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from service.compat.pydantic import construct_unchecked
from service.names import name_problem
from service.wire.format import (  # the wire's constants (measured channels: SI, wire order)
    BATCH_ACCEPTED,
    BATCH_DECODED,
    BATCH_UNDECODED,
    CHANNELS,
    REC_BYTES,
)

__all__ = [
    "CHANNELS",
    "REC_BYTES",
    "BATCH_ACCEPTED",
    "BATCH_DECODED",
    "BATCH_UNDECODED",
    "DEFAULT_FORMAT",
    "MAX_BYTES",
    "MessageError",
    "MeasSample",
    "FaultCommand",
    "FaultAck",
    "encode_meas",
    "decode_meas",
    "decode_meas_dicts",
    "decode_meas_arrays",
    "MeasArrays",
    "encode_json",
    "decode_json",
    "OUTPUT_LEAVES",
    "output_layout",
    "output_encoding",
    "output_schema",
    "encode_outputs",
    "encode_output_rows",
    "decode_output",
    "KEY_MEAS",
    "KEY_EST",
    "KEY_RES",
    "KEY_HEALTH",
    "KEY_FAULT",
    "KEY_ALIVE",
    "KEY_VIRTUAL",
    "KEY_STATUS",
    "key",
    "parse_meas_key",
    "parse_fleet_key",
    "mcap_topic",
]

DEFAULT_FORMAT: Literal["json", "bin"] = "bin"
MAX_BYTES = 65536
MAX_SAMPLES = 4096

KEY_MEAS = "fleet/{aircraft}/{actuator}/meas"
KEY_EST = "fleet/{aircraft}/{actuator}/est"
KEY_RES = "fleet/{aircraft}/{actuator}/res"
KEY_HEALTH = "fleet/{aircraft}/{actuator}/health"
KEY_FAULT = "fleet/{aircraft}/{actuator}/@fault"
KEY_ALIVE = "fleet/{aircraft}/{actuator}/alive"
#: liveliness token held by a virtual actuator only: fault commands go to no other key
KEY_VIRTUAL = "fleet/{aircraft}/{actuator}/@virtual"
KEY_STATUS = "monitor/{station}/{shard}/status"


_MAGIC = b"SW"
_VERSION = 1
_KIND_MEAS = ord("M")
_HEADER = struct.Struct("<2sBBI")
_REC = struct.Struct("<qdB" + "d" * len(CHANNELS))  # REC_BYTES
_ALLOWED_JSON_KEYS = frozenset(("seq", "t", *CHANNELS))
#: the largest sequence number (int64: the binary format's field, the arrays' dtype)
SEQ_MAX = 2**63 - 1


class MessageError(ValueError):
    """A message that cannot be decoded or does not validate; ``field`` names the culprit."""

    def __init__(self, message: str, field: str | None = None):
        super().__init__(f"{field}: {message}" if field else message)
        self.field = field


# --------------------------------------------------------------------------- schema


class MeasSample(BaseModel):
    """One sensor sample of one actuator (the documented schema of a ``meas`` message).

    ``seq`` counts samples per actuator from the publisher (>= 0, strictly increasing within a
    message); ``t`` is the sample time [s]. Channels are ``None`` when not measured.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False, strict=False)

    seq: int = Field(ge=0, le=SEQ_MAX, description="sample counter of the publisher")
    t: float = Field(description="sample time [s]")
    x_cmd: float | None = Field(None, description="position command [m]")
    i: float | None = Field(None, description="servovalve current [A]")
    x_s: float | None = Field(None, description="spool position [m]")
    x_j: float | None = Field(None, description="jack position [m]")
    p1: float | None = Field(None, description="chamber 1 pressure, absolute [Pa]")
    p2: float | None = Field(None, description="chamber 2 pressure, absolute [Pa]")
    p_sr: float | None = Field(None, description="supply minus return pressure [Pa]")

    @field_validator("seq", mode="before")
    @classmethod
    def _no_bool_seq(cls, v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ValueError("must be an integer")
        return v

    @field_validator("t", *CHANNELS, mode="before")
    @classmethod
    def _no_bool(cls, v: Any) -> Any:
        if isinstance(v, bool) or (v is not None and not isinstance(v, int | float)):
            raise ValueError("must be a number")
        return v

    def as_input(self) -> dict[str, float | None]:
        """The monitor's input mapping: ``t`` and the channels (``seq`` dropped)."""
        return {"t": self.t, **{c: getattr(self, c) for c in CHANNELS}}


def _make(seq: int, t: float, vals: Sequence[float | None]) -> MeasSample:
    """A MeasSample from already-validated values, bypassing validation (what
    ``model_construct`` does, at about half its cost: ``research/pydantic_construct.py``)."""
    d: dict[str, Any] = {"seq": seq, "t": t}
    d.update(zip(CHANNELS, vals, strict=True))
    return construct_unchecked(MeasSample, d)


class FaultCommand(BaseModel):
    """A fault to inject into a virtual actuator (``fleet/{ac}/{act}/@fault``).

    ``leak``: leakage coefficient c_lk [m^3/s/Pa]; ``supply``: P_SR [Pa]; ``sensor_bias``:
    bias added to ``channel`` (SI unit of the channel); ``dropout``: ``channel`` reads None;
    ``clear``: remove every fault (or the one named by ``channel``). ``ramp_s`` > 0 ramps the
    change; ``duration_s`` ends it after that long.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: Literal["leak", "supply", "sensor_bias", "dropout", "clear"]
    value: float | None = None
    ramp_s: float = Field(0.0, ge=0)
    channel: str | None = None
    duration_s: float | None = Field(None, gt=0)


class FaultAck(BaseModel):
    """Answer of a virtual actuator to a :class:`FaultCommand`."""

    model_config = ConfigDict(extra="forbid")

    ok: bool
    message: str
    active: list[dict] = Field(default_factory=list)


# --------------------------------------------------------------------------- encoding


def encode_meas(
    samples: Sequence[MeasSample | Mapping[str, Any]], fmt: Literal["json", "bin"] = DEFAULT_FORMAT
) -> bytes:
    """Encode 1..N consecutive samples of one actuator (``bin`` or ``json``).

    Samples may be :class:`MeasSample` or mappings with ``seq``, ``t`` and channel keys.
    Values are not validated here (the receiver validates); ``n`` must be >= 1.
    """
    n = len(samples)
    if n == 0:
        raise MessageError("at least one sample is required", "samples")
    rows = [s.model_dump() if isinstance(s, MeasSample) else s for s in samples]
    if fmt == "json":
        out = [{k: v for k, v in r.items() if v is not None} for r in rows]
        return json.dumps({"v": 1, "samples": out}, separators=(",", ":")).encode()
    if fmt != "bin":
        raise ValueError(f"unknown format {fmt!r}")
    if n > MAX_SAMPLES:
        raise MessageError(f"{n} samples exceed {MAX_SAMPLES} per message", "samples")
    parts = [_HEADER.pack(_MAGIC, _VERSION, _KIND_MEAS, n)]
    for j, r in enumerate(rows):
        mask = 0
        vals = []
        for k, c in enumerate(CHANNELS):
            v = r.get(c)
            if v is None:
                vals.append(math.nan)
            else:
                mask |= 1 << k
                vals.append(v)
        try:
            parts.append(_REC.pack(r["seq"], r["t"], mask, *vals))
        except KeyError as e:
            raise MessageError("required", f"samples[{j}].{e.args[0]}") from None
        except struct.error as e:
            raise MessageError(f"cannot pack: {e}", f"samples[{j}]") from None
    return b"".join(parts)


def _check_size(payload: bytes, max_bytes: int) -> None:
    if not isinstance(payload, bytes | bytearray | memoryview):
        raise MessageError(f"expected bytes, got {type(payload).__name__}", "payload")
    if len(payload) > max_bytes:
        raise MessageError(f"{len(payload)} bytes exceeds max_bytes={max_bytes}", "payload")
    if len(payload) == 0:
        raise MessageError("empty message", "payload")


def _bin_count(payload: bytes) -> int:
    """Sample count n of a binary message whose header and length are valid (else raises)."""
    if len(payload) < _HEADER.size:
        raise MessageError("shorter than the 8-byte header", "header")
    _magic, version, kind, n = _HEADER.unpack_from(payload)
    if version != _VERSION:
        raise MessageError(f"unsupported version {version}", "version")
    if kind != _KIND_MEAS:
        raise MessageError(f"unsupported kind {kind}", "kind")
    if n < 1 or n > MAX_SAMPLES:
        raise MessageError(f"sample count {n} outside 1..{MAX_SAMPLES}", "n")
    want = _HEADER.size + n * _REC.size
    if len(payload) != want:
        raise MessageError(f"{len(payload)} bytes, expected {want} for n={n}", "n")
    return n


def _bin_rows(payload: bytes) -> list[tuple[int, float, list[float | None]]]:
    _bin_count(payload)
    out: list[tuple[int, float, list[float | None]]] = []
    isfinite = math.isfinite
    nch = len(CHANNELS)
    full = (1 << nch) - 1
    ps, pt = -1, -math.inf
    for k, rec in enumerate(_REC.iter_unpack(memoryview(payload)[_HEADER.size :])):
        seq, t, m = rec[0], rec[1], rec[2]
        vals: list[float | None] = list(rec[3:])
        if seq < 0:
            raise MessageError(f"must be >= 0, got {seq}", f"samples[{k}].seq")
        if not isfinite(t):
            raise MessageError(f"must be finite, got {t}", f"samples[{k}].t")
        if m != full:
            if m > full:
                raise MessageError(f"unknown bits in mask {m:#x}", f"samples[{k}].mask")
            for b in range(nch):
                if not (m >> b) & 1:
                    vals[b] = None
        for b, v in enumerate(vals):
            if v is not None and not isfinite(v):
                raise MessageError(f"must be finite, got {v}", f"samples[{k}].{CHANNELS[b]}")
        if k:
            if seq <= ps:
                raise MessageError(f"not increasing ({ps} then {seq})", f"samples[{k}].seq")
            if t <= pt:
                raise MessageError(f"not increasing ({pt} then {t})", f"samples[{k}].t")
        ps, pt = seq, t
        out.append((seq, t, vals))
    return out


def _num(v: Any, field: str, *, optional: bool) -> float | None:
    if v is None:
        if optional:
            return None
        raise MessageError("required", field)
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise MessageError(f"must be a number, got {type(v).__name__}", field)
    f = float(v)
    if not math.isfinite(f):
        raise MessageError(f"must be finite, got {v!r}", field)
    return f


def _json_rows(payload: bytes) -> list[tuple[int, float, list[float | None]]]:
    try:
        obj = json.loads(payload)
    except (UnicodeDecodeError, ValueError) as e:
        raise MessageError(f"malformed JSON: {e}", "payload") from None
    if not isinstance(obj, dict):
        raise MessageError("must be a JSON object", "payload")
    if "samples" in obj:
        extra = set(obj) - {"v", "samples"}
        if extra:
            raise MessageError("unknown key", sorted(extra)[0])
        if obj.get("v", 1) != 1:
            raise MessageError(f"unsupported version {obj.get('v')!r}", "v")
        items = obj["samples"]
        if not isinstance(items, list):
            raise MessageError("must be a list", "samples")
        prefix = "samples"
    else:
        items = [obj]
        prefix = None
    if not 1 <= len(items) <= MAX_SAMPLES:
        raise MessageError(f"sample count {len(items)} outside 1..{MAX_SAMPLES}", "samples")
    rows = []
    for k, s in enumerate(items):
        where = f"{prefix}[{k}]." if prefix else ""
        if not isinstance(s, dict):
            raise MessageError("must be an object", f"{prefix}[{k}]" if prefix else "payload")
        if not _ALLOWED_JSON_KEYS.issuperset(s):
            bad = sorted(set(s) - _ALLOWED_JSON_KEYS)[0]
            raise MessageError("unknown key", f"{where}{bad}")
        seq = s.get("seq")
        if seq is None:
            raise MessageError("required", f"{where}seq")
        if isinstance(seq, bool) or not isinstance(seq, int):
            raise MessageError(f"must be an integer, got {seq!r}", f"{where}seq")
        if seq < 0:
            raise MessageError(f"must be >= 0, got {seq}", f"{where}seq")
        if seq > SEQ_MAX:  # the binary format's int64, the arrays' dtype (issue 50)
            raise MessageError(f"must be <= {SEQ_MAX}, got {str(seq)[:40]}", f"{where}seq")
        t = _num(s.get("t"), f"{where}t", optional=False)
        vals = [_num(s.get(c), f"{where}{c}", optional=True) for c in CHANNELS]
        if rows:
            ps, pt, _ = rows[-1]
            if seq <= ps:
                raise MessageError(f"not increasing ({ps} then {seq})", f"{where}seq")
            if t <= pt:
                raise MessageError(f"not increasing ({pt} then {t})", f"{where}t")
        rows.append((seq, t, vals))
    return rows


def _rows(payload: bytes, max_bytes: int) -> list[tuple[int, float, list[float | None]]]:
    _check_size(payload, max_bytes)
    payload = bytes(payload)
    if payload[:2] == _MAGIC:
        return _bin_rows(payload)
    head = payload.lstrip()[:1]
    if head in (b"{", b"["):
        return _json_rows(payload)
    raise MessageError("neither the binary magic b'SW' nor a JSON object", "payload")


def decode_meas(payload: bytes, max_bytes: int = MAX_BYTES) -> list[MeasSample]:
    """Decode and validate a measurement message of either format (auto-detected).

    Rules (same as :class:`MeasSample` plus batch rules): size <= ``max_bytes``; 1..4096
    samples; ``seq`` integer >= 0; ``t`` and present channels finite numbers; ``seq`` and ``t``
    strictly increasing within the message; no unknown keys. Raises :class:`MessageError`
    naming the field (``samples[3].p1``, ``payload``, ``n``, ...).
    """
    return [_make(seq, t, vals) for seq, t, vals in _rows(payload, max_bytes)]


def decode_meas_dicts(payload: bytes, max_bytes: int = MAX_BYTES) -> list[dict[str, Any]]:
    """As :func:`decode_meas`, but plain dicts ``{seq, t, x_cmd, ..., p_sr}`` (faster)."""
    out = []
    for seq, t, vals in _rows(payload, max_bytes):
        d = dict(zip(CHANNELS, vals, strict=True))
        d["seq"] = seq
        d["t"] = t
        out.append(d)
    return out


class MeasArrays(NamedTuple):
    """The samples of one measurement message as arrays: ``seq`` (n,) int64, ``t`` (n,) [s],
    ``values`` (n, 7) in :data:`CHANNELS` order (SI), NaN where a channel is absent."""

    seq: np.ndarray
    t: np.ndarray
    values: np.ndarray


def _bin_arrays(payload: bytes) -> MeasArrays:
    """``_bin_rows`` compiled (``service.wire.kernels.intake_batch`` on one message): same
    checks; on a violation the scalar decoder raises the same error naming the first
    offending field."""
    n = _bin_count(payload)
    out = MeasArrays(np.empty(n, np.int64), np.empty(n), np.empty((n, len(CHANNELS))))
    from service.wire.kernels import decode_message  # numba: loaded on the first decode

    if decode_message(np.frombuffer(payload, np.uint8), *out) != n:
        _bin_rows(payload)  # raises the error of the first offending field
        raise MessageError("invalid record", "samples")  # pragma: no cover - unreachable
    return out


def decode_into(
    payloads: Sequence[bytes],
    seq: np.ndarray,
    t: np.ndarray,
    values: np.ndarray,
    max_bytes: int = MAX_BYTES,
    slot: np.ndarray | None = None,
    state: tuple | None = None,
    clock: tuple[float, float, float] = (2.0, 0.5, math.inf),
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Decode binary messages into ``seq`` (N,), ``t`` (N,), ``values`` (N, 7) (N at least
    the samples of every message) with the compiled decoder: ``(start, count, status)`` per
    message (``service.wire.kernels``: a message that does not decode has ``count`` 0 and
    status ``BATCH_UNDECODED``, and the Python decoder says why), or None when a payload is not
    ``bytes``. ``slot``, ``state`` and ``clock`` (factor, tol_s, t_future): the intake's
    acceptance of the plain messages (``service.daemon.intake.Intake.take``)."""
    from service.wire import kernels as wk  # numba: loaded on the first decode

    k = len(payloads)
    for p in payloads:
        if type(p) is not bytes:
            return None
    buf = np.frombuffer(b"".join(payloads), np.uint8)
    lens = np.fromiter(map(len, payloads), np.int64, k)
    offs = np.zeros(k, np.int64)
    np.cumsum(lens[:-1], out=offs[1:])
    start, count, status = np.empty(k, np.int64), np.empty(k, np.int64), np.empty(k, np.int64)
    if slot is None:
        slot = np.full(k, -1, np.int64)
    if state is None:
        state = _NO_STATE
    wk.intake_batch(
        buf, offs, lens, max_bytes, slot, seq, t, values, start, count, status, *state, *clock
    )
    return start, count, status


_NO_STATE = (
    np.zeros(0, np.bool_), np.zeros(0, np.bool_), np.zeros(0, np.int64), np.zeros(0, np.int64),
    np.zeros(0), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
)  # fmt: skip


def decode_meas_arrays(payload: bytes, max_bytes: int = MAX_BYTES) -> MeasArrays:
    """As :func:`decode_meas` (same rules, same errors), as arrays: the binary form is
    validated and unpacked with numpy, without a Python object per sample."""
    _check_size(payload, max_bytes)
    payload = bytes(payload)
    if payload[:2] == _MAGIC:
        return _bin_arrays(payload)
    rows = _rows(payload, max_bytes)
    seq = np.array([r[0] for r in rows], np.int64)
    t = np.array([r[1] for r in rows], float)
    values = np.array([[math.nan if v is None else v for v in r[2]] for r in rows], float).reshape(
        len(rows), len(CHANNELS)
    )
    return MeasArrays(seq, t, values)


def encode_json(obj: Mapping[str, Any] | BaseModel) -> bytes:
    """Compact JSON bytes of a mapping or pydantic model (est/res/health/status/ack)."""
    if isinstance(obj, BaseModel):
        return obj.model_dump_json().encode()
    return json.dumps(obj, separators=(",", ":"), allow_nan=False, default=str).encode()


def decode_json(payload: bytes, max_bytes: int = MAX_BYTES) -> dict[str, Any]:
    """A JSON object from bytes; :class:`MessageError` on size, syntax or a non-object."""
    _check_size(payload, max_bytes)
    try:
        obj = json.loads(bytes(payload))
    except (UnicodeDecodeError, ValueError) as e:
        raise MessageError(f"malformed JSON: {e}", "payload") from None
    if not isinstance(obj, dict):
        raise MessageError("must be a JSON object", "payload")
    return obj


# --------------------------------------------------------------------------- outputs

#: leaves of the published outputs, ``fleet/{aircraft}/{actuator}/{leaf}``
OUTPUT_LEAVES: tuple[str, ...] = ("est", "res", "health")
#: fields a published output carries after the log row's
#: (docs/messages.md, "Published outputs (Zenoh)")
_OUTPUT_EXTRA = {"est": ("t",), "res": ("t",), "health": ("t", "commissioned", "baseline_version")}
_OUTPUT_MESSAGE = {"est": "EstOutput", "res": "ResidualOutput", "health": "HealthOutput"}
#: ``commissioned`` of a published health: unknown (no store), not commissioned, commissioned
COMMISSIONED_UNKNOWN, COMMISSIONED_NO, COMMISSIONED_YES = -1, 0, 1


@functools.cache
def output_layout(leaf: str) -> Any:
    """The ``service.log.rows.RowLayout`` of a published ``est``, ``res`` or ``health``: the
    log row's fields (field k + 1 = k-th name of ``EST_KEYS`` / ``RES_KEYS`` /
    ``HEALTH_KEYS``, doubles) then ``t`` [s] (double) and, on health, ``commissioned`` (1,
    0, -1: unknown) and ``baseline_version`` (0: none), both ``sfixed64``."""
    from service.log.rows import PROTO_PACKAGE, RowLayout
    from service.monitor.outputs import EST_KEYS, HEALTH_KEYS, RES_KEYS

    if leaf not in _OUTPUT_MESSAGE:
        raise MessageError(f"not one of {OUTPUT_LEAVES}", "leaf")
    keys = {"est": EST_KEYS, "res": RES_KEYS, "health": HEALTH_KEYS}[leaf]
    names = (*keys, *_OUTPUT_EXTRA[leaf])
    ints = tuple(n in ("commissioned", "baseline_version") for n in names)
    return RowLayout(f"{PROTO_PACKAGE}.{_OUTPUT_MESSAGE[leaf]}", names, ints)


@functools.cache
def output_encoding(leaf: str) -> str:
    """The Zenoh encoding of a published output: ``application/protobuf;{message}``."""
    return f"application/protobuf;{output_layout(leaf).message}"


@functools.cache
def output_schema() -> bytes:
    """The serialised ``google.protobuf.FileDescriptorSet`` of the three output messages
    (one file each, ``servowatch/EstOutput.proto`` ...): what a reader outside servowatch
    needs to decode them with a stock protobuf library."""
    return b"".join(output_layout(leaf).schema for leaf in OUTPUT_LEAVES)


def encode_outputs(leaf: str, vals: np.ndarray) -> np.ndarray:
    """The messages of ``leaf`` for the rows of ``vals`` (n, F): the log row's columns then
    the extra fields of :func:`output_layout`, as an (n, size) uint8 array (row k is the
    payload of one put). Integer fields must be finite."""
    return output_layout(leaf).encode(vals)


@functools.cache
def _fused() -> tuple[np.ndarray, np.ndarray, tuple[int, ...], list[int], int]:
    """The three output messages of a row side by side: (template bytes, positions of the
    value bytes in field order, message sizes, columns of the integer fields, fields)."""
    lays = [output_layout(leaf) for leaf in OUTPUT_LEAVES]
    sizes = tuple(lay.size for lay in lays)
    base = np.cumsum((0, *sizes[:-1]))
    tmpl = np.concatenate([lay.template for lay in lays])
    vb = np.concatenate([b + lay.value_bytes for b, lay in zip(base.tolist(), lays, strict=True)])
    ints = [k for k, i in enumerate(i for lay in lays for i in lay.ints) if i]
    return tmpl, vb, sizes, ints, sum(len(lay.names) for lay in lays)


def encode_output_rows(
    est: np.ndarray, res: np.ndarray, health: np.ndarray, t: np.ndarray, info: np.ndarray
) -> tuple[bytes, tuple[int, ...]]:
    """The est, res and health messages (:func:`output_layout`) of n rows at once: row k's
    are ``est`` (n, len(EST_KEYS)), ``res``, ``health`` of row k, its time ``t[k]`` [s] and
    ``info[k]`` = (commissioned, baseline_version) (n, 2) integers. Returns the bytes of the
    n x 3 messages in the order est, res, health of row 0, then of row 1, ..., and the three
    message sizes; the same bytes as :func:`encode_outputs` of each leaf."""
    tmpl, vb, sizes, ints, nf = _fused()
    n = len(t)
    fe, fr = est.shape[1], res.shape[1]
    w = np.empty((n, nf), "<f8")
    w[:, :fe] = est
    w[:, fe] = t
    w[:, fe + 1 : fe + 1 + fr] = res
    w[:, fe + 1 + fr] = t
    w[:, fe + 2 + fr : nf - 3] = health
    w[:, nf - 3] = t
    w.view("<i8")[:, ints] = info
    out = np.empty((n, len(tmpl)), np.uint8)
    out[:] = tmpl
    out[:, vb] = w.view(np.uint8)
    return out.tobytes(), sizes


def decode_output(
    leaf: str, payload: bytes, encoding: str | None = None, max_bytes: int = MAX_BYTES
) -> dict[str, Any]:
    """A published ``est``, ``res`` or ``health`` as ``{"t": ..., name: value, ...}``: the
    protobuf form of :func:`output_layout` (any valid protobuf encoding of it), or the JSON
    object older daemons published. The Zenoh ``encoding`` decides (``application/protobuf``
    or ``application/json``); without one of those (older daemons set none) the first byte
    does: ``{`` (or a space, CR, LF) is not a field tag of these messages (a tab is: field
    1's). Health's ``commissioned`` is a bool and
    ``baseline_version`` an int or None, both left out when unknown. Raises
    :class:`MessageError`."""
    _check_size(payload, max_bytes)
    payload = bytes(payload)
    enc = (encoding or "").split(";", 1)[0]
    if enc in ("application/json", "text/json") or (
        enc != "application/protobuf" and payload[:1] in (b"{", b" ", b"\n", b"\r")
    ):
        return decode_json(payload, max_bytes)
    lay = output_layout(leaf)
    try:
        vals = lay.decode_one(payload)
    except (ValueError, struct.error) as e:
        raise MessageError(f"malformed {lay.message}: {e}", "payload") from None
    d = dict(zip(lay.names, vals, strict=True))
    out: dict[str, Any] = {"t": d.pop("t")}
    if leaf == "health":
        c, v = d.pop("commissioned"), d.pop("baseline_version")
        if c not in (COMMISSIONED_UNKNOWN, COMMISSIONED_NO, COMMISSIONED_YES):
            raise MessageError(f"must be -1, 0 or 1, got {c}", "commissioned")
        if v < 0:
            raise MessageError(f"must be >= 0, got {v}", "baseline_version")
        out.update(d)
        if c != COMMISSIONED_UNKNOWN:
            out["commissioned"] = c == COMMISSIONED_YES
            out["baseline_version"] = v or None
        return out
    out.update(d)
    return out


# --------------------------------------------------------------------------- keys


def _check_name(v: str, field: str) -> str:
    why = name_problem(v)  # the station's one grammar (service.names)
    if why is not None:
        raise MessageError(why, field)
    return v


def key(template: str, **names: str) -> str:
    """Fill a key template (``KEY_MEAS`` ...) after checking each name is one plain chunk."""
    for k, v in names.items():
        _check_name(v, k)
    return template.format(**names)


def parse_fleet_key(key_expr: str) -> tuple[str, str, str]:
    """``fleet/{aircraft}/{actuator}/{leaf}`` -> (aircraft, actuator, leaf); MessageError else."""
    parts = str(key_expr).split("/")
    if len(parts) != 4 or parts[0] != "fleet":
        raise MessageError(f"not fleet/<aircraft>/<actuator>/<leaf>: {key_expr!r}", "key")
    _check_name(parts[1], "aircraft")
    _check_name(parts[2], "actuator")
    return parts[1], parts[2], parts[3]


def parse_meas_key(key_expr: str) -> tuple[str, str]:
    """``fleet/{aircraft}/{actuator}/meas`` -> (aircraft, actuator); MessageError if malformed."""
    aircraft, actuator, leaf = parse_fleet_key(key_expr)
    if leaf != "meas":
        raise MessageError(f"leaf {leaf!r} is not 'meas'", "key")
    return aircraft, actuator


def mcap_topic(aircraft: str, actuator: str, kind: str) -> str:
    """MCAP topic ``/fleet/{aircraft}/{actuator}/{kind}`` (kind: meas, est, residual, health,
    events)."""
    return f"/fleet/{_check_name(aircraft, 'aircraft')}/{_check_name(actuator, 'actuator')}/{kind}"
