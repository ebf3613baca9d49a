"""The compiled part of the wire decoder (``service.wire.messages``) and of the intake's
acceptance checks (``service.daemon.intake``): kept apart so that importing the message types
does not import numba.

:func:`intake_batch` decodes a batch of binary ``meas`` messages (one buffer, no Python per
sample) and runs the common case of the intake's sequence and time checks on them: a message
whose samples are all accepted with no event. Every other message (refused samples, a
restart, a message that does not decode) is left to the Python code, which then sees the
stream state exactly as if every earlier message had been through it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.wire.format import BATCH_ACCEPTED as FAST
from service.wire.format import BATCH_DECODED as DECODED
from service.wire.format import BATCH_UNDECODED as UNDECODED
from service.wire.format import CHANNELS, REC_BYTES

__all__ = ["decode_message", "intake_batch"]

# the status of a message after intake_batch: FAST (decoded, and every sample accepted by the
# kernel, the stream state updated), DECODED (the acceptance left to the Python code),
# UNDECODED (not a valid binary message: decoded or refused by the Python code)
HEADER_BYTES = 8  # messages._HEADER
NCH = len(CHANNELS)


@njit(cache=True, inline="always")
def _word(buf, o, scratch):  # pragma: no cover - numba
    """The 8 bytes ``buf[o : o + 8]`` in ``scratch`` (aligned), for an int64/float64 view."""
    for i in range(8):
        scratch[i] = buf[o + i]


@njit(cache=True)
def _decode_one(buf, o, ln, max_bytes, seq, t, values, pos, scratch):  # pragma: no cover
    """Decode the binary message ``buf[o : o + ln]`` into ``seq``, ``t``, ``values`` from row
    ``pos``: its sample count, or -1 when it breaks a rule of ``messages._bin_count`` /
    ``messages._bin_rows`` or is not binary (the Python decoder then says why)."""
    if ln == 0 or ln > max_bytes or ln < HEADER_BYTES:
        return -1
    if buf[o] != 83 or buf[o + 1] != 87 or buf[o + 2] != 1 or buf[o + 3] != 77:  # SW, 1, M
        return -1
    n = (
        np.int64(buf[o + 4])
        | (np.int64(buf[o + 5]) << 8)
        | (np.int64(buf[o + 6]) << 16)
        | (np.int64(buf[o + 7]) << 24)
    )
    if n < 1 or n > 4096 or ln != HEADER_BYTES + n * REC_BYTES:
        return -1
    wi = scratch.view(np.int64)
    wf = scratch.view(np.float64)
    r = o + HEADER_BYTES
    for k in range(n):
        _word(buf, r, scratch)
        s_k = wi[0]
        _word(buf, r + 8, scratch)
        t_k = wf[0]
        m_k = buf[r + 16]
        if s_k < 0 or not np.isfinite(t_k) or m_k >= (1 << NCH):
            return -1
        if k > 0 and (s_k <= seq[pos + k - 1] or t_k <= t[pos + k - 1]):
            return -1
        seq[pos + k] = s_k
        t[pos + k] = t_k
        for b in range(NCH):
            if (m_k >> b) & 1:
                _word(buf, r + 17 + 8 * b, scratch)
                x = wf[0]
                if not np.isfinite(x):
                    return -1
                values[pos + k, b] = x
            else:
                values[pos + k, b] = np.nan
        r += REC_BYTES
    return n


@njit(cache=True)
def decode_message(buf, seq, t, values):  # pragma: no cover - numba
    """:func:`_decode_one` of the whole of ``buf`` (one message; no size limit)."""
    z, n = np.int64(0), np.int64(buf.shape[0])
    return _decode_one(buf, z, n, n, seq, t, values, z, np.empty(8, np.uint8))


@njit(cache=True)
def intake_batch(
    buf, offs, lens, max_bytes, slot, seq, t, values, start, count, status,
    has_last, divert, last_seq, refused, last_t, period, first_seq, gaps, samples,
    factor, tol_s, t_future,
):  # pragma: no cover - numba  # fmt: skip
    """Decode the messages ``buf[offs[k] : offs[k] + lens[k]]`` and accept the plain ones.

    Message k's samples go to rows ``start[k] : start[k] + count[k]`` of ``seq``, ``t``,
    ``values`` (``count[k]`` 0 when it does not decode: ``status`` UNDECODED). Message k is of
    stream ``slot[k]`` (-1: none, decoded only); the stream arrays (indexed by slot) hold its
    state as ``service.daemon.intake.ActuatorState`` does (``period`` NaN: None;
    ``first_seq`` -1: None). A message is FAST when ``intake.accept`` would accept all its
    samples with no event: none ahead of ``t_future`` (the receiving clock + future_s; inf
    for none), the first after the last accepted time, none ahead of what its sequence gap
    implies, the sequence not falling back; the kernel then updates the state (``gaps``,
    ``samples``: added counts) with the same arithmetic. At the first other message of a
    stream (and from the start for ``divert[s]``), the stream is diverted: its messages from
    there on are left to the Python code (DECODED or UNDECODED)."""
    scratch = np.empty(8, np.uint8)
    pos = 0
    for k in range(offs.shape[0]):
        n = _decode_one(buf, offs[k], lens[k], max_bytes, seq, t, values, pos, scratch)
        start[k] = pos
        if n < 0:
            count[k] = 0
            status[k] = UNDECODED
            if slot[k] >= 0:
                divert[slot[k]] = True
            continue
        count[k] = n
        pos += n
        s = slot[k]
        status[k] = DECODED
        if s < 0 or divert[s]:
            continue
        a, e = start[k], start[k] + n - 1
        plain = t[e] <= t_future
        if plain and has_last[s]:
            lt, ls = last_t[s], last_seq[s]
            plain = t[a] > lt and seq[a] > ls
            p = period[s]
            if np.isnan(p) and n > 1:
                p = float(t[e] - t[a]) / float(seq[e] - seq[a])
            if plain and not np.isnan(p):
                for j in range(a, e + 1):
                    ds = seq[j] - ls
                    if ds > 0 and t[j] > lt + factor * ds * p + tol_s:
                        plain = False
                        break
        if not plain:
            divert[s] = True
            continue
        s0 = seq[a]
        if has_last[s] and s0 > last_seq[s] + 1:
            gaps[s] += max(0, s0 - last_seq[s] - 1 - refused[s])
        refused[s] = 0
        if first_seq[s] < 0:
            first_seq[s] = s0
        gaps[s] += seq[e] - s0 - (n - 1)
        if n > 1:
            p = float(t[e] - t[a]) / float(seq[e] - s0)
            period[s] = p if np.isnan(period[s]) else 0.9 * period[s] + 0.1 * p
        last_seq[s], last_t[s] = seq[e], t[e]
        has_last[s] = True
        samples[s] += n
        status[k] = FAST
    return pos
