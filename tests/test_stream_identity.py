"""The stream identity of a unit's samples (service/store/identity.py, decision record 0033):
copies, prefixes, trims, rotation members, divergence and gaps told apart from the stored
summaries alone (block digests and edge mixes), 20,000 noisy samples."""

from __future__ import annotations

import numpy as np
import pytest

from service.store.identity import StreamDigest, StreamId, stream_source

N = 20_000


@pytest.fixture(scope="module")
def x():
    rng = np.random.default_rng(1)
    return np.column_stack([np.arange(N) * 1e-3, rng.normal(size=(N, 7))])


def _sid(x, stored=None, cuts=(), step=333):
    """The stream read in blocks of ``step`` samples, with a gap (a corrupt chunk) at each
    of ``cuts``; returns (its digest, its identity)."""
    d = StreamDigest(stored)
    a = 0
    for c in [*cuts, len(x)]:
        for s in range(a, c, step):
            d.add(x[s : min(s + step, c)])
        if c < len(x):
            d.cut()
        a = c
    return d, d.finish()


def _rel(new, old_x, **kw):
    _, old = _sid(old_x, **kw.pop("old", {}))
    d, n = _sid(new, {"s": old}, **kw)
    return d.relation(n, "s"), n, old


def test_blocks_are_set_by_the_samples_not_by_how_they_are_read(x):
    _, a = _sid(x, step=333)
    _, b = _sid(x, step=4096)
    assert a.key() == b.key() and stream_source("A/b", a) == stream_source("A/b", b)
    assert stream_source("A/b", a) != stream_source("A/c", a)  # the unit enters
    assert 40 < len(a.runs[0].blocks) < 200  # about one block per 256 samples
    assert StreamId.loads(a.dumps()).key() == a.key()


def test_a_copy_a_grown_log_and_a_partial_copy(x):
    r, _, _ = _rel(x, x)
    assert r.equal
    r, _, _ = _rel(x, x[:7000])  # the stored log was a partial ingest: the new one holds it
    assert r.holds and not r.inside and not r.equal
    r, _, _ = _rel(x[:7000], x)  # a partial copy of a stored log: inside it
    assert r.inside and not r.holds


@pytest.mark.parametrize("k", [1, 10, 100, 5000])
def test_a_trimmed_copy_is_inside_and_a_shared_prefix_then_other_samples_is_not(x, k):
    r, _, _ = _rel(x[k:], x)
    assert r.inside and not r.holds
    y = x.copy()
    y[N - k :, 1] += 1.0  # the same samples but the last k: another log
    r, _, _ = _rel(y, x)
    assert not r.inside and not r.holds and not r.equal and r.shared > 0
    r, _, _ = _rel(x, y)
    assert not r.inside and not r.holds


def test_a_rotation_set_and_its_members(x):
    for lo, hi in ((0, 10_000), (10_000, N), (3_333, 12_345)):
        r, _, _ = _rel(x, x[lo:hi])
        assert r.holds, (lo, hi)
        r, _, _ = _rel(x[lo:hi], x)
        assert r.inside, (lo, hi)


def test_a_damaged_copy_with_a_gap_is_held_by_the_repaired_log(x):
    damaged = np.concatenate([x[:8000], x[9000:]])
    _, d = _sid(damaged, cuts=[8000])
    assert len(d.runs) == 2
    dg, n = _sid(x, {"d": d})
    assert dg.relation(n, "d").holds
    y = x.copy()
    y[9500, 2] += 1e-9  # one sample after the gap differs: not held
    dg, n = _sid(y, {"d": d})
    assert not dg.relation(n, "d").holds


def test_short_streams_without_a_block_end(x):
    r, _, _ = _rel(x, x[100:150])
    assert r.holds
    r, _, _ = _rel(x[100:150], x)
    assert r.inside and not r.holds
