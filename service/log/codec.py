"""Numba kernels for block MCAP I/O of flat JSON messages (used by :mod:`service.log`).

Writing (:func:`encode_records`): rows of a float64 array formatted exactly like
``json.JSONEncoder(separators=(",", ":"))`` formats ``{name: float_or_int_or_None}`` (floats as
``float.__repr__``: shortest round-trip digits by the Ryu algorithm, Python's fixed/exponent
layout) and packed straight into MCAP Message records.

Reading (:func:`scan_records`, :func:`parse_objects`): the records of a decompressed chunk
without a Python loop, then a run of flat JSON objects with the same key bytes into an (N, F)
float64 array. Numbers are converted with Clinger's fast path or the Eisel-Lemire algorithm,
which are correctly rounded (the result equals ``float(text)``); anything else (more than 19
significant digits, nested values, escapes, NaN/Infinity literals, differing keys) makes
:func:`parse_objects` report failure so the caller can fall back to ``json.loads``.

Algorithms (implemented here from the papers; the tables are computed at import):

* Ryu: Ulf Adams, "Ryu: fast float-to-string conversion", Proceedings of the 39th ACM
  SIGPLAN Conference on Programming Language Design and Implementation (PLDI 2018),
  pp. 270-282, doi:10.1145/3192366.3192369. The shortest digits that round-trip; the layout
  around them (fixed or exponent form, ``1e+16``, ``-0.0``) is CPython's ``float.__repr__``.
* Eisel-Lemire: Daniel Lemire, "Number parsing at a gigabyte per second", Software: Practice
  and Experience 51(8), 2021, pp. 1700-1727, doi:10.1002/spe.2984 (the algorithm of Michael
  Eisel); with William D. Clinger's exact fast path, "How to read floating point numbers
  accurately", PLDI 1990.

Why byte-identical with ``json.dumps``: see docs/messages.md ("MCAP log"). In short, one
message logged per row by :meth:`McapLogger.log_block` and by :meth:`McapLogger.log` must give
the same file, so the tests can hold the compiled encoder to the standard library byte for
byte, and a replay's log compares with the daemon's by bytes or hash.

All kernels are ``@njit(cache=True)``: the first call compiles (or loads the cache; a cold
compile takes some seconds, :func:`warm_up` does it ahead). The kernels that allocate nothing are
compiled without numba's reference counting (its atomic incref/decref on every array argument
otherwise costs more than the parsing).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit

from service.compat.numba import NO_NRT

# kernels that allocate nothing: compiled without NRT reference counting
_LEAF = {"cache": True, "error_model": "numpy", "nogil": True, **NO_NRT}
_INLINE = {**_LEAF, "inline": "always"}  # small helpers: inlined into their callers

__all__ = [
    "MSG_OPCODE",
    "warm_up",
    "RowFormat",
    "row_format",
    "encode_records",
    "scan_records",
    "parse_objects",
    "parse_number",
    "format_float",
]

MSG_OPCODE = 0x05
_M64 = (1 << 64) - 1
_U0 = np.uint64(0)
_U1 = np.uint64(1)
_U32 = np.uint64(32)
_LO32 = np.uint64(0xFFFFFFFF)
_MANT = np.uint64((1 << 52) - 1)
_HIDDEN = np.uint64(1 << 52)
_SIGN = np.uint64(1 << 63)


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


def _el_table() -> np.ndarray:
    """Eisel-Lemire's 128-bit truncated 5^q for q in [-342, 308] as (high, low) pairs."""
    t = np.empty((651, 2), np.uint64)
    for q in range(-342, 309):
        if q < 0:
            p5 = 5**-q
            z = p5.bit_length()
            if q >= -27:
                c = (1 << (z + 127)) // p5 + 1
            else:
                c = (1 << (2 * z + 128)) // p5 + 1
                while c >= 1 << 128:
                    c >>= 1
        else:
            c = 5**q
            while c < 1 << 127:
                c <<= 1
            while c >= 1 << 128:
                c >>= 1
        t[q + 342, 0], t[q + 342, 1] = c >> 64, c & _M64
    return t


