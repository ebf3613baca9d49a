"""Shared parts of the MCAP codec kernels (:mod:`service.log.codec`): numba options, uint64
constants and 128-bit arithmetic."""

from __future__ import annotations

import numpy as np
from numba import njit

from service.compat.numba import NO_NRT

# kernels that allocate nothing: compiled without NRT reference counting
_LEAF = {"cache": True, "error_model": "numpy", "nogil": True, **NO_NRT}
_INLINE = {**_LEAF, "inline": "always"}  # small helpers: inlined into their callers

MSG_OPCODE = 0x05  # an MCAP Message record
_M64 = (1 << 64) - 1
_U0 = np.uint64(0)
_U1 = np.uint64(1)
_U32 = np.uint64(32)
_LO32 = np.uint64(0xFFFFFFFF)
_MANT = np.uint64((1 << 52) - 1)
_HIDDEN = np.uint64(1 << 52)
_SIGN = np.uint64(1 << 63)


def readonly(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a``: the kernels take their inputs read-only, whatever the
    caller holds (a chunk's bytes and the log process's arrays come from ``np.frombuffer``,
    read-only; the daemon's own arrays are writable), so that numba compiles one signature,
    the one the warm-up compiles, and not a second on first use."""
    v = a.view()
    v.flags.writeable = False
    return v


@njit(**_INLINE)
def _umul128(a, b):
    a0 = a & _LO32
    a1 = a >> _U32
    b0 = b & _LO32
    b1 = b >> _U32
    p00 = a0 * b0
    p01 = a0 * b1
    p10 = a1 * b0
    p11 = a1 * b1
    mid = (p00 >> _U32) + (p01 & _LO32) + (p10 & _LO32)
    lo = (p00 & _LO32) | (mid << _U32)
    hi = p11 + (p01 >> _U32) + (p10 >> _U32) + (mid >> _U32)
    return hi, lo


@njit(**_INLINE)
def _shr128(lo, hi, s):
    return (lo >> np.uint64(s)) | (hi << np.uint64(64 - s))
