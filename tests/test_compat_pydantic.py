"""Check tests of the pydantic internals fenced in ``service.compat.pydantic``: each fails
with a message naming the internal when a pydantic release changes it."""

from __future__ import annotations

import copy
import pickle

from pydantic import BaseModel

from service.compat.pydantic import INSTANCE_SLOTS, construct_unchecked
from service.wire.messages import CHANNELS, MeasSample, decode_meas, encode_meas

VALUES = {"seq": 7, "t": 1.25, **dict.fromkeys(CHANNELS, None), "x_j": 0.01, "p1": 1.1e7}


def test_instance_slots_are_pydantics() -> None:
    assert BaseModel.__slots__ == INSTANCE_SLOTS, (
        f"pydantic.BaseModel.__slots__ is now {BaseModel.__slots__}, not {INSTANCE_SLOTS}: "
        "construct_unchecked (service/compat/pydantic.py) writes these by hand"
    )


def test_construct_unchecked_equals_model_construct_and_validation() -> None:
    a = construct_unchecked(MeasSample, dict(VALUES))
    b = MeasSample.model_construct(**VALUES)
    c = MeasSample(**VALUES)
    for other, how in ((b, "model_construct"), (c, "validation")):
        assert a == other, f"construct_unchecked differs from {how}"
        assert a.model_fields_set == other.model_fields_set == set(VALUES), how
        assert a.model_dump() == other.model_dump(), how
        assert a.model_dump_json() == other.model_dump_json(), how
        assert repr(a) == repr(other), how
        assert hash(a) == hash(other), how  # frozen model: hashed by its fields
    assert a.model_extra is None and a.__pydantic_private__ is None


def test_constructed_object_behaves_as_a_model() -> None:
    a = construct_unchecked(MeasSample, dict(VALUES))
    assert a.x_j == 0.01 and a.p2 is None
    assert a.model_copy(update={"seq": 8}).seq == 8 and a.seq == 7
    assert pickle.loads(pickle.dumps(a)) == a
    assert copy.deepcopy(a) == a
    try:
        a.seq = 9  # frozen
    except Exception as e:  # pydantic's ValidationError
        assert "frozen" in str(e)
    else:
        raise AssertionError("a constructed MeasSample is no longer frozen")


def test_decoded_samples_are_built_this_way() -> None:
    msgs = decode_meas(encode_meas([VALUES]))
    assert msgs == [MeasSample(**VALUES)]
    assert msgs[0].model_fields_set == set(VALUES)
