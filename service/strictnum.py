"""Booleans are not numbers: find a ``true``/``false`` given for a numeric field of a pydantic
model, before the model validates it (pydantic's lax mode reads ``true`` as 1 and 1.0).

``bool_in_number(Model, data)`` walks the raw data (a TOML table) along the model's fields,
nested models, lists and tables included, and returns the first offending field's location;
the loaders (``service.config.load_config``, ``service.sim.scenarios.load_scenario``) refuse it
naming the file and the field. Strings (environment overrides) are left to the model.
"""

from __future__ import annotations

import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any

from pydantic import BaseModel

__all__ = ["bool_in_number"]


def _is_model(ann: Any) -> bool:
    return isinstance(ann, type) and issubclass(ann, BaseModel)


def _unwrap(ann: Any) -> Any:
    while typing.get_origin(ann) is typing.Annotated:
        ann = typing.get_args(ann)[0]
    return ann


def _members(ann: Any) -> tuple[Any, ...]:
    """The alternatives of a union (``int | None``), else ``(ann,)``."""
    ann = _unwrap(ann)
    if typing.get_origin(ann) in (typing.Union, types.UnionType):
        return tuple(_unwrap(a) for a in typing.get_args(ann))
    return (ann,)


def _numeric_only(ann: Any) -> bool:
    """A field that takes a number and not a boolean (``float``, ``int | None``, ...)."""
    alts = _members(ann)
    if any(a is bool or a is Any for a in alts):
        return False
    return any(a in (int, float) for a in alts)


def _walk(ann: Any, v: Any, loc: tuple[str, ...]) -> tuple[str, ...] | None:
    if isinstance(v, bool):
        return loc if _numeric_only(ann) else None
    for a in _members(ann):
        if _is_model(a) and isinstance(v, Mapping):
            hit = bool_in_number(a, v, loc)
            if hit is not None:
                return hit
            continue
        origin, args = typing.get_origin(a), typing.get_args(a)
        if origin in (list, tuple, Sequence, set, frozenset) and isinstance(v, list) and args:
            for i, x in enumerate(v):
                elem = (
                    args[i]
                    if origin is tuple and args[-1] is not Ellipsis and i < len(args)
                    else args[0]
                )
                hit = _walk(elem, x, (*loc, str(i)))
                if hit is not None:
                    return hit
        elif origin in (dict, Mapping) and isinstance(v, Mapping) and len(args) == 2:
            for k, x in v.items():
                hit = _walk(args[1], x, (*loc, str(k)))
                if hit is not None:
                    return hit
    return None


def bool_in_number(
    model: type[BaseModel], data: Any, loc: tuple[str, ...] = ()
) -> tuple[str, ...] | None:
    """The location (field names, list indices) of the first boolean given for a numeric
    field of ``model`` in the raw ``data``; None when there is none."""
    if not isinstance(data, Mapping):
        return None
    for name, field in model.model_fields.items():
        key = field.alias or name
        if key not in data:
            continue
        hit = _walk(field.annotation, data[key], (*loc, key))
        if hit is not None:
            return hit
    return None
