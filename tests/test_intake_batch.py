"""The intake's compiled batch (``Intake.take`` with ``service.wire.kernels.intake_batch``)
applies the clock and sequence rules exactly as ``intake.accept`` does message by message:
same accepted samples, counters, stream state (bit for bit), events in the same order."""

from __future__ import annotations

import json
import logging
import math
import random
import time

import numpy as np
import pytest

from service.daemon import RateLimitedLog
from service.daemon.block import Event, Part
from service.daemon.intake import ClockCheck, Intake
from service.wire import messages as m

T0 = 1.7e9  # a Unix-time sample clock
KEYS = [f"fleet/AC{a:03d}/act{a}/meas" for a in range(3)]
CH = {"x_cmd": 0.01, "i": 0.002, "x_s": 1e-5, "x_j": 0.02, "p1": 1.1e7, "p2": 0.9e7,
      "p_sr": 2.0e7}  # fmt: skip


def intake(**kw) -> Intake:
    return Intake(
        queue_size=100_000, max_bytes=kw.pop("max_bytes", 65536), clock=ClockCheck(**kw),
        max_batch=500, bad_log=RateLimitedLog(logging.getLogger("test"), 60),
    )  # fmt: skip


def payload(seqs, ts, **over) -> bytes:
    return m.encode_meas([{**CH, "seq": s, "t": t, **over} for s, t in zip(seqs, ts, strict=True)])


def good(k0: int, n: int = 10, t0: float = T0, p: float = 1e-3) -> bytes:
    return payload(range(k0, k0 + n), [t0 + k * p for k in range(k0, k0 + n)])


def state_of(it: Intake) -> dict:
    out = {}
    for key, st in it.actuators.items():
        out[key] = {
            k: getattr(st, k)
            for k in (
                "messages",
                "samples",
                "gaps",
                "restarts",
                "bad",
                "first_seq",
                "last_seq",
                "last_t",
                "period",
                "resync",
                "refused",
                "silent",
            )  # fmt: skip
        }
    out["unknown"] = dict(it.unknown)
    return out


def trace(blocks) -> list:
    """Everything a block passes on: its log (parts' accepted samples, events), restarts and
    the concatenated arrays."""
    out = []
    for b in blocks:
        for e in b.log:
            if isinstance(e, Part):
                out.append(("part", e.key, e.j0, e.a.seq[e.j0 :].tolist(), e.a.t[e.j0 :].tolist(),
                            np.nan_to_num(e.a.values[e.j0 :], nan=-1.0).tolist()))  # fmt: skip
            else:
                assert isinstance(e, Event)
                out.append(("event", e.st.name, e.kind, e.t, e.value))
        out.append(("restarts", list(b.restarts)))
        if b.parts:
            seq, t, ch = b.arrays()
            out.append(("arrays", seq.tolist(), t.tolist(), np.nan_to_num(ch, nan=-1.0).tolist()))
    return out


def run(msgs, batches, *, python: bool, silence_at=(), forget_at=(), **clock) -> tuple:
    """Submit ``msgs`` ((key, payload)) in takes of the ``batches`` sizes; ``python``: as a
    bytearray, which every message takes through ``accept`` one by one. ``silence_at`` /
    ``forget_at``: take indices before which every actuator is marked silent / forgotten."""
    it = intake(**clock)
    blocks = []
    k = 0
    for j, n in enumerate(batches):
        if j in silence_at:
            for st in it.actuators.values():
                st.silent = True
        if j in forget_at:
            for key in list(it.actuators):
                it.forget(key)
        for key, p in msgs[k : k + n]:
            it.submit(key, bytearray(p) if python else p)  # a key that names none: refused
        k += n
        blk = it.take()
        if blk is not None:
            blocks.append(blk)
    return state_of(it), trace(blocks)


