"""The MCAP codec's writing kernels (:func:`encode_records`, :func:`format_float`): rows of a
float64 array formatted like ``json.JSONEncoder(separators=(",", ":"))`` (floats as
``float.__repr__``: shortest round-trip digits by Ryu) and packed into MCAP Message records.
See :mod:`service.log.codec`."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit

from service.log.codec_arith import (
    _HIDDEN,
    _INLINE,
    _LEAF,
    _M64,
    _MANT,
    _SIGN,
    _U0,
    _U1,
    _shr128,
    _umul128,
    readonly,
)

# ----------------------------------------------------------------------------- tables


def _ryu_tables() -> tuple[np.ndarray, np.ndarray]:
    """Ryu's 5^-i and 5^i tables, 125 significant bits as (low, high) uint64 pairs."""
    inv = np.empty((342, 2), np.uint64)
    for i in range(342):
        p = 5**i
        v = (1 << (p.bit_length() - 1 + 125)) // p + 1
        inv[i, 0], inv[i, 1] = v & _M64, v >> 64
    pos = np.empty((326, 2), np.uint64)
    for i in range(326):
        p = 5**i
        s = p.bit_length() - 125
        v = p >> s if s >= 0 else p << -s
        pos[i, 0], pos[i, 1] = v & _M64, v >> 64
    return inv, pos


_POW5_INV, _POW5 = _ryu_tables()
_POW10_U64 = np.array([10**i for i in range(20)], np.uint64)
_DIGITS2 = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), np.uint8).copy()


# ----------------------------------------------------------------------------- writing


@njit(**_LEAF)
def _mul_shift_all(m2, mlo, mhi, j, mm_shift):
    """Ryu's mulShiftAll64: (vr, vp, vm) = ((4 m2 + {0, 2, -1 - mm_shift}) * mul) >> j."""
    m = m2 << _U1
    tmp, lo = _umul128(m, mlo)
    hi, lo1 = _umul128(m, mhi)
    mid = tmp + lo1
    if mid < tmp:
        hi += _U1
    lo2 = lo + mlo
    mid2 = mid + mhi + (_U1 if lo2 < lo else _U0)
    hi2 = hi + (_U1 if mid2 < mid else _U0)
    vp = _shr128(mid2, hi2, j - 65)
    if mm_shift == _U1:
        lo3 = lo - mlo
        mid3 = mid - mhi - (_U1 if lo3 > lo else _U0)
        hi3 = hi - (_U1 if mid3 > mid else _U0)
        vm = _shr128(mid3, hi3, j - 65)
    else:
        lo3 = lo + lo
        mid3 = mid + mid + (_U1 if lo3 < lo else _U0)
        hi3 = hi + hi + (_U1 if mid3 < mid else _U0)
        lo4 = lo3 - mlo
        mid4 = mid3 - mhi - (_U1 if lo4 > lo3 else _U0)
        hi4 = hi3 - (_U1 if mid4 > mid3 else _U0)
        vm = _shr128(mid4, hi4, j - 64)
    return _shr128(mid, hi, j - 65), vp, vm


@njit(**_LEAF)
def _pow5_factor(v):
    c = 0
    five = np.uint64(5)
    while v % five == _U0:
        v //= five
        c += 1
    return c


@njit(**_INLINE)
def _dec_len(v):
    """Number of decimal digits of v (>= 1)."""
    n = 20
    while n > 1 and v < _POW10_U64[n - 1]:
        n -= 1
    return n