_POW5_INV, _POW5 = _ryu_tables()
_EL_POW5 = _el_table()
_POW10 = np.array([10.0**i for i in range(23)])
_POW10_U64 = np.array([10**i for i in range(20)], np.uint64)
_DIGITS2 = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), np.uint8).copy()


# ----------------------------------------------------------------------------- arithmetic


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
    end = _encode(values, fmt.isint, fmt.keys, fmt.key_off, channel_id, seq0, log_times, buf, ends)
    return buf[:end], ends


# ----------------------------------------------------------------------------- parsing


@njit(**_INLINE)
def _clz(w):
    n = 0
    for s in (32, 16, 8, 4, 2, 1):
        if w >> np.uint64(64 - s) == _U0:
            n += s
            w <<= np.uint64(s)
    return n


@njit(**_LEAF)
def _to_double(w, q):
    """Correctly rounded w * 10**q as a positive double (w > 0, w < 10**19)."""
    if w <= np.uint64(1 << 53) and -22 <= q <= 22:
        x = np.float64(w)
        return x * _POW10[q] if q >= 0 else x / _POW10[-q]
    if q < -342:
        return 0.0
    if q > 308:
        return np.inf
    lz = _clz(w)
    w <<= np.uint64(lz)
    hi5 = _EL_POW5[q + 342, 0]
    lo5 = _EL_POW5[q + 342, 1]
    fh, fl = _umul128(w, hi5)
    if fh & np.uint64(0x1FF) == np.uint64(0x1FF):
        sh, _sl = _umul128(w, lo5)
        fl2 = fl + sh
        if sh > fl2:
            fh += _U1
        fl = fl2
    upper = np.int64(fh >> np.uint64(63))
    shift = np.uint64(upper + 9)
    mant = fh >> shift
    power2 = (((152170 + 65536) * q) >> 16) + 63 + upper - lz + 1023
    if power2 <= 0:
        if -power2 + 1 >= 64:
            return 0.0
        mant >>= np.uint64(-power2 + 1)
        mant += mant & _U1
        mant >>= _U1
        p2 = _U0 if mant < _HIDDEN else _U1
        return np.uint64(mant | (p2 << np.uint64(52))).view(np.float64)
    if fl <= _U1 and -4 <= q <= 23 and (mant & np.uint64(3)) == _U1 and (mant << shift) == fh:
        mant &= ~_U1
    mant += mant & _U1
    mant >>= _U1
    if mant >= np.uint64(2 << 52):
        mant = _HIDDEN
        power2 += 1
    mant &= ~_HIDDEN
    if power2 >= 0x7FF:
        return np.inf
    return np.uint64(mant | (np.uint64(power2) << np.uint64(52))).view(np.float64)


@njit(**_INLINE)
def _load8(buf, p):
    v = _U0
    for i in range(8):
        v |= np.uint64(buf[p + i]) << np.uint64(8 * i)
    return v


@njit(**_INLINE)
def _is8digits(v):
    f0 = np.uint64(0xF0F0F0F0F0F0F0F0)
    return ((v & f0) | (((v + np.uint64(0x0606060606060606)) & f0) >> np.uint64(4))) == np.uint64(
        0x3333333333333333
    )


@njit(**_INLINE)
def _parse8(v):
    """Value of 8 ASCII digits packed little-endian in v (SWAR)."""
    mask = np.uint64(0x000000FF000000FF)
    v -= np.uint64(0x3030303030303030)
    v = v * np.uint64(10) + (v >> np.uint64(8))
    return (
        (v & mask) * np.uint64(100 + (1000000 << 32))
        + ((v >> np.uint64(16)) & mask) * np.uint64(1 + (10000 << 32))
    ) >> _U32


@njit(**_INLINE)
def _digits(buf, p, e, w):
    """Consume the digits at p: returns (end, w * 10**count + their value), mod 2**64."""
    e8 = np.uint64(100000000)
    while p + 8 <= e:
        v = _load8(buf, p)
        if not _is8digits(v):
            break
        w = w * e8 + _parse8(v)
        p += 8
    ten = np.uint64(10)
    while p < e:
        d = np.uint64(buf[p]) - np.uint64(48)
        if d >= ten:
            break
        w = w * ten + d
        p += 1
    return p, w