def scenario(rng: random.Random, n_msgs: int) -> list[tuple[str, bytes]]:
    """Messages of 3 actuators with every irregularity the rules know."""
    now = time.time()
    nxt = {k: 0 for k in KEYS}  # next seq
    t0 = {k: T0 for k in KEYS}  # t of seq 0
    sent: dict[str, list[bytes]] = {k: [] for k in KEYS}
    out = []
    broken = 0
    for _ in range(n_msgs):
        key = rng.choice(KEYS)
        s, n = nxt[key], rng.randint(1, 12)
        what = rng.random()

        def ts(k0, n, base=None, key=key):
            b = t0[key] if base is None else base
            return [b + k * 1e-3 for k in range(k0, k0 + n)]

        if what < 0.55 or not sent[key]:
            p = payload(range(s, s + n), ts(s, n))
            nxt[key] = s + n
        elif what < 0.62:  # a gap
            s += rng.randint(1, 30)
            p = payload(range(s, s + n), ts(s, n))
            nxt[key] = s + n
        elif what < 0.67:  # a duplicate of the last message, or an old message late
            p = sent[key][-1] if rng.random() < 0.5 else rng.choice(sent[key])
        elif what < 0.71:  # the clock jumps forward for good
            t0[key] += rng.choice([100.0, 3600.0])
            p = payload(range(s, s + n), ts(s, n))
            nxt[key] = s + n
        elif what < 0.74:  # a reboot: the clock back at 1970, the sequence at 0 or not
            t0[key] = rng.choice([0.0, 5.0]) - (s * 1e-3 if rng.random() < 0.5 else 0.0)
            if rng.random() < 0.5:
                t0[key], s = 0.0, 0
            p = payload(range(s, s + n), ts(s, n))
            nxt[key] = s + n
        elif what < 0.77:  # the publisher restarts its sequence, time goes on
            t0[key] += s * 1e-3
            s = 0
            p = payload(range(s, s + n), ts(s, n))
            nxt[key] = s + n
        elif what < 0.80:  # one sample far ahead, inside the message
            tt = ts(s, n)
            tt[rng.randrange(n)] += 1e5
            tt = sorted(tt)
            p = payload(range(s, s + n), tt)
            nxt[key] = s + n
        elif what < 0.82:  # ahead of the receiving clock
            p = payload(range(s, s + n), ts(s, n, base=now + 1e3))
            nxt[key] = s + n
        elif what < 0.85:  # samples closer than the stream's period, or slower
            f = rng.choice([0.3, 3.5])
            p = payload(range(s, s + n), [t0[key] + s * 1e-3 + f * 1e-3 * j for j in range(n)])
            nxt[key] = s + n
        elif what < 0.88:  # channels absent
            p = m.encode_meas([{"seq": s + j, "t": t0[key] + (s + j) * 1e-3, "p1": 1e7}
                               for j in range(n)])  # fmt: skip
            nxt[key] = s + n
        elif what < 0.91:  # JSON
            p = m.encode_meas([{**CH, "seq": s + j, "t": t0[key] + (s + j) * 1e-3}
                               for j in range(n)], "json")  # fmt: skip
            nxt[key] = s + n
        elif what < 0.95:  # broken: NaN, not increasing, bad mask, truncated, empty, oversize
            broken += 1
            bad = broken % 6
            if bad == 0:
                p = payload(range(s, s + n), ts(s, n), p1=math.nan)
            elif bad == 1:
                p = payload([s] * 2, [t0[key] + s * 1e-3] * 2)
            elif bad == 2:
                b = bytearray(good(s, n, t0[key]))
                b[8 + 16] = 0xFF
                p = bytes(b)
            elif bad == 3:
                p = good(s, n, t0[key])[:-5]
            elif bad == 4:
                p = b""
            else:
                p = good(s, 200, t0[key])  # 14608 bytes: over the max_bytes of these runs
        else:  # a message of a key that names no actuator
            out.append(("fleet/AC001/x/y/meas", good(s, n)))
            continue
        sent[key].append(p)
        out.append((key, p))
    return out


def batches_of(rng: random.Random, n: int) -> list[int]:
    out = []
    while sum(out) < n:
        out.append(rng.choice([1, 2, 3, 7, 20, 60]))
    return out


@pytest.mark.parametrize("seed", range(12))
def test_batches_equal_message_by_message(seed):
    """Random streams with duplicates, late and out-of-order messages, gaps, clock steps
    forward and back, restarts, samples ahead of the stream and of the receiving clock,
    broken and JSON messages, silences and forgotten streams: taken in batches of random
    sizes through the compiled path, the daemon's state and every block equal those of the
    message-by-message Python path."""
    rng = random.Random(seed)
    msgs = scenario(rng, 400)
    sizes = batches_of(rng, len(msgs))
    marks = {"silence_at": {rng.randrange(len(sizes)) for _ in range(3)},
             "forget_at": {rng.randrange(len(sizes))}}  # fmt: skip
    ref = run(msgs, [1] * len(msgs), python=True, max_bytes=8192, **_marks_for(marks, sizes))
    got = run(msgs, sizes, python=False, max_bytes=8192, **marks)
    assert got[0] == ref[0]
    assert _merge(got[1]) == _merge(ref[1])
    st = got[0]
    # the scenario met every rule
    bad = {r for k in KEYS for r in st[k]["bad"]}
    assert {"clock", "duplicate", "out_of_order", "non_finite", "malformed"} <= bad, bad
    assert sum(st[k]["restarts"] for k in KEYS) > 0 and sum(st[k]["gaps"] for k in KEYS) > 0


def _marks_for(marks: dict, sizes: list[int]) -> dict:
    """The take indices of one message per take at which the batched run has its marks."""
    starts = np.concatenate(([0], np.cumsum(sizes)))
    return {k: {int(starts[j]) for j in v} for k, v in marks.items()}


def _merge(tr: list) -> list:
    """A trace without the block boundaries: the per-block entries (restarts, the arrays)
    concatenated, the log kept in order."""
    log, restarts, seq, t, ch = [], [], [], [], []
    for e in tr:
        if e[0] == "restarts":
            restarts += e[1]
        elif e[0] == "arrays":
            seq += e[1]
            t += e[2]
            ch += e[3]
        else:
            log.append(e)
    return [log, restarts, seq, t, ch]


