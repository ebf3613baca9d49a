"""The pydantic internals the message decoder relies on, fenced in one module (checked by
``tests/test_compat_pydantic.py`` on every pydantic release the project allows).

``construct_unchecked`` builds a model instance from values that are already validated by
writing pydantic's four instance slots (``BaseModel.__slots__``: ``__dict__``,
``__pydantic_fields_set__``, ``__pydantic_extra__``, ``__pydantic_private__``) itself. It
gives what the public ``Model.model_construct(**values)`` gives (equal objects, same
``model_fields_set``), at about half its cost: ``research/pydantic_construct.py`` measured
``model_construct`` 1.7-1.9x slower per ``MeasSample``, and decoding builds one per sample.
"""

from __future__ import annotations

from typing import Any, TypeVar

from pydantic import BaseModel

__all__ = ["construct_unchecked", "INSTANCE_SLOTS"]

INSTANCE_SLOTS = (
    "__dict__",
    "__pydantic_fields_set__",
    "__pydantic_extra__",
    "__pydantic_private__",
)

M = TypeVar("M", bound=BaseModel)
_new = object.__new__
_set = object.__setattr__


def construct_unchecked(cls: type[M], values: dict[str, Any]) -> M:
    """An instance of ``cls`` holding ``values`` (every field, already validated; the dict
    is taken, not copied) with no extra and no private attributes, as
    ``cls.model_construct(**values)`` would build it."""
    m = _new(cls)
    _set(m, "__dict__", values)
    _set(m, "__pydantic_fields_set__", set(values))
    _set(m, "__pydantic_extra__", None)
    _set(m, "__pydantic_private__", None)
    return m