@njit(**_INLINE)
def _number_inl(buf, p, e):
    """JSON number at p (strict grammar). Returns (end, value, ok); ok False if the text
    is not a JSON number or has more than 19 significant digits."""
    neg = False
    if p < e and buf[p] == 45:
        neg = True
        p += 1
    if p >= e:
        return p, 0.0, False
    s0 = p
    c = buf[p]
    if c == 48:
        p += 1
        w = _U0
        if p < e and 48 <= buf[p] <= 57:
            return p, 0.0, False  # leading zero
    elif 49 <= c <= 57:
        p, w = _digits(buf, p, e, _U0)
    else:
        return p, 0.0, False
    n_int = p - s0
    n_frac = 0
    is_float = False
    if p < e and buf[p] == 46:
        is_float = True
        p += 1
        f0 = p
        p, w = _digits(buf, p, e, w)
        n_frac = p - f0
        if n_frac == 0:
            return p, 0.0, False
    if n_int + n_frac > 19:  # too many digits unless leading zeros make up the excess
        lz = 0
        if c == 48:
            lz = 1
            while lz - 1 < n_frac and buf[s0 + 1 + lz] == 48:
                lz += 1
        if n_int + n_frac - lz > 19:
            return p, 0.0, False
    scale = -n_frac
    if p < e and (buf[p] == 101 or buf[p] == 69):
        is_float = True
        p += 1
        eneg = False
        if p < e and (buf[p] == 43 or buf[p] == 45):
            eneg = buf[p] == 45
            p += 1
        if p >= e or not 48 <= buf[p] <= 57:
            return p, 0.0, False
        x = 0
        while p < e and 48 <= buf[p] <= 57:
            if x < 100000:
                x = x * 10 + (buf[p] - 48)
            p += 1
        scale += -x if eneg else x
    if w == _U0:
        return p, (-0.0 if neg and is_float else 0.0), True  # json: "-0" is the int 0
    v = _to_double(w, scale)
    return p, (-v if neg else v), True


@njit(**_LEAF)
def _number(buf, p, e):
    """:func:`_number_inl` as a call (for the callers that are not hot)."""
    return _number_inl(buf, p, e)


@njit(**_LEAF)
def _parse_numbers(buf, starts, ends, out):
    """Parse each buf[starts[k]:ends[k]] into out[k]; returns the count parsed (for tests)."""
    for k in range(starts.size):
        p, v, ok = _number(buf, starts[k], ends[k])
        if not ok or p != ends[k]:
            return k
        out[k] = v
    return starts.size


def parse_number(texts: list[str]) -> np.ndarray:
    """The compiled JSON number parser on each text (for tests); NaN where it declines."""
    raw = [t.encode() for t in texts]
    buf = np.frombuffer(b"".join(raw) or b"\0", np.uint8)
    ends = np.cumsum([len(r) for r in raw]).astype(np.int64)
    starts = ends - np.array([len(r) for r in raw], np.int64)
    out = np.full(len(raw), np.nan)
    k = 0
    while k < len(raw):
        k = _parse_numbers(buf, starts[k:], ends[k:], out[k:]) + k
        if k < len(raw):
            k += 1
    return out


@njit(**_INLINE)
def _ws(buf, p, e):
    while p < e:
        c = buf[p]
        if c != 32 and c != 9 and c != 10 and c != 13:
            break
        p += 1
    return p