def test_a_refused_sample_inside_a_batch_diverts_only_its_stream():
    """In one take: a good message, one with a sample far ahead, then good ones of the same
    stream and of another: the far sample alone is refused, the rest accepted, in order."""
    it = intake()
    a, b = KEYS[0], KEYS[1]
    far = payload([10], [T0 + 1e6])
    for key, p in [(a, good(0)), (b, good(0)), (a, far), (a, good(11)), (b, good(10)),
                   (a, good(21))]:  # fmt: skip
        it.submit(key, p)
    blk = it.take()
    assert [(p.key, p.a.seq[p.j0 :].tolist()[:1]) for p in blk.parts] == [
        (a, [0]), (b, [0]), (a, [11]), (b, [10]), (a, [21])]  # fmt: skip
    sa, sb = it.actuators[a], it.actuators[b]
    assert sa.bad == {"clock": 1} and sa.samples == 30 and sa.last_seq == 30 and sa.gaps == 0
    assert sb.bad == {} and sb.samples == 20 and sb.last_t == T0 + 19e-3
    seq, _, _ = blk.arrays()
    assert seq.tolist() == [*range(10), *range(10), *range(11, 21), *range(10, 20),
                            *range(21, 31)]  # fmt: skip


def test_a_resumed_stream_logs_its_last_time_before_the_batch():
    """A silent stream's messages in one take: the ``resumed`` event carries the last
    accepted time before them, and comes before their samples."""
    it = intake()
    it.submit(KEYS[0], good(0))
    it.take()
    it.actuators[KEYS[0]].silent = True
    it.submit(KEYS[0], good(10))
    it.submit(KEYS[0], good(20))
    blk = it.take()
    assert isinstance(blk.log[0], Event) and blk.log[0].kind == "resumed"
    assert blk.log[0].t == T0 + 9e-3
    assert [type(e).__name__ for e in blk.log] == ["Event", "Part", "Part"]
    assert it.actuators[KEYS[0]].last_seq == 29


def test_the_first_message_sets_the_state_a_later_check_uses():
    """Two messages of a new stream in one take: the second is checked against the first's
    time and the period estimated from it (a sample 1 s ahead of 10 ms of stream: refused)."""
    it = intake()
    s, t = list(range(10, 20)), [T0 + k * 1e-3 for k in range(10, 20)]
    t[-1] += 1.0
    it.submit(KEYS[0], good(0))
    it.submit(KEYS[0], payload(s, t))
    blk = it.take()
    st = it.actuators[KEYS[0]]
    assert st.bad == {"clock": 1} and st.samples == 19 and st.first_seq == 0
    assert st.period == pytest.approx(1e-3, rel=1e-4)
    assert sum(len(p.a.t) - p.j0 for p in blk.parts) == 19


def test_a_json_message_between_binary_ones_keeps_its_place():
    it = intake()
    js = json.dumps({"v": 1, "samples": [{"seq": 10, "t": T0 + 0.010, **CH}]}).encode()
    for p in (good(0), js, good(11)):
        it.submit(KEYS[0], p)
    blk = it.take()
    assert blk.arrays()[0].tolist() == list(range(21))
    assert it.actuators[KEYS[0]].samples == 21 and it.actuators[KEYS[0]].gaps == 0


def test_decode_into_agrees_with_the_scalar_decoder():
    """The batch decoder's verdict and values, message by message, are decode_meas's."""
    rng = random.Random(3)
    msgs = [p for _, p in scenario(rng, 300)]
    n = sum(map(len, msgs)) // m.REC_BYTES + 1
    seq, t, v = np.empty(n, np.int64), np.empty(n), np.empty((n, 7))
    start, count, status = m.decode_into(msgs, seq, t, v, 8192)
    for p, b0, nb, code in zip(msgs, start, count, status, strict=True):
        try:
            ref = m.decode_meas(p, 8192)
        except m.MessageError:
            assert code == m.BATCH_UNDECODED and nb == 0
            continue
        if p[:2] != b"SW":  # JSON: left to the Python decoder
            assert code == m.BATCH_UNDECODED
            continue
        assert code == m.BATCH_DECODED and nb == len(ref)
        assert seq[b0 : b0 + nb].tolist() == [s.seq for s in ref]
        assert t[b0 : b0 + nb].tolist() == [s.t for s in ref]
        want = [[math.nan if getattr(s, c) is None else getattr(s, c) for c in m.CHANNELS]
                for s in ref]  # fmt: skip
        np.testing.assert_array_equal(v[b0 : b0 + nb], np.array(want))


def test_a_first_message_ahead_of_the_receiving_clock_is_refused_in_a_batch():
    """The first message of a stream (no history to check it against), 100 s ahead of the
    receiving clock: refused, and the next (on time) accepted as the stream's first."""
    it = intake()
    now = time.time()
    it.submit(KEYS[0], payload([0], [now + 100.0]))
    it.submit(KEYS[0], good(1, t0=now - 1.0))
    blk = it.take()
    st = it.actuators[KEYS[0]]
    assert st.bad == {"clock": 1} and st.samples == 10 and st.first_seq == 1
    assert blk.arrays()[0].tolist() == list(range(1, 11))
