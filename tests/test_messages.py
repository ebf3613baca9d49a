"""Wire format of measurement messages: round trips, auto-detection, validation verdicts."""

from __future__ import annotations

import json
import math
import random
import struct

import numpy as np
import pytest
from pydantic import ValidationError

from service.wire.messages import (
    CHANNELS,
    KEY_FAULT,
    KEY_MEAS,
    FaultAck,
    FaultCommand,
    MeasSample,
    MessageError,
    decode_json,
    decode_meas,
    decode_meas_dicts,
    encode_json,
    encode_meas,
    key,
    mcap_topic,
    parse_meas_key,
)


def _samples(n: int, seq0: int = 0, t0: float = 10.0, missing: tuple[str, ...] = ()):
    out = []
    for k in range(n):
        d = {
            "seq": seq0 + k,
            "t": t0 + k * 1e-3,
            "x_cmd": 0.02,
            "i": 1.5e-3 * (k + 1),
            "x_s": -3.25e-5,
            "x_j": 0.0123456789,
            "p1": 12.5e6 + k,
            "p2": 8.1e6,
            "p_sr": 20e6,
        }
        for c in missing:
            d[c] = None
        out.append(MeasSample(**d))
    return out


@pytest.mark.parametrize("fmt", ["bin", "json"])
def test_round_trip_exact(fmt):
    s = _samples(25, missing=("x_s", "p_sr"))
    assert decode_meas(encode_meas(s, fmt)) == s
    d = decode_meas_dicts(encode_meas(s, fmt))
    assert d[3] == s[3].model_dump()
    assert d[0]["x_s"] is None and d[0]["p1"] == 12.5e6


def test_binary_size_is_header_plus_73_bytes_per_sample():
    for n in (1, 20, 50):
        assert len(encode_meas(_samples(n), "bin")) == 8 + 73 * n


def test_binary_header_layout():
    b = encode_meas(_samples(3), "bin")
    magic, version, kind, n = struct.unpack_from("<2sBBI", b)
    assert (magic, version, kind, n) == (b"SW", 1, ord("M"), 3)
    seq, t, mask = struct.unpack_from("<qdB", b, 8)
    assert (seq, t, mask) == (0, 10.0, 0x7F)


def test_mappings_and_bare_json_sample_accepted():
    b = encode_meas([{"seq": 7, "t": 1.0, "p1": 1e6}], "bin")
    (s,) = decode_meas(b)
    assert s.seq == 7 and s.p1 == 1e6 and s.x_j is None
    (s2,) = decode_meas(b'  {"seq": 7, "t": 1.0, "p1": 1000000.0}')
    assert s2 == s
    assert s.as_input() == {"t": 1.0, **{c: (1e6 if c == "p1" else None) for c in CHANNELS}}


def _bad_bin(field: str, value: float, k: int = 1) -> bytes:
    s = [x.model_dump() for x in _samples(3)]
    s[k][field] = value
    return encode_meas(s, "bin")


@pytest.mark.parametrize(
    ("payload", "field"),
    [
        (_bad_bin("p1", math.nan), "samples[1].p1"),
        (_bad_bin("x_j", math.inf), "samples[1].x_j"),
        (_bad_bin("t", -math.inf), "samples[1].t"),
        (_bad_bin("seq", -5, k=0), "samples[0].seq"),
        (_bad_bin("seq", 0), "samples[1].seq"),  # duplicate of samples[0]
        (_bad_bin("t", 5.0), "samples[1].t"),  # goes back in time
        (encode_meas(_samples(3), "bin")[:-1], "n"),  # truncated
        (encode_meas(_samples(3), "bin") + b"\0", "n"),  # trailing byte
        (b"SW\x02M" + b"\0" * 4, "version"),
        (b"SW\x01X" + struct.pack("<I", 1) + b"\0" * 73, "kind"),
        (b"SW\x01M" + struct.pack("<I", 0), "n"),
        (b"SW\x01", "header"),
        (b"", "payload"),
        (b"\x00\x01garbage", "payload"),
        (b"{not json", "payload"),
        (b"[1, 2]", "payload"),
        (b'{"samples": []}', "samples"),
        (b'{"samples": {}}', "samples"),
        (b'{"v": 2, "samples": [{"seq": 0, "t": 0}]}', "v"),
        (b'{"samples": [{"seq": 0, "t": 0}], "extra": 1}', "extra"),
        (b'{"samples": [{"seq": 0, "t": 0, "p3": 1.0}]}', "samples[0].p3"),
        (b'{"samples": [{"t": 0}]}', "samples[0].seq"),
        (b'{"samples": [{"seq": 0}]}', "samples[0].t"),
        (b'{"samples": [{"seq": true, "t": 0}]}', "samples[0].seq"),
        (b'{"samples": [{"seq": 1.0, "t": 0}]}', "samples[0].seq"),
        (b'{"samples": [{"seq": 0, "t": 0, "p1": "1e6"}]}', "samples[0].p1"),
        (b'{"samples": [{"seq": 0, "t": 0, "p1": NaN}]}', "samples[0].p1"),
        (b'{"samples": [{"seq": 0, "t": Infinity}]}', "samples[0].t"),
        (b'{"samples": [{"seq": 3, "t": 0}, {"seq": 2, "t": 1}]}', "samples[1].seq"),
        (b'{"samples": [{"seq": 1, "t": 0}, {"seq": 2, "t": 0}]}', "samples[1].t"),
        (b'{"samples": [1]}', "samples[0]"),
    ],
)
def test_bad_messages_name_the_field(payload, field):
    with pytest.raises(MessageError) as ei:
        decode_meas(payload)
    assert ei.value.field == field
    assert field in str(ei.value)