@njit(**_LEAF)
def _d2d(bits):
    """Ryu: shortest decimal (digits, exponent10) of the positive finite double ``bits``."""
    ieee_m = bits & _MANT
    ieee_e = np.int64((bits >> np.uint64(52)) & np.uint64(0x7FF))
    if ieee_e == 0:
        e2 = 1 - 1023 - 52 - 2
        m2 = ieee_m
    else:
        e2 = ieee_e - 1023 - 52 - 2
        m2 = _HIDDEN | ieee_m
    accept = (m2 & _U1) == _U0
    mv = np.uint64(4) * m2
    mm_shift = _U1 if (ieee_m != _U0 or ieee_e <= 1) else _U0
    vm_tz = False
    vr_tz = False
    if e2 >= 0:
        q = ((e2 * 78913) >> 18) - (1 if e2 > 3 else 0)
        e10 = q
        k = 125 + (((q * 1217359) >> 19) + 1) - 1
        i = -e2 + q + k
        vr, vp, vm = _mul_shift_all(m2, _POW5_INV[q, 0], _POW5_INV[q, 1], i, mm_shift)
        if q <= 21:
            if mv % np.uint64(5) == _U0:
                vr_tz = _pow5_factor(mv) >= q
            elif accept:
                vm_tz = _pow5_factor(mv - _U1 - mm_shift) >= q
            elif _pow5_factor(mv + np.uint64(2)) >= q:
                vp -= _U1
    else:
        q = ((-e2 * 732923) >> 20) - (1 if -e2 > 1 else 0)
        e10 = q + e2
        i = -e2 - q
        k = (((i * 1217359) >> 19) + 1) - 125
        j = q - k
        vr, vp, vm = _mul_shift_all(m2, _POW5[i, 0], _POW5[i, 1], j, mm_shift)
        if q <= 1:
            vr_tz = True
            if accept:
                vm_tz = mm_shift == _U1
            else:
                vp -= _U1
        elif q < 63:
            vr_tz = (mv & ((_U1 << np.uint64(q)) - _U1)) == _U0
    ten = np.uint64(10)
    removed = 0
    last = 0
    if vm_tz or vr_tz:
        while True:
            vp10 = vp // ten
            vm10 = vm // ten
            if vp10 <= vm10:
                break
            vr10 = vr // ten
            vm_tz = vm_tz and (vm - vm10 * ten) == _U0
            vr_tz = vr_tz and last == 0
            last = np.int64(vr - vr10 * ten)
            vr = vr10
            vp = vp10
            vm = vm10
            removed += 1
        if vm_tz:
            while True:
                vm10 = vm // ten
                if vm - vm10 * ten != _U0:
                    break
                vp10 = vp // ten
                vr10 = vr // ten
                vr_tz = vr_tz and last == 0
                last = np.int64(vr - vr10 * ten)
                vr = vr10
                vp = vp10
                vm = vm10
                removed += 1
        if vr_tz and last == 5 and (vr & _U1) == _U0:
            last = 4
        up = (vr == vm and (not accept or not vm_tz)) or last >= 5
        out = vr + (_U1 if up else _U0)
    else:
        up = False
        hundred = np.uint64(100)
        vp100 = vp // hundred
        vm100 = vm // hundred
        if vp100 > vm100:
            vr100 = vr // hundred
            up = vr - vr100 * hundred >= np.uint64(50)
            vr = vr100
            vp = vp100
            vm = vm100
            removed += 2
        while True:
            vp10 = vp // ten
            vm10 = vm // ten
            if vp10 <= vm10:
                break
            vr10 = vr // ten
            up = vr - vr10 * ten >= np.uint64(5)
            vr = vr10
            vp = vp10
            vm = vm10
            removed += 1
        out = vr + (_U1 if (vr == vm or up) else _U0)
    return out, e10 + removed


# ----------------------------------------------------------------------------- formatting


@njit(**_INLINE)
def _put_digits(buf, p, v, n, dot):
    """Write the n digits of v at p, with '.' after ``dot`` digits if 0 < dot < n."""
    i = p + n
    hundred = np.uint64(100)
    if n > 8:  # the low 8 digits on their own: two independent division chains
        e8 = np.uint64(100000000)
        hi = v // e8
        lo = v - hi * e8
        v = hi
        for _ in range(4):
            q = lo // hundred
            r = 2 * np.int64(lo - q * hundred)
            lo = q
            buf[i - 1] = _DIGITS2[r + 1]
            buf[i - 2] = _DIGITS2[r]
            i -= 2
    while v >= hundred:
        q = v // hundred
        r = 2 * np.int64(v - q * hundred)
        v = q
        buf[i - 1] = _DIGITS2[r + 1]
        buf[i - 2] = _DIGITS2[r]
        i -= 2
    if v >= np.uint64(10):
        r = 2 * np.int64(v)
        buf[i - 1] = _DIGITS2[r + 1]
        buf[i - 2] = _DIGITS2[r]
    else:
        buf[i - 1] = 48 + np.uint8(v)
    if 0 < dot < n:
        for k in range(p + n, p + dot, -1):
            buf[k] = buf[k - 1]
        buf[p + dot] = 46
        return p + n + 1
    return p + n


@njit(**_LEAF)
def _put_float(buf, p, bits):
    """``float.__repr__`` of the finite double ``bits`` at p; returns the new end."""
    if bits & _SIGN:
        buf[p] = 45  # -
        p += 1
        bits &= ~_SIGN
    if bits == _U0:
        buf[p] = 48
        buf[p + 1] = 46
        buf[p + 2] = 48
        return p + 3
    digits, e10 = _d2d(bits)
    n = _dec_len(digits)
    decpt = n + e10
    if -4 < decpt <= 16:
        if decpt <= 0:
            buf[p] = 48
            buf[p + 1] = 46
            p += 2
            for _ in range(-decpt):
                buf[p] = 48
                p += 1
            return _put_digits(buf, p, digits, n, 0)
        if decpt < n:
            return _put_digits(buf, p, digits, n, decpt)
        p = _put_digits(buf, p, digits, n, 0)
        for _ in range(decpt - n):
            buf[p] = 48
            p += 1
        buf[p] = 46
        buf[p + 1] = 48
        return p + 2
    p = _put_digits(buf, p, digits, n, 1)
    buf[p] = 101  # e
    x = decpt - 1
    if x < 0:
        buf[p + 1] = 45
        x = -x
    else:
        buf[p + 1] = 43
    p += 2
    if x >= 100:
        buf[p] = 48 + x // 100
        p += 1
        x %= 100
    buf[p] = 48 + x // 10
    buf[p + 1] = 48 + x % 10
    return p + 2