@njit(**_INLINE)
def _value(buf, p, e):
    """JSON scalar at p: (end, value, ok). Strings (plain ASCII, no escapes) and null -> NaN,
    true/false -> 1/0; ok False for anything else (nested values, escapes, NaN literals)."""
    c = buf[p]
    if c == 34:
        p += 1
        while p < e and buf[p] != 34:
            c = buf[p]
            if c == 92 or c < 32 or c >= 128:
                return p, 0.0, False
            p += 1
        if p >= e:
            return p, 0.0, False
        return p + 1, np.nan, True
    if c == 110:
        if p + 4 > e or buf[p + 1] != 117 or buf[p + 2] != 108 or buf[p + 3] != 108:
            return p, 0.0, False
        return p + 4, np.nan, True
    if c == 116:
        if p + 4 > e or buf[p + 1] != 114 or buf[p + 2] != 117 or buf[p + 3] != 101:
            return p, 0.0, False
        return p + 4, 1.0, True
    if c == 102:
        if (
            p + 5 > e
            or buf[p + 1] != 97
            or buf[p + 2] != 108
            or buf[p + 3] != 115
            or buf[p + 4] != 101
        ):
            return p, 0.0, False
        return p + 5, 0.0, True
    return _number(buf, p, e)


@njit(**_LEAF)
def _object(buf, p, e, ks, kl, vs, ve, nk, record, vals, row):
    """Parse one flat JSON object in buf[p:e]. record: store the key spans in ks/kl and the
    value spans in vs/ve and return the key count; else compare the keys with ks/kl[:nk]
    and store the values in vals[row]. Returns -1 if the object is not understood (or the
    keys differ)."""
    p = _ws(buf, p, e)
    if p >= e or buf[p] != 123:
        return -1
    p = _ws(buf, p + 1, e)
    if p < e and buf[p] == 125:
        p = _ws(buf, p + 1, e)
        return 0 if (p == e and (record or nk == 0)) else -1
    f = 0
    while True:
        # key
        if p >= e or buf[p] != 34:
            return -1
        p += 1
        s = p
        while p < e and buf[p] != 34:
            c = buf[p]
            if c == 92 or c < 32:
                return -1
            p += 1
        if p >= e:
            return -1
        n = p - s
        if record:
            if f >= ks.size:
                return -1
            ks[f] = s
            kl[f] = n
        else:
            if f >= nk or kl[f] != n:
                return -1
            r = ks[f]
            for i in range(n):
                if buf[s + i] != buf[r + i]:
                    return -1
        p = _ws(buf, p + 1, e)
        if p >= e or buf[p] != 58:
            return -1
        p = _ws(buf, p + 1, e)
        if p >= e:
            return -1
        v0 = p
        p, v, ok = _value(buf, p, e)
        if not ok:
            return -1
        if record:
            vs[f] = v0
            ve[f] = p
        else:
            vals[row, f] = v
        f += 1
        p = _ws(buf, p, e)
        if p >= e:
            return -1
        if buf[p] == 44:
            p = _ws(buf, p + 1, e)
            continue
        if buf[p] != 125:
            return -1
        p = _ws(buf, p + 1, e)
        if p != e:
            return -1
        if not record and f != nk:
            return -1
        return f


@njit(**_LEAF)
def _object_like(buf, p, e, seg_s, seg_n, nk, vals, row):
    """An object whose bytes around the values equal the first object's (segment f, before
    value f, is buf[seg_s[f]:seg_s[f] + seg_n[f]]; segment nk follows the last value): its
    values into vals[row]. False if the bytes differ or a value is not understood."""
    for f in range(nk + 1):
        n = seg_n[f]
        if p + n > e:
            return False
        r = seg_s[f]
        for i in range(n):
            if buf[p + i] != buf[r + i]:
                return False
        p += n
        if f == nk:
            break
        if p >= e:
            return False
        c = buf[p]
        if c == 45 or 48 <= c <= 57:
            p, v, ok = _number_inl(buf, p, e)
        else:
            p, v, ok = _value(buf, p, e)
        if not ok:
            return False
        vals[row, f] = v
    return p == e