def test_binary_unknown_mask_bits_refused():
    b = bytearray(encode_meas(_samples(2), "bin"))
    b[8 + 73 + 16] = 0xFF  # mask byte of samples[1]
    with pytest.raises(MessageError) as ei:
        decode_meas(bytes(b))
    assert ei.value.field == "samples[1].mask"


def test_absent_channel_may_hold_nan_in_binary():
    """A cleared mask bit means missing whatever the value bytes say (NaN-filled by encode)."""
    (s,) = decode_meas(encode_meas([{"seq": 0, "t": 0.0, "p1": None}], "bin"))
    assert s.p1 is None


def test_max_bytes():
    b = encode_meas(_samples(50), "bin")
    assert len(b) == 3658
    decode_meas(b, max_bytes=3658)
    with pytest.raises(MessageError) as ei:
        decode_meas(b, max_bytes=3657)
    assert ei.value.field == "payload"


# Same verdicts from the pydantic schema and the hand-written check.
_CANDIDATES = [
    {"seq": 0, "t": 0.0},
    {"seq": 5, "t": -1.5, "p1": 2e7, "x_s": None},
    {"seq": -1, "t": 0.0},
    {"seq": 2**40, "t": 1e9},
    {"seq": True, "t": 0.0},
    {"seq": 1.0, "t": 0.0},
    {"seq": "1", "t": 0.0},
    {"seq": 0, "t": "0"},
    {"seq": 0, "t": None},
    {"seq": 0},
    {"t": 0.0},
    {"seq": 0, "t": 0, "p2": 3},
    {"seq": 0, "t": 0.0, "p2": False},
    {"seq": 0, "t": 0.0, "p2": math.nan},
    {"seq": 0, "t": 0.0, "i": -math.inf},
    {"seq": 0, "t": math.inf},
    {"seq": 0, "t": 0.0, "bogus": 1.0},
    {"seq": 0, "t": 0.0, "x_cmd": [1.0]},
]


@pytest.mark.parametrize("cand", _CANDIDATES, ids=[json.dumps(c) for c in _CANDIDATES])
def test_pydantic_schema_and_fast_check_agree(cand):
    try:
        ref = MeasSample.model_validate(cand)
    except ValidationError:
        ref = None
    payload = json.dumps({"v": 1, "samples": [cand]}).encode()
    try:
        (got,) = decode_meas(payload)
    except MessageError:
        got = None
    assert (ref is None) == (got is None), (ref, got)
    if ref is not None:
        assert got == ref


def test_fuzz_only_message_errors():
    rng = random.Random(1)
    good = encode_meas(_samples(4), "bin")
    goodj = encode_meas(_samples(4), "json")
    for _ in range(3000):
        src = bytearray(rng.choice([good, goodj]))
        for _ in range(rng.randint(1, 4)):
            src[rng.randrange(len(src))] = rng.randrange(256)
        if rng.random() < 0.3:
            src = src[: rng.randrange(len(src))]
        try:
            decode_meas(bytes(src))
        except MessageError as e:
            assert e.field
    # a flipped value byte in a good message still decodes or is refused, never crashes


