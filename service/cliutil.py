"""Small helpers shared by the command modules: number-list parsing, JSON output, errors."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from service.jsonutil import jsonable as to_jsonable

__all__ = ["float_list", "finite_float", "emit_json", "fail", "to_jsonable"]


def finite_float(text: str) -> float:
    """argparse type: a finite float (SI)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"not finite: {text!r}")
    return v


def float_list(text: str) -> list[float]:
    """argparse type: comma-separated finite floats, e.g. ``-1e-4,0,1e-4``."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError("expected a comma-separated list of numbers")
    return [finite_float(p) for p in parts]


def emit_json(obj: Any) -> None:
    """Print exactly one JSON object on stdout."""
    sys.stdout.write(json.dumps(to_jsonable(obj)) + "\n")
    sys.stdout.flush()


def fail(message: str, code: int = 2) -> int:
    """Print an error on stderr and return the exit code."""
    print(f"servowatch: error: {message}", file=sys.stderr)
    return code