@njit(**_LEAF)
def _put_int(buf, p, v):
    """Decimal text of the int64 ``v`` at p."""
    if v < 0:
        buf[p] = 45
        p += 1
        u = np.uint64(-(v + 1)) + _U1
    else:
        u = np.uint64(v)
    return _put_digits(buf, p, u, _dec_len(u), 0)


@njit(cache=True, nogil=True)
def _format_floats(bits, buf):
    """repr of each double of ``bits`` into ``buf``; returns the end offsets (for tests)."""
    ends = np.empty(bits.size, np.int64)
    p = 0
    for k in range(bits.size):
        p = _put_float(buf, p, bits[k])
        ends[k] = p
    return ends


def format_float(x: np.ndarray) -> list[str]:
    """``repr`` of each finite float of ``x`` by the compiled formatter (for tests)."""
    b = np.ascontiguousarray(x, np.float64).reshape(-1).view(np.uint64)
    buf = np.empty(b.size * 25 + 1, np.uint8)
    ends = _format_floats(b, buf)
    text = buf[: ends[-1] if ends.size else 0].tobytes().decode()
    starts = np.concatenate(([0], ends[:-1]))
    return [text[s:e] for s, e in zip(starts.tolist(), ends.tolist(), strict=True)]


@njit(**_INLINE)
def _put_u64(buf, p, v, n):
    for i in range(n):
        buf[p + i] = np.uint8((v >> np.uint64(8 * i)) & np.uint64(0xFF))


@njit(**_LEAF)
def _encode(values, isint, keys, key_off, channel_id, seq0, log_times, buf, ends):
    n, nf = values.shape
    vbits = values.view(np.uint64)
    p = 0
    mask32 = np.uint64(0xFFFFFFFF)
    for k in range(n):
        rec = p
        p += 31
        buf[p] = 123  # {
        p += 1
        for f in range(nf):
            if f:
                buf[p] = 44  # ,
                p += 1
            for i in range(key_off[f], key_off[f + 1]):
                buf[p] = keys[i]
                p += 1
            v = values[k, f]
            if not np.isfinite(v):
                buf[p] = 110  # null
                buf[p + 1] = 117
                buf[p + 2] = 108
                buf[p + 3] = 108
                p += 4
            elif isint[f]:
                p = _put_int(buf, p, np.int64(v))
            else:
                p = _put_float(buf, p, vbits[k, f])
        buf[p] = 125  # }
        p += 1
        buf[rec] = 5
        _put_u64(buf, rec + 1, np.uint64(p - rec - 9), 8)
        _put_u64(buf, rec + 9, np.uint64(channel_id), 2)
        _put_u64(buf, rec + 11, (np.uint64(seq0) + np.uint64(k)) & mask32, 4)
        lt = np.uint64(log_times[k])
        _put_u64(buf, rec + 15, lt, 8)
        _put_u64(buf, rec + 23, lt, 8)
        ends[k] = p
    return p


class RowFormat:
    """The fixed parts of one message layout: ``"key":`` texts and which fields are integers."""

    __slots__ = ("names", "keys", "key_off", "isint", "max_len")

    def __init__(self, names: tuple[str, ...], int_fields: frozenset[str]):
        from json import dumps

        self.names = names
        parts = [(dumps(n) + ":").encode() for n in names]
        self.keys = np.frombuffer(b"".join(parts), np.uint8) if parts else np.zeros(0, np.uint8)
        self.key_off = np.concatenate(([0], np.cumsum([len(x) for x in parts]))).astype(np.int64)
        self.isint = np.array([n in int_fields for n in names], dtype=np.bool_)
        self.max_len = 31 + 2 + int(self.key_off[-1]) + 25 * len(names)


@lru_cache(maxsize=256)
def row_format(names: tuple[str, ...], int_fields: frozenset[str]) -> RowFormat:
    """Cached :class:`RowFormat` for ``names`` (integers written for ``int_fields``)."""
    return RowFormat(names, int_fields)


def encode_records(
    fmt: RowFormat, values: np.ndarray, channel_id: int, seq0: int, log_times: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """MCAP Message records (opcode, length, channel, sequence, log and publish time, JSON)
    for each row of ``values`` (C-contiguous float64 (N, F)); non-finite values -> ``null``,
    ``fmt.isint`` columns as integers (truncated; they must be < 2**63 in magnitude).

    Returns the record bytes (uint8 array) and the end offset of each record in it.
    """
    n = values.shape[0]
    buf = np.empty(n * fmt.max_len, np.uint8)
    ends = np.empty(n, np.int64)
    end = _encode(readonly(values), fmt.isint, fmt.keys, fmt.key_off, channel_id, seq0,
                  log_times, buf, ends)  # fmt: skip
    return buf[:end], ends


# ----------------------------------------------------------------------------- parsing