def test_fault_command_and_ack():
    c = FaultCommand.model_validate_json(b'{"kind": "leak", "value": 6e-13, "ramp_s": 10}')
    assert c.kind == "leak" and c.value == 6e-13 and c.ramp_s == 10 and c.duration_s is None
    for bad in (
        '{"kind": "explode"}',
        '{"kind": "leak", "ramp_s": -1}',
        '{"kind": "leak", "value": NaN}',
        '{"kind": "leak", "colour": 1}',
    ):
        with pytest.raises(ValidationError):
            FaultCommand.model_validate_json(bad)
    ack = FaultAck(ok=True, message="leak 6e-13", active=[{"kind": "leak"}])
    assert decode_json(encode_json(ack)) == ack.model_dump()
    with pytest.raises(MessageError):
        decode_json(b"[]")
    with pytest.raises(ValueError):
        encode_json({"x": math.nan})


def test_keys():
    k = key(KEY_MEAS, aircraft="AC001", actuator="elevator_L")
    assert k == "fleet/AC001/elevator_L/meas"
    assert parse_meas_key(k) == ("AC001", "elevator_L")
    assert key(KEY_FAULT, aircraft="A", actuator="b") == "fleet/A/b/@fault"
    assert mcap_topic("AC001", "elevator_L", "residual") == "/fleet/AC001/elevator_L/residual"
    for bad in (
        "fleet/AC001/meas",
        "fleet/AC001/elevator_L/est",
        "fleet/*/elevator_L/meas",
        "fleet/AC001/el/x/meas",
        "other/AC001/el/meas",
        "fleet//el/meas",
    ):
        with pytest.raises(MessageError):
            parse_meas_key(bad)
    with pytest.raises(MessageError):
        key(KEY_MEAS, aircraft="**", actuator="x")


def test_encode_refuses_what_it_cannot_pack():
    with pytest.raises(MessageError) as ei:
        encode_meas([{"seq": 0, "t": 0.0}, {"t": 1.0}], "bin")
    assert ei.value.field == "samples[1].seq"
    with pytest.raises(MessageError) as ei:
        encode_meas([{"seq": 0, "t": 0.0, "p1": "high"}], "bin")
    assert ei.value.field == "samples[0]"
    with pytest.raises(MessageError):
        encode_meas([])
    with pytest.raises(MessageError):
        encode_meas([{"seq": k, "t": float(k)} for k in range(4097)], "bin")
    with pytest.raises(ValueError):
        encode_meas(_samples(1), "xml")  # type: ignore[arg-type]


def _arrays_equal_dicts(payload: bytes) -> None:
    """decode_meas_arrays and decode_meas_dicts agree: same error field, or same values."""
    from service.wire.messages import CHANNELS, decode_meas_arrays, decode_meas_dicts

    try:
        rows = decode_meas_dicts(payload)
    except MessageError as e:
        with pytest.raises(MessageError) as ei:
            decode_meas_arrays(payload)
        assert ei.value.field == e.field
        return
    a = decode_meas_arrays(payload)
    assert a.seq.tolist() == [r["seq"] for r in rows]
    assert a.t.tolist() == [r["t"] for r in rows]
    want = [[math.nan if r[c] is None else r[c] for c in CHANNELS] for r in rows]
    np.testing.assert_array_equal(a.values, np.array(want, float).reshape(-1, len(CHANNELS)))


@pytest.mark.parametrize("fmt", ["bin", "json"])
def test_arrays_decoder_round_trip(fmt):
    s = [x.model_dump() for x in _samples(5)]
    s[2]["p1"] = None
    s[3]["x_cmd"] = None
    _arrays_equal_dicts(encode_meas(s, fmt))


def test_arrays_decoder_same_errors_and_fuzz():
    bad = [
        _bad_bin("p1", math.nan), _bad_bin("x_j", math.inf), _bad_bin("t", -math.inf),
        _bad_bin("seq", -5, k=0), _bad_bin("seq", 0), _bad_bin("t", 5.0),
        encode_meas(_samples(3), "bin")[:-1], b"SW\x02M" + b"\0" * 4, b"", b"{not json",
    ]  # fmt: skip
    b = bytearray(encode_meas(_samples(2), "bin"))
    b[8 + 73 + 16] = 0xFF
    for p in [*bad, bytes(b)]:
        _arrays_equal_dicts(p)
    rng = random.Random(2)
    good = encode_meas(_samples(4), "bin")
    for _ in range(2000):
        src = bytearray(good)
        for _ in range(rng.randint(1, 4)):
            src[rng.randrange(len(src))] = rng.randrange(256)
        _arrays_equal_dicts(bytes(src))
