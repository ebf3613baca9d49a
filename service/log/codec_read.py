"""The MCAP codec's reading kernels (:func:`scan_records`, :func:`parse_objects`,
:func:`parse_number`): the records of a decompressed chunk, then runs of flat JSON objects
with the same key bytes into (N, F) float64 arrays, numbers correctly rounded by Clinger's
fast path or Eisel-Lemire. See :mod:`service.log.codec`."""

from __future__ import annotations

import numpy as np
from numba import njit

from service.log.codec_arith import (
    _HIDDEN,
    _INLINE,
    _LEAF,
    _M64,
    _U0,
    _U1,
    _U32,
    MSG_OPCODE,
    _umul128,
    readonly,
)

# ----------------------------------------------------------------------------- tables


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


_EL_POW5 = _el_table()
_POW10 = np.array([10.0**i for i in range(23)])


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
    ok, ks, kl, vals = _objects(readonly(buf), offs, lens)
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
    buf = readonly(buf)
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