@njit(cache=True, nogil=True)
def _objects(buf, offs, lens):
    n = offs.size
    cap = lens[0] // 4 + 1
    ks = np.empty(cap, np.int64)
    kl = np.empty(cap, np.int64)
    vs = np.empty(cap, np.int64)
    ve = np.empty(cap, np.int64)
    dummy = np.empty((0, 0), np.float64)
    s0 = offs[0]
    e0 = s0 + lens[0]
    zero = np.int64(0)  # not literals: one compiled _object for both calls
    nk = _object(buf, s0, e0, ks, kl, vs, ve, zero, np.bool_(True), dummy, zero)
    if nk < 0:
        return False, ks[:0], kl[:0], dummy
    seg_s = np.empty(nk + 1, np.int64)
    seg_n = np.empty(nk + 1, np.int64)
    prev = s0
    for f in range(nk):
        seg_s[f] = prev
        seg_n[f] = vs[f] - prev
        prev = ve[f]
    seg_s[nk] = prev
    seg_n[nk] = e0 - prev
    vals = np.empty((n, nk), np.float64)
    for k in range(n):
        p = offs[k]
        e = p + lens[k]
        if (
            not _object_like(buf, p, e, seg_s, seg_n, nk, vals, k)
            and _object(buf, p, e, ks, kl, vs, ve, nk, np.bool_(False), vals, k) < 0
        ):
            return False, ks[:0], kl[:0], dummy
    return True, ks[:nk], kl[:nk], vals


def parse_objects(
    buf: np.ndarray, offs: np.ndarray, lens: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Flat JSON objects buf[offs[k]:offs[k]+lens[k]] (N >= 1) with the same key bytes.

    Returns (key starts, key lengths, values (N, F) float64) with null -> NaN, true/false ->
    1/0, strings -> NaN, numbers equal to ``float(text)``; ``None`` if any object is not
    understood (then use ``json.loads``).
    """
    ok, ks, kl, vals = _objects(buf, offs, lens)
    return (ks, kl, vals) if ok else None


@njit(**_INLINE)
def _get_u64(buf, p, n):
    v = _U0
    for i in range(n):
        v |= np.uint64(buf[p + i]) << np.uint64(8 * i)
    return v


@njit(**_LEAF)
def _scan(buf):
    end = buf.size
    pos = 0
    n = 0
    while pos < end:
        if end - pos < 9:
            return -1, n
        ln = _get_u64(buf, pos + 1, 8)
        if ln > np.uint64(end - pos - 9):
            return -2, n
        if buf[pos] == MSG_OPCODE and ln < np.uint64(22):
            return -3, n
        pos += 9 + np.int64(ln)
        n += 1
    return 0, n


@njit(**_LEAF)
def _fill(buf, ops, starts, lens, cids, lts):
    pos = 0
    for k in range(ops.size):
        op = buf[pos]
        ln = np.int64(_get_u64(buf, pos + 1, 8))
        ops[k] = op
        starts[k] = pos + 9
        lens[k] = ln
        if op == MSG_OPCODE:
            cids[k] = np.int64(_get_u64(buf, pos + 9, 2))
            lts[k] = _get_u64(buf, pos + 15, 8)
        else:
            cids[k] = -1
            lts[k] = _U0
        pos += 9 + ln


def scan_records(
    buf: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Records of a decompressed chunk: (opcode, body start, body length, channel id or -1,
    log_time) arrays. Raises ValueError if a record overruns the chunk."""
    status, n = _scan(buf)
    if status:
        raise ValueError(
            {-1: "record header overruns its chunk", -2: "record overruns its chunk"}.get(
                status, "message record too short"
            )
        )
    ops = np.empty(n, np.uint8)
    starts = np.empty(n, np.int64)
    lens = np.empty(n, np.int64)
    cids = np.empty(n, np.int64)
    lts = np.empty(n, np.uint64)
    _fill(buf, ops, starts, lens, cids, lts)
    return ops, starts, lens, cids, lts


def warm_up() -> None:
    """Compile (or load from the cache) the kernels of the write and read paths."""
    fmt = row_format(("seq", "x"), frozenset({"seq"}))
    recs, ends = encode_records(fmt, np.array([[1.0, 0.5]]), 1, 0, np.zeros(1, np.int64))
    ops, starts, lens, _cids, _lts = scan_records(recs)
    parse_objects(recs, starts + 22, lens - 22)
