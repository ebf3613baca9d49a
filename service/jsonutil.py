"""Plain-JSON conversion shared by the CLI, the daemon's MCAP logging and the replay."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Mapping
from typing import Any

__all__ = ["jsonable", "flat", "event_dict"]


def jsonable(v: Any) -> Any:
    """Plain JSON types: non-finite floats -> None, numpy arrays/scalars -> Python, nested
    mappings and sequences converted, anything else as float if it converts, else str."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, bool | int | str) or v is None:
        return v
    if isinstance(v, Mapping):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [jsonable(x) for x in v]
    np = sys.modules.get("numpy")  # not imported: no value can be a numpy one (fast start-up)
    if np is not None and isinstance(v, np.ndarray):
        return jsonable(v.tolist())
    if np is not None and isinstance(v, np.generic):
        return jsonable(v.item())
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f if math.isfinite(f) else None


def flat(d: dict[str, Any]) -> dict[str, Any]:
    """A flat mapping for an MCAP JSON message (scalars kept; lists/dicts as JSON text).
    ``d`` itself when it is all plain finite floats (the monitor's outputs: the hot path)."""
    for v in d.values():  # fast path: the monitor's outputs are plain finite floats
        if type(v) is not float or v - v != 0.0:
            break
    else:
        return d
    out = {}
    for k, v in d.items():
        v = jsonable(v)
        out[str(k)] = json.dumps(v) if isinstance(v, dict | list) else v
    return out


def event_dict(ev: Any) -> dict[str, Any]:
    """An AlarmEvent (dataclass, pydantic model or mapping) as a plain dict."""
    if isinstance(ev, Mapping):
        d = dict(ev)
    elif hasattr(ev, "model_dump"):
        d = ev.model_dump()
    elif hasattr(ev, "__dataclass_fields__"):
        d = {k: getattr(ev, k) for k in ev.__dataclass_fields__}
    else:
        d = {k: getattr(ev, k, None) for k in ("t", "kind", "state", "value")}
    return jsonable(d)
